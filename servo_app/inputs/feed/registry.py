"""Feed sources that arrive over HTTP/WebSocket: validate, place on our clock, measure, publish.

The sender stamps each sample with its wall clock; latency = our wall clock at receipt minus that
stamp, and the sample goes into its slot at (monotonic now - latency), so staleness and tracking
extrapolation see how old the value really is. Stamps from the future beyond `max_future_s`
(unsynchronised clocks) are rejected, and so are stamps more than a day old (a monotonic clock's
reading, or a wrong unit); slightly-future stamps count as zero latency. A sample already older
than the source's `stale_after_s` on arrival is dropped, saying so (it could never command), and so
is one older than the last published one (by seq or stamp): a late packet must not move the robot back.

Sequence numbers resynchronise: a seq at most `seq_window` behind the last accepted one is a late
(or repeated) sample and dropped, unless its stamp is newer than the last one's (measured later with
a smaller number: the counter restarted); one further behind is the sender's counter restarting (a
sensor rebooted), and one further ahead a jump: each is accepted as the new sequence, and the
answer and the source's stats say so. Otherwise one stray seq far ahead, or a restarted counter,
made every later sample "older than the last" and locked the feed out until the service restarted.
"""

from __future__ import annotations

import math
import threading
import time
from collections import deque
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

from pydantic import TypeAdapter, ValidationError

from servo_app.inputs.adapter import Clock, SourceSpec
from servo_app.inputs.feed.models import FeedAck, FeedMessage, FeedSourceConfig, MeasurementFeed, PoseFeed, TwistFeed
from servo_app.inputs.fields import DEFAULT_FIELD
from servo_app.inputs.samples import Measurement, PoseSample, TwistSample
from servo_app.inputs.slots import LatestValue
from servo_app.inputs.validate import ValueRejected

_MESSAGE = TypeAdapter(FeedMessage)
_AXES = "xyzwpr"
# A stamp further in the past than this is no wall-clock time of a live value: a monotonic clock's
# reading (seconds since boot) or a wrong unit. Accepted, it was placed decades back, so the sample
# went stale at once while its answer said "accepted" (and -1.8e305 s overflowed the latency in ms
# to inf: the socket dropped without a close frame, found by tests/test_feed_ws_fuzz.py).
MAX_STAMP_AGE_S = 86_400.0
# The servo refuses a twist with a component beyond these (servo_app.motion.commands' MAX_LINEAR_MM_S and
# MAX_ANGULAR_DEG_S; the inputs never import motion, and a test checks that the numbers agree). A twist
# feed without its own max_* took such a sample as "accepted", and the servo then kept the previous
# command until its hold ran out: refused here instead, where the sender hears why.
SERVO_MAX_LINEAR_MM_S = 4000.0
SERVO_MAX_ANGULAR_DEG_S = 1000.0


@dataclass(frozen=True)
class FlangeLimit:
    """The robot's flange-speed cap as its servo checks a twist, passed in by the service (the inputs
    never import the robot backends): the share of the cap it takes (mm/s), and the TCP's distance from
    the flange (mm), about which a turn swings the flange at up to |w| r on top of the TCP's speed."""

    cap_mm_s: float
    tool_offset_mm: float = 0.0


_FINER_UNITS = (("milliseconds", 1e3), ("microseconds", 1e6), ("nanoseconds", 1e9))


def _unit_hint(stamp: float, wall: float) -> str:
    """What a stamp far in the future is, when it is Unix time in a finer unit than seconds."""
    for unit, per_s in _FINER_UNITS:
        if abs(wall - stamp / per_s) < MAX_STAMP_AGE_S:
            return f"; this one is in {unit}: divide it by {per_s:g}"
    return ""


class UnknownSource(KeyError):
    pass


class FeedRejected(ValueError):
    pass


@dataclass(frozen=True)
class FeedStats:
    source: str
    kind: str
    accepted: int
    rejected: int
    out_of_order: int
    resyncs: int  # the sender's seq restarted or jumped, and was taken as the new sequence
    rate_hz: float
    latency_ms_last: float | None
    latency_ms_mean: float | None
    latency_ms_max: float | None
    last_error: str | None


class _Source:
    def __init__(self, name: str, config: FeedSourceConfig) -> None:
        self.name = name
        self.config = config
        self.slot: LatestValue[Any] = LatestValue(name)
        self.arrivals: deque[float] = deque()
        self.latencies: deque[float] = deque(maxlen=200)
        self.accepted = self.rejected = self.out_of_order = self.resyncs = 0
        self.last_seq: int | None = None
        self.last_error: str | None = None


def parse_feed_message(payload: Mapping[str, Any] | str | bytes) -> FeedMessage:
    """Validate a raw message (dict or JSON text); raises FeedRejected naming the field and value."""
    try:
        if isinstance(payload, str | bytes):
            return _MESSAGE.validate_json(payload)
        return _MESSAGE.validate_python(payload)
    except ValidationError as exc:
        raise FeedRejected(describe_validation(exc)) from None


_KINDS = ("pose", "twist", "measurement")


def field_path(loc: Sequence[Any]) -> str:
    """A pydantic error location as the sender wrote it: no "body", no union tag in front."""
    parts = [p for p in loc if p != "body"]
    if parts and parts[0] in _KINDS:
        parts = parts[1:]
    return ".".join(str(p) for p in parts)


def describe_validation(exc: ValidationError) -> str:
    return "; ".join(f"field {field_path(e['loc'])!r} value {e.get('input')!r}: {e['msg']}" for e in exc.errors())


class FeedRegistry:
    def __init__(self, sources: Mapping[str, FeedSourceConfig] | None = None, *, clock: Clock = time.monotonic,
                 wall_clock: Clock = time.time, rate_window_s: float = 2.0) -> None:
        self._clock = clock
        self._wall = wall_clock
        self._window = rate_window_s
        self._sources: dict[str, _Source] = {}
        self._lock = threading.Lock()
        # The robot's flange-speed cap in force, when a servo checks one (the service sets it): a twist
        # under the servo's 4000 mm/s but over the cap was "accepted" here and then refused by the servo.
        self.flange_limit: Callable[[], FlangeLimit | None] | None = None
        for name, cfg in (sources or {}).items():
            self.add_source(name, cfg)

    def add_source(self, name: str, config: FeedSourceConfig) -> LatestValue[Any]:
        with self._lock:
            if name in self._sources:
                raise ValueError(f"feed source {name!r} already exists")
            self._sources[name] = _Source(name, config)
            return self._sources[name].slot

    def names(self) -> list[str]:
        return list(self._sources)

    def _get(self, name: str) -> _Source:
        try:
            return self._sources[name]
        except KeyError:
            raise UnknownSource(f"unknown feed source {name!r}; configured: {sorted(self._sources)}") from None

    def slot(self, name: str) -> LatestValue[Any]:
        return self._get(name).slot

    def config(self, name: str) -> FeedSourceConfig:
        return self._get(name).config

    def specs(self) -> list[SourceSpec]:
        """Command sources (pose, twist) for the arbiter; measurement feeds feed applications instead."""
        return [SourceSpec(s.name, s.config.priority, s.config.stale_after_s, s.slot, s.config.yield_when_idle)
                for s in self._sources.values() if s.config.kind != "measurement"]

    def submit(self, source: str, message: FeedMessage | Mapping[str, Any] | str | bytes) -> FeedAck:
        src = self._get(source)
        with self._lock:
            try:
                if not isinstance(message, PoseFeed | TwistFeed | MeasurementFeed):
                    message = parse_feed_message(message)
                return self._accept(src, message)
            except (FeedRejected, ValueRejected) as exc:
                src.rejected += 1
                src.last_error = str(exc)
                raise FeedRejected(str(exc)) from None

    def note_rejected(self, source: str, detail: str) -> None:
        """Count a message rejected before it reached `submit` (e.g. by the HTTP layer's validation)."""
        src = self._sources.get(source)
        if src is not None:
            with self._lock:
                src.rejected += 1
                src.last_error = detail

    def _accept(self, src: _Source, msg: PoseFeed | TwistFeed | MeasurementFeed) -> FeedAck:
        cfg = src.config
        if msg.kind != cfg.kind:
            raise FeedRejected(f"field 'kind' value {msg.kind!r}: source {src.name!r} takes {cfg.kind} samples")
        now, wall = self._clock(), self._wall()
        latency: float | None = None
        stamp = now
        if msg.stamp is not None:
            latency = wall - msg.stamp
            if latency < -MAX_STAMP_AGE_S:  # years ahead is no clock skew: a finer unit than seconds
                raise FeedRejected(f"field 'stamp' value {msg.stamp!r}: {-latency:.6g} s in the future: a stamp is "
                                   f"the sender's wall-clock time in Unix seconds{_unit_hint(msg.stamp, wall)}")
            if latency < -cfg.max_future_s:
                raise FeedRejected(f"field 'stamp' value {msg.stamp!r}: {-latency:.3f} s in the future "
                                   f"(more than max_future_s {cfg.max_future_s}); are the clocks synchronised?")
            if latency > MAX_STAMP_AGE_S:
                raise FeedRejected(f"field 'stamp' value {msg.stamp!r}: {latency:.6g} s in the past (more than a "
                                   "day): a stamp is the sender's wall-clock time in Unix seconds, not a monotonic "
                                   "clock's reading; send the wall-clock time, or no stamp")
            stamp = now - max(latency, 0.0)
            if latency > cfg.stale_after_s:
                # Stale before it could command: "accepted" while the arm never followed (a sender's
                # clock a few tenths behind) told the sender nothing. Dropped, and it says why.
                detail = (f"field 'stamp' value {msg.stamp!r}: {latency:.3f} s old on arrival, more than "
                          f"stale_after_s {cfg.stale_after_s}: stale before it could command; dropped. Are the "
                          "sender's and this computer's clocks synchronised? (Or send no stamp.)")
                src.rejected += 1
                src.last_error = detail
                return FeedAck(source=src.name, accepted=False, seq=src.slot.seq, latency_ms=latency * 1e3,
                               detail=detail)
        prev = src.slot.read()
        # Stamped by the sender and placed after the last sample: measured later (the counter restarted).
        later = msg.stamp is not None and prev is not None and stamp > prev.stamp
        resync = self._seq_resync(src, msg.seq, later)
        late_seq = resync is None and msg.seq is not None and src.last_seq is not None and msg.seq <= src.last_seq
        if late_seq or (prev is not None and stamp < prev.stamp):
            src.out_of_order += 1
            return FeedAck(source=src.name, accepted=False, seq=src.slot.seq,
                           latency_ms=None if latency is None else latency * 1e3,
                           detail="older than the last accepted sample; dropped")
        sample = self._sample(src, msg, stamp)
        seq = src.slot.publish(sample)
        src.accepted += 1
        if resync is not None:
            src.resyncs += 1
        src.last_seq = msg.seq if msg.seq is not None else src.last_seq
        src.arrivals.append(now)
        while src.arrivals and now - src.arrivals[0] > self._window:
            src.arrivals.popleft()
        if latency is not None:
            src.latencies.append(latency)
        return FeedAck(source=src.name, seq=seq, latency_ms=None if latency is None else latency * 1e3,
                       detail=resync, resynced=resync is not None)

    @staticmethod
    def _seq_resync(src: _Source, seq: int | None, measured_later: bool) -> str | None:
        """Why ``seq`` starts a new sequence (too far behind or ahead of the last accepted, or behind
        it but measured later by the sender's stamp), or None."""
        if seq is None or src.last_seq is None:
            return None
        window = src.config.seq_window
        if seq <= src.last_seq and measured_later:
            return (f"seq {seq} is not after the last accepted {src.last_seq} but its stamp is newer: taken as the "
                    "sender's counter restarting; resynchronised")
        if seq < src.last_seq - window:
            return (f"seq {seq} is {src.last_seq - seq} behind the last accepted {src.last_seq} (more than "
                    f"seq_window {window}): taken as the sender's counter restarting; resynchronised")
        if seq > src.last_seq + window:
            return (f"seq {seq} jumped {seq - src.last_seq} ahead of the last accepted {src.last_seq} (more than "
                    f"seq_window {window}); resynchronised")
        return None

    def _sample(self, src: _Source, msg: PoseFeed | TwistFeed | MeasurementFeed,
                stamp: float) -> PoseSample | TwistSample | Measurement:
        cfg = src.config
        if isinstance(msg, PoseFeed):
            xyzwpr = [cfg.limits.get(a, DEFAULT_FIELD).convert(a, v) for a, v in zip(_AXES, msg.xyzwpr, strict=True)]
            return PoseSample(tuple(xyzwpr), stamp, src.name, msg.frame)  # type: ignore[arg-type]
        if isinstance(msg, TwistFeed):
            for field, vec, limit, servo_max, unit, key in (
                    ("linear", msg.linear, cfg.max_linear_mm_s, SERVO_MAX_LINEAR_MM_S, "mm/s", "max_linear_mm_s"),
                    ("angular", msg.angular, cfg.max_angular_deg_s, SERVO_MAX_ANGULAR_DEG_S, "deg/s",
                     "max_angular_deg_s")):
                speed = math.sqrt(sum(c * c for c in vec))
                if limit is not None and speed > limit:
                    raise ValueRejected(field, list(vec), f"speed {speed:.6g} above the limit {limit}")
                over = [i for i, c in enumerate(vec) if abs(c) > servo_max]
                if over:
                    i = over[0]
                    raise ValueRejected(field, list(vec), f"{field}[{i}] = {vec[i]:g} {unit} is beyond the servo's "
                                        f"limit of {servo_max:g} {unit} per component: send each within "
                                        f"+-{servo_max:g} {unit} (and set {key} on feed {src.name!r} to "
                                        "refuse lower speeds here); nothing was changed")
            self._check_flange(src.name, msg.linear, msg.angular)
            return TwistSample(msg.linear, msg.angular, msg.frame, stamp, src.name)
        missing = [k for k in cfg.required if k not in msg.values]
        if missing:
            raise FeedRejected(f"field 'values' value {dict(msg.values)!r}: missing {missing}")
        values = {k: cfg.limits.get(k, DEFAULT_FIELD).convert(k, v) for k, v in msg.values.items()}
        return Measurement(values, stamp, src.name)

    def _check_flange(self, source: str, linear: Sequence[float], angular: Sequence[float]) -> None:
        """ValueRejected when the flange would move faster than the robot's cap, as the servo checks it
        (``ServoCycle.check_twist``): the TCP's speed plus the swing of a turn about a TCP off the flange."""
        limit = self.flange_limit() if self.flange_limit is not None else None
        if limit is None:
            return
        speed, turn = math.hypot(*linear), math.hypot(*angular)
        swing = math.radians(turn) * limit.tool_offset_mm
        if speed + swing <= limit.cap_mm_s:
            return
        cap = f"the robot's flange-speed cap in force, {limit.cap_mm_s:.0f} mm/s"
        how = f"(and set max_{{}} on feed {source!r} to refuse faster twists here); nothing was changed"
        if speed > limit.cap_mm_s or swing == 0.0:
            raise ValueRejected("linear", list(linear), f"linear speed {speed:.1f} mm/s is above {cap}: send at "
                                f"most {limit.cap_mm_s:.0f} mm/s {how.format('linear_mm_s')}")
        raise ValueRejected("angular", list(angular), f"{turn:g} deg/s about a TCP {limit.tool_offset_mm:.0f} mm from "
                            f"the flange swings the flange at up to {swing:.0f} mm/s; with the linear speed "
                            f"{speed:.1f} mm/s that is {speed + swing:.0f} mm/s, above {cap}: send a slower turn "
                            f"or linear speed {how.format('angular_deg_s')}")

    def stats(self, source: str) -> FeedStats:
        src = self._get(source)
        with self._lock:
            now = self._clock()
            arr = [t for t in src.arrivals if now - t <= self._window]
            span = arr[-1] - arr[0] if len(arr) >= 2 else 0.0
            lat = list(src.latencies)
            return FeedStats(
                source=src.name, kind=src.config.kind, accepted=src.accepted, rejected=src.rejected,
                out_of_order=src.out_of_order, resyncs=src.resyncs, rate_hz=(len(arr) - 1) / span if span > 0 else 0.0,
                latency_ms_last=lat[-1] * 1e3 if lat else None,
                latency_ms_mean=sum(lat) / len(lat) * 1e3 if lat else None,
                latency_ms_max=max(lat) * 1e3 if lat else None,
                last_error=src.last_error,
            )

    def all_stats(self) -> list[FeedStats]:
        return [self.stats(n) for n in self._sources]
