"""The embedded simulator in a process of its own.

``servo-app run`` starts it beside the servo process, so neither the API's event loop nor the servo
cycle shares a GIL with the simulator's tick thread (a late tick would look like a late controller).
The parent calls simulator controls (reset, mode, override, program start, jog) through a pipe.

Each request carries an id and a deadline, and its reply the same id (as the servo process's
requests do, ``servo_app.process_handle``): a reply comes back to the call that asked for it, never to
a later one. A call gives up at its deadline (TimeoutError); a reply that comes after that is
discarded, and the simulator does not carry out a request whose deadline has passed before it took it
up (a stopped or starved controller process answers late or not at all: it must not reset its alarm
seconds after the operator was told the reset failed). ``time.monotonic`` is the system's clock,
the same in both processes.
"""

from __future__ import annotations

import contextlib
import multiprocessing as mp
import signal
import threading
import time
from collections.abc import Iterator, Sequence
from multiprocessing.connection import Connection
from typing import Any

from servo_app.realtime import exit_done_child, make_realtime, single_threaded_blas

_CALLS = {"reset", "start_program", "abort_program", "set_mode", "set_override", "set_joints", "jog_to",
          "set_payload"}


def _event_dict(ev: Any) -> dict[str, Any]:
    return {"code": ev.code, "message": ev.message, "time_s": ev.time_s, "axis": ev.axis, "seq": ev.seq,
            "controller_time_ms": ev.controller_time_ms}


def _serve(kwargs: dict[str, Any], conn: Connection) -> None:
    from servo_app.sim.fanuc_server import FanucSimulator

    # Ctrl-C reaches the whole process group: the controller must keep sending status while the servo
    # process decelerates and sends last data. It ends when its parent says quit or goes away.
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    sim = FanucSimulator(**kwargs).start()
    conn.send({"address": sim.address})
    try:
        serve_calls(sim, conn)
    finally:
        sim.stop()
    exit_done_child()


def serve_calls(sim: Any, conn: Connection) -> None:
    """Answer the parent's calls until it says quit or goes away (then outlive it a moment)."""
    while True:
        if not conn.poll(0.5):
            continue
        try:
            msg = conn.recv()
        except (EOFError, OSError):
            _outlive_parent(sim)
            return
        deadline = msg.get("deadline")
        if deadline is not None and time.monotonic() > deadline:
            continue  # the caller has given up on it (we were stopped or starved): not done late
        name = msg["call"]
        rid = msg.get("id")
        if name == "quit":
            conn.send({"id": rid, "ok": True})
            return
        try:
            if name == "events":
                result: Any = [_event_dict(e) for e in sim.events()]
            elif name in _CALLS:
                with sim.lock:
                    result = getattr(sim, name)(*msg.get("args", ()))
            else:
                raise ValueError(f"unknown simulator call {name!r}")
            conn.send({"id": rid, "ok": True, "result": result})
        except Exception as exc:  # a refused control is reported, the simulator keeps running
            conn.send({"id": rid, "ok": False, "error": f"{type(exc).__name__}: {exc}"})


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


class ControlPipe:
    """The parent's end of the simulator's control pipe: calls from any thread, each answered by its
    own reply (matched by id), within its timeout.

    One reader thread owns the receiving end: a reply wakes the call waiting for it; one for a call
    that has given up is counted (``late_replies``) and dropped. When the pipe ends (the simulator
    process is gone), every waiting call fails at once."""

    def __init__(self, conn: Connection, name: str = "simulator") -> None:
        self._conn = conn
        self.name = name
        self._send_lock = threading.Lock()
        self._cv = threading.Condition()
        self._next_id = 0
        self._waiting: set[int] = set()
        self._replies: dict[int, dict[str, Any]] = {}
        self._ended = False
        self.late_replies = 0  # replies that came after their call had given up (discarded)
        self._reader = threading.Thread(target=self._read_loop, name=f"{name} pipe", daemon=True)
        self._reader.start()

    def _read_loop(self) -> None:
        while True:
            try:
                reply = self._conn.recv()
            except (EOFError, OSError):
                break
            rid = reply.get("id") if isinstance(reply, dict) else None
            with self._cv:
                if rid in self._waiting:
                    self._replies[rid] = reply
                    self._cv.notify_all()
                else:
                    self.late_replies += 1
        with self._cv:
            self._ended = True
            self._cv.notify_all()

    def call(self, name: str, *args: Any, timeout: float = 5.0) -> Any:
        """The simulator's answer to ``name(*args)``; RuntimeError if it refused, TimeoutError if it
        did not answer within ``timeout`` s (then it will not carry the call out later either, unless
        it had begun it already) or its process is gone."""
        deadline = time.monotonic() + timeout
        with self._send_lock:
            self._next_id += 1
            rid = self._next_id
            with self._cv:
                if self._ended:
                    raise TimeoutError(f"the {self.name} process has ended: it cannot answer {name!r}")
                self._waiting.add(rid)
            try:
                self._conn.send({"id": rid, "call": name, "args": args, "deadline": deadline})
            except (OSError, ValueError) as exc:  # (ValueError: our end closed)
                with self._cv:
                    self._waiting.discard(rid)
                raise TimeoutError(f"the {self.name} is not reachable: {exc}") from None
        with self._cv:
            try:
                while rid not in self._replies:
                    if self._ended:
                        raise TimeoutError(f"the {self.name} process ended before answering {name}")
                    left = deadline - time.monotonic()
                    if left <= 0:
                        raise TimeoutError(
                            f"the {self.name} did not answer {name} within {timeout:g} s (its process is "
                            "stopped or overloaded); it drops the request rather than carry it out late")
                    self._cv.wait(left)
                reply = self._replies.pop(rid)
            finally:  # (also on an interrupt in the wait: a reply stored meanwhile goes with it)
                self._waiting.discard(rid)
                self._replies.pop(rid, None)
        if not reply.get("ok"):
            raise RuntimeError(reply.get("error") or f"the {self.name} refused {name}")
        return reply.get("result")

    def close(self, timeout: float = 1.0) -> None:
        """Once the other end is gone: the reader has seen the end of the pipe; then close ours."""
        self._reader.join(timeout)
        with contextlib.suppress(OSError):
            self._conn.close()


@contextlib.contextmanager
def _sigint_ignored() -> Iterator[None]:
    """SIGINT ignored while a child starts, which inherits that before it can set it itself (its
    start-up takes a second); only the main thread may set a handler (a restart from another thread
    leaves it to the child)."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    old = signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, old)


class SimulatorProcess:
    """The embedded FANUC controller (``FanucSimulator(**kwargs)``) in a process of its own, at
    ``realtime_priority`` (None: as the service runs)."""

    def __init__(self, realtime_priority: int | None = None, **kwargs: Any) -> None:
        kwargs.setdefault("host", "127.0.0.1")
        self._kwargs = kwargs
        self.realtime_priority = realtime_priority
        self.address: tuple[str, int] = ("", 0)
        self.scheduling = "not set"  # its real-time priority, as make_realtime reports it
        self.pipe: ControlPipe | None = None
        self._launch()

    def _launch(self) -> None:
        ctx = mp.get_context("spawn")
        self._conn, self._child_conn = ctx.Pipe()
        self.process = ctx.Process(target=_serve, args=(self._kwargs, self._child_conn), name="fanuc-sim",
                                   daemon=True)

    def start(self, timeout: float = 30.0) -> SimulatorProcess:
        with single_threaded_blas(), _sigint_ignored():
            self.process.start()
        self._child_conn.close()  # ours is the only copy left: the child's death shows as end of file
        if not self._conn.poll(timeout):
            raise TimeoutError("simulator process did not start")
        self.address = tuple(self._conn.recv()["address"])  # type: ignore[assignment]
        self.pipe = ControlPipe(self._conn, "embedded simulator")
        self.scheduling = make_realtime(self.realtime_priority, self.process.pid)
        return self

    @property
    def alive(self) -> bool:
        return self.process.is_alive()

    def restart(self, timeout: float = 30.0, at: Sequence[float] | None = None) -> None:
        """After its process died (killed): a new controller at the same address, where the servo
        process sends, with no alarm posted, as a controller after a power cycle: with the arm at ``at``
        (FANUC deg, the last status's joints), where its brakes held it, not at the initial joints."""
        self.stop(timeout=1.0)
        self._kwargs["port"] = self.address[1]
        if at is not None:
            self._kwargs["initial_joints"] = [float(v) for v in at]
        self._launch()
        self.start(timeout)

    def call(self, name: str, *args: Any, timeout: float = 5.0) -> Any:
        """A control (``reset``, ``set_override``, ``events``, ...): its result; thread-safe."""
        if self.pipe is None:
            raise RuntimeError("the simulator process is not started")
        return self.pipe.call(name, *args, timeout=timeout)

    def events(self) -> list[dict[str, Any]]:
        return self.call("events")  # type: ignore[no-any-return]

    def reset(self) -> None:
        self.call("reset")

    def stop(self, timeout: float = 5.0) -> None:
        if self.process.is_alive():
            try:
                self.call("quit", timeout=timeout)
            except (TimeoutError, RuntimeError, OSError, EOFError):
                self.process.kill()  # stopped or hung: it would not quit, nothing to wait for
            self.process.join(timeout)
            if self.process.is_alive():
                self.process.kill()
        deadline = time.monotonic() + 1
        while self.process.is_alive() and time.monotonic() < deadline:
            time.sleep(0.01)
        if self.pipe is not None:
            self.pipe.close()


def _serve_janome(server: tuple[str, int], model: str, conn: Connection,
                  start: tuple[float, ...] | None = None) -> None:
    from servo_app.sim.janome_sim import JanomeSimulator

    # Ctrl-C reaches the whole process group: the robot must keep answering while the servo process
    # ends its stream (END, the robot's BYE). It ends when its parent says quit or goes away.
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    # repeat: like a point job in a loop, it connects again after each session
    sim = JanomeSimulator(server, model, start=start, repeat=True).start()
    conn.send({"ok": True})
    try:
        while not conn.poll(0.5) or conn.recv().get("call") != "quit":
            pass
    except EOFError:
        pass
    finally:
        sim.stop()
    exit_done_child()


class JanomeSimulatorProcess:
    """The embedded Janome robot (its point job) in a process of its own; it connects to ``server``."""

    def __init__(self, server: tuple[str, int], model: str = "jr3000") -> None:
        self.address = server
        self.model = model
        self._lock = threading.Lock()  # a reset's restart and stop, one at a time
        self._stopped = False
        self._launch()

    def _launch(self, start: tuple[float, ...] | None = None) -> None:
        ctx = mp.get_context("spawn")
        self._conn, child = ctx.Pipe()
        self.process = ctx.Process(target=_serve_janome, args=(self.address, self.model, child, start),
                                   name="janome-sim", daemon=True)

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

    @property
    def alive(self) -> bool:
        return self.process.is_alive()

    def restart(self, timeout: float = 30.0, at: Sequence[float] | None = None) -> None:
        """After its process died (killed): the point job started again, as its operator would, with
        the arm at ``at`` (X, Y, Z, R: the last status's position, where it stopped; the profile's elbow);
        it connects once up (this does not wait for that)."""
        with self._lock:
            if self._stopped or self.process.is_alive():
                return
            self.process.join(0)
            self._conn.close()
            self._launch(None if at is None else tuple(float(v) for v in at[:4]))
            self.process.start()

    def events(self) -> list[dict[str, Any]]:
        return self.call("events")  # type: ignore[no-any-return]

    def reset(self) -> None:
        """Nothing to reset on the robot side: its errors are reported over the link and reset there."""

    def stop(self, timeout: float = 5.0) -> None:
        with self._lock:
            self._stopped = True
            if self.process.is_alive():
                with contextlib.suppress(OSError, BrokenPipeError):
                    self._conn.send({"call": "quit"})
                self.process.join(timeout)
                if self.process.is_alive():
                    self.process.kill()
