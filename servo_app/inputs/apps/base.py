"""An input-driven application as a pipeline: named input slots -> control law -> one command sample.

An application reads the newest samples of the sources it names, runs its control law when any of
them changed (or on its own clock, for those that extrapolate), and publishes one twist or pose into
its own latest-value slot, which the arbiter then treats like any other command source.

Staleness carries through. The output's slot stamp is placed so that the output goes stale exactly
when the first required input does (each input by its own timeout), and `stale_input` names that
input, so the servo process can stop with "input <sensor> stale" rather than a vaguer name. An
optional input that is stale reads as absent (stand-off without the operator's jog: no sideways
motion). Bad input is counted and skipped: the output then ages and goes stale, it never carries it.
"""

from __future__ import annotations

import logging
import math
import time
from abc import ABC, abstractmethod
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, ClassVar

from servo_app.inputs.adapter import Clock, SourceSpec
from servo_app.inputs.problems import ProblemLog
from servo_app.inputs.samples import PoseSample, TwistSample
from servo_app.inputs.slots import LatestValue, Stamped

Feedback = Mapping[str, Any]  # the servo process's published state (cart_servo, status_received, ...)


@dataclass(frozen=True)
class InputRef:
    """One input of an application: the source's slot, its timeout, whether the output needs it."""

    role: str
    source: str
    slot: LatestValue[Any]
    stale_after_s: float
    required: bool = True

    def fresh(self, now: float) -> Stamped[Any] | None:
        cur = self.slot.read()
        if cur is None or now - cur.stamp > self.stale_after_s:
            return None
        return cur

    def expiry(self) -> float:
        cur = self.slot.read()
        return -math.inf if cur is None else cur.stamp + self.stale_after_s


class Application(ABC):
    type_name: ClassVar[str]
    roles: ClassVar[dict[str, tuple[str, bool]]]  # role -> (sample kind it takes, required)
    output_kind: ClassVar[str] = "twist"
    wants_feedback: ClassVar[bool] = False

    def __init__(self, name: str, inputs: Mapping[str, InputRef], *, priority: int = 0,
                 stale_after_s: float | None = None, yield_when_idle: bool = False,
                 period_s: float | None = None, clock: Clock = time.monotonic) -> None:
        missing = [r for r, (_, req) in self.roles.items() if req and r not in inputs]
        if missing:
            raise ValueError(f"application {name!r} needs the inputs {missing}")
        self.name = name
        self.inputs = dict(inputs)
        self.priority = priority
        required = [i.stale_after_s for i in self.inputs.values() if i.required]
        self.stale_after_s = stale_after_s or max(required)
        self.yield_when_idle = yield_when_idle
        self.period_s = period_s  # also run on this period without new input (extrapolation)
        self.output: LatestValue[Any] = LatestValue(name)
        self.problems = ProblemLog(logging.getLogger(f"servo_app.inputs.apps.{name}"), clock)
        self._seen = dict.fromkeys(self.inputs, 0)
        self._next_tick = -math.inf

    # -- what each application implements ---------------------------------------------------------
    @abstractmethod
    def compute(self, now: float, values: Mapping[str, Any], changed: set[str]) -> TwistSample | PoseSample | None:
        """The command from the fresh input values (by role; optional stale ones are absent)."""

    def observe(self, now: float, feedback: Feedback, active: bool) -> None:  # noqa: B027 - an optional hook
        """The servo's published state, for applications that report how well they follow."""

    def idle(self) -> None:  # noqa: B027 - an optional hook
        """Not commanding the arm this pass (input control off, another source in control, or, for one
        that `integrates`, the arm not streaming): a law that integrates forgets what it gathered, so
        taking over starts without a stored push."""

    @property
    def integrates(self) -> bool:
        """Whether the law gathers state over time (then the bridge also checks that the arm streams)."""
        return False

    def describe(self) -> dict[str, Any]:
        return {}

    # -- the pipeline -----------------------------------------------------------------------------
    def source_spec(self) -> SourceSpec:
        return SourceSpec(self.name, self.priority, self.stale_after_s, self.output, self.yield_when_idle)

    def next_due(self) -> float:
        return self._next_tick if self.period_s else math.inf

    def stale_input(self, now: float) -> str:
        """The one to blame when the output went stale: the required input whose timeout ran out first,
        or, when every one has sent since the last output (the law refused them: see its errors), the
        application itself. Blaming the input then stopped the arm with "input gauge stale" while the
        gauge streamed and stand-off refused an operator's base-frame twist."""
        req = [i for i in self.inputs.values() if i.required]
        first = min(req, key=lambda i: i.expiry())
        out = self.output.read()
        if out is not None and first.expiry() > out.stamp + self.stale_after_s + 1e-6:  # renewed since
            return self.name
        return first.source

    def update(self, now: float) -> bool:
        """Run the law if an input changed or the period came round; True if a sample was published."""
        changed = {r for r, ref in self.inputs.items() if ref.slot.seq != self._seen[r]}
        for r in changed:
            self._seen[r] = self.inputs[r].slot.seq
        due = self.period_s is not None and now >= self._next_tick
        if due:
            self._next_tick = now + self.period_s  # type: ignore[operator]
        if not changed and not due:
            return False
        expiry = min(i.expiry() for i in self.inputs.values() if i.required)
        if expiry <= now:
            return False  # a required input is missing or stale: the output ages with it
        values = {}
        for role, ref in self.inputs.items():
            cur = ref.fresh(now)
            if cur is not None:
                values[role] = cur.value
        try:
            sample = self.compute(now, values, changed)
        except (ValueError, KeyError, TypeError) as exc:  # ValueRejected is a ValueError
            kind = "bad_input" if isinstance(exc, KeyError | TypeError) else "rejected"
            self.problems.record(kind, f"{type(exc).__name__}: {exc}")
            return False
        if sample is None:
            return False
        self.output.publish(sample, stamp=expiry - self.stale_after_s)
        return True


def require(value: Any, cls: type[Any], role: str, app: str) -> Any:
    if not isinstance(value, cls):
        raise TypeError(f"application {app!r} input {role!r} gave a {type(value).__name__}, expected {cls.__name__}")
    return value
