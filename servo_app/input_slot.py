"""The live input command, from the inputs bridge (API process) to the servo process.

One latest-value slot in shared memory (see :mod:`servo_app.ipc`): the bridge writes the arbiter's
winning command whenever it changes or is renewed; the servo process reads it when a status packet
arrives, before it computes that packet's command, and again after each IK solve (a new motion that
arrived meanwhile is solved into the same packet while the answer is still early). Time stamps are
``time.monotonic()``, one clock for every process on the machine.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, replace

import numpy as np

from servo_app.ipc import LatestValueSlot

NONE, TWIST, POSE = 0, 1, 2
FRAMES = ("base", "tool")
SIZE = 16  # kind, frame, 6 values, linear speed, angular speed, stamp, timeout, source, stale, spare x2


@dataclass(frozen=True)
class InputCommand:
    kind: int  # NONE, TWIST (mm/s, deg/s) or POSE (XYZWPR, with speed caps)
    frame: str
    values: tuple[float, ...]
    linear_speed: float
    angular_speed: float
    stamp: float  # monotonic seconds of the sample the command comes from
    timeout_s: float  # the source's staleness timeout: no renewal within it stops the arm
    source: int  # index into the bridge's source list (names travel once, through the pipe)
    stale: bool  # the active source went stale: the servo process stops with reason "input stale"

    def same_motion(self, other: InputCommand | None) -> bool:
        """Asks for the same motion as ``other`` (a renewal: only the stamp and timeout differ)."""
        return other is not None and replace(other, stamp=self.stamp, timeout_s=self.timeout_s) == self

    def encode(self) -> np.ndarray:
        out = np.zeros(SIZE)
        out[0] = self.kind
        out[1] = FRAMES.index(self.frame)
        out[2:8] = self.values[:6]
        out[8:14] = (self.linear_speed, self.angular_speed, self.stamp, self.timeout_s, self.source,
                     float(self.stale))
        return out

    @classmethod
    def decode(cls, data: np.ndarray) -> InputCommand:
        return cls(kind=int(data[0]), frame=FRAMES[int(data[1])], values=tuple(float(v) for v in data[2:8]),
                   linear_speed=float(data[8]), angular_speed=float(data[9]), stamp=float(data[10]),
                   timeout_s=float(data[11]), source=int(data[12]), stale=bool(data[13]))


class InputSlotWriter:
    def __init__(self) -> None:
        self.slot = LatestValueSlot(SIZE)

    @property
    def name(self) -> str:
        return self.slot.name

    def publish(self, cmd: InputCommand) -> None:
        self.slot.write(cmd.encode())

    def close(self) -> None:
        self.slot.close()


class InputSlotReader:
    def __init__(self, name: str) -> None:
        self.slot = LatestValueSlot(SIZE, name=name, create=False)
        self._version = 0
        self._peeked: tuple[int, InputCommand] | None = None
        self.current: InputCommand | None = None  # the command last taken (poll, or peek and consume)
        self.torn_reads = 0

    def poll(self) -> InputCommand | None:
        """The command if it changed since the last poll, else None.

        The writer is an ordinary thread of the API process: the scheduler may stop it halfway through
        a write for milliseconds (seen under load: the servo process spun out its retries and died,
        MOTN-603). A write still in progress reads as "nothing new"; the command in force keeps only
        its own hold-to-run, and the next cycle reads the finished write."""
        cmd = self.peek()
        if cmd is not None:
            self.consume()
        return cmd

    def peek(self) -> InputCommand | None:
        """Like :meth:`poll`, but the command stays new until :meth:`consume` takes it."""
        if self.slot.version == self._version:  # nothing written since: the slot's counter alone
            return None
        try:
            version, data = self.slot.read(retries=100)
        except TimeoutError:
            self.torn_reads += 1
            return None
        if version == self._version:
            return None
        cmd = InputCommand.decode(data)
        self._peeked = (version, cmd)
        return cmd

    def consume(self) -> None:
        """The command the last :meth:`peek` returned is taken (a newer write stays new)."""
        assert self._peeked is not None, "consume() follows a peek() that returned a command"
        self._version, self.current = self._peeked

    def close(self) -> None:
        self.slot.close()


MAX_HOLD_S = 2.0  # the longest a live input command holds the arm, whatever timeout it carries


class InputControl:
    """What a servo-process supervisor keeps about input control, the same for every backend.

    Inputs move the arm only after the lease holder enables them (request op ``inputs``). A stale
    source (or "nothing live" while one was driving) is reported once through ``on_stale``; a live
    command goes to ``move(cmd, source_name, hold_s)``; a refused one is kept as ``error`` and
    changes nothing.
    """

    def __init__(self, min_hold_s: float) -> None:
        self.enabled = False
        self.sources: list[str] = []
        self.error = ""
        self.min_hold_s = min_hold_s
        self._active = False

    def configure(self, enable: bool = False, sources: list[str] | None = None) -> None:
        self.enabled = bool(enable)
        if sources is not None:
            self.sources = [str(x) for x in sources]

    def name(self, cmd: InputCommand) -> str:
        return self.sources[cmd.source] if 0 <= cmd.source < len(self.sources) else str(cmd.source)

    def apply(self, cmd: InputCommand, on_stale: Callable[[str], None],
              move: Callable[[InputCommand, str, float], None]) -> None:
        if not self.enabled:
            return
        name = self.name(cmd)
        try:
            if cmd.stale or cmd.kind == NONE:
                if self._active:
                    on_stale(name)
                self._active = False
                return
            move(cmd, name, min(max(cmd.timeout_s, self.min_hold_s), MAX_HOLD_S))
            self._active = True
            self.error = ""
        except ValueError as exc:  # refused (CommandRejected is one): reported, the arm stays as it is
            self.error = f"{name}: {exc}"
