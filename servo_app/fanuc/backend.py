"""FANUC Stream Motion (J519) as a robot backend: what the service asks of a FANUC controller."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from servo_app.backends import AlarmInfo, InvalidRequest, ProcessOptions, RobotBackend, Target
from servo_app.fanuc.alarms import ALARMS
from servo_app.fanuc.packets import ROBOT_PORT, IoType
from servo_app.fanuc.runner import StreamConfig, StreamProcess
from servo_app.fanuc.supervisor import check_pose_plausible
from servo_app.fanuc.view import fanuc_view
from servo_app.messages import Event
from servo_app.motion.limit_tables import LimitTables, default_tables
from servo_app.motion.servo import ServoSettings
from servo_app.robots.profile import RobotProfile, available_profiles, load_profile

IO_SPAN = 16  # a command packet's read or write covers 16 points from its index (manual 61.7)

# The embedded simulator's assigned I/O (points per type) that clients may use. SI/SO/WI/WO/WSI/WSO
# are not assigned there, and UI/UO drive the controller itself: not offered. RI/RO have 8 points
# there, fewer than the 16 every access covers: the manual (61.7) alarms on an access "that contains
# an index that has not been assigned", so no RI/RO access is safe and they are not offered either.
DEFAULT_IO_ALLOW: dict[str, int] = {"DI": 512, "DO": 512, "F": 1024, "M": 1024}


class FanucBackend(RobotBackend):
    name = "fanuc"
    default_port = ROBOT_PORT
    default_model = "lrmate200id"
    cartesian_jog = True
    simulator_payload = True
    default_io_allow = DEFAULT_IO_ALLOW

    @classmethod
    def models(cls) -> list[str]:
        return available_profiles()

    def load_profile(self, model: str) -> RobotProfile:
        return load_profile(model)

    # -- the servo process and the simulator
    def make_process(self, target: Target, options: ProcessOptions, on_event: Callable[[Event], None],
                     on_exit: Callable[[str], None]) -> StreamProcess:
        o = options
        return StreamProcess(StreamConfig(
            host=target.host, port=target.port, model=self.model, interval_ms=o.interval_ms, lead=o.lead,
            log_dir=o.log_dir, limit_fraction=o.limit_fraction, flange_speed_cap=o.flange_speed_cap,
            payload_kg=o.payload_kg, input_slot=o.input_slot, start_timeout_s=o.start_timeout_s),
            on_event=on_event, on_exit=on_exit)

    def start_simulator(self, target: Target, sim_options: dict[str, Any], realtime_priority: int | None) -> Any:
        from servo_app.sim.process import SimulatorProcess

        # The embedded controller starts at the usual FANUC home (wrist bent down), as a cell would
        # after a taught joint move before IBGN start; all-zero joints would be a wrist singularity.
        options = {"initial_joints": [0.0, 0.0, 0.0, 0.0, -90.0, 0.0], **sim_options}
        return SimulatorProcess(realtime_priority, model=self.model, port=target.port, **options).start()

    # -- views
    def axes(self) -> list[dict[str, Any]]:
        return fanuc_view(self.profile, [0.0] * 6)["axes"]  # type: ignore[no-any-return]

    def robot_view(self, q: list[float]) -> dict[str, Any]:
        return fanuc_view(self.profile, q)

    def limits(self, state: dict[str, Any], options: ProcessOptions) -> dict[str, Any]:
        p = self.profile
        tables = default_tables(p)
        vel, acc, jerk = tables.for_cap(tables.cap(options.flange_speed_cap), options.payload_kg)
        from_ctrl = bool(state.get("tables_from_controller"))
        if from_ctrl:
            vel, acc, jerk = state["vel_limit"], state["acc_limit"], state["jerk_limit"]
        return {
            "model": p.name,
            "backend": self.name,
            "source": "controller limit tables" if from_ctrl else "profile defaults (configured, not published)",
            "interval_ms": options.interval_ms or p.interval_ms,
            "limit_fraction": options.limit_fraction,
            "joint_min_deg": list(p.joint_min_deg),
            "joint_max_deg": list(p.joint_max_deg),
            "vel_deg_s": [float(v) for v in vel],
            "acc_deg_s2": [float(v) for v in acc],
            "jerk_deg_s3": [float(v) for v in jerk],
            # Only what check_io lets through: a type with fewer points than an access covers has none.
            "io_allow": {t: [1, n] for t, n in self._io_allow.items() if n >= IO_SPAN},
        }

    def flange_speed_cap(self, options: ProcessOptions, tables: LimitTables | None = None) -> tuple[float, str]:
        # As the servo cycle holds it (LimitTables.cap): the configured cap, never above the $MAX_SPD
        # of the controller's tables once a start has read them, else of the profile's.
        vmax_of = ("the controller's $MAX_SPD (its limit tables, read at the last start)" if tables is not None
                   else f"the profile's $MAX_SPD ({self.profile.name}; the controller's tables are read at start)")
        tables = tables if tables is not None else default_tables(self.profile)
        configured, cap = options.flange_speed_cap, tables.cap(options.flange_speed_cap)
        if not configured:
            return cap, vmax_of
        if configured < tables.vmax:
            return cap, f"the configured flange_speed_cap (below {vmax_of}, {tables.vmax:g} mm/s)"
        return cap, f"{vmax_of}, which holds the configured flange_speed_cap of {configured:g} mm/s to it"

    def twist_flange_cap(self, options: ProcessOptions, tables: LimitTables | None = None) -> float | None:
        # As the servo cycle checks a twist (StreamSupervisor._flange_cap): its share of the cap in force.
        return float(self.flange_speed_cap(options, tables)[0] * ServoSettings.flange_speed_margin)

    def alarm(self, code: str) -> AlarmInfo | None:
        spec = ALARMS.get(code)
        return None if spec is None else AlarmInfo(code, spec.cause, spec.remedy, spec.warning)

    def target_bounds(self) -> list[tuple[float, float]] | None:
        # The ranges are in the model convention; a target is in FANUC's, where J3 = J3_model - f * J2
        # (robots.conventions): J3's bound is the widest over J2's range.
        p = self.profile
        lo, hi = list(p.joint_min_deg), list(p.joint_max_deg)
        shifts = (p.j23_factor * lo[1], p.j23_factor * hi[1])
        lo[2], hi[2] = lo[2] - max(shifts), hi[2] - min(shifts)
        return list(zip(lo, hi, strict=True))

    def check_pose(self, xyzwpr: tuple[float, ...], tool_xyzwpr: tuple[float, ...] | None = None) -> None:
        check_pose_plausible(xyzwpr, self.profile, tool_xyzwpr)

    # -- I/O: a command packet reads or writes 16 points from an index; anything outside the assigned
    # points makes the controller post PRIO-023 and stop, so it is refused here first.
    def check_io_allow(self, io_allow: dict[str, int]) -> dict[str, int]:
        types = ", ".join(t.name for t in IoType if t is not IoType.NONE)
        for key, n in io_allow.items():
            if not (isinstance(key, str) and key in IoType.__members__ and key != "NONE"):
                hint = f" (write {key.upper()!r})" if isinstance(key, str) and key.upper() in IoType.__members__ else ""
                raise ValueError(f"io_allow key {key!r} (value {n!r}) is not a FANUC I/O type{hint}; the types are "
                                 f"{types}, in capitals")
            # An access covers IO_SPAN points from an index sent as a u16: fewer points allow no access.
            if isinstance(n, bool) or not isinstance(n, int) or not IO_SPAN <= n <= 0xFFFF:
                raise ValueError(f"io_allow[{key!r}]={n!r}: must be the number of {key} points assigned, a whole "
                                 f"number in {IO_SPAN}..{0xFFFF} (an access covers {IO_SPAN} points); leave {key} "
                                 "out to allow none")
        return dict(io_allow)

    def io_indexes(self) -> dict[str, tuple[int, int]]:
        # As check_io: a type with fewer points than an access covers allows none.
        return {t: (1, n - IO_SPAN + 1) for t, n in self._io_allow.items() if n >= IO_SPAN}

    def check_io(self, io_type: str, index: int) -> str:
        name = str(io_type).upper()
        allowed = ", ".join(f"{t} 1..{n}" for t, n in self._io_allow.items())
        if name not in self._io_allow:
            known = name in IoType.__members__
            raise InvalidRequest(
                f"type={io_type!r}: {'this I/O type is not' if known else 'not an I/O type'} allowed by the "
                f"service (the controller would post PRIO-023 and stop); send an allowed type: {allowed}")
        n = self._io_allow[name]
        if n < IO_SPAN:
            raise InvalidRequest(
                f"type={name}: only {n} points are assigned and an access always covers {IO_SPAN} points, so "
                f"any {name} access would make the controller post PRIO-023; send an allowed type: {allowed}")
        if not 1 <= index <= n - IO_SPAN + 1:
            raise InvalidRequest(
                f"index={index}: an access covers {IO_SPAN} points from the index, so {name} indexes must be in "
                f"1..{n - IO_SPAN + 1} ({name} has points 1..{n}; the controller would post PRIO-023); send an index "
                f"in 1..{n - IO_SPAN + 1}")
        return name

    def io_type_code(self, name: str) -> int:
        return int(IoType[name])

    def io_window(self, io_type: str, point: int) -> tuple[int, int]:
        """The index is the point itself where the allowed range permits, else the last index that
        reaches it (an access covers 16 points from its index)."""
        n = self._io_allow.get(io_type, 0)
        if io_type in self._io_allow and point > n:  # an unknown type is check_io's to refuse, by name
            raise InvalidRequest(f"{io_type}[{point}] is outside the allowed {io_type} 1..{n}")
        index = max(1, min(point, n - IO_SPAN + 1))
        return index, 1 << (point - index)
