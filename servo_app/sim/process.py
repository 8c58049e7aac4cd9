"""The embedded simulator in a process of its own.

``servo-app run`` starts it beside the servo process, so neither the API's event loop nor the servo
cycle shares a GIL with the simulator's tick thread (a late tick would look like a late controller).
The parent calls simulator controls (reset, mode, override, program start, jog) through a pipe.
"""

from __future__ import annotations

import contextlib
import multiprocessing as mp
import time
from multiprocessing.connection import Connection
from typing import Any

from servo_app.realtime import single_threaded_blas

_CALLS = {"reset", "start_program", "abort_program", "set_mode", "set_override", "set_joints", "jog_to",
          "set_payload"}


def _event_dict(ev: Any) -> dict[str, Any]:
    return {"code": ev.code, "message": ev.message, "time_s": ev.time_s, "axis": ev.axis, "seq": ev.seq,
            "controller_time_ms": ev.controller_time_ms}


def _serve(kwargs: dict[str, Any], conn: Connection) -> None:
    from servo_app.sim.fanuc_server import FanucSimulator

    sim = FanucSimulator(**kwargs).start()
    conn.send({"address": sim.address})
    try:
        while True:
            if not conn.poll(0.5):
                continue
            try:
                msg = conn.recv()
            except (EOFError, OSError):
                _outlive_parent(sim)
                return
            name = msg["call"]
            if name == "quit":
                conn.send({"ok": True})
                return
            try:
                if name == "events":
                    result: Any = [_event_dict(e) for e in sim.events()]
                elif name in _CALLS:
                    with sim.lock:
                        result = getattr(sim, name)(*msg.get("args", ()))
                else:
                    raise ValueError(f"unknown simulator call {name!r}")
                conn.send({"ok": True, "result": result})
            except Exception as exc:  # a refused control is reported, the simulator keeps running
                conn.send({"ok": False, "error": f"{type(exc).__name__}: {exc}"})
    finally:
        sim.stop()


# The embedded controller stands in for a real one, which does not vanish with servo_app: after the
# service's main process dies it keeps serving the servo process's soft stop (deceleration, last data,
# status output stop), then goes. A soft stop from jog speed takes well under a second.
LINGER_S = 1.5


def _outlive_parent(sim: Any) -> None:
    """The parent is gone: keep answering until the client stops the status output, LINGER_S at most."""
    deadline = time.monotonic() + LINGER_S
    while time.monotonic() < deadline:
        with sim.lock:
            if not sim.controller.status_active:
                return
        time.sleep(0.01)


class SimulatorProcess:
    def __init__(self, **kwargs: Any) -> None:
        ctx = mp.get_context("spawn")
        self._conn, child = ctx.Pipe()
        kwargs.setdefault("host", "127.0.0.1")
        self.process = ctx.Process(target=_serve, args=(kwargs, child), name="fanuc-sim", daemon=True)
        self.address: tuple[str, int] = ("", 0)
        self.scheduling = "not set"  # its real-time priority, as make_realtime reports it

    def start(self, timeout: float = 30.0) -> SimulatorProcess:
        with single_threaded_blas():
            self.process.start()
        if not self._conn.poll(timeout):
            raise TimeoutError("simulator process did not start")
        self.address = tuple(self._conn.recv()["address"])  # type: ignore[assignment]
        return self

    def call(self, name: str, *args: Any, timeout: float = 5.0) -> Any:
        self._conn.send({"call": name, "args": args})
        if not self._conn.poll(timeout):
            raise TimeoutError(f"simulator did not answer {name}")
        reply = self._conn.recv()
        if not reply["ok"]:
            raise RuntimeError(reply["error"])
        return reply.get("result")

    def events(self) -> list[dict[str, Any]]:
        return self.call("events")  # type: ignore[no-any-return]

    def reset(self) -> None:
        self.call("reset")

    def stop(self, timeout: float = 5.0) -> None:
        if self.process.is_alive():
            with contextlib.suppress(TimeoutError, OSError, EOFError):
                self.call("quit", timeout=timeout)
            self.process.join(timeout)
            if self.process.is_alive():
                self.process.kill()
        deadline = time.monotonic() + 1
        while self.process.is_alive() and time.monotonic() < deadline:
            time.sleep(0.01)


def _serve_janome(server: tuple[str, int], model: str, conn: Connection) -> None:
    from servo_app.sim.janome_sim import JanomeSimulator

    # repeat: like a point job in a loop, it connects again after each session
    sim = JanomeSimulator(server, model, repeat=True).start()
    conn.send({"ok": True})
    try:
        while not conn.poll(0.5) or conn.recv().get("call") != "quit":
            pass
    except EOFError:
        pass
    finally:
        sim.stop()


class JanomeSimulatorProcess:
    """The embedded Janome robot (its point job) in a process of its own; it connects to ``server``."""

    def __init__(self, server: tuple[str, int], model: str = "jr3000") -> None:
        ctx = mp.get_context("spawn")
        self._conn, child = ctx.Pipe()
        self.process = ctx.Process(target=_serve_janome, args=(server, model, child), name="janome-sim",
                                   daemon=True)
        self.address = server

    def start(self, timeout: float = 30.0) -> JanomeSimulatorProcess:
        self.process.start()
        if not self._conn.poll(timeout):
            raise TimeoutError("Janome simulator process did not start")
        self._conn.recv()
        return self

    def call(self, name: str, *args: Any, timeout: float = 5.0) -> Any:
        """The controls the service asks of an embedded simulator; the Janome robot has none of FANUC's."""
        if name == "events":
            return []  # Janome faults reach the service through its own link supervisor
        if name == "reset":
            return None  # robot-side errors are reported over the link and reset there
        raise RuntimeError(f"the Janome simulator has no control {name!r}")

    def events(self) -> list[dict[str, Any]]:
        return self.call("events")  # type: ignore[no-any-return]

    def reset(self) -> None:
        """Nothing to reset on the robot side: its errors are reported over the link and reset there."""

    def stop(self, timeout: float = 5.0) -> None:
        if self.process.is_alive():
            with contextlib.suppress(OSError, BrokenPipeError):
                self._conn.send({"call": "quit"})
            self.process.join(timeout)
            if self.process.is_alive():
                self.process.kill()
