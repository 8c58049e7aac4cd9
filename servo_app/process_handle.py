"""A servo process, both sides: the generic child host and the parent's handle, for any backend.

The child (spawned: nothing of the parent's threads or locks comes along) runs a backend's
:class:`ServoProcessHost` subclass: it owns the robot link and the supervisor, answers typed requests
(:mod:`servo_app.messages`) from the pipe, sends events, and publishes its state into a shared-memory
latest-value slot (layout: :mod:`servo_app.state`). What every backend's process does is here:

- SIGTERM/SIGINT are noted and handed to the supervisor at the next step (it decelerates, ends the
  stream, then the process exits); so is the parent's death (end of file on the pipe, or a new
  parent pid), once;
- requests are dispatched by type; a start that must wait for the controller is answered when the
  stream runs or when it is given up, never with an early "ok";
- the safety event goes out before the state vector that shows its mode;
- the session log is closed, and the link shut, on every way out.

The parent's :class:`ServoProcessHandle` starts the process, sends requests (thread-safe, one reader
thread owns the pipe), and watches the process: its death wakes every waiter and is reported with
its cause ("ended by signal 9"), so the service can name the fault and start a new process.
"""

from __future__ import annotations

import contextlib
import logging
import multiprocessing as mp
import os
import pickle
import select
import signal
import threading
import time
import traceback
from collections.abc import Callable
from dataclasses import asdict, replace
from multiprocessing.connection import Connection
from pathlib import Path
from typing import Any

from servo_app import messages as msg
from servo_app.errors import CommandRejected, InvalidRequest
from servo_app.ipc import LatestValueSlot
from servo_app.pipe_frames import PipeEnd
from servo_app.realtime import exit_done_child, single_threaded_blas
from servo_app.safety import Mode
from servo_app.session_log import SessionLogWriter
from servo_app.state import MODES, OFFSET, PHASES, STATE_SIZE, StateVector, decode_state

log = logging.getLogger(__name__)

# ------------------------------------------------------------------------------------- child side


def _configured_child(target: Callable[[dict[str, Any], Connection, str], None], conn: Connection,
                      slot_name: str) -> None:
    """The child's entry. It unpickles ``target`` first, which imports the backend's modules (2-3 s of
    CPU for FANUC's: numba's cached kernels, MuJoCo): the parent may launch it before it knows the
    controller's address (ServoProcessHandle.launch) and send the configuration, the pipe's first
    message, once it does (start)."""
    try:
        cfg_dict = conn.recv()
    except (EOFError, OSError):
        return  # the parent shut it down before configuring it
    target(cfg_dict, conn, slot_name)
    exit_done_child()


def run_child(conn: Connection, body: Callable[[], None]) -> None:
    """The child's top level: run ``body``; if it raises, report the traceback, then die (the parent
    turns it into a fault)."""
    try:
        body()
    except Exception:
        with contextlib.suppress(OSError):
            conn.send(msg.Crashed(traceback=traceback.format_exc()))
        raise


READS_PER_PASS = 8  # of the request pipe per loop pass, 64 KB each (pipe_frames): ~1 ms here
# A new warning's safety view goes out at most this often (the last one of a burst goes out too).
WARNINGS_PUBLISH_S = 0.05


class ServoProcessHost:
    """The generic servo process. A backend implements ``_io_step`` (wait for and handle its link's
    traffic, at most ~20 ms), ``_deliver_signal``, ``_publish_backend`` and, optionally, the hooks
    around requests; everything else is shared."""

    conn: Connection
    sup: Any  # the backend's SupervisorBase
    slot: LatestValueSlot
    state: StateVector
    start_waits_for_stream = True  # answer a start once streaming (or given up), not at once

    def __init__(self, conn: Connection, slot_name: str) -> None:
        self.conn = conn
        self.pipe = PipeEnd(conn)  # the pipe's frames read and written here, not by conn (see pipe_frames)
        self.slot = LatestValueSlot(STATE_SIZE, name=slot_name, create=False)
        self.state = StateVector()
        self.pending_signal: int | None = None
        self.quit = False
        self.parent_pid = os.getppid()
        self.parent_gone = False
        self.t0 = time.monotonic()
        self._start_waiters: list[int] = []
        self._replies: list[msg.Reply] = []  # answers made in this loop, sent after its publish
        self._last_phase: str | None = None
        self.log: SessionLogWriter | None = None
        self._log_troubles: list[str] = []  # what the session log reported, handled by _housekeeping
        # The pipe polled by a poll object made once: Connection.poll() builds a selector per call
        # (4 us here, every loop iteration), this one call costs 0.6 us.
        self._pipe_poll = select.poll()
        self._pipe_poll.register(conn.fileno(), select.POLLIN)
        self._warnings_due = 0.0  # monotonic: the next warning-only safety view not before then

    # -- what each backend implements
    def _io_step(self) -> None:
        raise NotImplementedError

    def _deliver_signal(self, sig: int, now: float) -> None:
        raise NotImplementedError

    def _publish_backend(self, sv: StateVector) -> None:
        raise NotImplementedError

    def _before_request(self, req: msg.Request) -> None:
        """Called before the supervisor handles ``req`` (e.g. open the session log on a start)."""

    def _after_request(self) -> None:
        """Called after each request (e.g. send what the request produced)."""

    def _on_link_phase(self, phase: str) -> None:
        """The link changed phase (already reported to the parent)."""

    def _shutdown(self) -> None:
        """Close the link (on every way out; the session log is closed after it)."""

    # -- the loop
    def serve(self, ready: msg.Ready) -> None:
        # The safety view first: whoever sees Ready already has the state's reasons (fault: none).
        self.sup.changed = True
        self._publish()
        self._event(ready)
        try:
            while not self.quit:
                self._io_step()
                self._housekeeping()
        finally:
            self._shutdown()
            self._close_log()
            self.slot.close()

    def _on_signal(self, signum: int, frame: object) -> None:
        self.pending_signal = signum

    def _install_signals(self) -> None:
        signal.signal(signal.SIGTERM, self._on_signal)
        signal.signal(signal.SIGINT, self._on_signal)

    def _housekeeping(self) -> None:
        # The parent's death ends the stream as SIGTERM would (soft stop, last data, status off): an
        # orphan must not keep an arm under its control. Checked by pid, since a pipe's end of file
        # only shows once somebody reads it (here, not in a method of its own: one call less a cycle).
        if not self.parent_gone and os.getppid() != self.parent_pid:
            self._parent_died()
        if self.pending_signal is not None:  # handled here, not inside the signal handler
            sig, self.pending_signal = self.pending_signal, None
            self._deliver_signal(sig, time.monotonic())
        # The pipe's poll here first: _poll_requests' call only when a request (or the parent's end) is
        # there, not at every loop iteration. A failing poll is _poll_requests' to report.
        if not self.parent_gone:
            try:
                pending = bool(self._pipe_poll.poll(0))
            except OSError:
                pending = True
            if pending:
                self._poll_requests()
        if self._log_troubles:
            self._on_log_trouble()
        sup = self.sup
        if sup.start_pending:  # (no call per cycle while none is)
            sup.watch_start(time.monotonic())
        if self._start_waiters:
            self._answer_start()
        self._watch_link()
        self._publish()
        if self._replies:  # after the publish: a reader after the reply sees the request's effect
            self._send_replies()
        if sup.state.shutdown and sup.finished:  # (finished needs shutdown: no call per cycle before)
            self.quit = True

    def _parent_died(self) -> None:
        if not self.parent_gone:
            self.parent_gone = True
            self.pending_signal = int(signal.SIGTERM)

    def _poll_requests(self) -> None:
        if self.parent_gone:
            return
        # At most READS_PER_PASS reads: a big request (a long trajectory's plan, megabytes) comes in
        # over several passes, the statuses between them answered. Read whole in one pass, a 9.5 MB
        # plan held a 4 ms cycle up ~17 ms (MOTN-603 with lead 2). Requests are one read each.
        for _ in range(READS_PER_PASS):
            try:
                if not self._pipe_poll.poll(0):  # readable, or hung up (then read raises EOFError)
                    return
                frames = self.pipe.read()
            except (EOFError, OSError):  # the parent is gone
                self._parent_died()
                return
            for data in frames:
                self._handle(pickle.loads(data))

    def _handle(self, env: msg.Envelope) -> None:
        req = env.request
        try:
            if not isinstance(req, msg.Request):
                raise CommandRejected(f"{type(req).__name__} is not a request")
            late = time.monotonic() - env.deadline if env.deadline is not None else 0.0
            if late > 0.0:
                raise CommandRejected(f"{type(req).__name__} came {late:.2f} s after its deadline (the servo process "
                                      "was stalled; the service stopped waiting and reported it not done): not "
                                      "applied")
            self._before_request(req)
            result = self.sup.request(req, time.monotonic())
            self._after_request()
        except InvalidRequest as exc:
            self._reply(env.id, False, error=str(exc), invalid=True)
            return
        except (CommandRejected, RuntimeError) as exc:  # refused by the state (RuntimeError: not set up yet)
            self._reply(env.id, False, error=str(exc))
            return
        except (ValueError, TypeError) as exc:  # a bad value found deeper down: the request's own fault
            self._reply(env.id, False, error=str(exc), invalid=True)
            return
        if isinstance(req, msg.Start) and self.sup.start_pending and self.start_waits_for_stream:
            if env.id is not None:
                self._start_waiters.append(env.id)
            return
        self._reply(env.id, True, result=result)

    def _reply(self, rid: int | None, ok: bool, result: Any = None, error: str = "", invalid: bool = False) -> None:
        """The answer to request ``rid``, sent once this loop has published its state (_housekeeping):
        one publish a loop, where a publish of its own per reply cost ~30 us of a jog renewal's
        ~350 here (issue 15)."""
        if rid is not None:
            self._replies.append(msg.Reply(rid, ok, result, error, invalid))

    def _send_replies(self) -> None:
        replies, self._replies = self._replies, []
        for reply in replies:
            self._send_message(reply)

    def _answer_start(self) -> None:
        if not self._start_waiters or self.sup.start_pending:
            return
        waiters, self._start_waiters = self._start_waiters, []
        mode = self.sup.state.mode
        ok = mode in (Mode.STREAMING, Mode.STOPPING, Mode.STOPPED)
        fault = self.sup.state.fault
        error = ""
        if not ok:
            why = self.sup.start_error or (fault.message if fault else f"the stream did not start ({mode.value})")
            then = ("reset the fault: POST /api/reset" if mode is Mode.FAULT
                    else "then start again: POST /api/session/start")
            error = f"start failed: {why}; {then}"
        for rid in waiters:
            self._reply(rid, ok, error=error)

    def _open_log(self, path: Path, header: dict[str, Any], reserve_bytes: int = 0) -> SessionLogWriter:
        """Start a session log (closing one still open) and tell the parent; OSError if it cannot be
        opened with ``reserve_bytes`` of disk kept free for it (see SessionLogWriter)."""
        self._close_log()
        self.log = SessionLogWriter(path, header, reserve_bytes, on_trouble=self._log_troubles.append)
        self._event(msg.LogOpened(path=str(path)))
        return self.log

    def _on_log_trouble(self) -> None:
        """The session log's trouble (told while a record was written): the supervisor ends the stream
        with a soft stop, while the log's reserve still takes its records."""
        troubles, self._log_troubles = self._log_troubles, []
        now = time.monotonic()
        for trouble in troubles:
            self.sup.log_failing(trouble, now)
        self._after_request()  # what ending the stream sends at once

    def _close_log(self, remove_empty: bool = False) -> None:
        """Close the session log; ``remove_empty``: delete it if it holds no record (its header alone
        records nothing, and the log list would show it as a session)."""
        if self.log is not None:
            log, self.log = self.log, None
            log.close()
            removed = remove_empty and log.records == 0
            if removed:
                with contextlib.suppress(OSError):
                    log.path.unlink(missing_ok=True)
            self._event(msg.LogClosed(path=str(log.path), records=log.records, removed=removed))

    def _event(self, event: msg.Event) -> None:
        self._send_message(event)

    def _send_message(self, message: msg.Event | msg.Reply) -> None:
        """One message to the parent, as ``Connection.send`` frames it (its ``recv`` reads it), pickled by
        ``pickle.dumps``: multiprocessing's pickler copies the copyreg dispatch table on every call
        (a reply cost ~165 us that way, ~120 this way, with caches cold here)."""
        with contextlib.suppress(BrokenPipeError, OSError):
            self.pipe.write(pickle.dumps(message, pickle.HIGHEST_PROTOCOL))

    def _watch_link(self) -> None:
        # The session's phase (a StrEnum, equal to link_phase's string) compared every cycle without the
        # call; link_phase, with its reason, on a change.
        if self.sup.session.phase == self._last_phase:
            return
        phase, reason = self.sup.link_phase()
        if phase != self._last_phase:
            self._last_phase = phase
            self._event(msg.LinkPhase(phase=phase, reason=reason))
            self._on_link_phase(phase)

    def _publish(self) -> None:
        # The safety event first, so a reader who sees the new mode can have its reason too. A new
        # warning alone (no state change) is published too, at most every WARNINGS_PUBLISH_S: it was
        # seen only at the next state change, and a warning every cycle must not cost a view every cycle.
        sup = self.sup
        if sup.changed or (sup.warned and time.monotonic() >= self._warnings_due):
            sup.changed = sup.warned = False
            self._warnings_due = time.monotonic() + WARNINGS_PUBLISH_S
            self._event(msg.SafetyChanged(view=sup.describe()))
        sv = self.state
        d = sv.data
        d[_PUBLISHED_UNIX] = time.time()
        # The session's phase and the safety mode are StrEnums: each member finds its value's entry (and
        # the phase is link_phase's, read here without the call).
        d[_PHASE] = _PHASE_INDEX[self.sup.session.phase]
        d[_MODE] = _MODE_INDEX[self.sup.state.mode]
        d[_SESSION_TIME] = time.monotonic() - self.t0
        self._publish_backend(sv)
        self.slot.write(d)  # the one write a reader sees


_PUBLISHED_UNIX, _PHASE, _MODE, _SESSION_TIME = (OFFSET[k] for k in ("published_unix", "phase", "mode",
                                                                     "session_time"))
_PHASE_INDEX = {name: i for i, name in enumerate(PHASES)}
_MODE_INDEX = {name: i for i, name in enumerate(MODES)}


# ------------------------------------------------------------------------------------ parent side


def describe_exit(code: int | None) -> str:
    """A process's exit code in words: "ended by signal 9 (SIGKILL)", "exited with code 1"."""
    if code is None:
        return "still running"
    if code < 0:
        with contextlib.suppress(ValueError):
            return f"ended by signal {-code} ({signal.Signals(-code).name})"
        return f"ended by signal {-code}"
    return f"exited with code {code}"


class ServoProcessHandle:
    """The parent's side: start, request (from any thread), watch, shut down.

    One reader thread owns the pipe: replies wake their waiters, events are kept (``events``) and
    passed to ``on_event``. A reply nobody waits for any more (its request timed out, without
    ``on_late``) is counted (``late_replies``) and dropped: kept, they piled up for the service's life.
    When the process dies, ``alive`` turns False, every waiter wakes with a TimeoutError naming the
    cause, and ``on_exit(cause)`` is called once."""

    def __init__(self, cfg: Any, target: Callable[..., None], name: str,
                 on_event: Callable[[msg.Event], None] | None = None,
                 on_exit: Callable[[str], None] | None = None) -> None:
        self.cfg = cfg
        self.name = name
        self.slot = LatestValueSlot(STATE_SIZE)
        ctx = mp.get_context("spawn")
        self._conn, child_conn = ctx.Pipe()
        self.process = ctx.Process(target=_configured_child, args=(target, child_conn, self.slot.name), name=name,
                                   daemon=True)
        self._child_conn = child_conn
        self.events: list[msg.Event] = []
        self.on_event = on_event
        self.on_exit = on_exit
        self.exit_cause = ""
        self._cv = threading.Condition()
        self._replies: dict[int, msg.Reply] = {}  # only for requests in _waiting
        self._waiting: set[int] = set()  # ids of requests whose caller still waits for the reply
        self.late_replies = 0  # replies that came after their caller had given up (dropped)
        self._late: dict[int, Callable[[msg.Reply], None]] = {}  # expired requests' on_late, by id
        self._next_id = 0
        self._send_lock = threading.Lock()
        self._reader: threading.Thread | None = None
        self._closing = False
        self._given_up: tuple[str, str] | None = None  # give_up's (why, next step): no reply will come
        self._quiet_version = -1  # the state's version as quiet_for last saw it, and since when
        self._quiet_since = 0.0

    @property
    def alive(self) -> bool:
        return not self.exit_cause

    @property
    def pid(self) -> int | None:
        return self.process.pid

    def launch(self) -> None:
        """Start the process and its reader, once: it imports its modules, then waits for its
        configuration (``start`` sends it). Until then ``cfg`` may still change (``retarget``)."""
        if self._reader is not None:
            return
        with single_threaded_blas():
            self.process.start()
        self._child_conn.close()  # ours is the only copy left: the child's death shows as end of file
        self._reader = threading.Thread(target=self._read_loop, name=f"{self.name} pipe", daemon=True)
        self._reader.start()

    def retarget(self, host: str, port: int) -> None:
        """Before ``start``: the controller's address, known only once its simulator is up (make_process
        put its target's host and port in ``cfg``)."""
        self.cfg = replace(self.cfg, host=host, port=port)

    def start(self, timeout: float = 30.0) -> msg.Ready:
        """Launch the process (unless ``launch`` did), send its configuration and return its ``Ready``
        event. A process that dies, crashes or stays silent before it is ready is shut down (killed if
        need be, its slot closed) and the error raised: RuntimeError naming how it ended, or TimeoutError."""
        self.launch()
        with self._send_lock, contextlib.suppress(OSError):  # (one that died: wait_event names how)
            self._conn.send(asdict(self.cfg))
        try:
            ev = self.wait_event(msg.Ready, timeout)
        except (RuntimeError, TimeoutError):
            self.shutdown(timeout=2.0)
            raise
        assert isinstance(ev, msg.Ready)
        return ev

    def _read_loop(self) -> None:
        while True:
            try:
                item = self._conn.recv()
            except (EOFError, OSError):
                break
            if isinstance(item, msg.Reply):
                with self._cv:
                    on_late = self._late.pop(item.id, None)
                    if item.id in self._waiting:
                        self._replies[item.id] = item
                        self._cv.notify_all()
                    elif on_late is None:
                        self.late_replies += 1
                        if self.late_replies == 1:  # once: a stalled process may leave many
                            log.warning("the %s answered request %d after its caller had given up: "
                                        "reply dropped (late replies are counted, not logged again)",
                                        self.name, item.id)
                if on_late is not None:  # in order with the other replies: before any later request's
                    on_late(item)
                continue
            with self._cv:
                self.events.append(item)
                self._cv.notify_all()
            if self.on_event is not None:
                self.on_event(item)
        self.process.join(2.0)
        # Another thread's wait may have reaped it a moment ago: its exit code lands right after.
        deadline = time.monotonic() + 1.0
        while self.process.exitcode is None and time.monotonic() < deadline and not self.process.is_alive():
            time.sleep(0.005)
        cause = describe_exit(self.process.exitcode)
        crashed = next((e for e in reversed(self.events) if isinstance(e, msg.Crashed)), None)
        if crashed is not None:
            cause += ": " + crashed.traceback.strip().splitlines()[-1]
        with self._cv:
            self.exit_cause = cause
            self._cv.notify_all()
        if self.on_exit is not None and not self._closing:
            self.on_exit(cause)

    def send(self, req: msg.Request) -> None:
        """Fire-and-forget: no reply is asked for (the servo process validates and drops bad ones)."""
        if not self.alive:
            raise TimeoutError(f"the {self.name} is not running ({self.exit_cause})")
        with self._send_lock:
            self._conn.send(msg.Envelope(None, req))

    def request(self, req: msg.Request, timeout: float = 2.0,
                on_late: Callable[[msg.Reply], None] | None = None) -> Any:
        """Send a request and wait for its reply; a refusal raises CommandRejected with its message
        (InvalidRequest if the request itself was bad), a dead or silent process TimeoutError.

        With ``on_late`` the request expires with the wait: the servo process refuses it once
        ``timeout`` has passed (Envelope.deadline), and the reply to one it took just before, which
        came after the wait (a stall between the two), goes to ``on_late`` (from the pipe's reader)."""
        if not self.alive:
            raise TimeoutError(f"the {self.name} is not running ({self.exit_cause})")
        if self._given_up is not None:
            raise TimeoutError(self._given_up_text(req))
        deadline = time.monotonic() + timeout
        with self._send_lock:
            self._next_id += 1
            rid = self._next_id
            with self._cv:  # before the send: its reply may come before we wait
                self._waiting.add(rid)
            try:
                self._conn.send(msg.Envelope(rid, req, deadline if on_late is not None else None))
            except OSError as exc:
                with self._cv:
                    self._waiting.discard(rid)
                raise TimeoutError(f"the {self.name} is not reachable: {exc}") from None
        with self._cv:
            try:
                while rid not in self._replies:
                    left = deadline - time.monotonic()
                    if self._given_up is not None:
                        if on_late is not None:
                            self._late[rid] = on_late
                        raise TimeoutError(self._given_up_text(req))
                    if not self.alive:
                        raise TimeoutError(f"the {self.name} {self.exit_cause} before answering {type(req).__name__}")
                    if left <= 0:
                        if on_late is not None:
                            self._late[rid] = on_late
                        raise TimeoutError(f"the {self.name} did not answer {type(req).__name__} within {timeout} s")
                    self._cv.wait(left)
                reply = self._replies.pop(rid)
            finally:  # (also on an interrupt in the wait: a reply stored meanwhile goes with it)
                self._waiting.discard(rid)
                self._replies.pop(rid, None)
        if not reply.ok:
            raise (InvalidRequest if reply.invalid else CommandRejected)(reply.error)
        return reply.result

    def give_up(self, why: str, next_step: str) -> None:
        """No reply will come (the owner found the process stalled and ends it): every request waiting
        for one, and any asked from now on, raises TimeoutError at once with ``why`` and ``next_step``,
        not when its own timeout runs out. (What a waiting request's caller was told is unchanged:
        it was not answered; with ``on_late`` a reply that still comes goes there.)"""
        with self._cv:
            self._given_up = (why, next_step)
            self._cv.notify_all()

    def _given_up_text(self, req: msg.Request) -> str:
        assert self._given_up is not None
        why, next_step = self._given_up
        return f"the {self.name} {why} and did not answer {type(req).__name__}; {next_step}"

    def last_event(self, kind: type[msg.Event]) -> msg.Event | None:
        with self._cv:
            for ev in reversed(self.events):
                if isinstance(ev, kind):
                    return ev
        return None

    def wait_event(self, kind: type[msg.Event], timeout: float, **match: Any) -> msg.Event:
        deadline = time.monotonic() + timeout
        seen = 0
        with self._cv:
            while True:
                for ev in self.events[seen:]:
                    if isinstance(ev, kind) and all(getattr(ev, k) == v for k, v in match.items()):
                        return ev
                    if isinstance(ev, msg.Crashed):
                        raise RuntimeError(f"{self.name} crashed:\n{ev.traceback}")
                seen = len(self.events)
                if not self.alive:
                    raise RuntimeError(f"{self.name} {self.exit_cause} before {kind.__name__}; "
                                       f"events: {self.events[-5:]}")
                left = deadline - time.monotonic()
                if left <= 0:
                    raise TimeoutError(f"no {kind.__name__} event {match} within {timeout} s; "
                                       f"events: {self.events[-5:]}")
                self._cv.wait(left)

    def quiet_for(self, now: float) -> float:
        """How long the process has published no new state, as seen by this method's calls (one
        watcher's: a watcher that was itself held up sees the new version, not a stall). The process
        publishes every pass of its loop (~20 ms at most): a long quiet is a stalled process."""
        try:
            version = self.slot.version
        except AttributeError:  # its slot is closed: it has been shut down
            return 0.0
        if version != self._quiet_version:
            self._quiet_version, self._quiet_since = version, now
        return now - self._quiet_since

    def state(self) -> dict[str, Any]:
        _, data = self.slot.read(patience_s=0.25)  # (a writer preempted mid-write: see LatestValueSlot.read)
        return decode_state(data)

    def expect_exit(self) -> None:
        """The process is about to end by our will (a signal we sent or the terminal's Ctrl-C): its
        end is no fault to report."""
        self._closing = True

    def end_now(self, grace_s: float = 1.0) -> None:
        """End the process by our will (SIGTERM, SIGKILL after ``grace_s``: a stalled one takes no
        SIGTERM), keeping its state slot: the views read its last state, as a dead process's."""
        self._closing = True
        if self.alive:
            self.process.terminate()
            if not self.wait_exit(grace_s):
                self.process.kill()
                self.wait_exit(3.0)

    def wait_exit(self, timeout: float) -> bool:
        """Wait until the reader has seen the process end (it alone reaps it); True if it has."""
        with self._cv:
            return self._cv.wait_for(lambda: not self.alive, timeout)

    def shutdown(self, timeout: float = 10.0) -> int | None:
        """Signal the process (it ends a running stream cleanly) and wait for it; its exit code."""
        self._closing = True
        if self.alive:
            assert self.process.pid is not None
            with contextlib.suppress(ProcessLookupError):
                os.kill(self.process.pid, signal.SIGTERM)
            # The reader thread reaps it (one waiter only: two racing waits can lose the exit code).
            if not self.wait_exit(timeout):
                self.process.kill()
                self.wait_exit(3.0)
        if self._reader is not None:
            self._reader.join(3.0)
        with contextlib.suppress(OSError):
            self._conn.close()
        self.slot.close()
        return self.process.exitcode
