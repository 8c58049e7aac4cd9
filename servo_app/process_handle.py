"""The parent side of a servo process (FANUC or Janome): start it, send requests, read its state.

The child runs ``target(cfg_dict, conn, slot_name)`` in a process of its own (spawned: nothing of
the parent's threads or locks comes along); it answers requests ``{"id", "op", ...}`` with
``{"id", "ok", "result" | "error"}``, sends events ``{"event": kind, ...}`` (first ``ready``), and
publishes its state into a shared-memory slot (layout: :mod:`servo_app.state`).
"""

from __future__ import annotations

import contextlib
import multiprocessing as mp
import os
import signal
import time
import traceback
from collections.abc import Callable
from dataclasses import asdict
from multiprocessing.connection import Connection
from typing import Any

from servo_app.errors import CommandRejected
from servo_app.ipc import LatestValueSlot
from servo_app.realtime import single_threaded_blas
from servo_app.state import STATE_SIZE, decode_state


def run_child(conn: Connection, body: Callable[[], None]) -> None:
    """The child's top level: run ``body``; if it raises, report the traceback, then die (the parent
    turns a "crashed" event into a fault)."""
    try:
        body()
    except Exception:
        with contextlib.suppress(OSError):
            conn.send({"event": "crashed", "traceback": traceback.format_exc()})
        raise


class ChildLink:
    """The child's side of the link, the same for every backend: events to the parent, signals
    noted for the main loop (which decelerates and ends the stream before exiting), and the safety
    event sent before the state vector that shows its mode."""

    conn: Connection
    sup: Any  # the backend's supervisor: ``changed`` and ``describe()``
    pending_signal: int | None = None

    def _on_signal(self, signum: int, frame: object) -> None:
        self.pending_signal = signum

    def _event(self, kind: str, **kw: Any) -> None:
        with contextlib.suppress(BrokenPipeError, OSError):
            self.conn.send({"event": kind, **kw})

    def _publish_safety(self) -> None:
        # Before the state vector that shows the new mode, so a reader who sees the mode can have
        # its reason (stop reason, fault texts) too.
        if self.sup.changed:
            self.sup.changed = False
            self._event("safety", **self.sup.describe())


class ServoProcessHandle:
    def __init__(self, cfg: Any, target: Callable[..., None], name: str) -> None:
        self.cfg = cfg
        self.name = name
        self.slot = LatestValueSlot(STATE_SIZE)
        ctx = mp.get_context("spawn")
        self._conn, child_conn = ctx.Pipe()
        self.process = ctx.Process(target=target, args=(asdict(cfg), child_conn, self.slot.name), name=name,
                                   daemon=True)
        self.events: list[dict[str, Any]] = []
        self._next_id = 0
        self._replies: dict[int, dict[str, Any]] = {}

    def start(self, timeout: float = 30.0) -> dict[str, Any]:
        """Start the process; returns its ``ready`` event."""
        with single_threaded_blas():
            self.process.start()
        return self.wait_event("ready", timeout)

    def request(self, op: str, timeout: float = 2.0, **kw: Any) -> Any:
        """Send a request and wait for its reply; a refusal raises CommandRejected with its message."""
        self._next_id += 1
        rid = self._next_id
        self._conn.send({"id": rid, "op": op, **kw})
        deadline = time.monotonic() + timeout
        while rid not in self._replies:
            if not self._pump(deadline - time.monotonic()):
                raise TimeoutError(f"{self.name} did not answer '{op}' within {timeout} s")
        reply = self._replies.pop(rid)
        if not reply["ok"]:
            raise CommandRejected(reply["error"])
        return reply.get("result")

    def _pump(self, timeout: float) -> bool:
        if timeout <= 0 or not self._conn.poll(timeout):
            return False
        try:
            msg = self._conn.recv()
        except EOFError:
            return False
        if "event" in msg:
            self.events.append(msg)
        else:
            self._replies[msg["id"]] = msg
        return True

    def last_event(self, kind: str) -> dict[str, Any] | None:
        self.poll_events()
        for ev in reversed(self.events):
            if ev["event"] == kind:
                return ev
        return None

    def poll_events(self) -> list[dict[str, Any]]:
        while self._pump(0.0001):
            pass
        return self.events

    def wait_event(self, kind: str, timeout: float, **match: Any) -> dict[str, Any]:
        deadline = time.monotonic() + timeout
        seen = 0
        while True:
            for ev in self.events[seen:]:
                if ev["event"] == kind and all(ev.get(k) == v for k, v in match.items()):
                    return ev
                if ev["event"] == "crashed":
                    raise RuntimeError(f"{self.name} crashed:\n{ev['traceback']}")
            seen = len(self.events)
            if not self.process.is_alive() and not self._conn.poll():
                raise RuntimeError(f"{self.name} exited (code {self.process.exitcode}) before '{kind}'; "
                                   f"events: {self.events[-5:]}")
            if not self._pump(min(deadline - time.monotonic(), 0.5)) and time.monotonic() >= deadline:
                raise TimeoutError(f"no '{kind}' event {match} within {timeout} s; events: {self.events[-5:]}")

    def state(self) -> dict[str, Any]:
        _, data = self.slot.read()
        return decode_state(data)

    def shutdown(self, timeout: float = 10.0) -> int | None:
        """Signal the process (it ends a running stream cleanly) and wait for it; its exit code."""
        if self.process.is_alive():
            assert self.process.pid is not None
            os.kill(self.process.pid, signal.SIGTERM)
            self.process.join(timeout)
            if self.process.is_alive():
                self.process.kill()
                self.process.join(2)
        self.poll_events()
        self.slot.close()
        return self.process.exitcode
