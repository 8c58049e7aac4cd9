"""The service object behind the API: the robot backend, its servo process and simulator, the views.

It lives in the API process and stays thin: every motion decision is taken in the servo process
(the cycle owns stops, hold-to-run and watchdogs, so a frozen API cannot leave the arm moving). This
object owns the lifecycle and forwards typed requests; alarm forwarding, I/O and the views are
their own modules beside it, and everything vendor-specific comes from the backend.

The servo process is watched: if it dies, the state shows a fault naming the cause as soon as its
pipe ends (milliseconds), requests are refused with that cause and the way out instead of timing
out, and ``reset`` or ``start`` bring up a new process. Nothing here waits by sleeping.

Threads: the API calls in from many worker threads at once (requests, telemetry, metrics). The
servo process's handle owns its pipe (one reader thread: replies wake their own waiter, so a stop
never queues behind other requests; events and the process's death are passed here).
"""

from __future__ import annotations

import contextlib
import logging
import math
import threading
import time
from collections import Counter, deque
from collections.abc import Callable
from dataclasses import fields, replace
from pathlib import Path
from typing import Any

from servo_app import messages as msg
from servo_app.backends import ProcessOptions, RobotBackend, open_backend
from servo_app.errors import CommandRejected
from servo_app.process_handle import ServoProcessHandle, describe_exit
from servo_app.robots.tool import Tool, ToolError
from servo_app.service.alarms import AlarmForwarder
from servo_app.service.config import ServiceConfig
from servo_app.service.io import StreamIo
from servo_app.service.points import PointStore
from servo_app.service.tools import ActiveTool, load_tool_set
from servo_app.service.views import StateViews

log = logging.getLogger(__name__)


class ServoService:
    def __init__(self, cfg: ServiceConfig) -> None:
        self.cfg = cfg
        self.backend: RobotBackend = open_backend(cfg.robot, cfg.model, cfg.io_allow)
        self.profile: Any = self.backend.profile
        self.model = self.backend.model
        self.sim: Any = None
        self.stream: ServoProcessHandle | None = None
        self.stops_by_reason: Counter[str] = Counter()
        self.robot_address: tuple[str, int] | None = None
        self.events: deque[msg.Event] = deque(maxlen=2000)
        self.controller_tables: Any = None  # the last limit tables a start read from the controller
        self.recorders: list[Any] = []  # LiveMcapRecorder per session log, with cfg.mcap_live
        # The last live MCAP that stopped short (file, why, what to do): GET /api/state's mcap_error.
        self.mcap_error: dict[str, str] | None = None
        self._recorder_class: Any = None
        if cfg.mcap_live:  # imported here, not on the event thread at the first stream (mcap, rosbags: 0.3 s)
            from servo_app.service.mcap_live import LiveMcapRecorder

            self._recorder_class = LiveMcapRecorder
        self._safety: dict[str, Any] = {}  # the servo process's last SafetyChanged view
        self._safety_cv = threading.Condition()
        self._lifecycle = threading.Lock()  # one open / replace / close at a time
        self.servo_fault: dict[str, Any] | None = None  # the servo process died: why, and what to do
        self.servo_starts = 0
        self.spawning = False  # a servo process is being started (its predecessor, if any, is gone)
        self._watchdog: threading.Thread | None = None  # ends a stalled servo process (_watch_servo)
        self._watchdog_stop = threading.Event()
        self.inputs: Any = None  # the InputsBridge, with cfg.inputs_config
        self.alarm_forwarder = AlarmForwarder(self.backend, self.sim_call, self.send, cfg.alarm_poll_s)
        self.io = StreamIo(self.backend, self.request, self.state_vector, cfg.lead)
        self.views = StateViews(self)
        self.points = PointStore(cfg.var_dir / "points.json")  # teach points (servo_app.api.points)
        self.tools = ActiveTool(load_tool_set(cfg, self.profile), getattr(self.profile, "max_payload_kg", None),
                                self.request, self.state_vector, self._set_simulator_payload,
                                retire_servo=self._retire_servo)

    @property
    def options(self) -> ProcessOptions:
        c = self.cfg
        return ProcessOptions(interval_ms=c.interval_ms, lead=c.lead, log_dir=str(c.log_dir),
                              limit_fraction=c.limit_fraction, flange_speed_cap=c.flange_speed_cap,
                              payload_kg=self.tools.active.payload_kg, start_timeout_s=c.start_timeout_s,
                              input_slot=self.inputs.slot_name if self.inputs is not None else None)

    def _refuse_at_the_feeds_door(self) -> None:
        """The twist feeds refuse what the servo process would for the robot's flange-speed cap (with
        the active tool's offset), naming it: else they answered "accepted" and the servo refused."""
        from servo_app.inputs.feed import FlangeLimit

        if self.backend.twist_flange_cap(self.options) is None:
            return

        def limit() -> FlangeLimit | None:
            # The cap as the servo holds it now: the controller's tables, once a start has read them,
            # may carry a $MAX_SPD below the configured cap (the feed refused by the configured one).
            cap = self.backend.twist_flange_cap(self.options, self.controller_tables)
            return None if cap is None else FlangeLimit(cap, math.hypot(*self.tools.active.xyzwpr[:3]))

        self.inputs.feeds.flange_limit = limit

    @property
    def sim_scheduling(self) -> str:
        return str(getattr(self.sim, "scheduling", "no embedded simulator"))

    # ------------------------------------------------------------------ life
    def open(self) -> None:
        if self.cfg.inputs_config is not None:  # first: a bad file stops here; the servo process maps its slot
            from servo_app.inputs.bridge import InputsBridge

            self.inputs = InputsBridge.from_file(self.cfg.inputs_config)
            self._refuse_at_the_feeds_door()
        target = self.backend.target
        if target.embedded:
            target = replace(target, port=self.cfg.sim_port)
        launched = None
        try:
            if target.embedded and self.backend.simulator_first:
                # The servo process imports its modules while the simulator starts (each is 1-3 s of
                # CPU), told the simulator's address once that is up: with two cores the service is up
                # a simulator start sooner.
                launched = self._launch_early(target)
                sim_options = {"interval_ms": self.cfg.interval_ms, **self.cfg.sim_options}
                self.sim = self.backend.start_simulator(target, sim_options, self.cfg.sim_realtime_priority)
                target = replace(target, host=self.sim.address[0], port=self.sim.address[1])
            self.robot_address = (target.host, target.port)
            if self.sim is not None:
                self._set_simulator_payload(self.tools.active.payload_kg)
        except BaseException:
            if launched is not None:
                launched.shutdown(timeout=2.0)
            raise
        with self._lifecycle:
            self._spawn(launched)
        try:
            self.tools.apply_to_new_process()
        except (ToolError, TimeoutError):  # (a process that did not take the tool is stopped already)
            self.close()
            raise
        if target.embedded and not self.backend.simulator_first:  # the robot connects to us: it comes second
            assert self.robot_address is not None
            self.sim = self.backend.start_simulator(replace(target, host=self.robot_address[0],
                                                            port=self.robot_address[1]),
                                                    self.cfg.sim_options, self.cfg.sim_realtime_priority)
        # Also with an external robot (no alarm list to poll): the forwarder counts the faults the
        # service detects itself, whether or not anyone reads /api/state.
        self.alarm_forwarder.start()
        self._watchdog = threading.Thread(target=self._watch_servo, name="servo watchdog", daemon=True)
        self._watchdog.start()
        if self.inputs is not None:
            self.inputs.start(request=self.request, feedback=self.state_vector, act=self.io.on_action)

    def _launch_early(self, target: Any) -> ServoProcessHandle | None:
        """The first servo process, launched (importing) before its controller's address is known;
        None for a backend whose process configuration has no ``host`` and ``port`` to set later."""
        handle = self.backend.make_process(target, self.options, self._on_event, self._on_servo_exit)
        if not {"host", "port"} <= {f.name for f in fields(handle.cfg)}:
            handle.slot.close()  # (never launched: its pipe goes with it)
            return None
        handle.launch()
        return handle

    def _spawn(self, launched: ServoProcessHandle | None = None) -> None:
        """Start a servo process (the first, or one replacing a dead one; ``launched``: the first,
        launched by ``_launch_early``). Holds ``_lifecycle``.

        One that dies or stays silent before it is ready (killed while warming up, say) becomes the
        stream's fault: the state names it, the next reset tries again, and TimeoutError (503) says so."""
        self.spawning = True
        if self.inputs is not None:  # a new servo process starts with input control off
            self.inputs.servo_gone()
        try:
            if self.stream is not None:
                self.stream.shutdown(timeout=2.0)
            with self._safety_cv:
                self._safety = {}
            assert self.robot_address is not None
            # A replacement listens or connects where the first one did: the robot is configured for it.
            target = replace(self.backend.target, host=self.robot_address[0], port=self.robot_address[1])
            if launched is not None:
                handle = launched
                handle.retarget(target.host, target.port)
            else:
                handle = self.backend.make_process(target, self.options, self._on_event, self._on_servo_exit)
            try:
                ready = handle.start()  # (on failure it has shut the process down)
            except (RuntimeError, TimeoutError) as exc:
                how = "stayed silent" if isinstance(exc, TimeoutError) else handle.exit_cause
                why = self._start_failed(handle, how)
                raise TimeoutError(f"{why}; reset again to start another: POST /api/reset") from None
        finally:
            self.spawning = False
        if ready.address is not None:  # a listening backend: where it listens (port 0: any free port)
            self.robot_address = (str(ready.address[0]), int(ready.address[1]))
        if self.sim is not None:
            self.alarm_forwarder.skip_past()
        self.stream = handle
        self.servo_fault = None
        self.servo_starts += 1

    def _start_failed(self, handle: ServoProcessHandle, cause: str) -> str:
        """A new servo process ended (``cause``: how) before it was ready. It stays the stream, dead: the
        state shows this fault and a reset replaces it as it would any dead process. Returns the fault's
        message."""
        message = f"servo process {cause} before it was ready"
        self.stream = handle
        self.servo_fault = {
            "message": message,
            "code": None,
            "cause": "The new servo process did not come up; nothing streams to the robot.",
            "remedy": "Reset again (POST /api/reset) to start another servo process; if it keeps failing, "
                      "the service's output says why.",
            "during": "starting",
        }
        self.alarm_forwarder.record_fault("SERVO", message)
        return message

    def _on_servo_exit(self, cause: str) -> None:
        """The servo process ended unasked (the pipe's end of file): a fault the operator can leave
        with reset. (Even a clean exit on a signal: no stream can run until a new process is up.)"""
        self._servo_gone(f"servo process {cause}",
                         "The process that streams to the robot ended unexpectedly; the controller got no "
                         "further commands and stopped the arm itself.")

    def _retire_servo(self, message: str) -> None:
        """Stop a servo process that holds a tool other than the active one and did not answer its
        change in time (ActiveTool): it must not move that TCP once it runs again. The same fault as a
        dead process's, ``message`` naming why; a reset starts another, given the active tool. Not under
        ``_lifecycle``: a replacement (which holds it) calls this for the process it started."""
        stream = self.stream
        if stream is None or not stream.alive or self.servo_fault is not None:  # (being ended: _watch_servo)
            return
        log.warning("%s: stopping that servo process", message)
        stream.end_now(grace_s=1.0)
        self._servo_gone(message, "The servo process was stopped: it did not answer in time and may hold a "
                                  "tool other than the active one; nothing streams to the robot.")

    def _watch_servo(self) -> None:
        """End a servo process that is alive but stalled (SIGSTOP, stuck in a computation): it publishes
        its state every loop pass, so ``cfg.servo_stall_s`` without a new one is a stall. Without this
        the state showed the stalled process's last "streaming" for good, every request (a reset too)
        timed out, and the process, continued, sent the controller its stale commands (MOTN-600)."""
        stall_s = self.cfg.servo_stall_s
        while not self._watchdog_stop.wait(min(0.1, stall_s / 4)):
            stream = self.stream
            if stream is None or not stream.alive or self.servo_fault is not None:
                continue
            quiet = stream.quiet_for(time.monotonic())
            # Not while a reset or start replaces the process (they hold _lifecycle): look again next time.
            if quiet > stall_s and self._lifecycle.acquire(blocking=False):
                try:
                    if stream is self.stream and stream.alive and self.servo_fault is None:
                        self._end_stalled(stream, quiet)
                finally:
                    self._lifecycle.release()

    def _end_stalled(self, stream: ServoProcessHandle, quiet_s: float) -> None:
        # The stall time too: which setting made this a fault (servo-app run --servo-stall-s).
        why = (f"stalled: it ran no cycle for {quiet_s:.1f} s "
               f"(stall time {self.cfg.servo_stall_s:g} s, servo-app run --servo-stall-s)")
        message = f"servo process {why}"
        log.warning("%s: ending it (SIGTERM, then SIGKILL)", message)
        # The fault first: the state names it, and requests are refused with it, while the process is ended.
        self._servo_gone(message, "The process that streams to the robot stopped running its cycle (stopped by "
                                  "a signal, or stuck); the controller got no further commands and stopped the "
                                  "arm itself. The service ended that process (SIGTERM, then SIGKILL), so it "
                                  "cannot send the controller stale commands if it runs again.")
        # The requests waiting for it are answered now (503, the stall and the way out), not when the
        # process dies of the SIGKILL a second later ("ended by signal 9": neither why nor what to do).
        stream.give_up(why, "it is being ended; reset the fault to start a new servo process: POST /api/reset")
        stream.end_now(grace_s=1.0)

    def _servo_gone(self, message: str, cause: str) -> None:
        self.servo_fault = {
            "message": message,
            "code": None,
            "cause": cause,
            "remedy": "Reset (POST /api/reset) to start a new servo process, then start a new stream. "
                      "The session log is complete up to the process's last record.",
            "during": self._safety.get("state"),
        }
        self.alarm_forwarder.record_fault("SERVO", self.servo_fault["message"])
        if self.inputs is not None:  # nothing follows the inputs now: say so
            self.inputs.servo_gone()
        self._close_recorders()  # no LogClosed will come: what the process wrote is all there is
        with self._safety_cv:
            self._safety_cv.notify_all()

    def close(self, group_signal_wait_s: float = 0.0) -> dict[str, Any]:
        """End the stream cleanly (the servo process decelerates, sends last data, stops the status
        output), then stop the simulator. Returns what happened, for the operator.

        ``group_signal_wait_s``: after a Ctrl-C the servo process got the terminal's SIGINT too; wait
        this long to see it shutting down by itself, since a second signal would escalate its soft
        stop to the fast ramp."""
        summary: dict[str, Any] = {}
        self._watchdog_stop.set()  # the process is ours to end from here
        if self._watchdog is not None:
            self._watchdog.join(10.0)
        stream = self.stream
        if stream is not None:
            stream.expect_exit()  # from here on its end is ours, not a fault
        if stream is not None and group_signal_wait_s > 0:
            with self._safety_cv:
                self._safety_cv.wait_for(lambda: bool(self._safety.get("shutdown")) or not stream.alive,
                                         group_signal_wait_s)
            if self._safety.get("shutdown"):
                stream.wait_exit(10.0)  # then shutdown() finds it gone and sends no signal
        if self.inputs is not None:  # adapters close their devices; the slot lives until the servo process exits
            self.inputs.stop()
        self.alarm_forwarder.stop()
        with self._lifecycle:
            if self.stream is not None:
                # Ctrl-C reaches the whole process group: a servo process that ended its stream on
                # it and exited cleanly before we got here did what it was asked, no fault.
                clean = bool(self._safety.get("shutdown")) and self.stream.exit_cause in ("", describe_exit(0))
                died = self.servo_fault is not None and not clean
                summary["servo_exit_code"] = self.stream.shutdown()
                safety = self._safety
                summary.update(state=safety.get("state"), link=safety.get("link"),
                               stop_reason=safety.get("stop_reason"), fault=safety.get("fault"))
                if died:
                    summary.update(state="fault", fault=self.servo_fault)
                self.stream = None
        if self.sim is not None:
            # For the operator only: whatever the simulator answers (or not), the shutdown goes on.
            with contextlib.suppress(Exception):
                summary["alarms"] = [str(e["code"]) for e in self.sim_call("events")]
            self.sim.stop()
            self.sim = None
        if self.inputs is not None:
            self.inputs.close()
            self.inputs = None
        self._close_recorders()
        for rec in self.recorders:
            rec.join(10.0)
        return summary

    # ------------------------------------------------------------ the pipe
    def _on_event(self, ev: msg.Event) -> None:
        """Called on the handle's reader thread for every event."""
        self.events.append(ev)
        if self._recorder_class is not None and isinstance(ev, msg.LogOpened):
            self._close_recorders()
            self.recorders.append(self._recorder_class(Path(ev.path), on_error=self._mcap_failed,
                                                       on_finished=self._mcap_finished).start())
        elif isinstance(ev, msg.LogClosed):
            if ev.removed:  # a log that held nothing, deleted: its MCAP goes with it
                for rec in self.recorders:
                    if str(rec.srvlog) == ev.path:
                        rec.discard()
            self._close_recorders()
        if isinstance(ev, msg.LimitTablesReceived):
            self.controller_tables = ev.tables
        if isinstance(ev, msg.SafetyChanged):
            with self._safety_cv:
                self._safety = ev.view
                self._safety_cv.notify_all()

    def _mcap_finished(self, rec: Any) -> None:
        """A live MCAP was written whole: an earlier one's error is history (its MCAP-LIVE warning stays
        in the alarm history). It stood for good before: a full disk once, freed, and every later
        recording still showed that error as if it were the current one."""
        err = self.mcap_error
        if err is not None and err["file"] != str(rec.path):
            self.mcap_error = None

    def _mcap_failed(self, rec: Any) -> None:
        """A live MCAP writer stopped short (on its own thread): the operator must hear of it, or the
        cut-short .mcap is taken for the session (only the log's warning said so before)."""
        self.mcap_error = {"file": str(rec.path), "error": rec.error, "remedy": rec.remedy}
        self.alarm_forwarder.service_warning(
            "MCAP-LIVE", f"live MCAP {rec.path.name} stopped: {rec.error}",
            cause=f"{rec.path} could not be written ({rec.error}); it ends where the writer stopped.",
            remedy=rec.remedy[0].upper() + rec.remedy[1:] + ".")

    def _close_recorders(self) -> None:
        for rec in self.recorders:
            rec.close()
        self.recorders = [rec for rec in self.recorders if not rec.done]

    def last_event(self, kind: type[msg.Event]) -> msg.Event | None:
        for ev in reversed(self.events):
            if isinstance(ev, kind):
                return ev
        return None

    @property
    def safety(self) -> dict[str, Any]:
        """The servo process's last safety view (stop reason, fault, stops, ...), as it is now."""
        return self._safety

    def safety_view(self, mode: str, timeout: float = 0.05) -> dict[str, Any]:
        """The servo process's last safety view. It is sent just before the state vector shows a new
        ``mode``, but the reader thread may not have taken it in yet: wait for it (it is on its way)."""
        with self._safety_cv:
            self._safety_cv.wait_for(lambda: not self._safety or self._safety.get("state") == mode
                                     or self.servo_fault is not None, timeout)
            return self._safety

    @property
    def servo_alive(self) -> bool:
        """A servo process runs and may be asked (not one the service is ending: servo_fault)."""
        return self.stream is not None and self.stream.alive and self.servo_fault is None

    def request(self, req: msg.Request, timeout: float | None = None,
                on_late: Callable[[msg.Reply], None] | None = None) -> Any:
        """Send a typed request to the servo process and wait for its reply.

        A refusal raises CommandRejected (InvalidRequest when the request itself is bad: the servo
        process checks counts, ranges and plausibility first). With the servo process dead: a stop is
        accepted (nothing moves any more), a start first brings up a new process, anything else is
        refused with the cause and the way out. ``on_late``: the request expires with the wait
        (ProcessHandle.request)."""
        if not self.servo_alive:
            if isinstance(req, msg.Stop):
                return "nothing was moving: the servo process is not running"
            if isinstance(req, msg.Start) and self.stream is not None:
                self._replace_servo_process()
            else:
                raise CommandRejected(self._dead_why())
        assert self.stream is not None
        if timeout is None:
            timeout = self.cfg.request_timeout_s
            if isinstance(req, msg.Start):
                timeout += self.cfg.start_timeout_s
        return self.stream.request(req, timeout, on_late)

    def _dead_why(self) -> str:
        if self.stream is None:
            return "the service is not open; restart the service"
        cause = self.servo_fault["message"] if self.servo_fault else "the servo process is not running"
        return f"{cause}; reset the fault to start a new servo process: POST /api/reset"

    def _replace_servo_process(self) -> None:
        with self._lifecycle:
            if not self.servo_alive:
                self._spawn()
                self.tools.apply_to_new_process()  # accepted by the first process: the backend takes it

    def _set_simulator_payload(self, payload_kg: float | None) -> None:
        """The embedded controller's payload, where its backend has one (a real controller's is its
        TP program's PAYLOAD[]: docs/tools.md)."""
        if self.sim is not None and self.backend.simulator_payload:
            self.sim_call("set_payload", payload_kg)

    def set_tool(self, name: str) -> Tool:
        return self.tools.select(name)

    def send(self, req: msg.Request) -> None:
        """Fire-and-forget: no reply is asked for (the servo process validates and drops bad ones)."""
        if self.stream is None:
            raise RuntimeError("the service is not open")
        self.stream.send(req)

    def stop(self, reason: str, fast: bool = False) -> None:
        self.stops_by_reason[reason] += 1
        self.request(msg.Stop(reason=reason, fast=fast))

    def reset(self) -> str | None:
        """Clear a fault: the simulator's alarm (as an operator at the pendant would), then the
        supervisor; a dead servo process is replaced by a new one (in disconnected: start next).
        Returns what was done where it is not the usual (the embedded controller's alarm alone)."""
        if not self.servo_alive and self.stream is not None:
            # First the new process (about a second of warm-up), then the controller's reset: the
            # alarm the old process's silence caused (MOTN-603) has been posted by then.
            self._replace_servo_process()
            if self.sim is not None:
                self._reset_simulator("a new servo process is up, but the controller's alarm is not reset")
            self.alarm_forwarder.clear_active()
            return None
        not_ready = self._safety.get("not_ready")  # (before the reset: why the controller would not stream)
        if self.sim is not None:
            self._reset_simulator("the fault is not reset")  # first: if it fails, nothing has changed
        done = None
        try:
            self.request(msg.Reset())
        except TimeoutError:
            if self.servo_fault is None or self.stream is None:
                raise
            # The process stalled or died while it was asked: replace it as a reset after the fact would.
            return self.reset()
        except CommandRejected:
            # No fault here, but the embedded controller held one (a start alone after the servo process
            # died found MOTN-603): its reset at the pendant was this reset's work, so it is no refusal.
            if self.sim is None or not not_ready:
                raise
            done = (f"no fault in the service; the embedded controller was reset, as at its pendant "
                    f"(it was not ready: {not_ready}): start when it is ready")
        self.alarm_forwarder.clear_active()  # a reset acknowledges warnings too, fault or not
        return done

    def _reset_simulator(self, if_not: str) -> None:
        """The embedded controller's reset (its alarm, as at the pendant), within
        ``sim_call_timeout_s``: a stopped controller process makes the reset answer 503 well inside
        the lease, and does not reset later (it drops a request it took up too late)."""
        # Its process died (killed): started again where the servo process sends, where the simulator
        # can (a plug-in's may have neither ``alive`` nor ``restart``).
        if not getattr(self.sim, "alive", True) and hasattr(self.sim, "restart"):
            self._restart_simulator()
        try:
            self.sim_call("reset")
        except TimeoutError as exc:
            raise TimeoutError(f"{exc}; {if_not}: once the controller answers again "
                               "(status_received grows in GET /api/state), reset again: POST /api/reset") from None

    # ------------------------------------------------------------ simulator
    def _restart_simulator(self) -> None:
        """A new embedded simulator in place of one whose process died: as a controller after a power
        cycle, no alarm posted, the tool's payload set again; its alarm list starts anew."""
        log.warning("the embedded simulator's process has ended: starting it again")
        # With the arm where the last status had it (its brakes held it there), not at the initial
        # position: a jump of the feedback a real arm never makes.
        last = self.state_vector()
        at = last.get("q_servo") if last.get("status_received") else None
        self.sim.restart(at=at)
        self._set_simulator_payload(self.tools.active.payload_kg)
        self.alarm_forwarder.skip_past()

    def sim_call(self, name: str, *args: Any, timeout: float | None = None) -> Any:
        """A control of the embedded simulator (reset, set_override, ...): the teach pendant's part.
        From any thread at once (each call gets its own reply); TimeoutError after ``timeout``
        (default ``cfg.sim_call_timeout_s``) when the simulator does not answer."""
        if self.sim is None:
            raise RuntimeError("no embedded simulator: the robot is external")
        return self.sim.call(name, *args, timeout=self.cfg.sim_call_timeout_s if timeout is None else timeout)

    # ----------------------------------------------------- I/O and views (their own modules)
    def io_read(self, io_type: str, index: int, mask: int = 0xFFFF, timeout: float = 1.0) -> int:
        return self.io.read(io_type, index, mask, timeout)

    def io_write(self, io_type: str, index: int, mask: int, value: int) -> str:
        return self.io.write(io_type, index, mask, value)

    def state_vector(self) -> dict[str, Any]:
        return self.views.state_vector()

    def state(self) -> dict[str, Any]:
        return self.views.state()

    def stops(self) -> dict[str, int]:
        return self.views.stops()

    def limits(self) -> dict[str, Any]:
        return self.views.limits()

    def robot_view(self) -> dict[str, Any]:
        return self.views.robot()

    def session_logs(self) -> list[dict[str, Any]]:
        return self.views.session_logs()

    def session_log_path(self, name: str) -> Path:
        return self.views.session_log_path(name)

    def wait_state(self, state: str, timeout: float = 10.0) -> dict[str, Any]:
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            s = self.state()
            if s["state"] == state:
                return s
            time.sleep(0.01)
        raise TimeoutError(f"state {state!r} not reached within {timeout} s (now {self.state()['state']})")
