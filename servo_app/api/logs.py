"""``/api/sessions``: the servo process's session logs (one binary file per stream), to list and download."""

# No `from __future__ import annotations`: FastAPI reads the dependency annotations at runtime.
from collections.abc import Iterator
from pathlib import Path
from typing import Any

from fastapi import APIRouter, HTTPException
from fastapi.responses import StreamingResponse

from servo_app.api.deps import Service
from servo_app.api.models import Problem, SessionLogInfo

router = APIRouter(tags=["logs"])


@router.get("/api/sessions", response_model=list[SessionLogInfo], summary="List the session logs")
def sessions(service: Service) -> list[dict[str, Any]]:
    """The session logs in the service's var directory, newest first (open: no token)."""
    return service.session_logs()


_FILE = {"application/octet-stream": {"schema": {"type": "string", "format": "binary"}}}


def _first_bytes(path: Path, size: int, chunk: int = 1 << 16) -> Iterator[bytes]:
    with path.open("rb") as f:
        while size > 0 and (data := f.read(min(chunk, size))):
            size -= len(data)
            yield data


@router.get("/api/sessions/{name}", response_class=StreamingResponse, summary="Download a session log",
            responses={200: {"content": _FILE, "description": "the .srvlog file"},
                       404: {"model": Problem, "description": "no session log of that name"}})
def session_download(name: str, service: Service) -> StreamingResponse:
    """One ``.srvlog`` file by the name ``GET /api/sessions`` lists (``servo-app check`` reads it); the
    log of a running stream as far as it is written when asked."""
    # A name the file system cannot take (a NUL byte: ValueError; too long: OSError) names no log.
    try:
        if "\x00" in name:
            raise FileNotFoundError(f"no session log {name!r}")
        path = service.session_log_path(name)
    except (FileNotFoundError, ValueError, OSError) as exc:
        raise HTTPException(404, f"{exc}: list them with GET /api/sessions") from None
    # The bytes written when asked, and no more: the log of a running stream grows while it is sent,
    # and a file response read on to the end and sent more than its Content-Length (the client got a
    # broken response).
    size = path.stat().st_size
    return StreamingResponse(_first_bytes(path, size), media_type="application/octet-stream",
                             headers={"Content-Length": str(size),
                                      "Content-Disposition": f'attachment; filename="{path.name}"'})
