"""Janome robot profiles: ``configs/robots/janome/NAME.toml``, validated on load.

One format for both types (keys in docs/janome.md). Axes are always X Y Z R (mm, mm, mm, deg); a
SCARA profile adds ``[arm]`` (arm lengths, joint ranges, default configuration). Numbers that the
manual here does not give (strokes, speeds, accelerations, arm lengths) are configuration: set them
from the model's specification sheet. Errors name the file, the key and the value.
"""

from __future__ import annotations

import math
import os
import tomllib
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from servo_app.janome.kinematics import CartesianWorkspace, ScaraArm, ScaraWorkspace, Workspace
from servo_app.janome.protocol import Arm, RobotKind
from servo_app.robots.profile import ProfileError, find_profile_file, profile_names, search_dirs

JANOME_CONFIG_DIR = Path(__file__).resolve().parents[2] / "configs" / "robots" / "janome"
_KINDS = {"cartesian": RobotKind.CARTESIAN, "scara": RobotKind.SCARA}
_ARMS = {"righty": Arm.RIGHTY, "lefty": Arm.LEFTY}

Vec4 = tuple[float, float, float, float]


def janome_profile_dirs() -> list[Path]:
    """``$SERVO_APP_JANOME_ROBOTS`` (os.pathsep-separated) first, then configs/robots/janome."""
    return search_dirs("SERVO_APP_JANOME_ROBOTS", JANOME_CONFIG_DIR)


@dataclass(frozen=True)
class JanomeProfile:
    name: str
    display_name: str
    source: Path
    kind: RobotKind
    axis_min: Vec4  # X Y Z (mm) R (deg); SCARA X Y: bounding box of the work area
    axis_max: Vec4
    speed: Vec4  # per-axis maximum speed, mm/s and deg/s (PTP 100 %)
    accel: Vec4  # per-axis acceleration, mm/s^2 and deg/s^2 (configured)
    cp_speed: float  # lineMove maximum speed, mm/s
    cp_accel: float  # lineMove acceleration, mm/s^2
    home: Vec4  # where the simulator starts
    elbow: Arm  # SCARA: the arm configuration used when none is given (cartesian: righty, always)
    arm: ScaraArm | None  # SCARA only
    joint_speed: tuple[float, float] | None  # SCARA J1, J2 deg/s (PTP timing)
    joint_accel: tuple[float, float] | None  # SCARA J1, J2 deg/s^2
    step_s: float  # nominal time per streamed target
    max_step_mm: float  # longest XYZ step: what a stop may still travel
    max_step_deg: float  # longest R step

    def workspace(self, margin: float = 0.0) -> Workspace:
        """The reachable set, shrunk by ``margin`` (mm / deg) on every stroke."""
        lo = tuple(v + margin for v in self.axis_min)
        hi = tuple(v - margin for v in self.axis_max)
        if self.kind == RobotKind.CARTESIAN:
            return CartesianWorkspace(lo, hi)  # type: ignore[arg-type]
        assert self.arm is not None
        a = self.arm
        shrunk = ScaraArm(a.l1, a.l2, a.j1_min + margin, a.j1_max - margin, a.j2_min + margin, a.j2_max - margin,
                          a.singular_margin_deg + margin)
        return ScaraWorkspace(shrunk, lo, hi)  # type: ignore[arg-type]

    @property
    def pos_abs_max(self) -> np.ndarray:
        return np.maximum(np.abs(self.axis_min), np.abs(self.axis_max)) + 1.0


# ----------------------------------------------------------------------------------- loading


class _Reader:
    def __init__(self, path: Path) -> None:
        self.path = path

    def err(self, key: str, value: Any, why: str) -> ProfileError:
        return ProfileError(f"{self.path}: key '{key}' = {value!r} {why}")

    def get(self, data: dict[str, Any], key: str, prefix: str = "") -> Any:
        if key not in data:
            raise ProfileError(f"{self.path}: missing key '{prefix}{key}'")
        return data[key]

    def table(self, data: dict[str, Any], key: str) -> dict[str, Any]:
        value = self.get(data, key)
        if not isinstance(value, dict):
            raise self.err(key, value, "must be a table")
        return value

    def number(self, data: dict[str, Any], key: str, prefix: str = "", *, positive: bool = False,
               default: float | None = None) -> float:
        value = data.get(key, default) if default is not None else self.get(data, key, prefix)
        if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
            raise self.err(prefix + key, value, "is not a finite number")
        if positive and value <= 0:
            raise self.err(prefix + key, value, "must be > 0")
        return float(value)

    def vec4(self, data: dict[str, Any], key: str, prefix: str = "", *, positive: bool = False) -> Vec4:
        value = self.get(data, key, prefix)
        if not isinstance(value, list) or len(value) != 4:
            raise self.err(prefix + key, value, "must be a list of 4 numbers (X, Y, Z, R)")
        out = []
        for i, v in enumerate(value):
            if isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(v):
                raise self.err(f"{prefix}{key}[{i}]", v, "is not a finite number")
            if positive and v <= 0:
                raise self.err(f"{prefix}{key}[{i}]", v, "must be > 0")
            out.append(float(v))
        return (out[0], out[1], out[2], out[3])

    def choice(self, data: dict[str, Any], key: str, options: dict[str, Any], prefix: str = "",
               default: str | None = None) -> Any:
        value = data.get(key, default) if default is not None else self.get(data, key, prefix)
        if value not in options:
            raise self.err(prefix + key, value, f"must be one of {', '.join(map(repr, options))}")
        return options[value]


def find_janome_profile(name_or_path: str | os.PathLike[str]) -> Path:
    return find_profile_file(name_or_path, janome_profile_dirs(), "Janome robot")


def available_janome_profiles() -> list[str]:
    return profile_names(janome_profile_dirs())


def load_janome_profile(name_or_path: str | os.PathLike[str]) -> JanomeProfile:
    """Load and validate a Janome profile by name (``jr3000``, ``js3``) or by path to a TOML file."""
    path = find_janome_profile(name_or_path)
    try:
        data = tomllib.loads(path.read_text())
    except tomllib.TOMLDecodeError as exc:
        raise ProfileError(f"{path}: not valid TOML: {exc}") from exc
    rd = _Reader(path)
    name = rd.get(data, "name")
    if not isinstance(name, str) or not name:
        raise rd.err("name", name, "must be a non-empty string")
    kind = rd.choice(data, "type", _KINDS)
    axes = rd.table(data, "axes")
    lo, hi = rd.vec4(axes, "min", "axes."), rd.vec4(axes, "max", "axes.")
    for i in range(4):
        if lo[i] >= hi[i]:
            raise rd.err(f"axes.min[{i}]", lo[i], f"is not below axes.max[{i}] = {hi[i]}")
    cp = rd.table(data, "cp")
    link = data.get("link", {})
    if not isinstance(link, dict):
        raise rd.err("link", link, "must be a table")
    arm = joint_speed = joint_accel = None
    elbow = Arm.RIGHTY
    if kind == RobotKind.SCARA:
        arm, joint_speed, joint_accel, elbow = _scara(rd, rd.table(data, "arm"))
    elif "arm" in data:
        raise rd.err("arm", data["arm"], "is only for type = 'scara'")
    profile = JanomeProfile(
        name=name,
        display_name=str(data.get("display_name", name)),
        source=path,
        kind=kind,
        axis_min=lo,
        axis_max=hi,
        speed=rd.vec4(axes, "speed", "axes.", positive=True),
        accel=rd.vec4(axes, "accel", "axes.", positive=True),
        cp_speed=rd.number(cp, "speed_mm_s", "cp.", positive=True),
        cp_accel=rd.number(cp, "accel_mm_s2", "cp.", positive=True),
        home=rd.vec4(data, "home"),
        elbow=elbow,
        arm=arm,
        joint_speed=joint_speed,
        joint_accel=joint_accel,
        step_s=rd.number(link, "step_s", "link.", positive=True, default=0.1),
        max_step_mm=rd.number(link, "max_step_mm", "link.", positive=True, default=10.0),
        max_step_deg=rd.number(link, "max_step_deg", "link.", positive=True, default=20.0),
    )
    if not 0.02 <= profile.step_s <= 2.0:
        raise rd.err("link.step_s", profile.step_s, "must be in 0.02..2 s (10-20 targets per second is typical)")
    why = profile.workspace().check(np.array(profile.home), profile.elbow)
    if why is not None:
        raise rd.err("home", list(profile.home), f"is not reachable: {why.message}")
    return profile


def _scara(rd: _Reader, a: dict[str, Any]) -> tuple[ScaraArm, tuple[float, float], tuple[float, float], Arm]:
    p = "arm."
    arm = ScaraArm(
        l1=rd.number(a, "l1_mm", p, positive=True),
        l2=rd.number(a, "l2_mm", p, positive=True),
        j1_min=rd.number(a, "j1_min_deg", p),
        j1_max=rd.number(a, "j1_max_deg", p),
        j2_min=rd.number(a, "j2_min_deg", p),
        j2_max=rd.number(a, "j2_max_deg", p),
        singular_margin_deg=rd.number(a, "singular_margin_deg", p, default=1.0),
    )
    if arm.j1_min >= arm.j1_max:
        raise rd.err("arm.j1_min_deg", arm.j1_min, f"is not below arm.j1_max_deg = {arm.j1_max}")
    if arm.j2_min >= arm.j2_max:
        raise rd.err("arm.j2_min_deg", arm.j2_min, f"is not below arm.j2_max_deg = {arm.j2_max}")
    if arm.singular_margin_deg < 0:
        raise rd.err("arm.singular_margin_deg", arm.singular_margin_deg, "must be >= 0")
    speed = (rd.number(a, "j1_speed_deg_s", p, positive=True), rd.number(a, "j2_speed_deg_s", p, positive=True))
    accel = (rd.number(a, "j1_accel_deg_s2", p, positive=True), rd.number(a, "j2_accel_deg_s2", p, positive=True))
    elbow = rd.choice(a, "elbow", _ARMS, p, default="righty")
    return arm, speed, accel, elbow
