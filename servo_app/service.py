"""The service object behind the API: the servo process, the embedded simulator, leases, logs.

It lives in the API process and stays thin: every motion decision is taken in the servo process
(the cycle owns stops, hold-to-run and watchdogs, so a frozen API cannot leave the arm moving). This
object forwards requests, reads the published state and keeps the lists the API shows.

Threads: the API calls in from many worker threads at once (requests, telemetry, metrics). The
servo process's handle owns its pipe (one reader thread: replies wake their own waiter, so a stop
never queues behind other requests; events and the process's death are passed here); a monitor
thread polls the embedded simulator's alarm list and forwards new alarms to the servo process at
once, whether or not anyone reads state.
"""

from __future__ import annotations

import contextlib
import signal
import threading
import time
from collections import Counter, deque
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from servo_app import messages as msg
from servo_app.errors import CommandRejected
from servo_app.fanuc.alarms import ALARMS
from servo_app.fanuc.packets import ROBOT_PORT, IoType
from servo_app.fanuc.runner import StreamConfig, StreamProcess
from servo_app.inputs.actions import OutputToggle
from servo_app.janome.profile import available_janome_profiles, load_janome_profile
from servo_app.janome.runner import DEFAULT_PORT as JANOME_PORT
from servo_app.motion.diffik import holding_back
from servo_app.motion.limit_tables import default_tables
from servo_app.process_handle import ServoProcessHandle
from servo_app.realtime import make_realtime
from servo_app.robots.profile import load_profile

IO_SPAN = 16  # a command packet's read or write covers 16 points from its index (manual 61.7)

# The embedded simulator's assigned I/O (points per type). SI/SO/WI/WO/WSI/WSO are not assigned
# there, and UI/UO drive the controller itself: not offered.
DEFAULT_IO_ALLOW: dict[str, int] = {"DI": 512, "DO": 512, "RI": 8, "RO": 8, "F": 1024, "M": 1024}


class InvalidRequest(ValueError):
    """A request the service refuses before it reaches the controller (the API answers 422)."""


def parse_robot(spec: str | None) -> tuple[str, str, int] | None:
    """The ``--robot`` option.

    ``fanuc:HOST[:PORT]`` -> ("fanuc", host, port), a controller to stream to; ``janome:HOST[:PORT]``
    -> ("janome", host, port), where servo_app listens for the robot's point job (it is the TCP
    client); plain ``janome`` -> ("janome", "127.0.0.1", 0) with the embedded Janome simulator; None
    means the embedded FANUC simulator.
    """
    if not spec:
        return None
    kind, _, rest = spec.partition(":")
    if kind == "janome" and not rest:
        return kind, "127.0.0.1", 0
    if kind not in ("fanuc", "janome") or not rest:
        raise ValueError(f"--robot={spec!r}: expected fanuc:HOST[:PORT], janome[:HOST[:PORT]]")
    host, _, port = rest.partition(":")
    default = ROBOT_PORT if kind == "fanuc" else JANOME_PORT
    try:
        return kind, host, int(port) if port else default
    except ValueError:
        raise ValueError(f"--robot={spec!r}: port {port!r} is not a number") from None


@dataclass
class ServiceConfig:
    robot: str | None = None  # None: embedded simulator
    model: str = "lrmate200id"
    interval_ms: int | None = None
    # Two commands ahead in the controller's buffer: a lost status packet is made up at the next one,
    # and with lead 2 only three lost in a row starve the controller (MOTN-603). Measured with the
    # simulator dropping 5 % of status packets: lead 1 alarmed within 1 s, lead 2 ran 15 s clean
    # (tests/test_faults_e2e.py). The price is two intervals of extra response time.
    lead: int = 2
    var_dir: Path = Path("var")
    sim_port: int = 0  # embedded simulator UDP port (0: any free port)
    limit_fraction: float = 0.9
    flange_speed_cap: float | None = None
    payload_kg: float | None = None
    # The embedded controller starts at the usual FANUC home (wrist bent down), as a cell would after
    # a taught joint move before IBGN start; all-zero joints would be a wrist singularity.
    sim_options: dict[str, Any] = field(default_factory=lambda: {"initial_joints": [0.0, 0.0, 0.0, 0.0, -90.0, 0.0]})
    # I/O the service lets clients read and write (type -> assigned points). A 16-point access
    # outside it would make the controller post PRIO-023 and stop: refuse it here instead.
    io_allow: dict[str, int] = field(default_factory=lambda: dict(DEFAULT_IO_ALLOW))
    alarm_poll_s: float = 0.05  # how often the embedded simulator's alarm list is read
    # The embedded simulator stands in for a controller, which keeps its timing whatever else runs.
    # At normal priority it was starved for 100 ms by a SCHED_FIFO process busy on its core (another
    # servo process warming up): the servo process then saw no status and the simulator posted
    # MOTN-603. Below the servo process's priority (20), so that one still comes first. None: leave.
    sim_realtime_priority: int | None = 10
    request_timeout_s: float = 2.0
    # A start waits for the stream to run (status output, limit tables, the controller's waiting bit):
    # given up after this, with the reason (the request then answers 409).
    start_timeout_s: float = 5.0
    inputs_config: Path | None = None  # inputs TOML (servo-app run --inputs): adapters, feeds, applications

    @property
    def log_dir(self) -> Path:
        return self.var_dir / "sessions"


class ServoService:
    """The servo process (one, replaced after it dies), the embedded simulator, the views.

    The servo process is watched: if it dies, the state shows a fault naming the cause within the
    pipe's end of file (milliseconds), requests are refused with that cause instead of timing out,
    and ``reset`` or ``start`` bring up a new process. Nothing here waits by sleeping."""

    def __init__(self, cfg: ServiceConfig) -> None:
        self.cfg = cfg
        robot = parse_robot(cfg.robot)
        self.backend = robot[0] if robot else "fanuc"
        if self.backend == "janome":
            # A FANUC default model name means "the default Janome model" here.
            self.model = cfg.model if cfg.model in available_janome_profiles() else "jr3000"
            self.profile: Any = load_janome_profile(self.model)
        else:
            self.model = cfg.model
            self.profile = load_profile(cfg.model)
        self.sim: Any = None
        self.stream: ServoProcessHandle | None = None
        self.stops_by_reason: Counter[str] = Counter()
        self.faults: list[dict[str, Any]] = []
        self.robot_address: tuple[str, int] | None = None
        self.events: deque[msg.Event] = deque(maxlen=2000)
        self._safety: dict[str, Any] = {}  # the servo process's last SafetyChanged view
        self._safety_cv = threading.Condition()
        self._lifecycle = threading.Lock()  # one open / replace / close at a time
        self._sim_lock = threading.Lock()
        self._alarms_seen = 0
        self._sim_events: list[dict[str, Any]] = []
        self._stop = threading.Event()
        self._threads: list[threading.Thread] = []
        self.servo_fault: dict[str, Any] | None = None  # the servo process died: why, and what to do
        self.servo_starts = 0
        self.sim_scheduling = "no embedded simulator"
        self.inputs: Any = None  # the InputsBridge, with cfg.inputs_config

    # ------------------------------------------------------------------ life
    def open(self) -> None:
        robot = parse_robot(self.cfg.robot)
        if self.cfg.inputs_config is not None:  # first: a bad file stops here; the servo process maps its slot
            from servo_app.inputs.bridge import InputsBridge

            self.inputs = InputsBridge.from_file(self.cfg.inputs_config)
        if robot is None:
            self.sim = self._start_simulator()
            self.robot_address = self.sim.address
        elif robot[0] == "fanuc":
            self.robot_address = (robot[1], robot[2])
        with self._lifecycle:
            self._spawn()
        if robot is not None and robot[0] == "janome" and self.cfg.robot == "janome":
            from servo_app.sim.process import JanomeSimulatorProcess

            assert self.robot_address is not None
            self.sim = JanomeSimulatorProcess(server=self.robot_address, model=self.model).start()
        self._stop.clear()
        self._threads = [threading.Thread(target=self._monitor_loop, name="sim-alarms", daemon=True)]
        for t in self._threads:
            t.start()
        if self.inputs is not None:
            self.inputs.start(request=self.request, feedback=self.state_vector, act=self._output_action)

    def _make_handle(self) -> ServoProcessHandle:
        watch = {"on_event": self._on_event, "on_exit": self._on_servo_exit}
        slot = self.inputs.slot_name if self.inputs is not None else None
        if self.backend == "janome":
            from servo_app.janome.runner import JanomeConfig, JanomeProcess

            robot = parse_robot(self.cfg.robot)
            assert robot is not None
            # A replacement process listens where the first one did: the robot is configured for it.
            host, port = self.robot_address or (robot[1], robot[2])
            return JanomeProcess(JanomeConfig(host=host, port=port, model=self.model, log_dir=str(self.cfg.log_dir),
                                              input_slot=slot), **watch)
        assert self.robot_address is not None
        host, port = self.robot_address
        return StreamProcess(StreamConfig(
            host=host, port=port, model=self.cfg.model, interval_ms=self.cfg.interval_ms, lead=self.cfg.lead,
            log_dir=str(self.cfg.log_dir), limit_fraction=self.cfg.limit_fraction,
            flange_speed_cap=self.cfg.flange_speed_cap, payload_kg=self.cfg.payload_kg, input_slot=slot,
            start_timeout_s=self.cfg.start_timeout_s), **watch)

    def _spawn(self) -> None:
        """Start a servo process (the first, or one replacing a dead one). Holds ``_lifecycle``."""
        if self.stream is not None:
            self.stream.shutdown(timeout=2.0)
        with self._safety_cv:
            self._safety = {}
        handle = self._make_handle()
        handle.start()
        if self.sim is not None:  # alarms posted before this process existed are not its faults
            with contextlib.suppress(TimeoutError, RuntimeError, OSError, EOFError):
                self._alarms_seen = len(self.sim_call("events"))
        if self.backend == "janome":
            self.robot_address = handle.address  # type: ignore[attr-defined]
        self.stream = handle
        self.servo_fault = None
        self.servo_starts += 1

    def _on_servo_exit(self, cause: str) -> None:
        """The servo process died (the pipe's end of file): a fault the operator can leave with reset."""
        fault = {
            "message": f"servo process {cause}",
            "code": None,
            "cause": "The process that streams to the robot ended unexpectedly; the controller got no "
                     "further commands and stopped the arm itself (a FANUC posts MOTN-603).",
            "remedy": "Reset (POST /api/reset) to start a new servo process, then start a new stream. "
                      "The session log is complete up to the process's last record.",
            "during": (self._safety or {}).get("state"),
        }
        self.servo_fault = fault
        self.faults.append({"code": "SERVO", "message": fault["message"], "time_unix": time.time()})
        with self._safety_cv:
            self._safety_cv.notify_all()

    def _start_simulator(self) -> Any:
        from servo_app.sim.process import SimulatorProcess

        sim = SimulatorProcess(model=self.cfg.model, port=self.cfg.sim_port, interval_ms=self.cfg.interval_ms,
                               **self.cfg.sim_options)
        # Ctrl-C reaches the whole process group: the simulator (the "controller") must keep sending
        # status while the servo process decelerates and sends last data. A child inherits SIG_IGN.
        if threading.current_thread() is not threading.main_thread():
            sim.start()
        else:
            old = signal.signal(signal.SIGINT, signal.SIG_IGN)
            try:
                sim.start()
            finally:
                signal.signal(signal.SIGINT, old)
        self.sim_scheduling = make_realtime(self.cfg.sim_realtime_priority, sim.process.pid)
        return sim

    def close(self, group_signal_wait_s: float = 0.0) -> dict[str, Any]:
        """End the stream cleanly (the servo process decelerates, sends last data, stops the status
        output), then stop the simulator. Returns what happened, for the operator.

        ``group_signal_wait_s``: after a Ctrl-C the servo process got the terminal's SIGINT too; wait
        this long to see it shutting down by itself, since a second signal would escalate its soft
        stop to the fast ramp."""
        summary: dict[str, Any] = {}
        if self.stream is not None and group_signal_wait_s > 0:
            with self._safety_cv:
                self._safety_cv.wait_for(lambda: bool(self._safety.get("shutdown")) or not self.stream.alive,
                                         group_signal_wait_s)
            if self._safety.get("shutdown"):
                self.stream.process.join(10.0)  # then shutdown() finds it gone and sends no signal
        if self.inputs is not None:  # adapters close their devices; the slot lives until the servo process exits
            self.inputs.stop()
        self._stop.set()
        for t in self._threads:
            t.join(timeout=2.0)
        self._threads = []
        with self._lifecycle:
            if self.stream is not None:
                died = self.servo_fault is not None
                summary["servo_exit_code"] = self.stream.shutdown()
                safety = self._safety
                summary.update(state=safety.get("state"), link=safety.get("link"),
                               stop_reason=safety.get("stop_reason"), fault=safety.get("fault"))
                if died:
                    summary.update(state="fault", fault=self.servo_fault)
                self.stream = None
        if self.sim is not None:
            with contextlib.suppress(TimeoutError, RuntimeError, OSError, EOFError):
                summary["alarms"] = [e["code"] for e in self.sim_call("events")]
            self.sim.stop()
            self.sim = None
        if self.inputs is not None:
            self.inputs.close()
            self.inputs = None
        return summary

    # ------------------------------------------------------------ the pipe
    def _on_event(self, ev: msg.Event) -> None:
        """Called on the handle's reader thread for every event."""
        self.events.append(ev)
        if isinstance(ev, msg.SafetyChanged):
            with self._safety_cv:
                self._safety = ev.view
                self._safety_cv.notify_all()

    def last_event(self, kind: type[msg.Event]) -> msg.Event | None:
        for ev in reversed(self.events):
            if isinstance(ev, kind):
                return ev
        return None

    @property
    def servo_alive(self) -> bool:
        return self.stream is not None and self.stream.alive

    def request(self, req: msg.Request, timeout: float | None = None) -> Any:
        """Send a typed request to the servo process and wait for its reply.

        A refusal raises CommandRejected. With the servo process dead: a stop is accepted (nothing
        moves any more), a start first brings up a new process, anything else is refused with the
        cause and the way out."""
        if not self.servo_alive:
            if isinstance(req, msg.Stop):
                return None
            if isinstance(req, msg.Start) and self.stream is not None:
                self._replace_servo_process()
            else:
                raise CommandRejected(self._dead_why())
        assert self.stream is not None
        if timeout is None:
            timeout = self.cfg.request_timeout_s
            if isinstance(req, msg.Start):
                timeout += self.cfg.start_timeout_s
        return self.stream.request(req, timeout)

    def _dead_why(self) -> str:
        if self.stream is None:
            return "the service is not open"
        cause = self.servo_fault["message"] if self.servo_fault else "the servo process is not running"
        return f"{cause}: reset (POST /api/reset) to start a new servo process"

    def _replace_servo_process(self) -> None:
        with self._lifecycle:
            if not self.servo_alive:
                self._spawn()

    def send(self, req: msg.Request) -> None:
        """Fire-and-forget: no reply is asked for (the servo process validates and drops bad ones)."""
        if self.stream is None:
            raise RuntimeError("the service is not open")
        self.stream.send(req)

    def stop(self, reason: str, fast: bool = False) -> None:
        self.stops_by_reason[reason] += 1
        self.request(msg.Stop(reason=reason, fast=fast))

    def reset(self) -> None:
        """Clear a fault: the simulator's alarm (as an operator at the pendant would), then the
        supervisor; a dead servo process is replaced by a new one (in disconnected: start next)."""
        if not self.servo_alive and self.stream is not None:
            # First the new process (about a second of warm-up), then the controller's reset: the
            # alarm the old process's silence caused (MOTN-603) has been posted by then.
            self._replace_servo_process()
            if self.sim is not None:
                self.sim_call("reset")
            return
        if self.sim is not None:
            self.sim_call("reset")
        self.request(msg.Reset())

    # ------------------------------------------------------------ simulator
    def sim_call(self, name: str, *args: Any) -> Any:
        """A control of the embedded simulator (reset, set_override, ...): the teach pendant's part."""
        if self.sim is None:
            raise RuntimeError("no embedded simulator: the robot is external")
        with self._sim_lock:
            return self.sim.call(name, *args)

    def _monitor_loop(self) -> None:
        while not self._stop.wait(self.cfg.alarm_poll_s):
            with contextlib.suppress(TimeoutError, RuntimeError, OSError, EOFError):
                self._forward_alarms()

    def _forward_alarms(self) -> None:
        """The J519 status carries no alarm code: the embedded simulator's alarm list supplies it."""
        if self.sim is None:
            return
        events = self.sim_call("events")
        for ev in events[self._alarms_seen:]:
            spec = ALARMS.get(ev["code"])
            if spec is not None and not spec.warning:
                self.faults.append(ev)
            # Fire-and-forget: this thread must not wait on the pipe reader; warnings are reported too.
            with contextlib.suppress(RuntimeError, OSError, TimeoutError):
                self.send(msg.ControllerAlarm(code=ev["code"], message=ev["message"]))
        self._alarms_seen = len(events)
        self._sim_events = events

    # ----------------------------------------------------------------- I/O
    def _check_io(self, io_type: str, index: int) -> str:
        name = str(io_type).upper()
        allowed = ", ".join(f"{t} 1..{n}" for t, n in self.cfg.io_allow.items())
        if name not in self.cfg.io_allow:
            known = name in IoType.__members__
            raise InvalidRequest(
                f"type={io_type!r}: {'this I/O type is not' if known else 'not an I/O type'} allowed by the "
                f"service (allowed: {allowed}); the controller would post PRIO-023 and stop")
        n = self.cfg.io_allow[name]
        if n < IO_SPAN:
            raise InvalidRequest(
                f"type={name}: only {n} points are assigned and an access always covers {IO_SPAN} points, so "
                f"any {name} access would make the controller post PRIO-023")
        if not 1 <= index <= n - IO_SPAN + 1:
            raise InvalidRequest(
                f"index={index}: an access covers {IO_SPAN} points from the index, so {name} indexes must be in "
                f"1..{n - IO_SPAN + 1} ({name} has points 1..{n}); the controller would post PRIO-023")
        return name

    def io_write(self, io_type: str, index: int, mask: int, value: int) -> None:
        name = self._check_io(io_type, index)
        self.request(msg.IoWrite(type=name, index=index, mask=mask, value=value))

    def io_read(self, io_type: str, index: int, mask: int = 0xFFFF, timeout: float = 1.0) -> int:
        """Read 16 points through the command packets: the value comes back in a later status packet."""
        name = self._check_io(io_type, index)
        if self.state_vector()["link"] != "streaming":
            raise CommandRejected("I/O is read through command packets: only while streaming")
        self.request(msg.IoRead(type=name, index=index, mask=mask))
        seq0 = self.state_vector()["status_seq"]  # published just before the reply: the request's cycle
        # The read rides on the next command sent; with `lead` commands queued ahead, the controller
        # processes it lead + 1 statuses later. Any earlier write is processed before it.
        want = (int(IoType[name]), index, mask)
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            s = self.state_vector()
            if s["link"] != "streaming":
                raise CommandRejected(f"the stream stopped ({s['state']}) before the read came back")
            echo = (s["io_read_type"], s["io_read_index"], s["io_read_mask"])
            if echo == want and s["status_seq"] - seq0 >= self.cfg.lead + 2:
                return int(s["io_read_value"])
            time.sleep(0.002)
        raise TimeoutError(f"no status packet echoed the read of {name}[{index}] within {timeout} s")

    def toggle_output(self, io_type: str, point: int) -> int:
        """Flip one output point (a device button's gripper): read it through the status packets, then
        write it inverted; returns the new value. An access covers 16 points from its index, so the
        index is the point itself where the allowed range permits, else the last index that reaches it."""
        n = self.cfg.io_allow.get(io_type, 0)
        if io_type in self.cfg.io_allow and point > n:  # an unknown type is io_read's to refuse, by name
            raise InvalidRequest(f"{io_type}[{point}] is outside the allowed {io_type} 1..{n}")
        index = max(1, min(point, n - IO_SPAN + 1))
        bit = 1 << (point - index)
        new = (self.io_read(io_type, index, bit) & bit) ^ bit
        self.io_write(io_type, index, bit, new)
        return int(bool(new))

    def _output_action(self, action: OutputToggle) -> int:
        return self.toggle_output(action.io_type, action.point)

    # ----------------------------------------------------------------- views
    def state_vector(self) -> dict[str, Any]:
        """The servo process's published state alone (cheap: a shared-memory copy); a dead process's
        last state shows the fault."""
        if self.stream is None:
            return {"state": "disconnected", "link": "idle"}
        s = self.stream.state()
        if self.servo_fault is not None:
            s["state"], s["link"] = "fault", "fault"
        return s

    def state(self) -> dict[str, Any]:
        if self.stream is None:
            return {"state": "disconnected", "link": "idle"}
        s = self.stream.state()
        # The servo process sends its safety event (stop reason, fault) before it publishes the mode,
        # but the pipe's reader thread may not have taken it in yet: wait for it (it is on its way).
        with self._safety_cv:
            self._safety_cv.wait_for(lambda: not self._safety or self._safety.get("state") == s["state"]
                                     or self.servo_fault is not None, 0.05)
            safety = self._safety
        s.update({k: v for k, v in safety.items() if k not in ("event", "state", "link")})
        s["servo_process"] = "running"
        if self.servo_fault is not None:  # the last published state is stale: the process is gone
            s.update(state="fault", link="fault", fault=self.servo_fault, resumable=False, at_rest=True)
            s["servo_process"] = self.servo_fault["message"].removeprefix("servo process ")
        s["servo_starts"] = self.servo_starts
        s["model"] = self.profile.name
        # Why a Cartesian motion goes slower than asked, or stops short (None: no Cartesian motion).
        s["cartesian"] = {"scale": s["ik_scale"], "condition": s["ik_condition"],
                          "held_back_by": holding_back(s["ik_flags"])} if s.get("ik_active") else None
        s["robot"] = f"{self.robot_address[0]}:{self.robot_address[1]}" if self.robot_address else None
        s["simulated"] = self.sim is not None
        s["alarms"] = self.alarms()
        s["faults"] = self.faults[-10:]
        if self.inputs is not None:
            s["inputs"] = self.inputs.summary()
        return s

    def alarms(self) -> list[dict[str, Any]]:
        if self.sim is None:
            return []
        out = []
        for ev in self._sim_events[-20:]:
            spec = ALARMS.get(ev["code"])
            out.append({**ev, "cause": spec.cause if spec else "", "remedy": spec.remedy if spec else "",
                        "warning": bool(spec and spec.warning)})
        return out

    def stops(self) -> dict[str, int]:
        """Stops by reason: the servo process's (hold-to-run, lease, signals, API) plus API-only counts."""
        out = Counter(self.stops_by_reason)
        out.update(self._safety.get("stops") or {})
        return dict(out)

    def _janome_limits(self) -> dict[str, Any]:
        p = self.profile
        return {
            "model": p.name,
            "backend": "janome",
            "axes": ["X", "Y", "Z", "R"],
            "source": "profile (configured)",
            "axis_min": list(p.axis_min),
            "axis_max": list(p.axis_max),
            "speed": list(p.speed),
            "accel": list(p.accel),
            "cp_speed_mm_s": p.cp_speed,
            "step_s": p.step_s,
            "max_step_mm": p.max_step_mm,
            "max_step_deg": p.max_step_deg,
        }

    def limits(self) -> dict[str, Any]:
        if self.backend == "janome":
            return self._janome_limits()
        tables = default_tables(self.profile)
        vel, acc, jerk = tables.for_cap(self.cfg.flange_speed_cap or tables.vmax, self.cfg.payload_kg)
        st = self.stream.state() if self.stream else {}
        from_ctrl = bool(st.get("tables_from_controller"))
        if from_ctrl:
            vel, acc, jerk = st["vel_limit"], st["acc_limit"], st["jerk_limit"]
        return {
            "model": self.profile.name,
            "source": "controller limit tables" if from_ctrl else "profile defaults (configured, not published)",
            "interval_ms": self.cfg.interval_ms or self.profile.interval_ms,
            "limit_fraction": self.cfg.limit_fraction,
            "joint_min_deg": list(self.profile.joint_min_deg),
            "joint_max_deg": list(self.profile.joint_max_deg),
            "vel_deg_s": [float(v) for v in vel],
            "acc_deg_s2": [float(v) for v in acc],
            "jerk_deg_s3": [float(v) for v in jerk],
            "max_flange_speed_mm_s": tables.vmax,
            "io_allow": {t: [1, n] for t, n in self.cfg.io_allow.items()},
        }

    def session_logs(self) -> list[dict[str, Any]]:
        d = self.cfg.log_dir
        if not d.is_dir():
            return []
        return [{"name": p.name, "bytes": p.stat().st_size, "modified_unix": p.stat().st_mtime}
                for p in sorted(d.glob("*.srvlog"), key=lambda p: p.stat().st_mtime, reverse=True)]

    def session_log_path(self, name: str) -> Path:
        p = (self.cfg.log_dir / name).resolve()
        if p.parent != self.cfg.log_dir.resolve() or p.suffix != ".srvlog" or not p.is_file():
            raise FileNotFoundError(f"no session log named {name!r}")
        return p

    def wait_state(self, state: str, timeout: float = 10.0) -> dict[str, Any]:
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            s = self.state()
            if s["state"] == state:
                return s
            time.sleep(0.01)
        raise TimeoutError(f"state {state!r} not reached within {timeout} s (now {self.state()['state']})")
