"""The inputs bridge as the service and the API see it: one object that wires the parts (wiring),
runs their threads (loop), steps them (pipeline, publication), carries out button actions (buttons)
and reports (status).

Nothing here imports the robot side: the service passes `request` (an op to the servo process),
`feedback` (its published state) and `act` (an output action) in `start`.
"""

from __future__ import annotations

import contextlib
import logging
import time
from collections import Counter, deque
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

from servo_app.input_slot import InputCommand, InputSlotWriter
from servo_app.inputs.actions import OutputToggle
from servo_app.inputs.adapter import Clock, InputAdapter, SourceSpec
from servo_app.inputs.apps.base import Application
from servo_app.inputs.apps.config import AppConfig, load_service_inputs
from servo_app.inputs.arbiter import Arbiter
from servo_app.inputs.bridge.buttons import Act, ButtonActions
from servo_app.inputs.bridge.loop import BridgeLoop
from servo_app.inputs.bridge.pipeline import Feedback, Pipeline
from servo_app.inputs.bridge.publication import Publication
from servo_app.inputs.bridge.status import application_rows, describe_view, source_rows, summary_view
from servo_app.inputs.bridge.wiring import Slots, wire
from servo_app.inputs.config import InputsConfig
from servo_app.inputs.device_failure import DeviceFailure
from servo_app.inputs.feed import FeedRegistry
from servo_app.inputs.problems import ProblemLog
from servo_app.inputs.samples import ButtonEvent
from servo_app.messages import ConfigureInputs

Request = Callable[[ConfigureInputs], Any]  # the service's request(): a typed message to the servo process


class InputNotLive(RuntimeError):
    """Refused for now: an application's sensor is not sending (the request changed nothing)."""


class InputsBridge:
    def __init__(self, cfg: InputsConfig, apps: Sequence[AppConfig] = (), *, clock: Clock = time.monotonic,
                 hold_grace_s: float = 0.05, stale_latch_s: float = 0.05,
                 pose_speeds: tuple[float, float] = (100.0, 30.0), switch_interval_s: float | None = 0.001) -> None:
        self.clock = clock
        self.switch_interval_s = switch_interval_s
        self.problems = ProblemLog(logging.getLogger("servo_app.inputs.bridge"), clock)
        self._buttons = ButtonActions(clock, self.problems, lambda: self.enabled)
        self._loop = BridgeLoop(clock, self.problems, switch_interval_s)
        w = wire(cfg, apps, clock=clock, on_sample=self._loop.on_sample, on_button=self._buttons.on_button)
        self._wiring = w
        self.adapters: list[InputAdapter] = w.adapters
        self.feeds: FeedRegistry = w.feeds
        self.kinds: dict[str, str] = w.kinds
        self.apps: list[Application] = w.apps
        self.specs: dict[str, SourceSpec] = w.specs
        self.source_names: list[str] = w.source_names
        self.slots: Slots = w.slots
        self.arbiter = Arbiter(self.specs.values(), clock=clock)
        self._publication = Publication(self.specs, self.source_names, self.apps, hold_grace_s=hold_grace_s,
                                        stale_latch_s=stale_latch_s, pose_speeds=pose_speeds,
                                        rejected=lambda why: self.problems.record("rejected", why))
        self._pipeline = Pipeline(self.apps, self.arbiter, self._publication, self.slots)
        self._loop.drive(self.adapters, self._pipeline, self._buttons)
        self._lock = self._pipeline.lock
        self._request: Request | None = None

    @classmethod
    def from_file(cls, path: str | Path, **kw: Any) -> InputsBridge:
        cfg, apps = load_service_inputs(path)
        return cls(cfg, apps, **kw)

    # ------------------------------------------------------------ the parts' state
    @property
    def writer(self) -> InputSlotWriter:
        return self._pipeline.writer

    @property
    def slot_name(self) -> str:
        return self._pipeline.writer.name

    @property
    def enabled(self) -> bool:
        return self._pipeline.enabled

    @enabled.setter
    def enabled(self, on: bool) -> None:
        self._pipeline.enabled = on

    @property
    def published(self) -> int:
        return self._pipeline.published

    @property
    def last_command(self) -> InputCommand | None:
        return self._pipeline.last_command

    @property
    def stale_events(self) -> Counter[str]:
        return self._publication.stale_events

    @property
    def actions(self) -> deque[dict[str, Any]]:
        """The latest output actions and how they went."""
        return self._buttons.actions

    # ------------------------------------------------------------------ life
    def start(self, request: Request | None = None, feedback: Feedback | None = None, act: Act | None = None) -> None:
        self._request, self._pipeline.feedback, self._buttons.act = request, feedback, act
        for adapter in self.adapters:
            adapter.robot_state = feedback
        self._loop.start()

    def stop(self) -> None:
        """Stop the loop, then every adapter (each closes its device)."""
        self._loop.stop()

    def close(self) -> None:
        """After the servo process is gone: release the shared-memory slot too."""
        self.stop()
        with contextlib.suppress(OSError, AttributeError):
            self.writer.close()

    def failures(self) -> list[tuple[InputAdapter, DeviceFailure]]:
        """The adapters whose device cannot be opened now, with why."""
        return [(a, f) for a in self.adapters if (f := a.failure) is not None]

    def wait_first_open(self, timeout: float) -> list[tuple[InputAdapter, DeviceFailure]]:
        """Wait (at most ``timeout`` s in all) until every adapter has tried to open its device once;
        then the ones that failed. For the start-up report."""
        deadline = time.monotonic() + timeout
        for a in self.adapters:
            if a.running:
                a.first_attempt.wait(max(0.0, deadline - time.monotonic()))
        return self.failures()

    def _users(self, source: str) -> list[str]:
        """The applications that take input from ``source``."""
        return [app.name for app in self.apps if any(ref.source == source for ref in app.inputs.values())]

    def _failure_text(self, name: str, failure: DeviceFailure) -> str:
        users = self._users(name)
        used = f" (used by {', '.join(repr(u) for u in users)})" if users else ""
        return f"input source {name!r}{used} cannot command: {failure.message}"

    # --------------------------------------------------------------- control
    def enable(self, on: bool) -> dict[str, Any]:
        """Let the input sources move the arm (or stop them); the servo process gets the source names.
        Enabling while a source's device cannot be opened goes ahead (the others may command), and the
        answer says which source, why, and what to do."""
        if self._request is None:
            raise RuntimeError("the inputs bridge is not connected to a servo process")
        self._request(ConfigureInputs(enable=bool(on), sources=tuple(self.source_names)))
        self._pipeline.enable(bool(on))
        self._loop.wake()
        out: dict[str, Any] = {"enabled": self.enabled, "sources": self.source_names}
        failed = self.failures()
        if on and failed:
            out["failed_sources"] = [{"name": a.name, "used_by": self._users(a.name), **f.view()} for a, f in failed]
            out["warning"] = "; ".join(self._failure_text(a.name, f) for a, f in failed)
        return out

    def servo_gone(self) -> None:
        """The servo process that took input control ended: a new one starts with it off, so the bridge
        says off too (it said "enabled" while nothing followed the inputs); the lease holder enables
        again."""
        self._pipeline.enable(False)
        self._loop.wake()

    def set_owner(self, name: str | None) -> dict[str, Any]:
        """Give one source exclusive control (the others stay connected and reported, but cannot
        command); None gives it back to priority among all. KeyError names an unknown source."""
        with self._lock:
            self.arbiter.set_owner(name)
        self._loop.wake()  # the bridge's thread publishes the new decision (or the stop) at once
        return {"owner": name, "sources": list(self.specs)}

    def application(self, name: str) -> Application:
        for app in self.apps:
            if app.name == name:
                return app
        raise KeyError(f"no application named {name!r}; configured: {[a.name for a in self.apps]}")

    def zero(self, name: str, samples: int | None = None) -> None:
        """Zero a force/torque application's bias from its next samples (nobody touching the tool)."""
        app = self.application(name)
        zero = getattr(app, "zero", None)
        if zero is None:
            raise ValueError(f"application {name!r} ({app.type_name}) has no sensor bias to zero")
        with self._lock:
            # The bias comes from the next samples: with the sensor unplugged, they were whatever it read
            # when it came back (a hand on the tool, say), and guiding then pushed by itself on release.
            now = self.clock()
            for ref in app.inputs.values():
                if ref.required and ref.fresh(now) is None:
                    cur = ref.slot.read()
                    quiet = ("has sent nothing yet" if cur is None else
                             f"has sent nothing for {now - cur.stamp:.2f} s (stale after {ref.stale_after_s} s)")
                    raise InputNotLive(f"application {name!r} cannot zero: its sensor {ref.source!r} {quiet}; the "
                                       "bias is taken from its next samples with nobody touching the tool, so "
                                       "get the sensor sending, then zero again")
            zero(samples)

    def act_on(self, ev: ButtonEvent, action: OutputToggle) -> None:
        """Carry out one output action (the action thread calls this; tests may too)."""
        self._buttons.act_on(ev, action)

    def step(self, now: float) -> None:
        """One pass: applications, arbitration, publication (the thread calls this; tests may too)."""
        self._pipeline.step(now)

    # ----------------------------------------------------------------- views
    def summary(self) -> dict[str, Any]:
        """Short, for GET /api/state (the console polls it): sources with rate, age and staleness."""
        now = self.clock()
        with self._lock:
            rows = source_rows(self._wiring, self.arbiter.active, now, self._pipeline.rates)
        return summary_view(self, rows)

    def describe(self) -> dict[str, Any]:
        """Everything, for GET /api/inputs: sources with errors, applications, the last command."""
        now = self.clock()
        with self._lock:
            rows = source_rows(self._wiring, self.arbiter.active, now, self._pipeline.rates)
            apps = application_rows(self.apps)
            last = self.last_command
        return describe_view(self, now, rows, apps, last)
