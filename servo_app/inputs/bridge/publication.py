"""What goes into the servo's input slot, and when (pure: a decision in, a command or nothing out).

The source in control has its newest sample sent once, as a twist or pose command that renews the
servo's hold-to-run for the source's timeout plus `hold_grace_s`. When the source in control goes
stale the bridge publishes the stale marker and keeps it for `stale_latch_s` even if another source is
live, so the servo process surely reads it (the slot holds only the newest value): losing the
controlling sensor stops the arm until the operator resumes.
"""

from __future__ import annotations

import math
from collections import Counter
from collections.abc import Callable, Mapping, Sequence
from typing import Any

from servo_app.input_slot import FRAMES, NONE, POSE, TWIST, InputCommand
from servo_app.inputs.adapter import SourceSpec
from servo_app.inputs.apps.base import Application
from servo_app.inputs.arbiter import Decision
from servo_app.inputs.samples import PoseSample, TwistSample
from servo_app.inputs.validate import ValueRejected


def stop_command(now: float, index: int, stale: bool) -> InputCommand:
    """Nothing to follow: the stale marker naming source `index`, or control withdrawn (index 0)."""
    return InputCommand(NONE, "base", (0.0,) * 6, 0.0, 0.0, now, 0.0, index, stale)


class Publication:
    def __init__(self, specs: Mapping[str, SourceSpec], source_names: Sequence[str], apps: Sequence[Application],
                 *, hold_grace_s: float, stale_latch_s: float, pose_speeds: tuple[float, float],
                 rejected: Callable[[str], Any]) -> None:
        self.specs = specs
        self.source_names = source_names
        self.apps = apps
        self.hold_grace_s = hold_grace_s
        self.stale_latch_s = stale_latch_s
        self.pose_speeds = pose_speeds  # mm/s, deg/s caps for pose feeds that no application wraps
        self.rejected = rejected  # told why a sample was refused
        self.stale_events: Counter[str] = Counter()
        self.latched_until = -math.inf
        self._last: tuple[str | None, int] | None = None  # (source, sample seq) last published

    def resend(self) -> None:
        """The next sample is sent again, whatever was sent before."""
        self._last = None

    def command_for(self, d: Decision, now: float) -> InputCommand | None:
        """The command to publish after decision `d`, if any."""
        if d.went_stale is not None:
            culprit = self._culprit(d.went_stale, now)
            self.stale_events[culprit] += 1
            marker = stop_command(now, self._index(culprit), True)
            self._last = (None, 0)
            self.latched_until = now + self.stale_latch_s
            return marker
        if now < self.latched_until:
            return None  # the servo process must read the stale marker before anything replaces it
        if d.active is None:
            if self._last is not None and self._last[0] is not None:  # control withdrawn (disabled source)
                self._last = (None, 0)
                return stop_command(now, 0, False)
            return None
        cur = self.specs[d.active].slot.read()
        if cur is None or (d.active, cur.seq) == self._last:
            return None
        self._last = (d.active, cur.seq)
        try:
            return self._command(d.active, cur.value)
        except ValueError as exc:
            self.rejected(f"source {d.active!r}: {exc}")
            return None

    def _command(self, name: str, sample: Any) -> InputCommand:
        """A source's sample as the servo's command; ValueRejected for what the servo cannot follow."""
        hold = self.specs[name].stale_after_s + self.hold_grace_s
        index = self._index(name)
        if isinstance(sample, TwistSample):
            if sample.frame not in FRAMES:
                raise ValueRejected("frame", sample.frame, f"twists are commanded in {FRAMES}")
            return InputCommand(TWIST, sample.frame, sample.linear + sample.angular, 0.0, 0.0, sample.stamp, hold,
                                index, False)
        if isinstance(sample, PoseSample):
            if sample.frame != "base":
                raise ValueRejected("frame", sample.frame, "poses are commanded in the base (world) frame")
            lin, ang = self.pose_speeds
            app = next((a for a in self.apps if a.name == name), None)
            lin, ang = getattr(app, "linear_speed", lin), getattr(app, "angular_speed", ang)
            return InputCommand(POSE, "base", sample.xyzwpr, lin, ang, sample.stamp, hold, index, False)
        raise ValueRejected("sample", type(sample).__name__, "only twists and poses command the arm")

    def _index(self, name: str) -> int:
        return self.source_names.index(name)

    def _culprit(self, source: str, now: float) -> str:
        for app in self.apps:
            if app.name == source:
                return app.stale_input(now)
        return source
