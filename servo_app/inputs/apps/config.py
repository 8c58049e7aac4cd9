"""The `[[applications]]` section of an inputs TOML file, and the whole file with it.

    [[applications]]
    name = "guide"
    type = "admittance"                 # teleop | admittance | standoff | tracking
    sources = { wrench = "ft_serial" }  # role -> adapter or feed name
    priority = 20

Each type names the roles it reads (its class's `roles`); a source must exist and publish the kind the
role takes (twist, pose or measurement). Errors say file, key and value, all at once, like the rest.
"""

from __future__ import annotations

import time
from collections.abc import Mapping
from dataclasses import replace
from pathlib import Path
from typing import Annotated, Any, Literal

from pydantic import (
    BaseModel,
    ConfigDict,
    Field,
    PositiveFloat,
    PositiveInt,
    TypeAdapter,
    ValidationError,
    model_validator,
)

from servo_app.inputs.adapter import Clock
from servo_app.inputs.apps.admittance import AdmittanceParams
from servo_app.inputs.apps.base import Application, InputRef
from servo_app.inputs.apps.pipelines import APPLICATION_TYPES, AdmittanceApp, StandoffApp, TeleopApp, TrackingApp
from servo_app.inputs.apps.standoff import StandoffParams
from servo_app.inputs.apps.tracking import PoseExtrapolator
from servo_app.inputs.config import InputsConfig, parse_inputs_config, read_toml
from servo_app.inputs.errors import ConfigError, ConfigIssue, KeyedError, check_stale_after, issues_from_validation

# What each adapter type publishes; feeds say it themselves (`kind`).
ADAPTER_KINDS = {"spacemouse": "twist", "spacenav": "twist", "serial_line": "measurement",
                 "serial_binary": "measurement", "can": "measurement"}

# The servo refuses a pose command slower than this (mm/s, deg/s: servo_app.motion.commands'
# MIN_LINEAR_MM_S and MIN_ANGULAR_DEG_S; the inputs never import the motion floor, and a test checks
# that the numbers agree): a tracking app set slower is refused when its file is read.
SLOWEST_POSE_SPEED = 0.1
ROTATION_TOLERANCE = 1e-3  # a rotation written with 4 decimals (0.7071) passes


class _App(BaseModel):
    # TOML has inf and nan: an infinite stale_after_s never went stale (no stop naming the sensor),
    # and a NaN gain or target made every command NaN, each refused while the file loaded fine.
    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)

    name: str = Field(min_length=1)
    sources: dict[str, str]
    priority: int = 0
    stale_after_s: PositiveFloat | None = None  # default: the largest timeout of its required inputs
    yield_when_idle: bool = False

    @model_validator(mode="after")
    def _timeout(self) -> _App:
        check_stale_after(self.stale_after_s)
        return self


class TeleopConfig(_App):
    type: Literal["teleop"]
    yield_when_idle: bool = True  # a SpaceMouse at rest lets lower-priority sources command
    frame: Literal["base", "tool"] | None = None  # None: the device's own (its frame button toggles it)
    scale: float = Field(1.0, gt=0.0, le=1.0)
    max_linear_mm_s: PositiveFloat = 250.0
    max_angular_deg_s: PositiveFloat = 45.0


class AdmittanceConfig(_App):
    type: Literal["admittance"]
    keys: list[str] = Field(default_factory=lambda: ["fx", "fy", "fz", "tx", "ty", "tz"], min_length=6,
                            max_length=6)  # measurement names of Fx Fy Fz Tx Ty Tz
    frame: Literal["base", "tool"] = "tool"
    linear_gain: float = Field(2.0, ge=0.0)  # mm/s per N
    angular_gain: float = Field(5.0, ge=0.0)  # deg/s per N m
    force_deadband_n: float = Field(2.0, ge=0.0)
    torque_deadband_nm: float = Field(0.2, ge=0.0)
    max_linear_mm_s: PositiveFloat = 50.0
    max_angular_deg_s: PositiveFloat = 20.0
    lowpass_hz: float = Field(10.0, ge=0.0)  # 0: no filter
    axes: list[bool] = Field(default_factory=lambda: [True] * 6, min_length=6, max_length=6)
    bias_samples: PositiveInt = 10
    sensor_rotation: list[list[float]] | None = None  # 3x3, command frame <- sensor frame

    @model_validator(mode="after")
    def _keys_and_rotation(self) -> AdmittanceConfig:
        if len(set(self.keys)) != len(self.keys):  # a name twice drove two axes from one value
            raise KeyedError("keys", self.keys, "names Fx Fy Fz Tx Ty Tz: six different measurement values")
        # Another shape raised IndexError on every sample at run time (hand guiding never moved);
        # a scaled or skewed matrix silently changed the gains.
        r = self.sensor_rotation
        if r is None:
            return self
        if len(r) != 3 or any(len(row) != 3 for row in r):
            raise KeyedError("sensor_rotation", r, "must be 3 rows of 3 numbers (command frame <- sensor frame)")
        for i in range(3):
            for j in range(3):
                if abs(sum(r[i][k] * r[j][k] for k in range(3)) - (i == j)) > ROTATION_TOLERANCE:
                    raise KeyedError("sensor_rotation", r, "must be a rotation matrix: rows of length 1, at right "
                                     "angles to each other (a scale belongs in the gains)")
        return self


class StandoffConfig(_App):
    type: Literal["standoff"]
    field: str = "distance"  # the measurement value that is the distance, mm
    # A distance: at or below zero the sensor could never read it (a sign slip for -50), and stand-off
    # drove the tool into the surface at max_speed_mm_s.
    target_mm: float = Field(gt=0.0)
    kp: float = Field(2.0, ge=0.0)
    ki: float = Field(0.0, ge=0.0)
    max_speed_mm_s: PositiveFloat = 20.0
    deadband_mm: float = Field(0.0, ge=0.0)
    integral_limit_mm_s: float = Field(10.0, ge=0.0)
    direction: Literal[1, -1] = 1  # -1 if the sensor looks along -tool z


class TrackingConfig(_App):
    type: Literal["tracking"]
    lookahead_s: float = Field(0.0, ge=0.0, le=0.5)  # beyond the stamp compensation: the servo's own lag
    max_horizon_s: PositiveFloat = 0.2
    window: int = Field(3, ge=2)
    max_gap_s: PositiveFloat = 0.25
    linear_speed: float = Field(150.0, ge=SLOWEST_POSE_SPEED)  # caps of the pose command, mm/s and deg/s
    angular_speed: float = Field(30.0, ge=SLOWEST_POSE_SPEED)
    # Re-extrapolate this often between samples. No faster than the servo reads (every 4 ms at best):
    # at 1e5 the bridge's thread woke every 10 us: a third of a core, and the API process's GIL.
    update_hz: float = Field(125.0, gt=0.0, le=250.0)

    @model_validator(mode="after")
    def _horizon(self) -> TrackingConfig:
        if self.lookahead_s >= self.max_horizon_s:
            raise KeyedError("lookahead_s", self.lookahead_s, f"must stay below max_horizon_s {self.max_horizon_s}, "
                             "which also has to cover the feed's own latency")
        return self


AppConfig = Annotated[TeleopConfig | AdmittanceConfig | StandoffConfig | TrackingConfig, Field(discriminator="type")]
_APP = TypeAdapter(AppConfig)


def source_kinds(cfg: InputsConfig) -> dict[str, str]:
    kinds = {a.name: ADAPTER_KINDS.get(a.type, "unknown") for a in cfg.adapters}
    kinds.update({n: f.kind for n, f in cfg.feeds.items()})
    return kinds


def source_timeouts(cfg: InputsConfig) -> dict[str, float]:
    return {a.name: a.stale_after_s for a in cfg.adapters} | {n: f.stale_after_s for n, f in cfg.feeds.items()}


def parse_applications(raw: Any, kinds: Mapping[str, str], file: str, timeouts: Mapping[str, float] | None = None
                       ) -> tuple[list[AppConfig], list[ConfigIssue]]:
    if not isinstance(raw, list):
        return [], [ConfigIssue(file, "applications", raw, "must be an array of tables ([[applications]])")]
    apps: list[AppConfig] = []
    issues: list[ConfigIssue] = []
    names = set(kinds)
    for i, table in enumerate(raw):
        prefix = f"applications[{i}]."
        try:
            app = _APP.validate_python(table)
        except ValidationError as exc:
            # pydantic puts the union's tag (the type) in front of the key; the file has no such key.
            tag = f"{prefix}{table.get('type')}." if isinstance(table, dict) else None
            issues.extend(replace(i, key=prefix + i.key.removeprefix(tag)) if tag and i.key.startswith(tag) else i
                          for i in issues_from_validation(exc, file, prefix))
            continue
        if app.name in names:
            issues.append(ConfigIssue(file, f"{prefix}name", app.name, "already names a source or application"))
        names.add(app.name)
        issues.extend(_check_sources(app, kinds, file, prefix))
        issues.extend(_check_timeout(app, timeouts or {}, file, prefix))
        apps.append(app)
    return apps, issues


def _check_sources(app: AppConfig, kinds: Mapping[str, str], file: str, prefix: str) -> list[ConfigIssue]:
    roles = {role: kind for role, (kind, _) in APPLICATION_TYPES[app.type].roles.items()}
    out = []
    for role, (_, required) in APPLICATION_TYPES[app.type].roles.items():
        if required and role not in app.sources:
            out.append(ConfigIssue(file, f"{prefix}sources.{role}", "<missing>", f"{app.type} needs a {role} source"))
    for role, source in app.sources.items():
        key = f"{prefix}sources.{role}"
        if role not in roles:
            out.append(ConfigIssue(file, key, source, f"{app.type} reads the roles {sorted(roles)}"))
        elif source not in kinds:
            out.append(ConfigIssue(file, key, source, f"no adapter or feed of that name; known: {sorted(kinds)}"))
        elif kinds[source] not in (roles[role], "unknown"):
            out.append(ConfigIssue(file, key, source, f"publishes {kinds[source]} samples; {role} takes {roles[role]}"))
    return out


def _check_timeout(app: AppConfig, timeouts: Mapping[str, float], file: str, prefix: str) -> list[ConfigIssue]:
    """An application goes stale with its inputs (base.Application), whatever its own stale_after_s, which
    sets how long each command holds the arm: shorter than an input's timeout, the servo's hold ran out
    between that sensor's samples and the arm stopped, "hold-to-run expired" instead of naming it."""
    if app.stale_after_s is None:
        return []
    roles = APPLICATION_TYPES[app.type].roles
    slower = {src: timeouts[src] for role, src in app.sources.items()
              if role in roles and roles[role][1] and timeouts.get(src, 0.0) > app.stale_after_s}
    if not slower:
        return []
    src, t = max(slower.items(), key=lambda kv: kv[1])
    return [ConfigIssue(file, f"{prefix}stale_after_s", app.stale_after_s,
                        f"shorter than its input {src!r}'s stale_after_s {t}: the application goes stale with its "
                        "inputs and each command holds the arm this long, so the hold would run out between that "
                        f"input's samples; leave it out (it is then {t}) or shorten the input's instead")]


def load_service_inputs(path: str | Path) -> tuple[InputsConfig, list[AppConfig]]:
    """Adapters, feeds and applications from one TOML file; raises ConfigError listing every problem."""
    path = Path(path)
    file = str(path)
    data = read_toml(path)
    raw_apps = data.pop("applications", [])
    issues: list[ConfigIssue] = []
    try:
        cfg = parse_inputs_config(data, file=file, base_dir=path.parent, path=path)
    except ConfigError as exc:
        issues.extend(exc.issues)
        cfg = None
    kinds = source_kinds(cfg) if cfg is not None else {}
    apps, app_issues = parse_applications(raw_apps, kinds, file, source_timeouts(cfg) if cfg is not None else None)
    if cfg is not None:  # app source names are only meaningful once the sources parsed
        issues.extend(app_issues)
    else:
        issues.extend(i for i in app_issues if ".sources." not in i.key)
    if issues or cfg is None:
        raise ConfigError(issues)
    return cfg, apps


def build_application(cfg: AppConfig, slots: Mapping[str, tuple[Any, float]], *,
                      clock: Clock = time.monotonic) -> Application:
    """The application for a validated entry; `slots` maps source name -> (LatestValue, stale_after_s)."""
    roles = APPLICATION_TYPES[cfg.type].roles
    inputs = {role: InputRef(role, src, slots[src][0], slots[src][1], roles[role][1])
              for role, src in cfg.sources.items()}
    common: dict[str, Any] = {"priority": cfg.priority, "stale_after_s": cfg.stale_after_s,
                              "yield_when_idle": cfg.yield_when_idle, "clock": clock}
    if isinstance(cfg, TeleopConfig):
        return TeleopApp(cfg.name, inputs, frame=cfg.frame, scale=cfg.scale, max_linear_mm_s=cfg.max_linear_mm_s,
                         max_angular_deg_s=cfg.max_angular_deg_s, **common)
    if isinstance(cfg, AdmittanceConfig):
        rot = tuple(tuple(r) for r in cfg.sensor_rotation) if cfg.sensor_rotation else None
        params = AdmittanceParams(
            linear_gain=cfg.linear_gain, angular_gain=cfg.angular_gain, force_deadband_n=cfg.force_deadband_n,
            torque_deadband_nm=cfg.torque_deadband_nm, max_linear_mm_s=cfg.max_linear_mm_s,
            max_angular_deg_s=cfg.max_angular_deg_s, lowpass_hz=cfg.lowpass_hz or None,
            axes=tuple(cfg.axes), keys=tuple(cfg.keys), bias_samples=cfg.bias_samples,  # type: ignore[arg-type]
            sensor_rotation=rot, frame=cfg.frame)
        return AdmittanceApp(cfg.name, inputs, params=params, **common)
    if isinstance(cfg, StandoffConfig):
        params_s = StandoffParams(
            target_mm=cfg.target_mm, kp=cfg.kp, ki=cfg.ki, max_speed_mm_s=cfg.max_speed_mm_s,
            deadband_mm=cfg.deadband_mm, integral_limit_mm_s=cfg.integral_limit_mm_s,
            max_age_s=inputs["distance"].stale_after_s, direction=cfg.direction)
        return StandoffApp(cfg.name, inputs, params=params_s, field=cfg.field, **common)
    ex = PoseExtrapolator(max_horizon_s=cfg.max_horizon_s, window=cfg.window, max_gap_s=cfg.max_gap_s)
    return TrackingApp(cfg.name, inputs, extrapolator=ex, lookahead_s=cfg.lookahead_s, linear_speed=cfg.linear_speed,
                       angular_speed=cfg.angular_speed, period_s=1.0 / cfg.update_hz, **common)
