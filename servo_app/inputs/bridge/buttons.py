"""Button presses mapped to an output action (``toggle_output:DO[1]``, :mod:`servo_app.inputs.actions`)
are carried out by the bridge's action thread through `act` (the service's I/O), never in the
adapter's thread: an output is read and written through the stream's packets, which takes cycles.
They act only while input control is enabled; each outcome is kept (`actions`, newest last).
"""

from __future__ import annotations

import threading
from collections import deque
from collections.abc import Callable
from typing import Any

from servo_app.inputs.actions import OutputToggle, parse_action
from servo_app.inputs.adapter import Clock
from servo_app.inputs.problems import ProblemLog
from servo_app.inputs.samples import ButtonEvent
from servo_app.inputs.slots import EventQueue

Act = Callable[[OutputToggle], Any]


class ButtonActions:
    def __init__(self, clock: Clock, problems: ProblemLog, enabled: Callable[[], bool]) -> None:
        self.clock = clock
        self.problems = problems
        self.enabled = enabled  # whether input control is enabled right now
        self.act: Act | None = None  # the service's output action, once started
        self.actions: deque[dict[str, Any]] = deque(maxlen=20)  # the latest output actions and how they went
        self._presses: EventQueue[tuple[ButtonEvent, OutputToggle]] = EventQueue(maxlen=16)

    def on_button(self, ev: ButtonEvent) -> None:
        """An adapter's thread: queue a press mapped to an output action (configuration checked it)."""
        if ev.pressed and ev.action is not None:
            action = parse_action(ev.action)
            if isinstance(action, OutputToggle):
                self._presses.put((ev, action))

    def serve(self, stop: threading.Event) -> None:
        """The action thread: carry out the queued presses until `stop`."""
        while not stop.is_set():
            item = self._presses.get(timeout=0.1)
            if item is not None:
                self.act_on(*item)

    def act_on(self, ev: ButtonEvent, action: OutputToggle) -> None:
        """Carry out one output action (the action thread calls this; tests may too)."""
        row: dict[str, Any] = {"source": ev.source, "button": ev.button, "action": str(action), "ok": False}
        try:
            if self.act is None:
                raise RuntimeError("no robot I/O connected")
            if not self.enabled():
                raise RuntimeError("input control is not enabled")
            row["result"] = self.act(action)
            row["ok"] = True
        except Exception as exc:  # refused (not streaming, I/O not allowed) or failed: reported, nothing else
            row["error"] = f"{type(exc).__name__}: {exc}"
            self.problems.record("action_failed", f"{ev.source} button {ev.button} {action}: {row['error']}")
        row["took_s"] = round(self.clock() - ev.stamp, 4)  # press to done
        self.actions.append(row)
