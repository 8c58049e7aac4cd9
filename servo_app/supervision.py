"""What every servo-process supervisor shares, whatever the robot's protocol (FANUC's
:class:`~servo_app.fanuc.supervisor.StreamSupervisor`, Janome's
:class:`~servo_app.janome.supervisor.JanomeSupervisor`).

The safety state and its log, refused requests raised as :class:`CommandRejected` with the state
machine's reason, the gate every motion command passes, input control (a stale source stops a
streaming arm), and the safety part of ``describe()``. Each backend feeds events through its own
``_feed`` (how a fault is worded, which actions it carries out) and moves its own motion stage in
``_input_move``. Pure: no sockets, no clock.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from servo_app.errors import CommandRejected
from servo_app.input_slot import InputCommand, InputControl
from servo_app.safety import Event, InputStale, Mode, SafetyState, motion_allowed


@dataclass
class SupervisorLog:
    """What happened, for the parent process and the API (fault texts, warnings, stops)."""

    transitions: list[tuple[float, str, str, str]] = field(default_factory=list)  # (t, from, to, event)
    warnings: list[dict[str, Any]] = field(default_factory=list)
    stops: dict[str, int] = field(default_factory=dict)


class SupervisorBase:
    def __init__(self, min_input_hold_s: float) -> None:
        self.state = SafetyState()
        self.log = SupervisorLog()
        self.inputs = InputControl(min_hold_s=min_input_hold_s)
        self.changed = False  # set when the safety state changed; the runner clears it after publishing
        self._start_pending = False

    # -- what each backend implements
    def _feed(self, event: Event, now: float) -> str | None:
        """Apply one safety event and carry out its actions; the refusal text, if refused."""
        raise NotImplementedError

    def _input_move(self, cmd: InputCommand, name: str, hold: float, now: float) -> None:
        """Move as a live input command asks (its hold-to-run renewed for ``hold`` seconds)."""
        raise NotImplementedError

    # -- shared
    def _request(self, event: Event, now: float) -> None:
        err = self._feed(event, now)
        if err:
            raise CommandRejected(err)

    def _motion_gate(self, what: str) -> None:
        if not motion_allowed(self.state):
            raise CommandRejected(f"{what} refused in {self.state.mode.value}"
                                  + (f" (stopped: {self.state.stop_reason})" if self.state.stop_reason else ""))

    def on_input(self, cmd: InputCommand, now: float) -> None:
        """The inputs bridge's live command (read from shared memory when a status arrives)."""
        self.inputs.apply(cmd, lambda name: self._input_stale(name, now),
                          lambda c, name, hold: self._input_move(c, name, hold, now))

    def _input_stale(self, name: str, now: float) -> None:
        if self.state.mode == Mode.STREAMING:
            self._feed(InputStale(source=name), now)

    def _safety_view(self) -> dict[str, Any]:
        st = self.state
        fault = st.fault
        return {
            "state": st.mode.value,
            "stop_reason": st.stop_reason,
            "stop_fast": st.stop_fast,
            "resumable": st.resumable,
            "shutdown": st.shutdown,
            "fault": None if fault is None else {"message": fault.message, "code": fault.code,
                                                 "cause": fault.cause, "remedy": fault.remedy,
                                                 "during": fault.during.value if fault.during else None},
            "stops": dict(self.log.stops),
            "warnings": self.log.warnings[-10:],
        }
