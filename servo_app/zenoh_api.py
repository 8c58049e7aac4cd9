"""The Zenoh interface (``servo-app run --zenoh``): ROS 2 topics over Zenoh, named as rmw_zenoh names
them, so a ROS 2 node on ``rmw_zenoh_cpp`` reaches the service through a Zenoh router with no bridge.

It runs in the API process, never in the servo process: one session, one thread that publishes (the
state read as ``/ws/telemetry`` reads it) and one that runs the commands (a command waits for the
servo process's answer; Zenoh's own callback threads only queue it). Every command goes through the
REST layer's own functions: the same validation models, control lease, jog rate limit, hold-to-run and
refusal messages (see docs/zenoh.md for the key space and the lease).

Key expressions follow rmw_zenoh's mapping as of ROS 2 Jazzy (rmw_zenoh_cpp 0.2.x/0.6+):
``<domain>/<topic without leading slash>/<pkg>::msg::dds_::<Type>_/RIHS01_<hash>``, CDR payloads,
and the 33-byte publisher attachment (sequence number, source timestamp, GID) rmw_zenoh requires.
"""

from __future__ import annotations

import contextlib
import hashlib
import itertools
import json
import logging
import math
import queue
import re
import socket
import struct
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from fastapi import HTTPException
from fastapi.encoders import jsonable_encoder
from pydantic import TypeAdapter, ValidationError

from servo_app.api import lease as lease_routes
from servo_app.api import session as session_routes
from servo_app.api.auth import token_matches
from servo_app.api.deps import acting_as
from servo_app.api.models import JogBody, LeaseRequest, StopRequest, TargetBody
from servo_app.api.motion import admit_jog, jog_request, target_request
from servo_app.api.state import state_snapshot
from servo_app.errors import validation_errors
from servo_app.ros import messages as ros

if TYPE_CHECKING:
    import zenoh

    from servo_app.api.deps import ApiContext

log = logging.getLogger(__name__)

# The JSON key space (the fleet monitor, and tools that are not ROS): servo_app/<cell>/...
JSON_ROOT = "servo_app"
STATUS_SUFFIX = "status"
LEASE_SUFFIX = "lease"
REPLY_SUFFIX = "reply"
JOINT_NAMES_RE = re.compile(r"joint_(\d+)$")
COMMAND_QUEUE = 256  # commands waiting for the command thread; stops have as many places again


def cell_name(text: str | None = None) -> str:
    """A cell name usable in a ROS 2 name and a Zenoh key: letters, digits and '_', starting with a letter."""
    name = re.sub(r"[^A-Za-z0-9_]", "_", text or socket.gethostname())
    return name if name[:1].isalpha() else f"cell_{name}"


def dds_type_name(typename: str) -> str:
    """``sensor_msgs/msg/JointState`` -> ``sensor_msgs::msg::dds_::JointState_`` (rmw_zenoh's type token)."""
    pkg, kind, name = typename.split("/")
    return f"{pkg}::{kind}::dds_::{name}_"


def ros_key(domain: int, topic: str, typename: str) -> str:
    """A ROS 2 topic's data key expression under rmw_zenoh (Jazzy): domain/topic/type/hash."""
    return f"{domain}/{topic.strip('/')}/{dds_type_name(typename)}/{ros.type_hash(typename)}"


def rmw_attachment(seq: int, t_ns: int, gid: bytes) -> bytes:
    """rmw_zenoh's publisher attachment (zenoh-ext serialisation): int64 LE sequence number (from 1),
    int64 LE source time (ns since the epoch), the GID as a sequence (LEB128 length 16, 16 bytes)."""
    assert len(gid) == 16
    return struct.pack("<qqB", seq, t_ns, 16) + gid


def parse_rmw_attachment(data: bytes | None) -> tuple[int, int, bytes] | None:
    if data is None or len(data) != 33 or data[16] != 16:
        return None
    seq, t_ns = struct.unpack_from("<qq", data)
    return seq, t_ns, bytes(data[17:])


@dataclass
class ZenohSettings:
    cell: str = field(default_factory=cell_name)
    domain: int = 0  # ROS_DOMAIN_ID
    config_file: Path | None = None  # a Zenoh JSON5 configuration; the options below go on top
    mode: str = "peer"
    listen: list[str] = field(default_factory=list)
    connect: list[str] = field(default_factory=list)
    # rmw_zenoh's sessions scout by gossip through the router, not by multicast: off by default here
    # too, so a cell joins only the network it is told to (and tests stay on loopback).
    multicast_scouting: bool = False
    json: bool = False  # also the JSON keys for tools that are not ROS
    hz: float = 50.0  # joint states
    status_hz: float = 5.0  # TCP pose, safety state and the fleet status, besides every change


class ZenohConfigError(ValueError):
    """A Zenoh setting that cannot be used; the message names it (with the caller's option name)."""


def zenoh_words(exc: BaseException) -> str:
    """Zenoh's own reason, without its Rust source locations (``at /root/.cargo/...rs:86.``)."""
    text = str(exc)
    m = re.search(r'msg: "(.*?)", location', text)
    return re.sub(r" at /\S+\.rs:\d+\.?", "", m.group(1) if m else text).strip()


def session_config(settings: ZenohSettings, option_names: dict[str, str] | None = None) -> zenoh.Config:
    """The session's configuration; ZenohConfigError naming the setting (``option_names`` maps
    ``config``, ``listen`` and ``connect`` to the caller's options) when one cannot be used: a
    traceback from deep in zenoh named neither the option nor the value."""
    import zenoh

    names = {"config": "the Zenoh configuration", "listen": "listen", "connect": "connect", **(option_names or {})}
    try:
        conf = zenoh.Config.from_file(str(settings.config_file)) if settings.config_file else zenoh.Config()
    except zenoh.ZError as exc:
        raise ZenohConfigError(f"{names['config']} {settings.config_file}: {zenoh_words(exc)}") from None
    conf.insert_json5("mode", json.dumps(settings.mode))
    for key, endpoints in (("listen", settings.listen), ("connect", settings.connect)):
        for endpoint in endpoints:  # one at a time first: the error names the bad one
            try:
                conf.insert_json5(f"{key}/endpoints", json.dumps([endpoint]))
            except zenoh.ZError as exc:
                raise ZenohConfigError(f"{names[key]} {endpoint}: {zenoh_words(exc)}; give an endpoint such as "
                                       "tcp/127.0.0.1:7447") from None
        if endpoints:
            conf.insert_json5(f"{key}/endpoints", json.dumps(endpoints))
    if settings.config_file is None:
        conf.insert_json5("scouting/multicast/enabled", json.dumps(settings.multicast_scouting))
    return conf


class _RosPublisher:
    """One ROS 2 topic's publisher: CDR with the rmw attachment (its own GID and sequence)."""

    def __init__(self, session: zenoh.Session, domain: int, topic: str, typename: str) -> None:
        self.key = ros_key(domain, topic, typename)
        self.typename = typename
        self.gid = hashlib.blake2b(f"{session.zid()}/{self.key}".encode(), digest_size=16).digest()
        self.seq = 0
        self._pub = session.declare_publisher(self.key)

    def put(self, message: Any, t_ns: int) -> None:
        self.seq += 1
        self._pub.put(ros.serialize(message, self.typename), attachment=rmw_attachment(self.seq, t_ns, self.gid))

    def undeclare(self) -> None:
        self._pub.undeclare()


class Refused(Exception):
    """A command refused before it reaches the REST layer's functions (as HTTP would answer it)."""

    def __init__(self, status: int, detail: Any) -> None:
        super().__init__(detail)
        self.status, self.detail = status, detail


class ZenohInterface:
    """Publishes the cell's state and runs its commands; ``start`` / ``close``."""

    # Commands: topic (under /<cell>/) -> (ROS type, what the command is)
    ROS_COMMANDS: dict[str, tuple[str, str]] = {  # noqa: RUF012
        "delta_twist_cmds": (ros.TWIST_STAMPED, "twist"),
        "delta_joint_cmds": (ros.JOINT_JOG, "joint_jog"),
        "pose_target": (ros.POSE_STAMPED, "pose_target"),
        "joint_target": (ros.JOINT_STATE, "joint_target"),
        "stop": (ros.EMPTY, "stop"),
        "resume": (ros.EMPTY, "resume"),
    }
    JSON_COMMANDS = ("jog", "target", "stop", "resume")

    def __init__(self, api: ApiContext, settings: ZenohSettings) -> None:
        self.api = api
        self.settings = settings
        self.cell = settings.cell
        service = api.service
        self.axes = service.backend.axes()
        self.n = len(self.axes)
        self.linear = np.array([a["unit"] == "mm" for a in self.axes])
        self.j23 = float(getattr(service.profile, "j23_factor", 0.0) or 0.0)
        self.session: zenoh.Session | None = None
        # (priority, order, command): a stop goes ahead of every queued command (0), the rest in turn (1)
        self._commands: queue.PriorityQueue[tuple[int, int, _Queued | None]] = queue.PriorityQueue()
        self._order = itertools.count()
        self.dropped = 0  # commands the full queue could not take
        self._drop_logged_at = -math.inf
        self._stop = threading.Event()
        self._threads: list[threading.Thread] = []
        self._declared: list[Any] = []
        self._pubs: dict[str, _RosPublisher] = {}
        # The lease last granted through the queryable: ROS commands (no lease id in a ROS message)
        # act for it while it is the current lease.
        self._topics_lease_id: str | None = None
        self.published = 0  # joint-state ticks, for the bench

    # ------------------------------------------------------------------------------------ keys
    def json_key(self, suffix: str) -> str:
        return f"{JSON_ROOT}/{self.cell}/{suffix}"

    def topic(self, name: str) -> str:
        return f"/{self.cell}/{name}"

    # ------------------------------------------------------------------------------- lifecycle
    def start(self) -> ZenohInterface:
        import zenoh

        zenoh.init_log_from_env_or("error")
        self.session = s = zenoh.open(session_config(self.settings))
        d = self.settings.domain
        for name, topic, typename in (("measured", "joint_states", ros.JOINT_STATE),
                                      ("commanded", "joint_commands", ros.JOINT_STATE),
                                      ("pose", "tcp_pose", ros.POSE_STAMPED),
                                      ("safety", "safety_state", ros.DIAGNOSTIC_ARRAY),
                                      ("alarms", "diagnostics", ros.DIAGNOSTIC_ARRAY),
                                      ("reply", "servo_app/reply", ros.STRING)):
            self._pubs[name] = _RosPublisher(s, d, self.topic(topic), typename)
        self._status_pub = s.declare_publisher(self.json_key(STATUS_SUFFIX))
        self._reply_pub = s.declare_publisher(self.json_key(REPLY_SUFFIX))
        for topic, (typename, kind) in self.ROS_COMMANDS.items():
            self._declared.append(s.declare_subscriber(ros_key(d, self.topic(topic), typename),
                                                       self._enqueue("cdr", kind)))
        if self.settings.json:
            for kind in self.JSON_COMMANDS:
                self._declared.append(s.declare_subscriber(self.json_key(f"json/cmd/{kind}"),
                                                           self._enqueue("json", kind)))
        self._declared.append(s.declare_queryable(self.json_key(LEASE_SUFFIX), self._on_lease_query))
        for target, name in ((self._publish_loop, "zenoh telemetry"), (self._command_loop, "zenoh commands")):
            t = threading.Thread(target=target, name=name, daemon=True)
            t.start()
            self._threads.append(t)
        return self

    def close(self) -> None:
        self._stop.set()
        self._commands.put((-1, next(self._order), None))
        for t in self._threads:
            t.join(5.0)
        if self.session is not None:
            with contextlib.suppress(Exception):  # closing a session whose peers are gone
                self.session.close()
            self.session = None

    # -------------------------------------------------------------------------------- commands
    def _enqueue(self, encoding: str, kind: str) -> Callable[[Any], None]:
        # A stop jumps the queue and is not dropped while jogs fill it: behind a flood of jogs it was
        # dropped (or waited for them all) while they kept the arm moving.
        urgent = kind == "stop"
        limit = 2 * COMMAND_QUEUE if urgent else COMMAND_QUEUE

        def on_sample(sample: Any) -> None:  # a Zenoh thread: queue only, never block it
            attachment = sample.attachment.to_bytes() if sample.attachment is not None else None
            if self._commands.qsize() >= limit:
                self._drop(kind)
                return
            self._commands.put((0 if urgent else 1, next(self._order),
                                _Queued(encoding, kind, sample.payload.to_bytes(), attachment, time.monotonic_ns())))

        return on_sample

    def _drop(self, kind: str) -> None:
        """A command the full queue cannot take: counted, and logged at most once a second (a flood
        logged a line per command, thousands a second)."""
        self.dropped += 1
        now = time.monotonic()
        if now - self._drop_logged_at >= 1.0:
            self._drop_logged_at = now
            log.warning("zenoh: command queue full: %s dropped (%d dropped since the start): a publisher sends "
                        "faster than commands are handled", kind, self.dropped)

    def _command_loop(self) -> None:
        while True:
            _, _, item = self._commands.get()
            if item is None or self._stop.is_set():
                return
            self.handle(item.encoding, item.kind, item.payload, item.attachment, item.arrived_ns)

    def handle(self, encoding: str, kind: str, payload: bytes, attachment: bytes | None,
               arrived_ns: int | None = None) -> dict[str, Any]:
        """Run one command; its answer goes on the reply keys (and is returned). ``arrived_ns``
        (``time.monotonic_ns()``): when it was queued, so a jog that waited past its hold is refused."""
        rmw = parse_rmw_attachment(attachment)
        source = rmw[2].hex() if rmw else "zenoh"
        reply: dict[str, Any] = {"cell": self.cell, "command": kind, "encoding": encoding,
                                 "seq": rmw[0] if rmw else None, "source": source}
        try:
            ack = (self._run_cdr(kind, payload, source, arrived_ns) if encoding == "cdr"
                   else self._run_json(kind, payload, arrived_ns))
            reply.update(ok=True, status=200, detail=jsonable_encoder(ack.detail) if ack.detail is not None else None)
        except Refused as exc:
            reply.update(ok=False, status=exc.status, detail=exc.detail)
        except HTTPException as exc:
            reply.update(ok=False, status=exc.status_code, detail=exc.detail)
        except Exception as exc:  # a command must never take the interface down
            log.exception("zenoh command %s failed", kind)
            reply.update(ok=False, status=500, detail=f"{type(exc).__name__}: {exc}")
        self._reply(reply)
        return reply

    def _reply(self, reply: dict[str, Any]) -> None:
        text = json.dumps(reply, default=str)
        with contextlib.suppress(Exception):  # the session is closing
            self._reply_pub.put(text.encode())
            self._pubs["reply"].put(ros.string(text), time.time_ns())

    def _client(self, source: str) -> str:
        return f"zenoh:{source}"

    def _controlling(self, client: str, lease_id: str | None, kind: str) -> contextlib.AbstractContextManager[str]:
        """The lease checked, and the command acting under it until the block ends (as the REST routes')."""
        return acting_as(self.api, client, lease_id, f"ZENOH {kind}")

    def _run_cdr(self, kind: str, payload: bytes, source: str, arrived_ns: int | None = None) -> Any:
        typename = next(t for t, k in self.ROS_COMMANDS.values() if k == kind)
        try:
            message = ros.deserialize(payload, typename)
        except Exception as exc:
            raise Refused(422, f"not a CDR {typename}: {type(exc).__name__}: {exc}") from None
        client = self._client(source)
        if kind == "stop":  # a stop never waits for control (no lease, no token: see docs/zenoh.md)
            return session_routes.session_stop(client, self.api.calls, StopRequest())
        with self._controlling(client, self._topics_lease_id, kind) as controller:
            if kind == "resume":
                return session_routes.session_resume(controller, self.api.calls)
            topic = next(t for t, (_, k) in self.ROS_COMMANDS.items() if k == kind)
            if kind in ("twist", "joint_jog"):
                body, said = self._jog_body(kind, message)
                return as_sent(topic, said, lambda: self._jog(controller, body, arrived_ns))
            body, said = self._target_body(kind, message)
            return as_sent(topic, said, lambda: self._target(controller, body))

    def _run_json(self, kind: str, payload: bytes, arrived_ns: int | None = None) -> Any:
        try:
            body = json.loads(payload)
            if not isinstance(body, dict):
                raise ValueError("the body is not a JSON object")
        except ValueError as exc:
            raise Refused(422, f"not a JSON object: {exc}") from None
        client = self._client("json")
        token, lease_id = body.pop("token", None), body.pop("lease_id", None)
        if not token_matches(self.api.token, f"Bearer {token}" if isinstance(token, str) else None):
            self.api.metrics.count("unauthorized")
            self.api.audit.record(client, f"ZENOH {kind}", False, "bad token")
            raise Refused(401, "missing or wrong bearer token")
        if kind == "stop":
            return session_routes.session_stop(client, self.api.calls, _validated(StopRequest, body))
        with self._controlling(client, lease_id if isinstance(lease_id, str) else None, kind) as controller:
            if kind == "resume":
                return session_routes.session_resume(controller, self.api.calls)
            if kind == "jog":
                return self._jog(controller, body, arrived_ns)
            return self._target(controller, body)

    def _jog(self, controller: str, body: dict[str, Any], arrived_ns: int | None = None) -> Any:
        validated = _validated(_JOG, body)
        if arrived_ns is not None:  # an unstamped jog counts from its arrival, not from its turn in the queue
            waited_ms = (time.monotonic_ns() - arrived_ns) / 1e6
            if waited_ms > validated.hold_ms:
                raise Refused(409, f"stale hold-to-run command: received {waited_ms:.0f} ms ago, past its hold "
                                   f"time of {validated.hold_ms:.0f} ms, while the commands queued before it ran; "
                                   f"send a fresh one to keep moving, at most {self.api.jog_limiter.per_second} "
                                   "a second")
        admitted = admit_jog(self.api, controller)
        return self.api.calls.forward(controller, "jog", jog_request(validated), at=admitted)

    def _target(self, controller: str, body: dict[str, Any]) -> Any:
        return self.api.calls.forward(controller, "target", target_request(_validated(_TARGET, body)))

    # ROS units -> the REST bodies (deg, mm), so the REST models judge the values.
    def joints_to_service(self, values: np.ndarray) -> list[float]:
        """ROS (rad, m; the model's chain) -> service units (deg, mm; FANUC's coupled J2/J3). Linear,
        so it serves positions and rates alike."""
        from servo_app.robots.conventions import model_rad_to_fanuc_deg

        v = np.asarray(values, dtype=float)
        linear = self.linear[: len(v)]
        out = np.where(linear, v * 1000.0, np.degrees(v)) if linear.any() else model_rad_to_fanuc_deg(v, self.j23)
        return [float(x) for x in out]

    def _by_name(self, names: list[str], values: np.ndarray, what: str, every: bool = False) -> np.ndarray:
        """Values per axis from a named list (axes not named: 0, or refused when ``every`` axis must be
        named: a position target's 0 would move that axis); unknown names are refused."""
        if not names:
            return np.asarray(values, dtype=float)
        if len(set(names)) != len(names):  # the last value won, silently
            twice = sorted({n for n in names if names.count(n) > 1})
            raise Refused(422, f"{what}: {twice} named more than once: name each joint once")
        if len(names) != len(values):
            raise Refused(422, f"{what}: {len(names)} joint names but {len(values)} values")
        out = np.zeros(self.n)
        for name, v in zip(names, values, strict=True):
            m = JOINT_NAMES_RE.match(name)
            if m is None or not 1 <= int(m.group(1)) <= self.n:
                raise Refused(422, f"{what}: unknown joint {name!r}: this arm has {ros.joint_names(self.n)}")
            out[int(m.group(1)) - 1] = v
        missing = [n for n in ros.joint_names(self.n) if n not in names]
        if every and missing:
            raise Refused(422, f"{what}: no position for {missing}: name every joint of {ros.joint_names(self.n)} "
                               "(or none, positions in that order)")
        return out

    def _check_fresh(self, header: Any, hold_ms: float) -> None:
        """A stamped hold-to-run command older than its hold time is refused: its sender has let go."""
        t_ns = ros.stamp_ns(header)
        if t_ns == 0:
            return  # unstamped: it counts from its arrival, as a REST jog does
        age_ms = (time.time_ns() - t_ns) / 1e6
        if age_ms > hold_ms:
            raise Refused(409, f"stale hold-to-run command: stamped {age_ms:.0f} ms ago, past its hold time of "
                               f"{hold_ms:.0f} ms; send it fresh (clocks synchronised) to keep moving")

    def _joints_said(self, array: str, names: list[str], sent: np.ndarray, v: np.ndarray, service: list[float],
                     rate: bool) -> Said:
        """How a ROS command gave the REST body's ``joints``: ``array`` (``velocities``, ``position``)
        as sent, with ``names`` (or none: in order), ``v`` per axis and ``service`` converted from it.
        FANUC's J3 is joint_3 less joint_2 (J3 from the horizontal): its refusal names both as sent."""
        per_s = "/s" if rate else ""
        linear = [i < self.n and bool(self.linear[i]) for i in range(len(v))]  # (a count REST refuses too)
        ros_units = [("m" if lin else "rad") + per_s for lin in linear] or ["rad" + per_s]
        units = [("mm" if lin else "deg") + per_s for lin in linear] or ["deg" + per_s]

        def label(i: int) -> str:
            name = f"joint_{i + 1}"
            if not names:
                return f"{array}[{i}] ({name})"
            return f"{array}[{names.index(name)}] ({name})" if name in names else f"{name} (not named)"

        coupled = self.j23 != 0.0 and len(v) >= 3 and not self.linear[:3].any()
        coupling = "joint_3 - joint_2" if self.j23 == 1.0 else f"joint_3 - {self.j23:g} * joint_2"
        parts = [f"{label(i)} = {v[i]:g} {ros_units[i]} (joints[{i}] = {service[i]:g} {units[i]})"
                 for i in range(len(v))]
        if coupled:
            parts[2] = (f"{label(2)} = {v[2]:g} {ros_units[2]} with {label(1)} = {v[1]:g} {ros_units[1]} "
                        f"(joints[2], J3 = {service[2]:g} {units[2]} in FANUC's convention: {coupling}, J3 "
                        "measured from the horizontal)")
        one = len(set(ros_units)) == 1
        whole = (f"{array} = {[float(x) for x in sent]} {ros_units[0] if one else tuple(ros_units)}"
                 + (f" for {names}" if names else "") + f" (joints = {[round(x, 3) for x in service]} "
                 + (units[0] if one else str(tuple(units)))
                 + (f" in FANUC's convention: J3 = {coupling}" if coupled else "") + ")")
        return Said(whole, tuple(parts), tuple(units))

    def _jog_body(self, kind: str, m: Any) -> tuple[dict[str, Any], Callable[[], dict[str, Said]]]:
        """The REST body of a twist or JointJog, and how the sender gave each of its fields (told only
        for a refusal: a jog comes up to 100 times a second)."""
        hold_ms = 200.0
        if kind == "twist":
            self._check_fresh(m.header, hold_ms)
            frame = FRAMES.get(m.header.frame_id, m.header.frame_id)
            lin, ang = m.twist.linear, m.twist.angular
            body = {"frame": frame, "linear": [lin.x * 1000.0, lin.y * 1000.0, lin.z * 1000.0],
                    "angular": [math.degrees(ang.x), math.degrees(ang.y), math.degrees(ang.z)]}
            return body, lambda: {"frame": Said(f"header.frame_id = {m.header.frame_id!r}"),
                                  "linear": Said.vector("twist.linear", [lin.x, lin.y, lin.z], "m/s", "linear",
                                                        body["linear"], "mm/s"),
                                  "angular": Said.vector("twist.angular", [ang.x, ang.y, ang.z], "rad/s",
                                                         "angular", body["angular"], "deg/s")}
        if len(m.displacements) and not len(m.velocities):
            raise Refused(422, "delta_joint_cmds: displacements are not supported; send velocities (rad/s, m/s)")
        if not m.duration >= 0:  # NaN or negative: both were taken as no duration, the default hold
            raise Refused(422, f"delta_joint_cmds: duration={m.duration} is not a hold time: send the hold time "
                               f"in seconds, up to 2, or 0 for the default {hold_ms / 1000:g} s")
        if m.duration > 0:
            hold_ms = m.duration * 1000.0
        self._check_fresh(m.header, hold_ms)
        names = list(m.joint_names)
        v = self._by_name(names, np.asarray(m.velocities, float), "delta_joint_cmds")
        body = {"joints": self.joints_to_service(v), "hold_ms": hold_ms}
        return body, lambda: {
            "joints": self._joints_said("velocities", names, m.velocities, v, body["joints"], rate=True),
            "hold_ms": Said(f"duration = {m.duration:g} s (hold_ms = {hold_ms:g})", units=("ms",))}

    def _target_body(self, kind: str, m: Any) -> tuple[dict[str, Any], Callable[[], dict[str, Said]]]:
        """The REST body of a pose or joint target, and how the sender gave each of its fields."""
        from servo_app.robots.conventions import matrix_to_xyzwpr

        if kind == "pose_target":
            # Taken in the world frame: a pose in another (the tool's, a camera's) was taken as a
            # world pose, and the arm went there.
            if FRAMES.get(m.header.frame_id, m.header.frame_id) != "base":
                world = sorted({"base", *(f for f, ours in FRAMES.items() if ours == "base")})
                raise Refused(422, f"pose_target: frame_id {m.header.frame_id!r} is not the world frame: give the "
                                   f"pose in the robot's world frame, with frame_id one of {world}")
            try:
                pose = ros.pose_matrix(m.pose)
            except ValueError as exc:
                raise Refused(422, f"pose_target: {exc}") from None
            xyzwpr = [float(v) for v in matrix_to_xyzwpr(pose)]
            p, o = m.pose.position, m.pose.orientation
            return {"xyzwpr": xyzwpr}, lambda: {"xyzwpr": Said(
                f"pose.position = ({p.x:g}, {p.y:g}, {p.z:g}) m, pose.orientation = ({o.x:g}, {o.y:g}, {o.z:g}, "
                f"{o.w:g}) (xyzwpr = {[round(v, 3) for v in xyzwpr]} mm, deg)")}
        names = list(m.name)
        q = self._by_name(names, np.asarray(m.position, float), "joint_target", every=True)
        body = {"joints": self.joints_to_service(q)}
        return body, lambda: {"joints": self._joints_said("position", names, m.position, q, body["joints"],
                                                          rate=False)}

    # ----------------------------------------------------------------------------------- lease
    def _on_lease_query(self, query: Any) -> None:
        try:
            body = json.loads(query.payload.to_bytes()) if query.payload is not None else {}
            answer = self.lease_request(body if isinstance(body, dict) else {})
        except ValueError as exc:
            answer = {"ok": False, "status": 422, "detail": f"not a JSON object: {exc}"}
        except Exception as exc:  # answered all the same: a query left unanswered waits for its timeout
            log.exception("zenoh lease query failed")
            answer = {"ok": False, "status": 500, "detail": f"{type(exc).__name__}: {exc}"}
        query.reply(query.key_expr, json.dumps(answer, default=str).encode())

    def lease_request(self, body: dict[str, Any]) -> dict[str, Any]:
        """``{"token", "op": "take"|"renew"|"release", "client", "force", "ttl_s", "lease_id"}``: the
        REST lease routes' own functions answer it; the granted lease also covers the ROS topics."""
        api = self.api
        client = self._client("lease")
        token = body.pop("token", None)
        if not token_matches(api.token, f"Bearer {token}" if isinstance(token, str) else None):
            api.metrics.count("unauthorized")
            api.audit.record(client, "ZENOH lease", False, "bad token")
            return {"ok": False, "status": 401, "detail": "missing or wrong bearer token"}
        op = body.pop("op", "take")
        lease_id = body.pop("lease_id", None)
        try:
            if op == "take":
                granted = lease_routes.lease_acquire(_validated(LeaseRequest, body), client, api)
                self._topics_lease_id = granted.lease_id
                return {"ok": True, "status": 200, **granted.model_dump()}
            if op == "renew":
                renewed = lease_routes.lease_renew(client, api.leases, lease_id)
                return {"ok": True, "status": 200, **renewed.model_dump()}
            if op == "release":
                lease_routes.lease_release(client, api, api.audit, lease_id)
                return {"ok": True, "status": 200}
            return {"ok": False, "status": 422, "detail": f"op {op!r} is not one of take, renew, release"}
        except Refused as exc:
            return {"ok": False, "status": exc.status, "detail": exc.detail}
        except HTTPException as exc:
            return {"ok": False, "status": exc.status_code, "detail": exc.detail}

    # ------------------------------------------------------------------------------- telemetry
    def _publish_loop(self) -> None:
        period = 1.0 / self.settings.hz
        status_period = 1.0 / self.settings.status_hz
        due = time.monotonic()
        last_status = -math.inf
        last_change: tuple[Any, ...] | None = None
        seen_alarms: set[tuple[str, float]] = set()
        first = True
        while not self._stop.is_set():
            try:
                s = state_snapshot(self.api)
                t_ns = time.time_ns()
                self._publish_joints(s, t_ns)
                alarms = [a for a in s.get("alarm_history") or [] if (a.get("code"), a.get("time_unix")) not in
                          seen_alarms]
                seen_alarms.update((a.get("code"), a.get("time_unix")) for a in alarms)
                if alarms and not first:
                    self._publish_alarms(alarms, t_ns)
                change = (s.get("state"), s.get("stop_reason"), str(s.get("fault")), len(s.get("alarms") or []),
                          (s.get("lease") or {}).get("held"))
                now = time.monotonic()
                if change != last_change or now - last_status >= status_period:
                    self._publish_status(s, t_ns)
                    last_change, last_status = change, now
                first = False
            except Exception:  # the service is closing, or a reset replaces the servo process
                log.debug("zenoh telemetry tick failed", exc_info=True)
            due = max(due + period, time.monotonic() - period)
            self._stop.wait(max(0.0, due - time.monotonic()))

    def _publish_joints(self, s: dict[str, Any], t_ns: int) -> None:
        for name, key in (("commanded", "q_cmd"), ("measured", "q_servo")):
            q = s.get(key)
            if q is None or (key == "q_servo" and not s.get("status_received")):
                continue
            self._pubs[name].put(ros.joint_state(t_ns, self.joints_to_ros(q[: self.n])), t_ns)
            if self.settings.json:
                self._json_put(f"json/{'joint_commands' if name == 'commanded' else 'joint_states'}",
                               {"t_ns": t_ns, "joints": q[: self.n]})
        self.published += 1

    def joints_to_ros(self, q: list[float]) -> np.ndarray:
        """Service units (deg, mm; FANUC's coupled J2/J3) -> ROS (rad, m; the model's chain)."""
        v = np.asarray(q, dtype=float)
        if self.linear.any():
            return np.where(self.linear, v / 1000.0, np.radians(v))
        from servo_app.robots.conventions import fanuc_deg_to_model_rad

        return fanuc_deg_to_model_rad(v, self.j23)

    def _publish_status(self, s: dict[str, Any], t_ns: int) -> None:
        from servo_app.robots.conventions import xyzwpr_to_matrix

        cart = s.get("cart_servo")
        if cart is not None and s.get("status_live") and len(cart) >= 6 and not self.linear.any():
            pose = xyzwpr_to_matrix(cart[:6])  # in metres
            self._pubs["pose"].put(ros.pose_stamped(t_ns, pose), t_ns)
        fault = s.get("fault") or {}
        level = ros.ERROR if s.get("state") == "fault" else ros.WARN if s.get("state") in ("stopping", "stopped") \
            else ros.OK
        self._pubs["safety"].put(ros.diagnostics(t_ns, f"{self.cell}/safety", self.cell, [(
            level, str(s.get("state")), {"state": str(s.get("state")), "link": str(s.get("link")),
                                         "stop_reason": str(s.get("stop_reason") or ""),
                                         "fault": str(fault.get("message") or "") if isinstance(fault, dict) else
                                         str(fault)})]), t_ns)
        lease = s.get("lease") or {}
        status = {"cell": self.cell, "t_unix": t_ns / 1e9, "state": s.get("state"), "link": s.get("link"),
                  "stop_reason": s.get("stop_reason"), "fault": s.get("fault"),
                  "latency_p99_us": s.get("latency_p99_us"),
                  "alarms": [a.get("code") for a in s.get("alarms") or []],
                  "lease_held": bool(lease.get("held")), "lease_client": lease.get("client"),
                  "model": s.get("model"), "q_cmd": (s.get("q_cmd") or [])[: self.n]}
        self._status_pub.put(json.dumps(status, default=str).encode())

    def _publish_alarms(self, alarms: list[dict[str, Any]], t_ns: int) -> None:
        self._pubs["alarms"].put(ros.diagnostics(t_ns, f"{self.cell}/controller", self.cell, [
            (ros.WARN if a.get("warning") else ros.ERROR, f"{a.get('code')}: {a.get('message')}",
             {"code": str(a.get("code")), "time_unix": str(a.get("time_unix"))}) for a in alarms]), t_ns)
        if self.settings.json:
            self._json_put("json/alarms", {"t_ns": t_ns, "alarms": alarms})

    def _json_put(self, suffix: str, value: Any) -> None:
        assert self.session is not None
        self.session.put(self.json_key(suffix), json.dumps(value, default=str).encode())


@dataclass(frozen=True)
class _Queued:
    """A command as a Zenoh callback queued it."""

    encoding: str
    kind: str
    payload: bytes
    attachment: bytes | None
    arrived_ns: int  # time.monotonic_ns()


@dataclass(frozen=True)
class Said:
    """How a ROS command gave one field of the REST body it became, for that field's refusal: the
    REST layer's words name the converted value (1500 mm/s for a sent 1.5 m/s, FANUC's coupled J3)."""

    whole: str  # the field as sent, then as converted
    parts: tuple[str, ...] = ()  # per component, the same
    units: tuple[str, ...] = ()  # per component: the service's unit (a limit's value in the sender's units)

    @staticmethod
    def vector(ros_field: str, sent: list[float], ros_unit: str, field: str, service: list[float],
               unit: str) -> Said:
        parts = tuple(f"{ros_field}.{axis} = {v:g} {ros_unit} ({field}[{i}] = {x:g} {unit})"
                      for i, (axis, v, x) in enumerate(zip("xyz", sent, service, strict=True)))
        return Said(f"{ros_field} = ({', '.join(f'{v:g}' for v in sent)}) {ros_unit} "
                     f"({field} = [{', '.join(f'{x:g}' for x in service)}] {unit})", parts, (unit,) * len(parts))


# Service units -> the ROS sender's: (unit, factor)
ROS_UNITS = {"mm/s": ("m/s", 1e-3), "deg/s": ("rad/s", math.pi / 180.0), "mm": ("m", 1e-3),
             "deg": ("rad", math.pi / 180.0), "ms": ("s", 1e-3)}
_NUMBER = r"-?\d+(?:\.\d+)?(?:e[-+]?\d+)?"
# The REST field a refusal is about: its first mention (``linear[0]=``, ``joints has``, ``linear speed``);
# the servo process's commands call the joints ``velocity`` and ``position``.
_FIELD_RE = re.compile(r"\b(linear|angular|joints|velocity|position|hold_ms|frame|xyzwpr)(?:\[(\d+)\])?(?=[= ]|$)")
_FIELD_ALIASES = {"velocity": "joints", "position": "joints"}
# A value with its unit (not the echo of the value refused, ``joints[2]=572.958 deg/s``: the sender's
# value is named as sent), and a range ``outside [-4000.0, 4000.0]`` in the field's unit.
_QUANTITY_RE = re.compile(rf"(?<![=\w.\[-])({_NUMBER}) (mm/s|deg/s|mm|deg|ms)\b")
_RANGE_RE = re.compile(rf"((?:outside|range) \[({_NUMBER}), ({_NUMBER})\])")


def _in_ros_units(value: float, unit: str) -> str:
    ros_unit, factor = ROS_UNITS[unit]
    return f"{value * factor:.4g} {ros_unit}"


def _limits_in_ros_units(text: str, unit: str | None) -> str:
    """Each value with its unit in ``text`` followed by the same in the ROS sender's unit, and a range
    (in ``unit``, the field's service unit) too."""
    text = _QUANTITY_RE.sub(lambda q: f"{q.group(0)} ({_in_ros_units(float(q.group(1)), q.group(2))})", text)
    if unit not in ROS_UNITS:
        return text
    ros_unit, factor = ROS_UNITS[unit]
    return _RANGE_RE.sub(lambda r: f"{r.group(1)} ({float(r.group(2)) * factor:.4g} to "
                                   f"{float(r.group(3)) * factor:.4g} {ros_unit})", text)


def _refused_field(error: Any) -> tuple[str, str | None, int | None]:
    """A refusal's text, the REST field it is about and the component, if it names them: a validation
    error's ``loc`` says, else the text's first field."""
    loc: list[Any] = list(error.get("loc") or []) if isinstance(error, dict) else []
    text = (str(error.get("msg", error)) if isinstance(error, dict) else str(error)).removeprefix("Value error, ")
    m = _FIELD_RE.search(text)
    named = _FIELD_ALIASES.get(m.group(1), m.group(1)) if m else None
    field = next((x for x in reversed(loc) if isinstance(x, str)), None) or named
    field = _FIELD_ALIASES.get(field or "", field)
    index = next((x for x in reversed(loc) if isinstance(x, int)), None)
    if index is None and m is not None and m.group(2) is not None and named == field:
        index = int(m.group(2))
    return text, field, index


def refusal_as_sent(topic: str, said: dict[str, Said], detail: Any) -> str:
    """A REST refusal (its text, or its validation error list) of a ROS command, in the sender's terms:
    each error after the field it is about as the sender gave it (its value and unit as sent, then as
    converted), and every limit in it also in the sender's units."""
    texts = []
    for error in detail if isinstance(detail, list) else [detail]:
        text, field, index = _refused_field(error)
        s = said.get(field or "")
        if s is None:  # not a field the sender gave: the whole command, as sent
            what, unit = "; ".join(x.whole for x in said.values()), None
        elif index is not None and index < len(s.parts):
            what, unit = s.parts[index], s.units[index]
        else:
            what, unit = s.whole, (s.units[0] if s.units else None)
        ctx = error.get("ctx") if isinstance(error, dict) else None
        bound = next((ctx[k] for k in ("le", "ge", "lt", "gt") if k in ctx), None) if isinstance(ctx, dict) else None
        if isinstance(bound, int | float) and unit in ROS_UNITS:  # pydantic's bound has no unit: the field's
            text += f" ({_in_ros_units(float(bound), unit)})"
        texts.append(f"{what}: {_limits_in_ros_units(text, unit)}")
    return f"{topic}: " + "; ".join(texts)


def as_sent(topic: str, said: Callable[[], dict[str, Said]], run: Callable[[], Any]) -> Any:
    """``run()`` (a ROS command through the REST layer's functions), its refusal of the values (422)
    in the sender's terms (``refusal_as_sent``); the state's refusals (409, ...) are REST's words as they are."""
    try:
        return run()
    except Refused as exc:
        if exc.status != 422:
            raise
        raise Refused(422, refusal_as_sent(topic, said(), exc.detail)) from None
    except HTTPException as exc:
        if exc.status_code != 422:
            raise
        raise Refused(422, refusal_as_sent(topic, said(), exc.detail)) from None


# The frames MoveIt Servo users name in a TwistStamped's header: ours are "base" and "tool".
FRAMES = {"": "base", "base_link": "base", "world": "base", "tool0": "tool", "flange": "tool"}

_JOG: TypeAdapter[Any] = TypeAdapter(JogBody)
_TARGET: TypeAdapter[Any] = TypeAdapter(TargetBody)


def _validated(model: Any, body: dict[str, Any]) -> Any:
    """The REST model's verdict on ``body``: 422 with the same error list REST answers."""
    adapter = model if isinstance(model, TypeAdapter) else TypeAdapter(model)
    try:
        return adapter.validate_python(body)
    except ValidationError as exc:
        raise Refused(422, jsonable_encoder(validation_errors(list(exc.errors())))) from None

