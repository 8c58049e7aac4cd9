"""Teach points: named joint positions and TCP poses kept in one JSON file under the var directory.

The file is rewritten whole for every change, atomically (a temporary file in the same directory,
flushed to disk, then renamed over the old one): a crash or power cut mid-write leaves the old file
or the new one, never half of either. It is read afresh each time, so a file edited by hand (or
copied from another cell) is taken as it is.
"""

from __future__ import annotations

import json
import os
import re
import tempfile
import threading
import time
from pathlib import Path
from typing import Annotated, Any

from pydantic import BaseModel, ConfigDict, Field, ValidationError

from servo_app.errors import CommandRejected

# Safe as a file name anywhere (no separators, no leading dot or dash), short enough for a pendant.
POINT_NAME_PATTERN = r"^[A-Za-z0-9][A-Za-z0-9_.-]{0,63}$"
POINT_NAME = re.compile(POINT_NAME_PATTERN)
FILE_VERSION = 1


Finite = Annotated[float, Field(allow_inf_nan=False)]


class TaughtPoint(BaseModel):
    """A taught point as the file holds it: the one check of every entry, for every route (the list
    and its answer's schema, teach, move, delete), so a hand-edited file is refused alike by all."""

    # strict: a hand-edited "12" or true is not a number; extra: fields of a later version are kept.
    model_config = ConfigDict(extra="allow", strict=True)
    name: str
    joints: list[Finite] = Field(description="commanded joints at teach time: deg (FANUC J1..J6), or mm and "
                                             "deg (Janome X Y Z R); what moving to the point goes back to")
    xyzwpr: list[Finite] = Field(description="the TCP pose the controller reported: X Y Z mm, W P R deg (world)")
    tool: str | None = Field(None, description="the tool whose TCP that pose is (points taught before tools: none)")
    model: str = Field(description="the robot profile it was taught on")
    backend: str = Field(description="the robot backend's registered name")
    taught_unix: Finite = Field(description="when it was taught (Unix s)")
    taught_by: str = Field(description="the lease holder and address that taught it")


def _taught(point: dict[str, Any]) -> str:
    """When and by whom, as far as the (possibly hand-edited) entry says."""
    by, at = point.get("taught_by"), point.get("taught_unix")
    when = time.strftime("%Y-%m-%d %H:%M:%S", time.localtime(at)) if isinstance(at, (int, float)) else None
    return " ".join(part for part in (f"by {by}" if by else None, when and f"at {when}") if part) or "earlier"


class PointStore:
    def __init__(self, path: Path) -> None:
        self.path = path
        self._lock = threading.Lock()  # one read-modify-write at a time (API worker threads)

    def _load(self) -> dict[str, dict[str, Any]]:
        try:
            doc = json.loads(self.path.read_text(encoding="utf-8"))
        except FileNotFoundError:
            return {}
        except (ValueError, OSError) as exc:
            raise CommandRejected(f"the teach point file {self.path} cannot be read ({exc}); "
                                  "fix it or move it away, then teach again") from None
        points = doc.get("points") if isinstance(doc, dict) else None
        if not isinstance(points, dict):
            raise CommandRejected(f"the teach point file {self.path} has no 'points' object; "
                                  "fix it or move it away, then teach again")
        for name, point in points.items():  # a hand-edited entry: refused here, not a 500 where it is used
            self._check(name, point)
        return points

    def _check(self, name: str, point: Any) -> None:
        """CommandRejected naming the entry, the field and what is wrong, unless ``point`` is one."""
        where, what = f"points.{name}", ""
        try:
            TaughtPoint.model_validate(point)
        except ValidationError as exc:
            err = exc.errors()[0]
            where += "".join(f".{p}" for p in err["loc"])
            value = "" if err["type"] == "missing" else f"={json.dumps(err['input'], default=str)[:200]}"
            # The entry itself: pydantic's text would name this class, not what a point is.
            why = err["msg"] if err["loc"] else f"not a point (an object with {', '.join(TaughtPoint.model_fields)})"
            what = f"{where}{value}: {why}"
        else:
            if point["name"] != name:
                what = f"{where}.name={json.dumps(point['name'])[:200]}: not the name it is filed under"
        if what:
            raise CommandRejected(f"the teach point file {self.path}: {what}; fix it or move it away, then "
                                  "teach again")

    def _store(self, points: dict[str, dict[str, Any]]) -> None:
        text = json.dumps({"version": FILE_VERSION, "points": points}, indent=2, sort_keys=True)
        try:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            fd, tmp = tempfile.mkstemp(prefix=".points-", suffix=".json", dir=self.path.parent)
        except OSError as exc:
            raise self._unwritable(exc) from None
        try:
            with os.fdopen(fd, "w", encoding="utf-8") as f:
                f.write(text)
                f.flush()
                os.fsync(f.fileno())
            os.replace(tmp, self.path)
        except BaseException as exc:
            Path(tmp).unlink(missing_ok=True)
            if isinstance(exc, OSError):  # a full or read-only disk: the old file stands, the change is refused
                raise self._unwritable(exc) from None
            raise

    def _unwritable(self, exc: OSError) -> CommandRejected:
        return CommandRejected(f"the teach point file {self.path} cannot be written ({exc.strerror or exc}); "
                               f"nothing changed: free disk space in {self.path.parent} (or make it writable), "
                               "then try again")

    def all(self) -> list[dict[str, Any]]:
        with self._lock:
            points = self._load()
            return [points[name] for name in sorted(points)]

    def get(self, name: str) -> dict[str, Any] | None:
        with self._lock:
            return self._load().get(name)

    def save(self, point: dict[str, Any], replace: bool = False) -> None:
        """Add the point named ``point["name"]``; one of that name is replaced only with ``replace``
        (an operator must not lose a taught point to a name typed twice)."""
        with self._lock:  # the check and the write under one lock: two teachers cannot both add it
            points = self._load()
            name = point["name"]
            old = points.get(name)
            if old is not None and not replace:
                raise CommandRejected(
                    f"a point named {name!r} is already taught ({_taught(old)}); nothing changed: to replace it "
                    f"with the arm's position now, teach it again with replace: POST /api/points/{name}?replace=true")
            points[name] = point
            self._store(points)

    def delete(self, name: str) -> bool:
        with self._lock:
            points = self._load()
            if points.pop(name, None) is None:
                return False
            self._store(points)
            return True
