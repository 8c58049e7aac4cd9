"""The bridge's threads. A sample is stepped in the thread that publishes it (`on_sample`); the
bridge's own thread keeps the clocks: it sleeps until the source in control would go stale, a stale
marker's latch ends or an application's period comes round (tracking re-extrapolates between camera
frames), and wakes at least every `HOUSEKEEPING_S`. A second thread carries out button actions.
"""

from __future__ import annotations

import logging
import sys
import threading
from collections.abc import Sequence

from servo_app.inputs.adapter import Clock, InputAdapter, SourceSpec
from servo_app.inputs.apps.base import Application
from servo_app.inputs.bridge.buttons import ButtonActions
from servo_app.inputs.bridge.pipeline import Pipeline
from servo_app.inputs.problems import ProblemLog

HOUSEKEEPING_S = 0.1  # the loop wakes at least this often (rates, summaries)


def next_deadline(now: float, active: SourceSpec | None, latched_until: float, apps: Sequence[Application]) -> float:
    """When the bridge's thread must step next: the source in control goes stale, the latch ends, an
    application is due, or housekeeping."""
    t = now + HOUSEKEEPING_S
    if active is not None:
        cur = active.slot.read()
        if cur is not None:
            t = min(t, cur.stamp + active.stale_after_s + 1e-4)  # the moment it goes stale
    if latched_until > now:
        t = min(t, latched_until)
    return min([t] + [app.next_due() for app in apps])


class BridgeLoop:
    """Built before the sources (they call `on_sample`), given what it drives by `drive`; samples are
    only stepped once `start` runs the thread."""

    def __init__(self, clock: Clock, problems: ProblemLog, switch_interval_s: float | None) -> None:
        self.clock = clock
        self.problems = problems
        self.switch_interval_s = switch_interval_s
        self.adapters: Sequence[InputAdapter] = ()
        self.pipeline: Pipeline
        self.buttons: ButtonActions
        self._wake = threading.Event()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._acting: threading.Thread | None = None

    def drive(self, adapters: Sequence[InputAdapter], pipeline: Pipeline, buttons: ButtonActions) -> None:
        self.adapters, self.pipeline, self.buttons = adapters, pipeline, buttons
        self._arbiter = pipeline.arbiter
        self._publication = pipeline.publication
        self._step = pipeline.step

    def wake(self) -> None:
        """Step now (control changed): the thread publishes the new decision at once."""
        self._wake.set()

    def start(self) -> None:
        # A thread woken by a sample waits for the GIL up to the switch interval (5 ms by default) while
        # uvicorn or another adapter runs; at 1 ms the sensor -> slot p99 fell from 3-4 ms to about 2 ms
        # (bench/input_latency.py). Process-wide, so only ever lowered; the servo cycle has its own process.
        if self.switch_interval_s is not None and sys.getswitchinterval() > self.switch_interval_s:
            sys.setswitchinterval(self.switch_interval_s)
        for a in self.adapters:
            a.start()
        self._stop.clear()
        self._thread = threading.Thread(target=self._run, name="inputs-bridge", daemon=True)
        self._thread.start()
        self._acting = threading.Thread(target=self.buttons.serve, args=(self._stop,), name="inputs-actions",
                                        daemon=True)
        self._acting.start()

    def stop(self) -> None:
        """Stop the threads, then every adapter (each closes its device)."""
        self._stop.set()
        self._wake.set()
        for t in (self._thread, self._acting):
            if t is not None:
                t.join(5.0)
        self._thread = self._acting = None
        for a in self.adapters:
            a.stop()
        for log in self._problem_logs():  # counts still held back by the log's rate limit
            log.flush()

    def _problem_logs(self) -> list[ProblemLog]:
        return [self.problems, *(app.problems for app in self.pipeline.apps)]

    def _report_due(self) -> None:
        """Held-back counts whose kind did not recur reach the log (each at most once per interval)."""
        for log in self._problem_logs():
            log.report_due()

    def on_sample(self) -> None:
        """A new sample: step right here in the publishing thread, one GIL hand-over sooner than waking
        the bridge's thread (measured: sensor -> slot p99 2.3 -> 1.7 ms). The thread keeps the
        clocks: staleness, application periods. It only needs waking when control moved, since newer
        samples of the same source can only move its stale deadline later (an early wake-up is harmless)."""
        if self._thread is None:
            return
        active = self._arbiter.active
        try:
            self._step(self.clock())
        except Exception as exc:  # the publisher (an adapter, a request) must not fail for the bridge
            self.problems.record("error", f"{type(exc).__name__}: {exc}", level=logging.ERROR, exc_info=True)
        if self._arbiter.active != active or self._publication.latched_until > self.clock():
            self._wake.set()

    def _run(self) -> None:
        timeout = 0.0
        while not self._stop.is_set():
            self._wake.wait(timeout)
            self._wake.clear()
            if self._stop.is_set():
                return
            try:
                now = self.clock()
                self._step(now)
                self._report_due()
                timeout = max(0.0, self._next_deadline(now) - self.clock())
            except Exception as exc:  # a bug must not end the loop: the servo's hold stops the arm meanwhile
                self.problems.record("error", f"{type(exc).__name__}: {exc}", level=logging.ERROR, exc_info=True)
                timeout = 0.01

    def _next_deadline(self, now: float) -> float:
        active = self._arbiter.active
        spec = None if active is None else self._publication.specs[active]
        return next_deadline(now, spec, self._publication.latched_until, self.pipeline.apps)
