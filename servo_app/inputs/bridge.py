"""The inputs bridge (API process): adapters, feeds and applications -> arbiter -> the servo's input slot.

Every sample is handled at once in the thread that publishes it (an adapter's thread, or the request
that carried a feed message): the applications whose inputs changed run, the arbiter picks who
commands, and that source's newest sample goes into the shared-memory slot the servo process reads
each cycle. The bridge's own thread keeps the clocks: it sleeps until the source in control
would go stale or an application's period comes round (tracking re-extrapolates between camera
frames). Each sample renews the servo's hold-to-run for the source's timeout plus `hold_grace_s`, so
the bridge's explicit "stale" always reaches the servo before its hold would run out by itself, and
the stop says which input it was.

When the source in control goes stale the bridge publishes the stale marker and keeps it for
`stale_latch_s` even if another source is live, so the servo process surely reads it (the slot holds
only the newest value): losing the controlling sensor stops the arm until the operator resumes.

Button presses mapped to an output action (``toggle_output:DO[1]``, :mod:`servo_app.inputs.actions`)
are carried out by the bridge's action thread through `act` (the service's I/O), never in the
adapter's thread: an output is read and written through the stream's packets, which takes cycles.
They act only while input control is enabled; each outcome is in `describe()`.

Nothing here imports the robot side: the service passes `request` (an op to the servo process),
`feedback` (its published state) and `act` (an output action) in `start`.
"""

from __future__ import annotations

import contextlib
import logging
import math
import sys
import threading
import time
from collections import Counter, deque
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

from servo_app.input_slot import FRAMES, NONE, POSE, TWIST, InputCommand, InputSlotWriter
from servo_app.inputs.actions import OutputToggle, parse_action
from servo_app.inputs.adapter import Clock, InputAdapter, SourceSpec
from servo_app.inputs.apps.base import Application
from servo_app.inputs.apps.config import AppConfig, build_application, load_service_inputs, source_kinds
from servo_app.inputs.arbiter import Arbiter, Decision
from servo_app.inputs.bridge_status import RateMeter, finite_or_none, source_rows
from servo_app.inputs.config import InputsConfig, build_adapters
from servo_app.inputs.feed import FeedRegistry
from servo_app.inputs.feed.models import FeedSourceConfig
from servo_app.inputs.problems import ProblemLog
from servo_app.inputs.samples import ButtonEvent, PoseSample, TwistSample
from servo_app.inputs.slots import EventQueue, LatestValue
from servo_app.inputs.validate import ValueRejected
from servo_app.messages import ConfigureInputs

Request = Callable[[ConfigureInputs], Any]  # the service's request(): a typed message to the servo process
Feedback = Callable[[], Mapping[str, Any]]
Act = Callable[[OutputToggle], Any]
HOUSEKEEPING_S = 0.1  # the loop wakes at least this often (rates, summaries)


class _NotifyingSlot(LatestValue[Any]):
    """An adapter's output slot that tells the bridge about each sample."""

    def __init__(self, name: str, notify: Callable[[], None]) -> None:
        super().__init__(name)
        self._notify = notify

    def publish(self, value: Any, stamp: float | None = None) -> int:
        seq = super().publish(value, stamp)
        self._notify()
        return seq


class _ActingEvents(EventQueue[ButtonEvent]):
    """An adapter's button events, each also handed to the bridge (which picks the output actions)."""

    def __init__(self, on_event: Callable[[ButtonEvent], None]) -> None:
        super().__init__()
        self._on_event = on_event

    def put(self, item: ButtonEvent) -> None:
        super().put(item)
        self._on_event(item)


class _NotifyingFeeds(FeedRegistry):
    """The feed registry that tells the bridge about every message."""

    def __init__(self, sources: Mapping[str, FeedSourceConfig], notify: Callable[[], None], clock: Clock) -> None:
        self._notify = notify
        super().__init__(sources, clock=clock)

    def submit(self, source: str, message: Any) -> Any:
        try:
            return super().submit(source, message)
        finally:
            self._notify()


class InputsBridge:
    def __init__(self, cfg: InputsConfig, apps: Sequence[AppConfig] = (), *, clock: Clock = time.monotonic,
                 hold_grace_s: float = 0.05, stale_latch_s: float = 0.05,
                 pose_speeds: tuple[float, float] = (100.0, 30.0), switch_interval_s: float | None = 0.001) -> None:
        self.clock = clock
        self.switch_interval_s = switch_interval_s
        self.hold_grace_s = hold_grace_s
        self.stale_latch_s = stale_latch_s
        self.pose_speeds = pose_speeds  # mm/s, deg/s caps for pose feeds that no application wraps
        self._wake = threading.Event()
        self.adapters: list[InputAdapter] = build_adapters(cfg, clock=clock)
        for a in self.adapters:
            a.output = _NotifyingSlot(a.name, self._on_sample)  # before start: the adapter's thread publishes here
            a.events = _ActingEvents(self._on_button)
        self.feeds: FeedRegistry = _NotifyingFeeds(cfg.feeds, self._on_sample, clock)
        self.kinds = source_kinds(cfg)
        slots: dict[str, tuple[LatestValue[Any], float]] = {a.name: (a.output, a.stale_after_s) for a in self.adapters}
        slots.update({n: (self.feeds.slot(n), f.stale_after_s) for n, f in cfg.feeds.items()})
        self.apps: list[Application] = [build_application(c, slots, clock=clock) for c in apps]
        consumed = {src for c in apps for src in c.sources.values()}
        direct = [a.source_spec() for a in self.adapters
                  if a.name not in consumed and self.kinds[a.name] != "measurement"]
        direct += [s for s in self.feeds.specs() if s.name not in consumed]
        self.specs: dict[str, SourceSpec] = {s.name: s for s in direct + [app.source_spec() for app in self.apps]}
        self.arbiter = Arbiter(self.specs.values(), clock=clock)
        # The servo process names a source by its index here; application inputs come after the
        # arbiter's sources so a stale stop can name the sensor that went quiet.
        names = list(self.specs)
        names += [ref.source for app in self.apps for ref in app.inputs.values() if ref.source not in names]
        self.source_names: list[str] = list(dict.fromkeys(names))
        self.slots = slots | {app.name: (app.output, app.stale_after_s) for app in self.apps}
        self.writer = InputSlotWriter()
        self.enabled = False
        self.published = 0
        self.stale_events: Counter[str] = Counter()
        self.last_command: InputCommand | None = None
        self.problems = ProblemLog(logging.getLogger("servo_app.inputs.bridge"), clock)
        self._rates = RateMeter()
        self._last: tuple[str | None, int] | None = None  # (source, sample seq) last published
        self._latched_until = -math.inf
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._request: Request | None = None
        self._feedback: Feedback | None = None
        self._act: Act | None = None
        self._presses: EventQueue[tuple[ButtonEvent, OutputToggle]] = EventQueue(maxlen=16)
        self._acting: threading.Thread | None = None
        self.actions: deque[dict[str, Any]] = deque(maxlen=20)  # the latest output actions and how they went

    @classmethod
    def from_file(cls, path: str | Path, **kw: Any) -> InputsBridge:
        cfg, apps = load_service_inputs(path)
        return cls(cfg, apps, **kw)

    @property
    def slot_name(self) -> str:
        return self.writer.name

    # ------------------------------------------------------------------ life
    def start(self, request: Request | None = None, feedback: Feedback | None = None, act: Act | None = None) -> None:
        self._request, self._feedback, self._act = request, feedback, act
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
        self._acting = threading.Thread(target=self._run_actions, name="inputs-actions", daemon=True)
        self._acting.start()

    def stop(self) -> None:
        """Stop the loop, then every adapter (each closes its device)."""
        self._stop.set()
        self._wake.set()
        for t in (self._thread, self._acting):
            if t is not None:
                t.join(5.0)
        self._thread = self._acting = None
        for a in self.adapters:
            a.stop()

    def close(self) -> None:
        """After the servo process is gone: release the shared-memory slot too."""
        self.stop()
        with contextlib.suppress(OSError, AttributeError):
            self.writer.close()

    # --------------------------------------------------------------- control
    def enable(self, on: bool) -> dict[str, Any]:
        """Let the input sources move the arm (or stop them); the servo process gets the source names."""
        if self._request is None:
            raise RuntimeError("the inputs bridge is not connected to a servo process")
        self._request(ConfigureInputs(enable=bool(on), sources=tuple(self.source_names)))
        with self._lock:
            self.enabled = bool(on)
            self._last = None  # the next sample is sent again, whatever was sent while disabled
            for app in self.apps:
                reset = getattr(app, "reset_error", None)
                if on and reset is not None:
                    reset()
        self._wake.set()
        return {"enabled": self.enabled, "sources": self.source_names}

    def set_owner(self, name: str | None) -> dict[str, Any]:
        """Give one source exclusive control (the others stay connected and reported, but cannot
        command); None gives it back to priority among all. KeyError names an unknown source."""
        with self._lock:
            self.arbiter.set_owner(name)
        self._wake.set()  # the bridge's thread publishes the new decision (or the stop) at once
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
            zero(samples)

    # --------------------------------------------------------------- buttons
    def _on_button(self, ev: ButtonEvent) -> None:
        """An adapter's thread: queue a press mapped to an output action (configuration checked it)."""
        if ev.pressed and ev.action is not None:
            action = parse_action(ev.action)
            if isinstance(action, OutputToggle):
                self._presses.put((ev, action))

    def _run_actions(self) -> None:
        while not self._stop.is_set():
            item = self._presses.get(timeout=0.1)
            if item is not None:
                self.act_on(*item)

    def act_on(self, ev: ButtonEvent, action: OutputToggle) -> None:
        """Carry out one output action (the action thread calls this; tests may too)."""
        row: dict[str, Any] = {"source": ev.source, "button": ev.button, "action": str(action), "ok": False}
        try:
            if self._act is None:
                raise RuntimeError("no robot I/O connected")
            if not self.enabled:
                raise RuntimeError("input control is not enabled")
            row["result"] = self._act(action)
            row["ok"] = True
        except Exception as exc:  # refused (not streaming, I/O not allowed) or failed: reported, nothing else
            row["error"] = f"{type(exc).__name__}: {exc}"
            self.problems.record("action_failed", f"{ev.source} button {ev.button} {action}: {row['error']}")
        row["took_s"] = round(self.clock() - ev.stamp, 4)  # press to done
        self.actions.append(row)

    # ------------------------------------------------------------------ loop
    def _on_sample(self) -> None:
        """A new sample: step right here in the publishing thread, one GIL hand-over sooner than waking
        the bridge's thread (measured: sensor -> slot p99 2.3 -> 1.7 ms). The thread keeps the
        clocks: staleness, application periods. It only needs waking when control moved, since newer
        samples of the same source can only move its stale deadline later (an early wake-up is harmless)."""
        if self._thread is None:
            return
        active = self.arbiter.active
        try:
            self.step(self.clock())
        except Exception as exc:  # the publisher (an adapter, a request) must not fail for the bridge
            self.problems.record("error", f"{type(exc).__name__}: {exc}", level=logging.ERROR, exc_info=True)
        if self.arbiter.active != active or self._latched_until > self.clock():
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
                self.step(now)
                timeout = max(0.0, self._next_deadline(now) - self.clock())
            except Exception as exc:  # a bug must not end the loop: the servo's hold stops the arm meanwhile
                self.problems.record("error", f"{type(exc).__name__}: {exc}", level=logging.ERROR, exc_info=True)
                timeout = 0.01

    def step(self, now: float) -> None:
        """One pass: applications, arbitration, publication (the thread calls this; tests may too)."""
        with self._lock:
            updated = [app for app in self.apps if app.update(now)]
            decision = self.arbiter.select(now)
            self._publish(decision, now)
            self._observe(updated, decision, now)
            self._rates.sample(now, {n: slot.seq for n, (slot, _) in self.slots.items()})

    def _next_deadline(self, now: float) -> float:
        t = now + HOUSEKEEPING_S
        active = self.arbiter.active
        if active is not None:
            cur = self.specs[active].slot.read()
            if cur is not None:
                t = min(t, cur.stamp + self.specs[active].stale_after_s + 1e-4)  # the moment it goes stale
        if self._latched_until > now:
            t = min(t, self._latched_until)
        return min([t] + [app.next_due() for app in self.apps])

    def _observe(self, updated: list[Application], decision: Decision, now: float) -> None:
        watchers = [a for a in updated if a.wants_feedback]
        if not watchers or self._feedback is None:
            return
        try:
            fb = self._feedback()
        except (OSError, RuntimeError, TimeoutError, ValueError):
            return
        for app in watchers:
            app.observe(now, fb, active=self.enabled and decision.active == app.name)

    # ------------------------------------------------------------ publishing
    def _publish(self, d: Decision, now: float) -> None:
        if d.went_stale is not None:
            culprit = self._culprit(d.went_stale, now)
            self.stale_events[culprit] += 1
            self._send(InputCommand(NONE, "base", (0.0,) * 6, 0.0, 0.0, now, 0.0, self._index(culprit), True))
            self._last = (None, 0)
            self._latched_until = now + self.stale_latch_s
            return
        if now < self._latched_until:
            return  # the servo process must read the stale marker before anything replaces it
        if d.active is None:
            if self._last is not None and self._last[0] is not None:  # control withdrawn (disabled source)
                self._send(InputCommand(NONE, "base", (0.0,) * 6, 0.0, 0.0, now, 0.0, 0, False))
                self._last = (None, 0)
            return
        cur = self.specs[d.active].slot.read()
        if cur is None or (d.active, cur.seq) == self._last:
            return
        self._last = (d.active, cur.seq)
        try:
            cmd = self._command(d.active, cur.value)
        except ValueError as exc:
            self.problems.record("rejected", f"source {d.active!r}: {exc}")
            return
        self._send(cmd)

    def _send(self, cmd: InputCommand) -> None:
        self.writer.publish(cmd)
        self.published += 1
        self.last_command = cmd

    def _command(self, name: str, sample: Any) -> InputCommand:
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

    # ----------------------------------------------------------------- views
    def summary(self) -> dict[str, Any]:
        """Short, for GET /api/state (the console polls it): sources with rate, age and staleness."""
        now = self.clock()
        with self._lock:
            rows = source_rows(self, now, self._rates)
        return {"enabled": self.enabled, "active": self.arbiter.active, "owner": self.arbiter.owner,
                "sources": [{k: r[k] for k in ("name", "kind", "rate_hz", "age_s", "stale", "active", "latency_ms")
                             if k in r} for r in rows]}

    def describe(self) -> dict[str, Any]:
        """Everything, for GET /api/inputs: sources with errors, applications, the last command."""
        now = self.clock()
        with self._lock:
            rows = source_rows(self, now, self._rates)
            apps = [{"name": a.name, "type": a.type_name, "priority": a.priority,
                     "sources": {r: i.source for r, i in a.inputs.items()}, **a.describe()} for a in self.apps]
            last = self.last_command
        return {
            "enabled": self.enabled, "active": self.arbiter.active, "owner": self.arbiter.owner,
            "slot": self.slot_name,
            "servo_sources": self.source_names, "sources": rows, "applications": apps,
            "published": self.published, "stale_events": dict(self.stale_events), "button_actions": list(self.actions),
            "bridge_problems": dict(self.problems.snapshot()[0]),
            "last_command": None if last is None else {
                "kind": ("none", "twist", "pose")[last.kind], "source": self.source_names[last.source]
                if 0 <= last.source < len(self.source_names) else None, "frame": last.frame,
                "values": list(last.values), "stale": last.stale, "age_s": finite_or_none(now - last.stamp)},
        }
