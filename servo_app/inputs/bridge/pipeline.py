"""One pass of the bridge: the applications whose inputs changed run, the arbiter picks who commands,
the publication's command goes into the shared-memory slot the servo process reads each cycle, and
the applications that watch the robot get its published state.
"""

from __future__ import annotations

import threading
from collections.abc import Callable, Mapping, Sequence
from typing import Any

from servo_app.input_slot import InputCommand, InputSlotWriter
from servo_app.inputs.apps.base import Application
from servo_app.inputs.arbiter import Arbiter, Decision
from servo_app.inputs.bridge.publication import Publication
from servo_app.inputs.bridge.status import RateMeter
from servo_app.inputs.bridge.wiring import Slots

Feedback = Callable[[], Mapping[str, Any]]


class Pipeline:
    def __init__(self, apps: Sequence[Application], arbiter: Arbiter, publication: Publication, slots: Slots) -> None:
        self.apps = apps
        self.arbiter = arbiter
        self.publication = publication
        self.slots = slots
        self.writer = InputSlotWriter()
        self.lock = threading.Lock()  # one pass at a time; control changes and views wait for it
        self.rates = RateMeter()
        self.feedback: Feedback | None = None  # the servo process's published state, once started
        self.enabled = False
        self.published = 0
        self.last_command: InputCommand | None = None

    def step(self, now: float) -> None:
        with self.lock:
            updated = [app for app in self.apps if app.update(now)]
            decision = self.arbiter.select(now)
            for app in self.apps:
                # e.g. stand-off's integral would wind up against an arm it does not move: input control
                # off, another source in control, or the arm stopped (a stop over REST, say)
                if not self.enabled or decision.active != app.name or (app.integrates and not self._streaming()):
                    app.idle()
            cmd = self.publication.command_for(decision, now)
            if cmd is not None:
                self._send(cmd)
            self._observe(updated, decision, now)
            self.rates.sample(now, {n: slot.seq for n, (slot, _) in self.slots.items()})

    def enable(self, on: bool) -> None:
        with self.lock:
            self.enabled = on
            self.publication.resend()  # the next sample is sent again, whatever was sent while disabled
            for app in self.apps:
                reset = getattr(app, "reset_error", None)
                if on and reset is not None:
                    reset()

    def _streaming(self) -> bool:
        """Whether the servo process streams (True without a servo process to ask: tests, tools)."""
        if self.feedback is None:
            return True
        try:
            return self.feedback().get("state") == "streaming"
        except (OSError, RuntimeError, TimeoutError, ValueError):
            return True  # unknown: as before this check

    def _send(self, cmd: InputCommand) -> None:
        self.writer.publish(cmd)
        self.published += 1
        self.last_command = cmd

    def _observe(self, updated: list[Application], decision: Decision, now: float) -> None:
        watchers = [a for a in updated if a.wants_feedback]
        if not watchers or self.feedback is None:
            return
        try:
            fb = self.feedback()
        except (OSError, RuntimeError, TimeoutError, ValueError):
            return
        for app in watchers:
            app.observe(now, fb, active=self.enabled and decision.active == app.name)
