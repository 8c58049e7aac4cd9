"""The servo process's brain: the safety state machine driving the stream session and the servo cycle.

Pure (no sockets, no clock of its own): the runner hands it datagrams, requests and ``now``; it
returns the datagrams to send. Every decision about motion goes through
:func:`servo_app.safety.transition`, and every stop is the shaper's jerk-limited deceleration:

- requests (start, stop, resume, end, reset, jog, target) become safety events; refused ones raise
  :class:`CommandRejected` with the state machine's message and change nothing. Motion is checked
  whole first (:class:`InvalidRequest`): counts and joint ranges, a jog within the live speed limits
  (the controller's limit tables once fetched, in its J2/J3 convention), a twist or pose target within
  the flange-speed cap, a pose within the arm's reach and in millimetres;
- hold-to-run: each jog renews a deadline; when it passes, ``JogExpired`` stops the arm;
- status packets feed ``StatusReceived``; silence feeds ``StatusLost``;
- the shaper reaching rest during a stop feeds ``ShaperAtRest``;
- a controller alarm (reported by whoever can see it, e.g. the embedded simulator) feeds
  ``ControllerAlarm`` and so a fault carrying the manual's cause and remedy.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any, ClassVar, TypeVar

import numpy as np

from servo_app import messages as msg
from servo_app.errors import CommandRejected, InvalidRequest
from servo_app.fanuc.alarms import ALARMS
from servo_app.fanuc.packets import STATUS_BITS_OFFSET, IoType, Status, StatusBit
from servo_app.fanuc.session import IoRequest, Phase, SessionConfig, StreamSession
from servo_app.input_slot import POSE, TWIST, InputCommand
from servo_app.motion.commands import PoseTarget, Twist
from servo_app.motion.limit_tables import default_tables
from servo_app.motion.servo import ServoCycle
from servo_app.robots.profile import RobotProfile
from servo_app.safety import (
    SEND_FIRST_COMMAND,
    STREAM_ALIVE,
    ControllerAlarm,
    Mode,
    SafetyState,
    ShaperAtRest,
    Signal,
    StartRequested,
    StatusLost,
    StatusReceived,
    transition,
)
from servo_app.supervision import SupervisorBase, axis_values, check_count, check_speeds, next_step

_A = TypeVar("_A")
_R = TypeVar("_R")

# The status bits a StatusReceived event carries (bit 0, bit 1, SYSRDY, moving).
_STATUS_EVENT_BITS = int(StatusBit.WAITING_FOR_COMMAND | StatusBit.COMMAND_RECEIVED | StatusBit.SYSRDY
                         | StatusBit.MOVING)

# The link phases a ready status can start a stream from (StreamSupervisor._starts_on_ready).
_STARTS_FROM = (Phase.WAITING_READY, Phase.CONNECTED)
# What _after_status compares with on every status (an enum member looked up on its class costs ~0.1 us
# here, more with caches cold); the modes in which a failed link is a lost status.
_STREAMING, _STOPPING, _ENDING, _CLOSED, _FAULT = Mode.STREAMING, Mode.STOPPING, Mode.ENDING, Phase.CLOSED, Phase.FAULT
_LINK_ALIVE_MODES = (Mode.STREAMING, Mode.STOPPING, Mode.STOPPED, Mode.ENDING)
# The modes a status leaves the safety state in when it holds no fault and no stream: a failed link is
# then a start's failed status output start, which the status now flowing answers (StreamSession.relink).
_LINK_UP_MODES = (Mode.CONNECTED, Mode.READY, Mode.ENDED)

# A pose whose X, Y and Z all lie within this many mm of the base was almost surely sent in metres.
METRES_SUSPECT_MM = 5.0
# I/O writes waiting for a command packet each (one per packet): 64 are half a second at 8 ms, what an
# end then waits at most, instead of a queue a flood of writes makes as long as it likes.
MAX_IO_WRITES_PENDING = 64


def reach_mm(profile: RobotProfile, tool_xyzwpr: tuple[float, ...] | None = None) -> float:
    """How far the TCP can be from the J2 axis: upper arm + forearm to the wrist centre + flange (+ tool)."""
    d = profile.dims
    tool = math.hypot(*tool_xyzwpr[:3]) if tool_xyzwpr else 0.0
    return 1000.0 * (d.a2 + math.hypot(d.a3, d.d4) + d.d6) + tool


def check_pose_plausible(xyzwpr: tuple[float, ...], profile: RobotProfile,
                         tool_xyzwpr: tuple[float, ...] | None = None) -> None:
    """InvalidRequest for a pose in metres (X, Y and Z all within +-5) or beyond the arm's reach
    (measured from the J2 axis, which turns with J1 at a1 from the base axis, at the world origin's height)."""
    x, y, z = (float(v) for v in xyzwpr[:3])
    if max(abs(x), abs(y), abs(z)) <= METRES_SUSPECT_MM:
        raise InvalidRequest(f"xyzwpr X={x:g} Y={y:g} Z={z:g} all lie within +-{METRES_SUSPECT_MM:g}: units are mm "
                             f"(did you send metres? 0.4 m is 400)")
    limit = reach_mm(profile, tool_xyzwpr)
    a1 = 1000.0 * profile.dims.a1
    dist = math.hypot(math.hypot(x, y) - a1, z)
    if dist > limit:
        raise InvalidRequest(f"xyzwpr X={x:g} Y={y:g} Z={z:g} mm is {dist:.0f} mm from the J2 axis, out of "
                             f"the {profile.display_name}'s reach of {limit:.0f} mm; send a pose within reach")


class StreamSupervisor(SupervisorBase):
    REQUESTS: ClassVar[dict[type, str]] = {
        msg.Twist: "_on_twist", msg.PoseTarget: "_on_pose", msg.IoRead: "_on_io_read", msg.IoWrite: "_on_io_write",
        msg.SetTool: "_on_set_tool",
        msg.Trajectory: "_on_trajectory",
    }

    def __init__(self, cycle: ServoCycle, session_config: SessionConfig | None = None,
                 start_timeout_s: float = 5.0) -> None:
        super().__init__(min_input_hold_s=0.02, hold_s=0.2, start_timeout_s=start_timeout_s)
        self.cycle = self.motion = cycle
        self.session = StreamSession(cycle, session_config or SessionConfig())
        self._out: list[bytes] = []
        # A status's bits and the state they left as it was, with no action: the fixed point _on_status_before skips.
        self._steady_bits = -1
        self._steady_state: SafetyState | None = None

    # ------------------------------------------------------------------- the link
    def _link_open(self, now: float) -> None:
        # From fault too: after a lost link the status output must be started afresh (a restarted
        # controller sends nothing until it gets a status output start).
        if self.session.phase in (Phase.IDLE, Phase.CLOSED, Phase.FAULT):
            self._out += self.session.open(now)

    def _link_close(self) -> None:
        if self.session.output_on:
            self._out += self.session.close_now()

    def _link_arm(self) -> None:
        self.session.arm()

    def _link_end(self) -> None:
        self.session.request_end()

    def _link_abandon(self, reason: str, now: float) -> None:
        self.session.abandon(reason, now)

    def _link_recover(self, now: float) -> None:
        # The link starts afresh at the next start: the status bits from before the fault (a fault
        # the controller's alarm reported first leaves them behind) no longer say anything.
        if self.session.recover(now) and self.state.status is not None:
            self._feed(StatusLost(detail="the link restarts at the next start"), now)

    def _link_failure(self) -> str:
        return self.session.fault_reason if self.session.phase == Phase.FAULT else ""

    def _link_closed(self) -> bool:
        # A dead link (fault) has nothing left to close: the controller stopped talking.
        return not self.session.output_on or self.session.phase == Phase.FAULT

    def alarm_event(self, code: str, message: str) -> ControllerAlarm:
        spec = ALARMS.get(code)  # an unknown code still stops: the state machine words it generically
        if spec is None:
            return ControllerAlarm(code=code, message=message)
        return ControllerAlarm(code=code, message=message, warning=spec.warning, cause=spec.cause,
                               remedy=spec.remedy)

    # ------------------------------------------------------------- FANUC requests
    def _jog_axes(self, v: np.ndarray) -> None:
        self.cycle.jog_joints(v)

    def _joint_target(self, q: np.ndarray, speed_scale: float) -> None:
        self.cycle.set_joint_target(q, speed_scale)

    # ------------------------------------------------------------- checks (before anything changes)
    def _names(self) -> list[str]:
        return [f"J{i + 1}" for i in range(self.cycle.profile.dof)]

    def _speed_limits(self) -> tuple[np.ndarray, str]:
        """The joint speed limits in force (deg/s, FANUC convention) and where they come from: the
        stream's tables once it began (the controller's, if it published them), else the profile's."""
        c = self.cycle
        if c.limits is not None:
            src = "the controller's limit table" if c.tables_source == "controller" else "the profile's limit table"
            return np.asarray(c.limits[0]), src
        tables = default_tables(c.profile)
        vel = tables.for_cap(tables.cap(c.settings.flange_speed_cap), c.settings.payload_kg)[0]
        return np.asarray(vel[: c.profile.dof]), "the profile's limit table"

    def _flange_cap(self) -> float:
        """The Cartesian speed the cycle takes (mm/s): its share of the flange-speed cap."""
        c = self.cycle
        cap = c.cap or default_tables(c.profile).cap(c.settings.flange_speed_cap)
        return float(cap * c.settings.flange_speed_margin)

    def _check_jog(self, v: np.ndarray) -> np.ndarray:
        check_count("joints", v, self.cycle.profile.dof, ", ".join(self._names()) + " in deg/s")
        vel, source = self._speed_limits()
        check_speeds("joints", v, vel, self._names(), ["deg/s"] * v.size, source)
        return v

    def _check_joint_target(self, q: np.ndarray, speed_scale: float) -> None:
        check_count("joints", q, self.cycle.profile.dof, ", ".join(self._names()) + " in deg")
        _as_invalid(self.cycle.check_joint_target, q)

    def _on_twist(self, req: msg.Twist, now: float) -> None:
        try:
            cmd = Twist(source=req.source, stamp=now, frame=req.frame,  # type: ignore[arg-type]
                        linear=tuple(req.linear), angular=tuple(req.angular))  # type: ignore[arg-type]
        except ValueError as exc:
            raise InvalidRequest(str(exc)) from None
        speed, cap = math.hypot(*cmd.linear), self._flange_cap()
        if speed > cap:
            raise InvalidRequest(f"linear={list(cmd.linear)}: {speed:.1f} mm/s is above the flange-speed cap "
                                 f"{cap:.0f} mm/s; send at most {cap:.0f} mm/s")
        # The flange's own speed too (a turn about a long tool swings it), and hold_s, before the gate:
        # the gate may resume a stream stopped by a hold-to-run, which a refused twist must not do.
        # Too fast for the flange is the request's own values, as too fast for the TCP is (422).
        _as_invalid(self.cycle.check_twist, cmd)
        self._hold_to_run(float(req.hold_s), now, "twist")
        self.cycle.twist(cmd)

    def _on_pose(self, req: msg.PoseTarget, now: float) -> None:
        try:
            pose = PoseTarget(source=req.source, stamp=now, xyzwpr=tuple(req.xyzwpr),  # type: ignore[arg-type]
                              linear_speed=float(req.linear_speed), angular_speed=float(req.angular_speed))
        except ValueError as exc:
            raise InvalidRequest(str(exc)) from None
        cap = self._flange_cap()
        if pose.linear_speed > cap:
            raise InvalidRequest(f"linear_speed={pose.linear_speed:g} mm/s is above the flange-speed cap "
                                 f"{cap:.0f} mm/s; send at most {cap:.0f} mm/s")
        check_pose_plausible(pose.xyzwpr, self.cycle.profile, self.cycle.settings.tool_xyzwpr)
        _as_invalid(self.cycle.check_pose_target, pose)  # the flange's swing about the tool too, before the gate
        self._target_gate("pose target", now)
        self.cycle.pose_target(pose)

    def _on_set_tool(self, req: msg.SetTool, now: float) -> None:
        """The cycle's TCP and payload (ServoCycle.set_tool: at rest only, else refused unchanged). The
        service checked the values (servo_app.robots.tool); counts and finiteness again here."""
        xyzwpr = axis_values("xyzwpr", req.xyzwpr)
        check_count("xyzwpr", xyzwpr, 6, "X Y Z in mm, W P R in deg")
        payload = req.payload_kg
        if payload is not None and not (math.isfinite(payload) and 0.0 < payload <= self.cycle.profile.max_payload_kg):
            raise InvalidRequest(f"payload_kg={payload} must be in (0, {self.cycle.profile.max_payload_kg:g}] kg")
        self.cycle.set_tool(tuple(float(v) for v in xyzwpr) if xyzwpr.any() else None, payload,
                            streaming=self.state.mode in STREAM_ALIVE)

    def _on_trajectory(self, req: msg.Trajectory, now: float) -> dict[str, Any]:
        """Replay planned samples: the values first (422: shape, finite), then the state (409: streaming,
        at rest at the first sample), then the gate; a refusal changes nothing. The cycle checks each
        sample again as it plays it (``ServoCycle._step_replay``)."""
        if self.cycle.shaper is None:
            self._motion_gate("trajectory", now=now)  # not streaming: refused with the next step
        ramp = int(req.ramp_steps)
        if ramp < 1 or ramp % 2 == 0:
            raise InvalidRequest(f"ramp_steps={req.ramp_steps} must be odd and positive")
        q = _as_invalid(self.cycle.check_replay, req.joints)
        why = self.cycle.replay_start_mismatch(q)
        if why:
            raise CommandRejected(f"trajectory refused: {why}")
        self._target_gate("trajectory", now)
        self.cycle.replay(q, ramp)
        return {"samples": len(q), "duration_s": (len(q) - 1) * self.cycle.dt, "ramp_steps": ramp}

    def _on_io_read(self, req: msg.IoRead, now: float) -> int:
        """Returns the writes queued ahead of the read: its value is read after they went out."""
        self.session.io_read = IoRequest(_io_type(req.type), int(req.index), int(req.mask))
        return self.session.io_writes_pending

    def _on_io_write(self, req: msg.IoWrite, now: float) -> None:
        session = self.session
        if session.phase != Phase.STREAMING:
            raise CommandRejected("I/O is written through command packets: only while streaming; "
                                  f"{next_step(self.state)}")
        if session.end_requested:  # a write after it would be sent in no command of this stream
            raise CommandRejected("I/O write refused: the stream is ending (its last commands are going out); "
                                  "start a new session, then write: POST /api/session/start")
        if session.io_writes_pending >= MAX_IO_WRITES_PENDING:
            raise CommandRejected(f"I/O write refused: {session.io_writes_pending} writes are already waiting "
                                  "(one goes out per command packet); write again once they are out: POST /api/io")
        session.write_io(IoRequest(_io_type(req.type), int(req.index), int(req.mask), int(req.value)))

    def on_late_input(self, cmd: InputCommand, now: float) -> bool:
        """A command that reached the slot while this cycle's IK was solving (``ServoCycle.late_command``).

        Only a new twist or pose target for an arm streaming under input control is taken now (True);
        anything that changes the safety state (stale, nothing live) or needs a gate (enable, resume)
        waits for the next status packet's regular read, where it is handled in order."""
        if not (self.inputs.enabled and self.state.mode == Mode.STREAMING and not cmd.stale
                and cmd.kind in (TWIST, POSE)):
            return False
        self.on_input(cmd, now)
        return True

    def _input_move(self, cmd: InputCommand, name: str, hold: float, now: float) -> None:
        if cmd.kind == TWIST:
            twist = Twist(source=name, stamp=cmd.stamp, frame=cmd.frame, linear=cmd.values[:3],  # type: ignore[arg-type]
                          angular=cmd.values[3:6])
            self.cycle.check_twist(twist)  # before the gate, as a requested twist (_on_twist)
            self._hold_to_run(hold, now, f"input {name}")
            self.cycle.twist(twist)
        else:
            pose = PoseTarget(source=name, stamp=cmd.stamp, xyzwpr=cmd.values[:6],  # type: ignore[arg-type]
                              linear_speed=cmd.linear_speed, angular_speed=cmd.angular_speed)
            self.cycle.check_pose_target(pose)
            self._hold_to_run(hold, now, f"input {name}")
            self.cycle.pose_target(pose)

    def request(self, req: msg.Request, now: float) -> Any:
        self.session.begin_motion()  # a request acts on the stream's motion, which must be set up
        return super().request(req, now)

    def signal(self, sig: int, now: float) -> list[bytes]:
        self.session.begin_motion()
        self._out = []
        self._feed(Signal(sig=sig), now)
        return self._take()

    # ------------------------------------------------------------------ cycle
    def prepare_first_command(self) -> None:
        """Off the cycle, after each datagram and request: if the next ready status would start the
        stream, the session gets the first command's packet ready (the runner sends it with
        ``StreamSession.first_command_early`` before anything else, then calls ``on_datagram`` as usual)."""
        s = self.session
        # Only these phases can start on a ready status: in any other (streaming, every cycle) the
        # dry run's answer is no, and it is not run; nor is the session asked to drop a packet it has not.
        if s.phase in _STARTS_FROM:
            s.prepare_first_command(self._starts_on_ready())
        elif s.first_command is not None:
            s.prepare_first_command(False)

    def _starts_on_ready(self) -> bool:
        """Would a ready status (bit 0, SYSRDY, no command received) start the stream now? What
        ``on_datagram`` would do with it, as a dry run of the same pure transitions."""
        s = self.session
        if s.phase == Phase.WAITING_READY:  # armed: the session starts on it by itself
            return True
        if s.phase != Phase.CONNECTED or not self.start_pending:
            return False
        t = transition(self.state, StatusReceived(bit0=True, bit1=False, sysrdy=True))  # _on_status_before
        st = t.state
        ready = st.mode == Mode.READY or (st.mode == Mode.ENDED and st.status is not None and st.status.waiting)
        return ready and SEND_FIRST_COMMAND in transition(st, StartRequested()).actions  # _start_when_ready

    def on_datagram(self, data: bytes, now: float) -> list[bytes]:
        session = self.session
        # The usual status of a running stream, whose bits leave the safety state as it is, with no start,
        # hold-to-run expiry or output pending: the session's flat path (it declines anything else).
        if (self.state is self._steady_state and self.state.mode == _STREAMING and not self.start_pending
                and not self._out and len(data) > STATUS_BITS_OFFSET
                and data[STATUS_BITS_OFFSET] & _STATUS_EVENT_BITS == self._steady_bits
                and not self.hold.expired(now)):
            out = session.on_usual_status(data, now)
            if out is not None:
                return out
        self._out = []
        session.sent = []  # a malformed datagram sends nothing: nothing of an earlier one may be logged
        packet = session.decode(data)
        if packet is None:
            return []
        if not isinstance(packet, Status):  # a limit-table response: the session's alone
            return session.on_packet(packet, now)
        self._on_status_before(packet, now)
        self._out += session.on_packet(packet, now)
        self._after_status(packet, now)
        out, self._out = self._out, []  # _take()
        return out

    def _on_status_before(self, st: Status, now: float) -> None:
        prev = self.session.last_status
        if prev is not None and prev.seq == st.seq:
            return  # a duplicate carries no news
        bits = st.status & _STATUS_EVENT_BITS
        # The transition is pure: the same bits into the very state they left unchanged (no action)
        # leave it unchanged again, so a streaming cycle does not build the event and run it each time.
        if bits != self._steady_bits or self.state is not self._steady_state:
            before = self.state
            self._feed(StatusReceived(bit0=st.waiting_for_command, bit1=st.command_received, sysrdy=st.sysrdy,
                                      moving=st.moving), now)
            steady = self.state is before and not self._fed_actions
            self._steady_bits, self._steady_state = (bits, before) if steady else (-1, None)
        # A start after an ended stream stays in ended (not ready) while the controller comes back to
        # IBGN start: the waiting status there is as good as ready.
        if self.start_pending and self.session.phase != Phase.FETCHING_TABLES:
            self._start_when_ready(now)
        # Hold-to-run and rest are judged before the command for this status is computed.
        self._poll_hold(now)

    def _after_status(self, st: Status, now: float) -> None:
        if self.state.mode == _STOPPING and self.cycle.at_rest():
            self._feed(ShaperAtRest(), now)
        if self.session.phase == _CLOSED and self.state.mode == _ENDING:
            self._feed(StatusReceived(bit0=st.waiting_for_command, bit1=st.command_received, sysrdy=st.sysrdy),
                       now)
        if self.session.phase == _FAULT:
            mode = self.state.mode
            if mode in _LINK_ALIVE_MODES:
                self._feed(StatusLost(detail=self.session.fault_reason), now)
            elif mode in _LINK_UP_MODES and not self.state.shutdown:
                # Status flows again (a frozen controller thawed): the safety state follows it to
                # connected or ready, and so does the link, instead of staying failed beside it.
                self.session.relink(now)
                self.changed = True  # (link_error changes with it)

    def on_idle(self, now: float) -> list[bytes]:
        self._out = []
        self.session.sent = []
        self.session.on_idle(now)
        if self.session.phase == Phase.FAULT and self.state.mode not in (Mode.FAULT, Mode.DISCONNECTED,
                                                                        Mode.ENDED):
            self._feed(StatusLost(detail=self.session.fault_reason), now)
        elif (self.session.phase == Phase.CLOSED and self.state.mode == Mode.ENDED
              and self.state.status is not None):
            self._feed(StatusLost(detail="status output stopped"), now)
        return self._take()

    def _take(self) -> list[bytes]:
        out, self._out = self._out, []
        return out

    # ------------------------------------------------------------------ views
    def describe(self) -> dict[str, Any]:
        return {
            **self._safety_view(),
            "link": self.session.phase.value,
            "link_error": self.session.fault_reason or self.session.stats.last_error,
        }


def _io_type(value: Any) -> int:
    if isinstance(value, str):
        try:
            return int(IoType[value.upper()])
        except KeyError:
            raise InvalidRequest(f"io type={value!r} is unknown (DI, DO, RI, RO, ..., F, M)") from None
    return int(IoType(int(value)))


def _as_invalid(check: Callable[[_A], _R], value: _A) -> _R:
    """``check(value)``, a check of the request's own values: its refusal is an InvalidRequest (422),
    not the state's (409)."""
    try:
        return check(value)
    except CommandRejected as exc:
        raise InvalidRequest(str(exc)) from None
