"""Inputs core: samples, slots, the arbiter, the registry, configuration and the adapter thread."""

from __future__ import annotations

import ast
import math
import os
import threading
from pathlib import Path
from typing import Any, Literal

import pytest
from hypothesis import given
from hypothesis import strategies as st

from servo_app.inputs import (
    AdapterConfig,
    Arbiter,
    ConfigError,
    InputAdapter,
    LatestValue,
    Measurement,
    PoseSample,
    SourceSpec,
    TwistSample,
    ValueRejected,
    adapter_types,
    create_adapter,
    load_inputs_config,
    parse_inputs_config,
    register_adapter,
)
from servo_app.inputs.shaping import clamp_norm, cubic_blend, deadband, deadband_normalized
from servo_app.inputs.slots import EventQueue

ROOT = Path(__file__).resolve().parents[1]
CONFIGS = ROOT / "configs" / "inputs"


class FakeClock:
    def __init__(self, t: float = 100.0) -> None:
        self.t = t

    def __call__(self) -> float:
        return self.t


def twist(v: float, stamp: float, source: str) -> TwistSample:
    return TwistSample((v, 0.0, 0.0), (0.0, 0.0, 0.0), "base", stamp, source)


# -- samples ----------------------------------------------------------------------------------------

def test_samples_reject_nan_naming_field_and_value() -> None:
    with pytest.raises(ValueRejected, match=r"'linear\[1\]' value nan"):
        TwistSample((0.0, math.nan, 0.0), (0, 0, 0), "base", 0.0, "x")
    with pytest.raises(ValueRejected, match=r"'xyzwpr\[5\]' value inf"):
        PoseSample((0, 0, 0, 0, 0, math.inf), 0.0, "x")
    with pytest.raises(ValueRejected, match=r"'force' value nan"):
        Measurement({"force": math.nan}, 0.0, "x")
    with pytest.raises(ValueRejected, match="expected 3 values"):
        TwistSample((1.0, 2.0), (0, 0, 0), "base", 0.0, "x")  # type: ignore[arg-type]


def test_measurement_is_read_only_and_floats() -> None:
    m = Measurement({"d": 3}, 1.0, "s")
    assert m["d"] == 3.0 and isinstance(m["d"], float)
    with pytest.raises(TypeError):
        m.values["d"] = 4.0  # type: ignore[index]


# -- slots ------------------------------------------------------------------------------------------

def test_latest_value_keeps_newest_and_counts() -> None:
    slot: LatestValue[TwistSample] = LatestValue("a")
    assert slot.read() is None and slot.age(5.0) == math.inf
    for i in range(5):
        slot.publish(twist(float(i), 10.0 + i, "a"))
    cur = slot.read()
    assert cur is not None and cur.seq == 5 and cur.value.linear[0] == 4.0 and cur.stamp == 14.0
    assert slot.age(14.5) == pytest.approx(0.5)
    assert slot.age(13.0) == 0.0  # a stamp from the future is not a negative age


def test_latest_value_wait_newer_across_threads() -> None:
    slot: LatestValue[int] = LatestValue()
    got: list[Any] = []
    t = threading.Thread(target=lambda: got.append(slot.wait_newer(0, timeout=10.0)))
    t.start()
    slot.publish(7, stamp=1.0)
    t.join(10.0)
    assert got and got[0].value == 7
    assert slot.wait_newer(1, timeout=0.01) is None


def test_event_queue_bounded_counts_drops() -> None:
    q: EventQueue[int] = EventQueue(maxlen=3)
    for i in range(5):
        q.put(i)
    assert q.dropped == 2 and q.drain() == [2, 3, 4] and q.get(timeout=0.0) is None


# -- shaping ----------------------------------------------------------------------------------------

@given(st.floats(-10, 10), st.floats(0, 5))
def test_deadband_continuous_and_never_grows(x: float, w: float) -> None:
    y = deadband(x, w)
    assert abs(y) <= abs(x) + 1e-12
    assert y == 0.0 or math.copysign(1, y) == math.copysign(1, x)
    assert abs(y - x) <= w + 1e-12  # continuous: shifted by at most the width


@given(st.floats(-1, 1), st.floats(0, 0.9), st.floats(0, 1))
def test_normalized_deadband_and_curve_stay_in_unit_range(u: float, w: float, k: float) -> None:
    y = cubic_blend(deadband_normalized(u, w), k)
    assert -1.0 - 1e-12 <= y <= 1.0 + 1e-12
    assert cubic_blend(1.0, k) == pytest.approx(1.0)


@given(st.lists(st.floats(-1e3, 1e3), min_size=3, max_size=3), st.floats(0.1, 100))
def test_clamp_norm_keeps_direction(v: list[float], limit: float) -> None:
    out = clamp_norm(v, limit)
    assert math.hypot(*out) <= limit * (1 + 1e-9) or math.hypot(*out) == pytest.approx(math.hypot(*v))
    n = math.hypot(*v)
    if n > 1e-6:
        for a, b in zip(out, v, strict=True):
            assert a * n == pytest.approx(b * math.hypot(*out), abs=1e-6)


# -- arbiter ----------------------------------------------------------------------------------------

def make_arbiter(clock: FakeClock) -> tuple[Arbiter, dict[str, LatestValue[Any]]]:
    slots = {n: LatestValue(n) for n in ("spacemouse", "tracking", "feed")}
    arb = Arbiter([
        SourceSpec("spacemouse", 20, 0.1, slots["spacemouse"], yield_when_idle=True),
        SourceSpec("tracking", 5, 0.3, slots["tracking"]),
        SourceSpec("feed", 5, 0.2, slots["feed"]),
    ], clock=clock)
    return arb, slots


def test_arbiter_priority_staleness_and_deceleration() -> None:
    clock = FakeClock(100.0)
    arb, slots = make_arbiter(clock)
    d = arb.select()
    assert d.active is None and d.decelerate and not d.changed and d.went_stale is None

    slots["tracking"].publish(twist(1.0, 100.0, "tracking"))
    d = arb.select()
    assert d.active == "tracking" and d.changed and d.previous is None and d.sample.linear[0] == 1.0

    # The operator deflects the SpaceMouse: higher priority takes over.
    clock.t = 100.05
    slots["spacemouse"].publish(twist(5.0, 100.05, "spacemouse"))
    d = arb.select()
    assert d.active == "spacemouse" and d.previous == "tracking" and d.went_stale is None

    # The SpaceMouse link dies (no samples): after 0.1 s it is stale; tracking (still live) takes over.
    clock.t = 100.2
    d = arb.select()
    assert d.active == "tracking" and d.went_stale == "spacemouse" and not d.decelerate

    # Tracking goes stale too: nobody is live, decelerate, reported once.
    clock.t = 100.35
    d = arb.select()
    assert d.active is None and d.went_stale == "tracking" and d.decelerate
    d = arb.select()
    assert d.went_stale is None and not d.changed and d.decelerate


def test_arbiter_idle_spacemouse_yields_but_stays_live() -> None:
    clock = FakeClock(10.0)
    arb, slots = make_arbiter(clock)
    slots["spacemouse"].publish(twist(0.0, 10.0, "spacemouse"))  # at rest
    slots["tracking"].publish(twist(2.0, 10.0, "tracking"))
    d = arb.select()
    assert d.active == "tracking" and "spacemouse" in d.live
    # Only an idle SpaceMouse is live: it holds control with zero (not stale, no deceleration report).
    clock.t = 10.31
    slots["spacemouse"].publish(twist(0.0, 10.31, "spacemouse"))
    d = arb.select()
    assert d.active == "spacemouse" and d.sample.is_zero() and d.went_stale == "tracking"


def test_arbiter_equal_priority_incumbent_keeps_control_and_owner() -> None:
    clock = FakeClock(0.0)
    arb, slots = make_arbiter(clock)
    slots["feed"].publish(twist(1.0, 0.0, "feed"))
    assert arb.select().active == "feed"
    slots["tracking"].publish(twist(1.0, 0.0, "tracking"))  # same priority, configured first
    assert arb.select().active == "feed"  # no flapping to the newcomer
    arb.set_owner("tracking")  # e.g. the control lease moved
    d = arb.select()
    assert d.active == "tracking" and d.previous == "feed" and d.went_stale is None
    arb.set_owner(None)
    arb.enable("tracking", False)
    assert arb.select().active == "feed"
    with pytest.raises(KeyError, match="unknown source 'nope'"):
        arb.enable("nope")


# -- registry and configuration --------------------------------------------------------------------

class CountingConfig(AdapterConfig):
    type: Literal["counting"] = "counting"
    fail_opens: int = 0
    crash_every: int = 0


class CountingAdapter(InputAdapter):
    """Publishes a counter; fails to open `fail_opens` times, raises a bug every `crash_every` polls."""

    config_model = CountingConfig
    config: CountingConfig

    def __init__(self, config: CountingConfig, **kw: Any) -> None:
        super().__init__(config, **kw)
        self.opens = self.polls = 0
        self.unplug = threading.Event()

    def _open(self) -> None:
        self.opens += 1
        if self.opens <= self.config.fail_opens:
            raise FileNotFoundError("no such device")
        self.unplug.clear()

    def _poll(self) -> None:
        self.polls += 1
        if self.unplug.is_set():
            raise OSError(5, "Input/output error")
        if self.config.crash_every and self.polls % self.config.crash_every == 0:
            raise ZeroDivisionError("bug in a decoder")
        self._publish(Measurement({"n": float(self.polls)}, self.clock(), self.name))
        self._stop.wait(0.002)

    def _close(self) -> None:
        pass


register_adapter("counting", CountingAdapter)


def test_registry_create_by_name_and_errors() -> None:
    assert {"spacemouse", "spacenav", "serial_line", "serial_binary", "can", "counting"} <= set(adapter_types())
    a = create_adapter({"type": "counting", "name": "c1", "priority": 3})
    assert isinstance(a, CountingAdapter) and a.priority == 3 and a.source_spec().slot is a.output
    with pytest.raises(ConfigError, match=r"adapters\.c2\.priority = 'high'"):
        create_adapter({"type": "counting", "name": "c2", "priority": "high"})
    with pytest.raises(ConfigError, match="unknown adapter type"):
        create_adapter({"type": "nope", "name": "x"})
    with pytest.raises(TypeError):
        register_adapter("bad", dict)  # type: ignore[arg-type]


def test_adapter_thread_survives_bugs_and_reconnects() -> None:
    a = create_adapter({"type": "counting", "name": "c", "fail_opens": 2, "crash_every": 5,
                        "reconnect_min_s": 0.01, "reconnect_max_s": 0.02, "poll_timeout_s": 0.01})
    assert isinstance(a, CountingAdapter)
    with a:
        assert a.output.wait_newer(10, timeout=20.0) is not None
        st1 = a.status()
        assert st1.connected and st1.problems["open_failed"] == 2 and st1.problems["error"] >= 1 and a.running
        seq = a.output.seq
        a.unplug.set()  # the device disappears: the thread reconnects and publishes again
        assert a.output.wait_newer(seq + 5, timeout=20.0) is not None
        st2 = a.status()
        assert st2.connects >= 2 and st2.problems["disconnected"] >= 1
    assert not a.running and not a.connected


def test_adapter_thread_runs_at_its_configured_scheduling() -> None:
    """The reader thread asks for SCHED_FIFO (a frame is read as it arrives, ahead of ordinary work);
    0 leaves it at normal priority. Without the privilege it says so and keeps running."""
    for priority, expected in ((7, ("SCHED_FIFO 7", "unavailable")), (0, ("normal priority",))):
        a = create_adapter({"type": "counting", "name": f"c{priority}", "realtime_priority": priority})
        policy: list[int] = []
        original = a._open

        def open_and_note(original=original, policy=policy) -> None:
            policy.append(os.sched_getscheduler(0))  # the adapter's own thread
            original()

        a._open = open_and_note  # type: ignore[method-assign]
        with a:
            assert a.output.wait_newer(1, timeout=20.0) is not None
        assert a.scheduling.startswith(expected)
        if a.scheduling.startswith("SCHED_FIFO"):
            assert policy[0] & ~getattr(os, "SCHED_RESET_ON_FORK", 0) == os.SCHED_FIFO
        if priority == 0:
            assert policy[0] == os.SCHED_OTHER
    with pytest.raises(ConfigError, match=r"realtime_priority = 100"):
        create_adapter({"type": "counting", "name": "c", "realtime_priority": 100})


def test_example_configs_load() -> None:
    for path in sorted(CONFIGS.glob("*.toml")):
        cfg = load_inputs_config(path)
        assert cfg.adapters or cfg.feeds, path


def test_config_errors_name_file_key_value(tmp_path: Path) -> None:
    p = tmp_path / "inputs.toml"
    p.write_text(
        '[adapters.sm]\ntype = "spacemouse"\nfull_scale = -3\n'
        '[adapters.probe]\ntype = "serial_line"\nport = "/dev/x"\nbaudrate = "fast"\n'
        '[adapters.probe.fields.d]\npattern = "D=[0-9]+"\n'
        '[adapters.lidar]\ntype = "lidar"\n'
        '[feeds.v]\nkind = "posture"\n'
        '[extra]\n'
    )
    with pytest.raises(ConfigError) as ei:
        load_inputs_config(p)
    text = str(ei.value)
    for expected in (f"{p}: adapters.sm.full_scale = -3", f"{p}: adapters.probe.baudrate = 'fast'",
                     "adapters.probe.fields.d.pattern = 'D=[0-9]+'", "adapters.lidar.type = 'lidar'",
                     "feeds.v.kind = 'posture'", "extra = {}"):
        assert expected in text
    assert len(ei.value.issues) == 6
    p.write_text("[adapters.x\n")
    with pytest.raises(ConfigError, match="not valid TOML"):
        load_inputs_config(p)
    with pytest.raises(ConfigError, match="cannot read"):
        load_inputs_config(tmp_path / "missing.toml")


def test_settings_that_would_defeat_staleness_or_reverse_a_jog_are_refused(tmp_path: Path) -> None:
    """TOML spells inf and nan: stale_after_s = inf would keep an unplugged device's last twist live,
    and a negative scale reverses every direction of a SpaceMouse or a pad. Each is named with its value."""
    p = tmp_path / "inputs.toml"
    p.write_text(
        '[adapters.sm]\ntype = "spacemouse"\nstale_after_s = inf\nscale = -1.0\n'
        '[adapters.nav]\ntype = "spacenav"\nscale = nan\nmax_linear_mm_s = inf\n'
        '[adapters.pad]\ntype = "gamepad"\nscale = 0.0\nreconnect_max_s = inf\n'
        '[adapters.probe]\ntype = "serial_line"\nport = "/dev/x"\nstale_after_s = inf\n'
        '[adapters.probe.fields.d]\npattern = "D=([0-9]+)"\n'
    )
    with pytest.raises(ConfigError) as ei:
        load_inputs_config(p)
    keys = {(i.key, repr(i.value)) for i in ei.value.issues}
    assert keys == {("adapters.sm.stale_after_s", "inf"), ("adapters.sm.scale", "-1.0"), ("adapters.nav.scale", "nan"),
                    ("adapters.nav.max_linear_mm_s", "inf"), ("adapters.pad.scale", "0.0"),
                    ("adapters.pad.reconnect_max_s", "inf"), ("adapters.probe.stale_after_s", "inf")}, keys
    assert create_adapter({"type": "gamepad", "name": "pad", "scale": 0.5}).config.scale == 0.5


def test_a_jog_device_stale_timeout_shorter_than_its_reports_is_refused() -> None:
    """A SpaceMouse or pad reports every 4-8 ms: stale_after_s = 0.005 had its source go stale between
    reports, stopping the arm mid-jog again and again."""
    data = {"adapters": {t: {"type": t, "stale_after_s": 0.005} for t in ("spacemouse", "spacenav", "gamepad")}}
    with pytest.raises(ConfigError) as ei:
        parse_inputs_config(data, file="in.toml")
    assert [(i.key, i.value) for i in ei.value.issues] == [(f"adapters.{t}.stale_after_s", 0.005)
                                                           for t in ("spacemouse", "spacenav", "gamepad")]
    assert all("stale between two reports" in i.reason for i in ei.value.issues)
    assert parse_inputs_config({"adapters": {"pad": {"type": "gamepad", "stale_after_s": 0.02}}}).adapters


def test_an_adapter_timeout_longer_than_the_servos_longest_hold_is_refused() -> None:
    """stale_after_s = 200 (meant as milliseconds) loaded for a device: the servo holds an input command
    at most 2 s, so a device gone quiet mid-jog left the arm moving for 2 s on its last command, then
    'hold-to-run expired' without naming it. Feeds and applications were capped already."""
    probe = {"type": "serial_line", "port": "/dev/x", "fields": {"d": {"pattern": "D=([0-9]+)"}}}
    data = {"adapters": {"sm": {"type": "spacemouse", "stale_after_s": 200.0},
                         "pad": {"type": "gamepad", "stale_after_s": 5.0},
                         "probe": {**probe, "stale_after_s": 2.0}}}
    with pytest.raises(ConfigError) as ei:
        parse_inputs_config(data, file="in.toml")
    assert [(i.key, i.value) for i in ei.value.issues] == [("adapters.sm.stale_after_s", 200.0),
                                                           ("adapters.pad.stale_after_s", 5.0),
                                                           ("adapters.probe.stale_after_s", 2.0)]
    assert all("at most 1.9 (seconds, not milliseconds)" in i.reason for i in ei.value.issues)
    assert parse_inputs_config({"adapters": {"probe": {**probe, "stale_after_s": 1.9}}}).adapters


def test_non_finite_field_scaling_and_limits_are_refused(tmp_path: Path) -> None:
    """A field's scale, offset, min and max (a sensor's fields, a feed's limits) took nan and inf, which
    TOML spells: limits = { z = { scale = nan } } loaded, then every sample was refused at run time."""
    p = tmp_path / "inputs.toml"
    p.write_text(
        '[feeds.vision]\nkind = "pose"\nlimits = { z = { scale = nan }, x = { offset = inf } }\n'
        '[feeds.gauge]\nkind = "measurement"\nlimits = { d = { min = nan, max = -inf } }\n'
        '[adapters.probe]\ntype = "serial_line"\nport = "/dev/x"\n'
        '[adapters.probe.fields.d]\npattern = "D=([0-9]+)"\nscale = inf\n'
    )
    with pytest.raises(ConfigError) as ei:
        load_inputs_config(p)
    keys = {(i.key, repr(i.value)) for i in ei.value.issues}
    assert keys == {("feeds.vision.limits.z.scale", "nan"), ("feeds.vision.limits.x.offset", "inf"),
                    ("feeds.gauge.limits.d.min", "nan"), ("feeds.gauge.limits.d.max", "-inf"),
                    ("adapters.probe.fields.d.scale", "inf")}, keys
    assert all("finite" in i.reason for i in ei.value.issues)


def test_a_jog_device_frame_the_servo_lacks_is_refused_when_the_file_loads() -> None:
    """It used to load, and once toggle_frame reached it the bridge refused every sample: the arm
    stopped answering the device with nothing said at start-up."""
    data = {"adapters": {t: {"type": t, "frames": ["base", "world"]} for t in ("spacemouse", "spacenav", "gamepad")}}
    with pytest.raises(ConfigError) as ei:
        parse_inputs_config(data, file="in.toml")
    assert [(i.key, i.value) for i in ei.value.issues] == [(f"adapters.{t}.frames", ["base", "world"])
                                                           for t in ("spacemouse", "spacenav", "gamepad")]
    assert all("'world' is not a frame" in i.reason and "base, tool" in i.reason for i in ei.value.issues)
    assert parse_inputs_config({"adapters": {"pad": {"type": "gamepad", "frames": ["tool"]}}}).adapters[0].frames == \
        ["tool"]
    from servo_app.input_slot import FRAMES
    from servo_app.inputs.samples import TWIST_FRAMES

    assert TWIST_FRAMES == FRAMES  # the inputs' list is the servo's


def test_a_feed_named_like_an_adapter_is_refused() -> None:
    """The two shared one source name: the feed's slot replaced the adapter's in the bridge, and the
    gamepad, connected and read, never moved the arm."""
    data = {"adapters": {"pad": {"type": "gamepad"}}, "feeds": {"pad": {"kind": "pose"}, "cam": {"kind": "pose"}}}
    with pytest.raises(ConfigError) as ei:
        parse_inputs_config(data, file="in.toml")
    (issue,) = ei.value.issues
    assert (issue.file, issue.key, issue.value) == ("in.toml", "feeds.pad", {"kind": "pose"})
    assert "already names an adapter ([adapters.pad])" in issue.reason and "another name" in issue.reason


def test_inputs_never_import_the_robot_side() -> None:
    forbidden = ("servo_app.fanuc", "servo_app.janome", "servo_app.motion", "servo_app.robots",
                 "servo_app.safety", "servo_app.sim", "servo_app.api", "servo_app.cli", "servo_app.service")
    for path in (ROOT / "servo_app" / "inputs").rglob("*.py"):
        for node in ast.walk(ast.parse(path.read_text())):
            names = [a.name for a in node.names] if isinstance(node, ast.Import) else (
                [node.module or ""] if isinstance(node, ast.ImportFrom) else [])
            for n in names:
                assert not n.startswith(forbidden), f"{path} imports {n}"


def test_the_tracking_apps_slowest_speed_is_the_servos() -> None:
    """The inputs never import the motion floor: the one number they share is checked here."""
    from servo_app.inputs.apps.config import SLOWEST_POSE_SPEED
    from servo_app.motion.commands import MIN_ANGULAR_DEG_S, MIN_LINEAR_MM_S

    assert SLOWEST_POSE_SPEED == MIN_LINEAR_MM_S == MIN_ANGULAR_DEG_S


def test_the_twist_feeds_door_limits_are_the_servos() -> None:
    """A twist feed refuses what the servo would (its per-component bounds), mirrored, not imported."""
    from servo_app.inputs.feed.registry import SERVO_MAX_ANGULAR_DEG_S, SERVO_MAX_LINEAR_MM_S
    from servo_app.motion.commands import MAX_ANGULAR_DEG_S, MAX_LINEAR_MM_S

    assert (SERVO_MAX_LINEAR_MM_S, SERVO_MAX_ANGULAR_DEG_S) == (MAX_LINEAR_MM_S, MAX_ANGULAR_DEG_S)
