"""Allowable upper limit tables of manual Appendix B.

Each axis has, per limit type (velocity, acceleration, jerk), a 20-stage table over the flange-centre
speed at no payload and at maximum payload. Stage i (1..20) holds the limit at speed i * Vmax / 20.

Evaluation (Appendix B):
- below Vmax/20 the stage-1 value applies;
- between stages, linear interpolation; above Vmax, linear extrapolation from stages 19 and 20
  (clamped at zero: a limit never turns negative);
- payload: linear interpolation between the no-payload and the max-payload tables. When no payload is
  configured the controller assumes the maximum payload (Appendix B, payload note 2).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from servo_app.robots.profile import RobotProfile

N_STAGES = 20
VEL, ACC, JERK = 0, 1, 2
LIMIT_NAMES = ("velocity", "acceleration", "jerk")


@dataclass(frozen=True)
class AxisTable:
    """One axis, one limit type: 20 stages at no payload and at max payload."""

    no_payload: tuple[float, ...]
    max_payload: tuple[float, ...]

    def __post_init__(self) -> None:
        for name in ("no_payload", "max_payload"):
            if len(getattr(self, name)) != N_STAGES:
                raise ValueError(f"{name} has {len(getattr(self, name))} stages, expected {N_STAGES}")


@dataclass(frozen=True)
class LimitTables:
    """All tables of one robot: ``tables[limit_type][axis]`` (axis 0-based), plus Vmax and check time."""

    vmax: float  # $MAX_SPD, mm/s
    check_time_s: float  # intermediate check time, s
    max_payload_kg: float
    tables: tuple[tuple[AxisTable, ...], tuple[AxisTable, ...], tuple[AxisTable, ...]]

    @property
    def n_axes(self) -> int:
        return len(self.tables[VEL])

    def cap(self, configured: float | None) -> float:
        """The flange-speed cap in force (mm/s): the configured one (None: none), never above these
        tables' Vmax. A controller's tables carry its own $MAX_SPD: one set lower than the configured
        cap holds the flange to it, and limits evaluated above Vmax are Appendix B's extrapolation."""
        return self.vmax if not configured else min(float(configured), self.vmax)

    def stage_values(self, limit_type: int, payload_kg: float | None) -> np.ndarray:
        """(n_axes, 20) stage values for one payload (None: the maximum payload)."""
        frac = 1.0 if payload_kg is None else min(max(payload_kg / self.max_payload_kg, 0.0), 1.0)
        axes = self.tables[limit_type]
        no = np.array([t.no_payload for t in axes], dtype=float)
        mx = np.array([t.max_payload for t in axes], dtype=float)
        return no + (mx - no) * frac

    def at_speed(self, limit_type: int, flange_speed: float, payload_kg: float | None = None) -> np.ndarray:
        """Per-axis limit at a flange-centre speed (mm/s) and payload, per Appendix B."""
        return evaluate_stages(self.stage_values(limit_type, payload_kg), flange_speed, self.vmax)

    def for_cap(self, flange_speed_cap: float, payload_kg: float | None = None) -> tuple[np.ndarray, ...]:
        """(vel, acc, jerk) limits that hold at every flange speed up to ``flange_speed_cap``.

        The tables usually fall with speed; taking the minimum over the stages up to the cap keeps
        this safe for tables that do not.
        """
        speeds = [s for s in self.stage_speeds() if s < flange_speed_cap] + [flange_speed_cap]
        # The stage values once per limit type, not once per speed: ServoCycle.begin runs this right
        # after a stream's first command, and 60 rebuilds of the (n, 20) tables took 4.4 ms here.
        out = []
        for k in (VEL, ACC, JERK):
            stages = self.stage_values(k, payload_kg)
            out.append(np.min([evaluate_stages(stages, s, self.vmax) for s in speeds], axis=0))
        return tuple(out)

    def stage_speeds(self) -> list[float]:
        return [self.vmax * i / N_STAGES for i in range(1, N_STAGES + 1)]


def evaluate_stages(stages: np.ndarray, speed: float, vmax: float) -> np.ndarray:
    """Limit per row of ``stages`` (n, 20) at ``speed``: Appendix B interpolation and extrapolation."""
    step = vmax / N_STAGES
    x = speed / step  # stage coordinate: stage i sits at x = i
    if x <= 1.0:
        return stages[:, 0].copy()
    if x <= N_STAGES:
        i = min(int(np.floor(x)), N_STAGES - 1)  # between stage i and i + 1 (1-based)
        w = x - i
        return stages[:, i - 1] * (1.0 - w) + stages[:, i] * w
    slope = stages[:, N_STAGES - 1] - stages[:, N_STAGES - 2]
    return np.maximum(stages[:, N_STAGES - 1] + slope * (x - N_STAGES), 0.0)


def _ramp(ref: float, scale: tuple[float, float]) -> tuple[float, ...]:
    lo_speed, hi_speed = scale
    return tuple(ref * (lo_speed + (hi_speed - lo_speed) * i / (N_STAGES - 1)) for i in range(N_STAGES))


def default_tables(profile: RobotProfile) -> LimitTables:
    """The simulator's tables, built from a profile's configured reference limits.

    Velocity tables are constant (Appendix B: "always constant regardless of Cartesian speed or
    payload"); acceleration and jerk tables fall linearly from the low-speed to the Vmax multiple
    given by the profile's ``limit_table_shape``.
    """
    vel = tuple(AxisTable((v,) * N_STAGES, (v,) * N_STAGES) for v in profile.vel_limit)
    acc = tuple(AxisTable(_ramp(a, profile.table_scale_no_payload), _ramp(a, profile.table_scale_max_payload))
                for a in profile.acc_limit)
    jerk = tuple(AxisTable(_ramp(j, profile.table_scale_no_payload), _ramp(j, profile.table_scale_max_payload))
                 for j in profile.jerk_limit)
    return LimitTables(vmax=profile.max_flange_speed, check_time_s=profile.intermediate_check_s,
                       max_payload_kg=profile.max_payload_kg, tables=(vel, acc, jerk))


def tables_from_rows(vmax: float, check_time_s: float, max_payload_kg: float,
                     rows: Sequence[Sequence[tuple[Sequence[float], Sequence[float]]]]) -> LimitTables:
    """Build tables from ``rows[limit_type][axis] = (no_payload, max_payload)`` (e.g. read off the wire)."""
    t = tuple(tuple(AxisTable(tuple(no), tuple(mx)) for no, mx in per_type) for per_type in rows)
    if len(t) != 3:
        raise ValueError(f"expected 3 limit types, got {len(t)}")
    return LimitTables(vmax=vmax, check_time_s=check_time_s, max_payload_kg=max_payload_kg,
                       tables=(t[0], t[1], t[2]))
