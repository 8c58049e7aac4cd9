"""``ServoClient``: script the arm over the service's REST API and telemetry WebSocket.

What a script would otherwise do by hand is done here: the control lease is taken on entry, renewed
in the background (a third of its TTL) and released on exit; a jog is re-sent every 50 ms for as long
as a ``with client.jog(...)`` block runs, and released at its end; a motion call waits until the arm
has arrived (``wait=True``); refusals are typed exceptions carrying the server's own sentence, which
ends with the next step.

Only httpx and websockets: nothing from the server's side of servo_app is imported (the client is
installable on its own: ``pip install servo_app[client]``). No asyncio twin: the synchronous client
is what a cell script needs, and its waits are short polls of ``GET /api/state``.
"""

from __future__ import annotations

import builtins
import contextlib
import json
import os
import re
import threading
import time
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from types import TracebackType
from typing import Any
from urllib.parse import quote

import httpx
import websockets.exceptions
import websockets.sync.client

from servo_app.client.errors import (
    AuthError,
    FaultError,
    LeaseError,
    RefusedError,
    ServoError,
    StoppedError,
    TimeoutError,
)
from servo_app.client.state import Point, State, Tool

# The server's lease refusals (servo_app.api.auth.LeaseManager) all speak of control or the lease;
# the state's refusals never do.
_LEASE_WORDS = re.compile(r"control lease|control is held|X-Lease-Id")
# A refusal sentence that names its field first: "joints[0]=500 deg ...", "joints has 5 values ...".
_SENTENCE_FIELD = re.compile(r"^([A-Za-z_]+(?:\[\d+\])?)(?:=| has )")
# States in which a motion the client waits for is still on its way.
_MOVING_STATES = ("streaming",)
_STREAM_STATES = ("streaming", "stopping", "stopped", "ending")  # a stream runs: the robot reports
_POLL_S = 0.02  # state polls while waiting: 50 a second, a cycle's worth of the telemetry rate


def _field_of_schema_error(error: dict[str, Any]) -> str:
    # loc: ["body", "JointTarget", "joints", 5]: the model's name is pydantic's tag of a union member.
    parts = [str(p) for p in error.get("loc", []) if not (isinstance(p, str) and p[:1].isupper())]
    return ".".join(parts)


def _refusal(status: int, detail: Any) -> RefusedError:
    if isinstance(detail, list) and detail:  # a schema error: the fields, as pydantic lists them
        first = detail[0]
        where = _field_of_schema_error(first)
        message = "; ".join(f"{_field_of_schema_error(e)}: {e.get('msg')}" for e in detail)
        return RefusedError(message, status=status, field=where, errors=detail)
    text = str(detail)
    named = _SENTENCE_FIELD.match(text)
    return RefusedError(text, status=status, field=named.group(1) if named else None)


class JogHold:
    """A jog held down: re-sent every ``period_s`` until :meth:`release` (or the end of a ``with``
    block), then released, so the arm decelerates to rest. ``update`` changes the velocity on the fly.

    The service stops the arm by itself ``hold_ms`` after the last jog it got (hold-to-run), so a
    script that dies mid-jog leaves nothing moving."""

    def __init__(self, client: ServoClient, body: dict[str, Any], period_s: float = 0.05,
                 hold_ms: float = 300.0) -> None:
        self._client = client
        self._body = body
        self._period_s = period_s
        self._hold_ms = hold_ms
        self._lock = threading.Lock()
        self._released = threading.Event()
        self._failed = threading.Event()  # the renewal was refused: a duration ends early
        self._thread: threading.Thread | None = None
        self.error: ServoError | None = None  # why the renewal stopped early, if it did
        self.sent = 0

    def _send(self) -> None:
        with self._lock:
            body = {**self._body, "hold_ms": self._hold_ms}
        self._client._post("/api/jog", body)
        self.sent += 1

    def _renew(self) -> None:
        while not self._released.wait(self._period_s):
            try:
                self._send()
            except ServoError as exc:  # refused, faulted, lease lost: the arm stops by itself; say why at release
                self.error = exc
                self._failed.set()
                return

    def hold(self) -> JogHold:
        """Send the first jog (a refusal raises here, at once) and keep it renewed."""
        self._send()
        self._thread = threading.Thread(target=self._renew, name="servo-client-jog", daemon=True)
        self._thread.start()
        return self

    def update(self, **velocity: Sequence[float]) -> None:
        """New velocities from the next renewal on (``linear=``, ``angular=`` or ``joints=``)."""
        with self._lock:
            self._body = {**self._body, **{k: [float(x) for x in v] for k, v in velocity.items()}}

    def release(self, wait: bool = True, timeout: float = 10.0) -> None:
        """Let go: no more renewals, a zero velocity at once (the shaper brakes now rather than after
        the hold time), and with ``wait`` until the arm is at rest. Raises what ended the jog early."""
        self._released.set()
        if self._thread is not None:
            self._thread.join()
        if self.error is None:
            zero = {k: [0.0] * len(v) for k, v in self._body.items() if k in ("linear", "angular", "joints")}
            frame = {"frame": self._body["frame"]} if "frame" in self._body else {}
            try:
                self._client._post("/api/jog", {**zero, **frame, "hold_ms": 50.0})
            except ServoError as exc:
                self.error = exc
        if self.error is not None:
            raise self.error
        if wait:
            self._client.wait_at_rest(timeout)

    def __enter__(self) -> JogHold:
        return self

    def __exit__(self, kind: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None) -> None:
        if kind is None:
            self.release()
            return
        with contextlib.suppress(ServoError):  # the block raised: let go without waiting, let its exception through
            self.release(wait=False)


@dataclass
class Recording:
    """A stretch recorded by :meth:`ServoClient.record`: its session log and wall-clock window."""

    log: str
    start_unix: float
    end_unix: float | None = None

    @property
    def window(self) -> dict[str, Any]:
        """``ServoClient.replay``'s keyword arguments for this stretch."""
        return {"log": self.log, "from_unix": self.start_unix, "to_unix": self.end_unix}


class ServoClient:
    """A session with a running service. As a context manager it holds the control lease for the
    block (``take_over=True`` displaces another holder, whose motion the service stops first).

    ``token``: the service's bearer token (default: the ``SERVO_APP_TOKEN`` environment variable)."""

    def __init__(self, url: str = "http://127.0.0.1:8000", token: str | None = None, *,
                 name: str = "servo_app.client", take_over: bool = False, lease_ttl_s: float | None = None,
                 timeout: float = 10.0) -> None:
        self.url = url.rstrip("/")
        self.name = name
        self.take_over = take_over
        self.lease_ttl_s = lease_ttl_s
        token = token if token is not None else os.environ.get("SERVO_APP_TOKEN", "")
        self._auth = {"Authorization": f"Bearer {token}"} if token else {}
        self._http = httpx.Client(base_url=self.url, timeout=timeout)
        self.lease_id: str | None = None
        self.lease_renewals = 0
        self._lease_lost: LeaseError | None = None
        self._lease_stop = threading.Event()
        self._lease_thread: threading.Thread | None = None
        self._io_allow: dict[str, list[int]] | None = None  # GET /api/limits' io_allow, read once

    # ------------------------------------------------------------------ lease
    def __enter__(self) -> ServoClient:
        self.acquire()
        return self

    def __exit__(self, kind: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None) -> None:
        if kind is None:
            self.close()
            return
        # The block raised: that is the error to see. A release that fails too (the service gone, say)
        # must not replace it; the lease then runs out by itself.
        with contextlib.suppress(ServoError):
            self.close()

    def acquire(self) -> None:
        """Take the control lease and keep it renewed in the background (held already: nothing to do)."""
        if self.lease_id is not None and self._lease_lost is None and self._lease_thread is not None \
                and self._lease_thread.is_alive():
            return  # a second renewal thread would outlive release(), which stops one
        body: dict[str, Any] = {"client": self.name, "force": self.take_over}
        if self.lease_ttl_s is not None:
            body["ttl_s"] = self.lease_ttl_s
        granted = self._call("POST", "/api/lease", body, lease=False)
        self.lease_id, self._lease_lost = str(granted["lease_id"]), None
        self._lease_stop.clear()
        self._lease_thread = threading.Thread(target=self._renew_lease, args=(float(granted["ttl_s"]),),
                                              name="servo-client-lease", daemon=True)
        self._lease_thread.start()

    def _renew_lease(self, ttl_s: float) -> None:
        # A third of the TTL: two renewals may be lost (a slow network, a busy API) before it expires.
        while not self._lease_stop.wait(ttl_s / 3):
            try:
                self._call("POST", "/api/lease/renew", lease=True)
                self.lease_renewals += 1
            except LeaseError as exc:  # expired or taken over: every motion call raises it from now on
                self._lease_lost = exc
                return
            except (TimeoutError, ServoError):  # no answer this time: the next try may get through
                continue

    def release(self) -> None:
        """Stop renewing and give the lease back (the service stops a moving arm softly first)."""
        self._lease_stop.set()
        if self._lease_thread is not None:
            self._lease_thread.join()
            self._lease_thread = None
        if self.lease_id is not None and self._lease_lost is None:
            try:
                self._call("DELETE", "/api/lease", lease=True)
            except LeaseError:  # taken over or expired since the last renewal: nothing left to release
                pass
            finally:
                self.lease_id = None

    def close(self) -> None:
        try:
            self.release()
        finally:
            self._http.close()

    # --------------------------------------------------------------- requests
    def _headers(self, lease: bool) -> dict[str, str]:
        if not lease:
            return self._auth
        if self._lease_lost is not None:
            raise self._lease_lost
        if self.lease_id is None:
            raise LeaseError("this client holds no control lease: use it as a context manager "
                             "(with ServoClient(...) as arm:) or call acquire()")
        return {**self._auth, "X-Lease-Id": self.lease_id}

    def _call(self, method: str, path: str, body: Any = None, *, lease: bool = False,
              params: dict[str, Any] | None = None, csv: str | None = None) -> Any:
        headers = self._headers(lease)
        try:
            if csv is not None:  # a CSV body (POST /api/trajectory)
                r = self._http.request(method, path, content=csv.encode(), params=params,
                                       headers={**headers, "Content-Type": "text/csv"})
            else:
                r = self._http.request(method, path, json=body, params=params, headers=headers)
        except httpx.TimeoutException as exc:
            raise TimeoutError(f"{method} {path}: no answer from {self.url} ({exc})") from None
        except httpx.TransportError as exc:
            raise ServoError(f"{method} {path}: cannot reach the service at {self.url} ({exc})") from None
        if r.status_code < 400:
            return r.json()
        try:
            detail = r.json().get("detail", r.text)
        except ValueError:
            detail = r.text
        status = r.status_code
        if status == 401:
            raise AuthError(str(detail), status=status)
        if status == 503:
            raise TimeoutError(str(detail), status=status)
        if status == 409 and _LEASE_WORDS.search(str(detail)):
            raise LeaseError(str(detail), status=status)
        if status == 409 and method != "GET":
            fault = self._fault_now(status)
            if fault is not None:
                raise fault
        raise _refusal(status, detail)

    def _post(self, path: str, body: Any = None) -> Any:
        return self._call("POST", path, body, lease=True)

    def _fault_now(self, status: int | None = None) -> FaultError | None:
        s = self.state()
        return self._fault_of(self._with_alarm(s), status) if s.state == "fault" else None

    def _with_alarm(self, s: State, patience_s: float = 0.5) -> State:
        """The fault state once its alarm is in: a fault the service sees on the status bits (SYSRDY
        off) shows a poll of the controller's alarm list (50 ms) before the alarm that caused it."""
        deadline = time.monotonic() + patience_s
        while (s.fault is None or s.fault.code is None) and not any(not a.warning for a in s.alarms) \
                and time.monotonic() < deadline and s.state == "fault":
            time.sleep(_POLL_S)
            s = self.state()
        return s

    @staticmethod
    def _fault_of(s: State, status: int | None = None) -> FaultError:
        """The fault with its controller alarm: the newest active alarm that is no warning gives the
        code, cause and remedy (the fault view has them too when the service knows the alarm)."""
        alarms = [a for a in s.alarms if not a.warning]
        alarm = alarms[-1] if alarms else None
        f = s.fault
        message = f.message if f else (alarm.message if alarm else "the service is in the fault state")
        return FaultError(message, code=(f.code if f and f.code else None) or (alarm.code if alarm else None),
                          cause=(f.cause if f else None) or (alarm.cause if alarm else None),
                          remedy=(f.remedy if f else None) or (alarm.remedy if alarm else None), status=status)

    # ------------------------------------------------------------------ state
    def state(self) -> State:
        return State.from_json(self._call("GET", "/api/state"))

    def _wait(self, done: Callable[[State], bool], timeout: float, what: str, moving: bool = False) -> State:
        """Poll the state until ``done`` holds for a state published after this call began (an older
        one may predate the request just answered). A fault raises FaultError; with ``moving``, a
        motion that stops short (the arm stopped, the stream ended) raises StoppedError."""
        first = self.state()
        deadline = time.monotonic() + timeout
        s = first
        while True:
            if s.state == "fault":
                raise self._fault_of(self._with_alarm(s))
            fresh = s.published_unix is not None and first.published_unix is not None \
                and s.published_unix > first.published_unix
            if fresh and moving and s.state not in _MOVING_STATES and s.at_rest:
                raise StoppedError(f"the motion ended short: the arm is {s.state} ({s.stop_reason or 'no reason'})",
                                   reason=s.stop_reason)
            if fresh and done(s):
                return s
            if time.monotonic() > deadline:
                raise TimeoutError(f"{what}: not within {timeout} s (state {s.state}, at rest {s.at_rest}, "
                                   f"stop reason {s.stop_reason})")
            time.sleep(_POLL_S)
            s = self.state()

    def wait_at_rest(self, timeout: float = 30.0) -> State:
        """Until the commanded motion is at rest."""
        return self._wait(lambda s: s.at_rest, timeout, "at rest")

    def wait_settled(self, timeout: float = 30.0) -> State:
        """Until the commanded motion is at rest and the robot's feedback has stopped moving (a stream
        must run: without one the robot reports nothing, and RefusedError says so at once)."""
        s = self.state()
        if s.state not in _STREAM_STATES and s.state != "fault":
            raise RefusedError(f"settled: no stream runs (state {s.state}), so the robot's feedback cannot show the "
                               "arm settled; start one: POST /api/session/start (ServoClient.start())")
        return self._wait(lambda s: s.settled, timeout, "settled")

    def wait_state(self, *states: str, timeout: float = 15.0) -> State:
        """Until the safety state is one of ``states`` (a fault raises unless "fault" is one of them)."""
        deadline = time.monotonic() + timeout
        while True:
            s = self.state()
            if s.state in states:
                return s
            if s.state == "fault":
                raise self._fault_of(self._with_alarm(s))
            if time.monotonic() > deadline:
                raise TimeoutError(f"state {states}: not within {timeout} s (now {s.state}, {s.stop_reason})")
            time.sleep(_POLL_S)

    # ---------------------------------------------------------------- session
    def start(self, timeout: float = 15.0) -> State:
        """Open the link if needed and stream, holding the current position."""
        self._post("/api/session/start")
        return self.wait_state("streaming", timeout=timeout)

    def ensure_streaming(self, timeout: float = 15.0) -> State:
        """Whatever the stream is doing, have it streaming: start a new one (disconnected, ready,
        ended), or resume a soft stop. A fault or a fast stop is left to the operator (they need a
        look first): FaultError, or RefusedError naming the reset."""
        s = self.wait_state("streaming", "stopped", "disconnected", "connected", "ready", "ended", timeout=timeout)
        if s.state == "stopped":
            if s.stop_fast:
                raise RefusedError(f"the arm was fast-stopped ({s.stop_reason}); acknowledge it first: reset()")
            return self.resume()
        return s if s.state == "streaming" else self.start(timeout)

    def stop(self, fast: bool = False, wait: bool = True, timeout: float = 10.0) -> State | None:
        """Decelerate to rest and hold (``fast``: the shortest ramp; then ``reset()`` before ``resume()``).
        Needs the token only: any client may stop the arm."""
        self._call("POST", "/api/session/stop", {"fast": fast})
        return self.wait_state("stopped", "ended", timeout=timeout) if wait else None

    def resume(self) -> State:
        self._post("/api/session/resume")
        return self.wait_state("streaming")

    def reset(self, timeout: float = 15.0) -> State:
        """Leave a fault (the controller's alarm too) or acknowledge a fast stop."""
        self._post("/api/reset")
        deadline = time.monotonic() + timeout
        while True:
            s = self.state()
            if s.state != "fault" and not s.stop_fast:
                return s
            if time.monotonic() > deadline:
                raise TimeoutError(f"reset: still {s.state} after {timeout} s")
            time.sleep(_POLL_S)

    def end(self, timeout: float = 15.0) -> State:
        """Decelerate, close the stream and its session log."""
        self._post("/api/session/end")
        return self.wait_state("ended", timeout=timeout)

    # ----------------------------------------------------------------- motion
    def _move(self, path: str, body: dict[str, Any], wait: bool, timeout: float) -> State | None:
        self._post(path, body)
        return self._wait(lambda s: s.at_rest, timeout, f"the motion of {path}", moving=True) if wait else None

    def move_joints(self, joints: Sequence[float], speed_scale: float = 1.0, wait: bool = True,
                    timeout: float = 60.0) -> State | None:
        """Go to joint positions (deg, or mm for a linear axis) along a jerk-limited path; with ``wait``,
        return once the commanded motion is at rest there."""
        return self._move("/api/target", {"joints": [float(q) for q in joints], "speed_scale": speed_scale},
                          wait, timeout)

    def move_pose(self, xyzwpr: Sequence[float], linear_speed: float = 100.0, angular_speed: float = 30.0,
                  wait: bool = True, timeout: float = 60.0) -> State | None:
        """Go to a pose of the active tool's TCP (X Y Z mm, W P R deg, world frame; see :meth:`set_tool`)
        in a straight line at the given TCP speeds."""
        body = {"xyzwpr": [float(v) for v in xyzwpr], "linear_speed": linear_speed, "angular_speed": angular_speed}
        return self._move("/api/target", body, wait, timeout)

    def session_logs(self) -> list[dict[str, Any]]:
        """The service's session logs, newest first: name, bytes, modified_unix."""
        return list(self._call("GET", "/api/sessions"))

    @contextlib.contextmanager
    def record(self) -> Iterator[Recording]:
        """Record what the arm does in the block (jogging, teleoperation, hand guiding: every stream is
        logged per cycle); afterwards ``replay(**recording.window)`` replays that stretch. Needs a
        running stream (its session log is the newest)."""
        logs = self.session_logs()
        if not logs:
            raise ServoError("no session log: start a stream first (ensure_streaming())")
        rec = Recording(log=str(logs[0]["name"]), start_unix=time.time())
        try:
            yield rec
        finally:
            rec.end_unix = time.time()

    def replay(self, joints: Sequence[Sequence[float]] | None = None, *,
               poses: Sequence[Sequence[float]] | None = None, times: Sequence[float] | None = None,
               csv: str | None = None, log: str | None = None, from_s: float | None = None,
               to_s: float | None = None, from_unix: float | None = None, to_unix: float | None = None,
               speed_scale: float = 1.0, pace: str = "recorded", blend: bool = False, wait: bool = True,
               timeout: float = 300.0) -> dict[str, Any]:
        """Replay a path within the controller's limits (``POST /api/trajectory``): joint waypoints
        (deg), TCP ``poses`` (X Y Z mm, W P R deg), a ``csv`` text in ``servo-app check``'s form, or a
        recorded session ``log`` by name with an optional window (s after its first command). The arm
        first moves to the path's start if it rests elsewhere. With ``wait``, returns once the replay
        is done and at rest; a stop or a fault before that raises (StoppedError, FaultError). Returns
        the plan's summary (samples, duration_s, ramp_s, ...). A ``csv`` or ``log`` (one row per interval)
        replays no faster than it was recorded (``pace="recorded"``) or, with ``pace="limits"``, as fast
        as the limits allow. ``blend`` (joints only, no ``times``): pass through the waypoints without
        stopping, at rest only at the last (one joint spline through them all)."""
        if csv is not None:
            ack = self._call("POST", "/api/trajectory", lease=True, csv=csv,
                             params={"speed_scale": speed_scale, "pace": pace})
        else:
            body: dict[str, Any] = {"speed_scale": speed_scale}
            for key, value in (("joints", joints), ("poses", poses)):
                if value is not None:
                    body[key] = [[float(v) for v in row] for row in value]
            if times is not None:
                body["times"] = [float(t) for t in times]
            if blend:
                body["blend"] = True
            if log is not None:
                body["log"] = log
                body["pace"] = pace
                if from_s is not None:
                    body["from_s"] = from_s
                for key, t in (("to_s", to_s), ("from_unix", from_unix), ("to_unix", to_unix)):
                    if t is not None:
                        body[key] = t
            ack = self._post("/api/trajectory", body)
        summary: dict[str, Any] = dict(ack.get("detail") or {})
        if wait:
            self._wait(lambda s: s.trajectory is not None and s.trajectory.state == "done" and s.at_rest,
                       timeout, "the replay", moving=True)
        return summary

    def jog(self, linear: Sequence[float] = (0.0, 0.0, 0.0), angular: Sequence[float] = (0.0, 0.0, 0.0),
            frame: str = "base", duration: float | None = None) -> JogHold:
        """A Cartesian jog of the active tool's TCP (mm/s, deg/s; rotations turn about the TCP).
        ``frame`` "base": along and about the world axes; "tool": the TCP's own axes. Without ``duration``: a context
        manager that holds it until the block ends (``with arm.jog(linear=(20, 0, 0)): ...``); with
        one: held that long, then released, returning once the arm is at rest."""
        body = {"linear": [float(v) for v in linear], "angular": [float(v) for v in angular], "frame": frame}
        return self._jog(body, duration)

    def jog_joints(self, velocities: Sequence[float], duration: float | None = None) -> JogHold:
        """A joint jog (deg/s, or mm/s for a linear axis per axis), held as :meth:`jog` holds it."""
        return self._jog({"joints": [float(v) for v in velocities]}, duration)

    def _jog(self, body: dict[str, Any], duration: float | None) -> JogHold:
        held = JogHold(self, body).hold()
        if duration is not None:
            held._failed.wait(duration)  # the duration, or less if a renewal is refused
            held.release()
        return held

    # ------------------------------------------------------------------ tools
    def tools(self) -> list[Tool]:
        """The cell's tools (the built-in ``flange`` first); the active one is ``state().tool``."""
        return [Tool.from_json(t) for t in self._call("GET", "/api/tools")["tools"]]

    def set_tool(self, name: str) -> Tool:
        """Make ``name`` the TCP of jogs, pose targets and the reported pose, and its payload the limit
        tables'. Only at rest: waits until the arm has settled if a stream runs (a refusal raises
        RefusedError and changes nothing; an unknown name: RefusedError with status 404)."""
        if self.state().state in ("streaming", "stopping", "stopped", "ending"):
            self.wait_settled()
        return Tool.from_json(self._call("PUT", "/api/tool", {"name": name}, lease=True))

    def define_tool(self, name: str, xyzwpr: Sequence[float], payload_kg: float) -> Tool:
        """Add a tool until the service stops (the tools file keeps it: servo-app run --tools)."""
        body = {"name": name, "xyzwpr": [float(v) for v in xyzwpr], "payload_kg": float(payload_kg)}
        return Tool.from_json(self._post("/api/tools", body))

    # -------------------------------------------------------------------- I/O
    def _io_access(self, io_type: str, point: int) -> tuple[int, int]:
        """(index, bit) of the 16-point access that reaches ``point``: from the point itself where the
        allowed range permits, else from the last index that reaches it. An access covers 16 points, so
        the service takes indexes up to the last point - 15; one point past that (DO 498..512 of 512)
        was refused. A type or point the service does not allow goes as it is: refused, naming why."""
        if self._io_allow is None:
            self._io_allow = self._call("GET", "/api/limits").get("io_allow") or {}
        span = self._io_allow.get(str(io_type).upper())
        if span is None or not span[0] <= point <= span[1]:
            return point, 1
        index = max(span[0], min(point, span[1] - 15))
        return index, 1 << (point - index)

    def io_read(self, io_type: str, index: int) -> bool:
        """One I/O point (DI, DO, F, M, ...; only while streaming)."""
        start, bit = self._io_access(io_type, index)
        answer = self._call("GET", "/api/io", params={"type": io_type, "index": start, "mask": bit})
        return bool(int(answer["value"]) & bit)

    def io_read16(self, io_type: str, index: int) -> int:
        """16 points from ``index`` (bit 0: the point at ``index``)."""
        return int(self._call("GET", "/api/io", params={"type": io_type, "index": index})["value"])

    def io_write(self, io_type: str, index: int, value: bool | int) -> None:
        """Set one I/O point (DO, F, M, ...), sent with the next command packet."""
        start, bit = self._io_access(io_type, index)
        self._post("/api/io", {"type": io_type, "index": start, "mask": bit, "value": bit if value else 0})

    # -------------------------------------------------------------- telemetry
    def telemetry(self, hz: float = 50.0, timeout: float = 5.0) -> Iterator[State]:
        """The state ``hz`` times a second over ``/ws/telemetry``, until the loop stops iterating."""
        ws_url = "ws" + self.url.removeprefix("http") + f"/ws/telemetry?hz={hz}"
        with websockets.sync.client.connect(ws_url, open_timeout=timeout) as ws:
            while True:
                try:
                    text = ws.recv(timeout=timeout)
                except websockets.exceptions.ConnectionClosed as exc:
                    rcvd = exc.rcvd
                    if rcvd is not None and rcvd.code == 1008:  # the rate refused, with the reason
                        raise RefusedError(rcvd.reason, status=1008) from None
                    raise ServoError(f"the telemetry socket closed: {exc}") from None
                except builtins.TimeoutError as exc:  # websockets: recv ran out
                    raise TimeoutError(f"no telemetry message within {timeout} s") from exc
                yield State.from_json(json.loads(text))

    # ----------------------------------------------------------- teach points
    def teach(self, name: str, settle_timeout: float = 30.0, replace: bool = False) -> Point:
        """Save the current TCP pose and joints as ``name`` (once the arm has settled). A point of
        that name is kept and RefusedError (409) raised, unless ``replace=True``."""
        # Without a stream the arm never reports settled: the service's refusal says to start one.
        if self.state().state in _STREAM_STATES:
            self.wait_settled(settle_timeout)
        return Point.from_json(self._call("POST", f"/api/points/{quote(name, safe='')}", lease=True,
                                          params={"replace": "true"} if replace else None))

    def points(self) -> list[Point]:
        return [Point.from_json(p) for p in self._call("GET", "/api/points")]

    def delete_point(self, name: str) -> None:
        self._call("DELETE", f"/api/points/{quote(name, safe='')}", lease=True)

    def move_to(self, name: str, speed_scale: float = 1.0, wait: bool = True, timeout: float = 60.0) -> State | None:
        """Go to a taught point's joints (its configuration exactly as taught)."""
        return self._move(f"/api/points/{quote(name, safe='')}/move", {"speed_scale": speed_scale}, wait, timeout)

