"""Robot profiles: everything the servo core and the simulators need to know about one arm model.

Profiles are TOML files (``configs/robots/NAME.toml``), validated on load; errors name the file,
the key and the value. Joint ranges are in the model convention (each joint relative to its parent
link); speeds, accelerations and jerks are per FANUC axis (J3 measured from the horizontal).
Acceleration and jerk limits are *configured defaults*: FANUC does not publish them, a real
controller reports its own through the limit tables (packet type 3), which then take precedence.
"""

from __future__ import annotations

import math
import os
import tomllib
from dataclasses import dataclass
from pathlib import Path
from typing import Any

REPO_CONFIG_DIR = Path(__file__).resolve().parents[2] / "configs" / "robots"


def search_dirs(env_var: str, default: Path) -> list[Path]:
    """The folders named in ``$env_var`` (os.pathsep-separated), then ``default``."""
    return [*(Path(p) for p in os.environ.get(env_var, "").split(os.pathsep) if p), default]


def profile_dirs() -> list[Path]:
    """Where profiles are looked up: ``$SERVO_APP_ROBOTS`` (os.pathsep-separated), then configs/robots."""
    return search_dirs("SERVO_APP_ROBOTS", REPO_CONFIG_DIR)


class ProfileError(ValueError):
    """A profile that cannot be used; the message names the file, the key and the value."""


@dataclass(frozen=True)
class Dimensions:
    """Offsets in metres (REFERENCE.md section 2)."""

    d1: float
    a1: float
    a2: float
    a3: float
    d4: float
    d6: float


@dataclass(frozen=True)
class RobotProfile:
    name: str
    display_name: str
    source: Path
    dims: Dimensions
    joint_min_deg: tuple[float, ...]  # model convention
    joint_max_deg: tuple[float, ...]
    vel_limit: tuple[float, ...]  # deg/s, FANUC axes
    acc_limit: tuple[float, ...]  # deg/s^2, configured default ($JNT_ACC_LIM reference)
    jerk_limit: tuple[float, ...]  # deg/s^3, configured default ($JNT_JRK_LIM reference)
    interval_ms: int  # 8, or 4 for the starred models of manual 61.8
    j23_factor: float  # 1: FANUC J3 from the horizontal (the manual); 0: already model convention
    max_payload_kg: float
    max_flange_speed: float  # $MAX_SPD, mm/s
    intermediate_check_s: int  # Appendix B tentative-judgment period
    mjcf: Path
    # Appendix B table shape for the simulator's default tables: the multiple of the reference
    # acc/jerk limit at the lowest (Vmax/20) and highest (Vmax) stage, no payload and max payload.
    table_scale_no_payload: tuple[float, float] = (1.6, 1.2)
    table_scale_max_payload: tuple[float, float] = (1.3, 1.0)

    @property
    def dof(self) -> int:
        return len(self.vel_limit)

    @property
    def interval_s(self) -> float:
        return self.interval_ms / 1000.0

    @property
    def joint_min_rad(self) -> tuple[float, ...]:
        return tuple(math.radians(v) for v in self.joint_min_deg)

    @property
    def joint_max_rad(self) -> tuple[float, ...]:
        return tuple(math.radians(v) for v in self.joint_max_deg)


def _get(data: dict[str, Any], key: str, path: Path, prefix: str = "") -> Any:
    if key not in data:
        raise ProfileError(f"{path}: missing key '{prefix}{key}'")
    return data[key]


def _number(data: dict[str, Any], key: str, path: Path, prefix: str = "", *, positive: bool = False,
            default: float | None = None) -> float:
    value = data.get(key, default) if default is not None else _get(data, key, path, prefix)
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
        raise ProfileError(f"{path}: key '{prefix}{key}' = {value!r} is not a finite number")
    if positive and value <= 0:
        raise ProfileError(f"{path}: key '{prefix}{key}' = {value!r} must be > 0")
    return float(value)


def _vector(data: dict[str, Any], key: str, path: Path, n: int, prefix: str = "", *,
            positive: bool = False) -> tuple[float, ...]:
    value = _get(data, key, path, prefix)
    if not isinstance(value, list) or len(value) != n:
        raise ProfileError(f"{path}: key '{prefix}{key}' = {value!r} must be a list of {n} numbers")
    out = []
    for i, v in enumerate(value):
        if isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(v):
            raise ProfileError(f"{path}: key '{prefix}{key}[{i}]' = {v!r} is not a finite number")
        if positive and v <= 0:
            raise ProfileError(f"{path}: key '{prefix}{key}[{i}]' = {v!r} must be > 0")
        out.append(float(v))
    return tuple(out)


def find_profile_file(name_or_path: str | os.PathLike[str], dirs: list[Path], what: str) -> Path:
    """A profile given by path, or by name (``<name>.toml`` in the first of ``dirs`` that has it);
    ProfileError naming ``what`` ("robot", "Janome robot") and the names known."""
    p = Path(name_or_path)
    if p.suffix == ".toml" or p.exists():
        if not p.is_file():
            raise ProfileError(f"{p}: no such {what} profile file")
        return p
    for d in dirs:
        candidate = d / f"{name_or_path}.toml"
        if candidate.is_file():
            return candidate
    known = ", ".join(profile_names(dirs)) or "none"
    raise ProfileError(f"{what} model '{name_or_path}' is unknown (known: {known})")


def profile_names(dirs: list[Path]) -> list[str]:
    """The names of the profiles (``*.toml``) in ``dirs``, sorted."""
    names: set[str] = set()
    for d in dirs:
        if d.is_dir():
            names.update(p.stem for p in d.glob("*.toml"))
    return sorted(names)


def find_profile(name_or_path: str | os.PathLike[str]) -> Path:
    return find_profile_file(name_or_path, profile_dirs(), "robot")


def available_profiles() -> list[str]:
    return profile_names(profile_dirs())


def load_profile(name_or_path: str | os.PathLike[str]) -> RobotProfile:
    """Load and validate a profile by model name (``lrmate200id``) or by path to a TOML file."""
    path = find_profile(name_or_path)
    try:
        data = tomllib.loads(path.read_text())
    except tomllib.TOMLDecodeError as exc:
        raise ProfileError(f"{path}: not valid TOML: {exc}") from exc
    name = _get(data, "name", path)
    if not isinstance(name, str) or not name:
        raise ProfileError(f"{path}: key 'name' = {name!r} must be a non-empty string")
    dims_data = _get(data, "dimensions", path)
    dims = Dimensions(**{k: _number(dims_data, k, path, "dimensions.") for k in
                         ("d1", "a1", "a2", "a3", "d4", "d6")})
    joints = _get(data, "joints", path)
    n = 6
    jmin = _vector(joints, "min_deg", path, n, "joints.")
    jmax = _vector(joints, "max_deg", path, n, "joints.")
    for i, (lo, hi) in enumerate(zip(jmin, jmax, strict=True)):
        if lo >= hi:
            raise ProfileError(f"{path}: key 'joints.min_deg[{i}]' = {lo} is not below joints.max_deg[{i}] = {hi}")
    interval = _get(data, "interval_ms", path)
    if interval not in (4, 8):
        raise ProfileError(f"{path}: key 'interval_ms' = {interval!r} must be 4 or 8")
    mjcf_name = _get(data, "mjcf", path)
    if not isinstance(mjcf_name, str):
        raise ProfileError(f"{path}: key 'mjcf' = {mjcf_name!r} must be a file name")
    mjcf = (path.parent / mjcf_name).resolve()
    if not mjcf.is_file():
        raise ProfileError(f"{path}: key 'mjcf' = {mjcf_name!r}: no such file {mjcf}")
    check_s = _number(data, "intermediate_check_s", path, positive=True, default=5)
    table = data.get("limit_table_shape", {})
    shape_no = _vector(table, "no_payload", path, 2, "limit_table_shape.", positive=True) \
        if "no_payload" in table else (1.6, 1.2)
    shape_max = _vector(table, "max_payload", path, 2, "limit_table_shape.", positive=True) \
        if "max_payload" in table else (1.3, 1.0)
    return RobotProfile(
        name=name,
        display_name=str(data.get("display_name", name)),
        source=path,
        dims=dims,
        joint_min_deg=jmin,
        joint_max_deg=jmax,
        vel_limit=_vector(joints, "max_speed_deg_s", path, n, "joints.", positive=True),
        acc_limit=_vector(joints, "acc_limit_deg_s2", path, n, "joints.", positive=True),
        jerk_limit=_vector(joints, "jerk_limit_deg_s3", path, n, "joints.", positive=True),
        interval_ms=int(interval),
        j23_factor=_number(data, "j23_factor", path),
        max_payload_kg=_number(data, "max_payload_kg", path, positive=True),
        max_flange_speed=_number(data, "max_flange_speed_mm_s", path, positive=True),
        intermediate_check_s=int(check_s),
        mjcf=mjcf,
        table_scale_no_payload=(shape_no[0], shape_no[1]),
        table_scale_max_payload=(shape_max[0], shape_max[1]),
    )
