"""The inputs bridge without a robot: applications as pipelines, arbitration, what reaches the servo's
input slot (kind, frame, hold, source index, the stale marker naming the sensor), configuration errors.
Feeds stand in for the sensors here (an injected clock, no threads); tests/test_apps_e2e.py runs the
same pipelines against the simulator through real ptys, sockets and HTTP."""

from __future__ import annotations

import contextlib
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from servo_app.input_slot import NONE, POSE, TWIST, InputCommand, InputSlotReader
from servo_app.inputs import ConfigError
from servo_app.inputs.apps.config import load_service_inputs
from servo_app.inputs.bridge import InputsBridge
from servo_app.inputs.bridge.core import InputNotLive
from servo_app.inputs.feed.registry import FeedRejected
from servo_app.inputs.samples import TwistSample
from servo_app.messages import ConfigureInputs

CONFIG = """
[feeds.jog]
kind = "twist"
stale_after_s = 0.1

[feeds.gauge]
kind = "measurement"
stale_after_s = 0.2

[feeds.ft]
kind = "measurement"
stale_after_s = 0.05

[feeds.vision]
kind = "pose"
stale_after_s = 0.3

[feeds.pilot]
kind = "twist"
priority = 50
stale_after_s = 0.1

[[applications]]
name = "standoff"
type = "standoff"
sources = { distance = "gauge", operator = "jog" }
target_mm = 50.0
kp = 2.0
max_speed_mm_s = 20.0
priority = 10

[[applications]]
name = "guide"
type = "admittance"
sources = { wrench = "ft" }
lowpass_hz = 1000.0
bias_samples = 3
priority = 20

[[applications]]
name = "tracking"
type = "tracking"
sources = { target = "vision" }
priority = 5
lookahead_s = 0.05
linear_speed = 120.0

[[applications]]
name = "teleop"
type = "teleop"
sources = { twist = "pilot" }
frame = "base"
scale = 0.5
priority = 40
"""


class Clock:
    def __init__(self) -> None:
        self.t = 1000.0

    def __call__(self) -> float:
        return self.t


@contextlib.contextmanager
def opened_bridge(path: Path, **kwargs: Any) -> Iterator[tuple[InputsBridge, InputSlotReader]]:
    """The bridge of the inputs file ``path`` (InputsBridge.from_file's ``kwargs``) and a reader of its
    slot, as the service runs them; both closed after."""
    bridge = InputsBridge.from_file(path, **kwargs)
    reader = InputSlotReader(bridge.slot_name)
    try:
        yield bridge, reader
    finally:
        reader.close()
        bridge.close()


@pytest.fixture
def rig(tmp_path: Path) -> Iterator[tuple[InputsBridge, InputSlotReader, Clock]]:
    path = tmp_path / "inputs.toml"
    path.write_text(CONFIG)
    clock = Clock()
    with opened_bridge(path, clock=clock, hold_grace_s=0.05, stale_latch_s=0.05) as (bridge, reader):
        yield bridge, reader, clock


def wrench(fx: float = 0.0, fy: float = 0.0, fz: float = 0.0) -> dict[str, object]:
    return {"kind": "measurement", "values": {"fx": fx, "fy": fy, "fz": fz, "tx": 0.0, "ty": 0.0, "tz": 0.0}}


def twist(x: float, y: float = 0.0, z: float = 0.0, frame: str = "tool") -> dict[str, object]:
    return {"kind": "twist", "linear": [x, y, z], "frame": frame}


def test_sources_consumed_by_applications_do_not_command_directly(rig: tuple[InputsBridge, InputSlotReader, Clock]
                                                                  ) -> None:
    bridge, _, _ = rig
    assert set(bridge.specs) == {"standoff", "guide", "tracking", "teleop"}
    # Application inputs follow, so a stale stop can name the sensor itself.
    assert bridge.source_names[:4] == ["standoff", "guide", "tracking", "teleop"]
    assert set(bridge.source_names[4:]) == {"gauge", "jog", "ft", "vision", "pilot"}


def test_standoff_replaces_tool_z_and_goes_stale_with_its_distance_sensor(
        rig: tuple[InputsBridge, InputSlotReader, Clock]) -> None:
    bridge, reader, clock = rig
    bridge.feeds.submit("gauge", {"kind": "measurement", "values": {"distance": 60.0}})
    bridge.feeds.submit("jog", twist(15.0, -5.0, 99.0))
    bridge.step(clock())
    cmd = reader.poll()
    assert cmd is not None and cmd.kind == TWIST and cmd.frame == "tool"
    assert cmd.values == pytest.approx((15.0, -5.0, 20.0, 0, 0, 0))  # 10 mm too far * 2 /s, capped at 20
    assert cmd.timeout_s == pytest.approx(0.2 + 0.05)  # renewed hold: the timeout of its slowest input + grace
    assert bridge.source_names[cmd.source] == "standoff"

    # The operator's jog goes quiet: optional, so stand-off holds the distance alone.
    for _ in range(3):
        clock.t += 0.06
        bridge.feeds.submit("gauge", {"kind": "measurement", "values": {"distance": 52.0}})
        bridge.step(clock())
    cmd = reader.poll()
    assert cmd is not None and cmd.values == pytest.approx((0.0, 0.0, 4.0, 0, 0, 0))

    # The distance sensor goes quiet while the jog keeps coming: stale, and the marker names the sensor.
    stale: InputCommand | None = None
    for _ in range(6):
        clock.t += 0.05
        bridge.feeds.submit("jog", twist(10.0))
        bridge.step(clock())
        stale = reader.poll() or stale
        if stale is not None and stale.stale:
            break
    assert stale is not None and stale.stale and stale.kind == NONE
    assert bridge.source_names[stale.source] == "gauge"
    assert bridge.describe()["stale_events"] == {"gauge": 1}


def test_stale_marker_is_kept_before_another_source_takes_over(rig: tuple[InputsBridge, InputSlotReader, Clock]
                                                               ) -> None:
    bridge, reader, clock = rig
    bridge.feeds.submit("vision", {"kind": "pose", "xyzwpr": [400, 0, 300, 180, 0, 0]})
    bridge.feeds.submit("gauge", {"kind": "measurement", "values": {"distance": 50.0}})
    bridge.step(clock())
    assert reader.poll().source == bridge.source_names.index("standoff")  # type: ignore[union-attr]
    clock.t += 0.21  # the gauge (0.2 s) is stale, the camera (0.3 s) is not
    bridge.step(clock())
    cmd = reader.poll()
    assert cmd is not None and cmd.stale and bridge.source_names[cmd.source] == "gauge"
    clock.t += 0.02
    bridge.step(clock())
    assert reader.poll() is None  # latched: the servo process must read the marker first
    clock.t += 0.04
    bridge.step(clock())
    cmd = reader.poll()
    assert cmd is not None and cmd.kind == POSE and bridge.source_names[cmd.source] == "tracking"


def test_admittance_zeroing_then_guiding(rig: tuple[InputsBridge, InputSlotReader, Clock]) -> None:
    bridge, reader, clock = rig
    guide = bridge.application("guide")
    # Not while the sensor is silent: the bias would be whatever it read when it came back (a hand
    # on the tool, say), and guiding would then push by itself. The refusal changes nothing.
    with pytest.raises(InputNotLive, match="'ft' has sent nothing yet"):
        bridge.zero("guide")
    assert not guide.describe()["zeroing"]
    bridge.feeds.submit("ft", wrench(5.0, 0.0, -3.0))
    bridge.step(clock())
    bridge.zero("guide")
    for _ in range(3):  # the sensor's offset while nobody touches the tool
        clock.t += 0.004
        bridge.feeds.submit("ft", wrench(5.0, 0.0, -3.0))
        bridge.step(clock())
    assert guide.describe()["bias"][:3] == pytest.approx([5.0, 0.0, -3.0]) and not guide.describe()["zeroing"]
    clock.t += 0.004
    bridge.feeds.submit("ft", wrench(5.0, 0.0, -3.0))
    bridge.step(clock())
    cmd = reader.poll()
    assert cmd is not None and cmd.values == pytest.approx((0.0,) * 6)
    for _ in range(50):  # a steady push of 12 N along y (the low-pass settles)
        clock.t += 0.004
        bridge.feeds.submit("ft", wrench(5.0, 12.0, -3.0))
        bridge.step(clock())
    cmd = reader.poll()
    assert cmd is not None and cmd.frame == "tool" and cmd.values[1] == pytest.approx((12.0 - 2.0) * 2.0, rel=1e-3)
    clock.t += 0.2  # the sensor is unplugged (stale after 0.05 s)
    with pytest.raises(InputNotLive, match=r"'ft' has sent nothing for 0.20 s \(stale after 0.05 s\)"):
        bridge.zero("guide")
    assert not guide.describe()["zeroing"]
    with pytest.raises(ValueError, match="no sensor bias"):
        bridge.zero("standoff")
    with pytest.raises(KeyError):
        bridge.zero("nope")


def test_teleop_scales_and_overrides_the_frame_and_wins_by_priority(
        rig: tuple[InputsBridge, InputSlotReader, Clock]) -> None:
    bridge, reader, clock = rig
    bridge.feeds.submit("gauge", {"kind": "measurement", "values": {"distance": 50.0}})
    bridge.feeds.submit("pilot", twist(40.0, 0.0, -20.0, frame="tool"))
    bridge.step(clock())
    cmd = reader.poll()
    assert cmd is not None and bridge.source_names[cmd.source] == "teleop"
    assert cmd.frame == "base" and cmd.values[:3] == pytest.approx((20.0, 0.0, -10.0))


def test_tracking_extrapolates_with_the_feed_stamps(rig: tuple[InputsBridge, InputSlotReader, Clock]) -> None:
    bridge, reader, clock = rig
    # A target moving +100 mm/s in x, sampled at 20 Hz.
    for i in range(4):
        bridge.feeds.submit("vision", {"kind": "pose", "xyzwpr": [400 + 5 * i, 0, 300, 180, 0, 0]})
        bridge.step(clock())
        clock.t += 0.05
    clock.t -= 0.03  # 20 ms after the last sample
    bridge.step(clock())
    cmd = reader.poll()
    assert cmd is not None and cmd.kind == POSE and cmd.linear_speed == 120.0
    # 20 ms since the sample, plus the 50 ms lookahead, at 100 mm/s.
    assert cmd.values[0] == pytest.approx(415.0 + 100.0 * 0.07, abs=1e-6)


def test_a_source_publishing_a_frame_the_servo_does_not_know_is_refused(tmp_path: Path) -> None:
    path = tmp_path / "inputs.toml"
    path.write_text('[feeds.jog]\nkind = "twist"\n')
    clock = Clock()
    with opened_bridge(path, clock=clock) as (bridge, reader):
        with pytest.raises(FeedRejected, match="frame"):  # the feed refuses it at the door
            bridge.feeds.submit("jog", twist(1.0, frame="world"))
        # The bridge checks again whatever reaches a slot (an adapter publishes there directly).
        bridge.feeds.slot("jog").publish(TwistSample((1.0, 0.0, 0.0), (0.0, 0.0, 0.0), "world", clock(), "jog"))
        bridge.step(clock())
        assert reader.poll() is None
        assert bridge.describe()["bridge_problems"] == {"rejected": 1}


def test_the_thread_wakes_on_each_feed_sample(tmp_path: Path) -> None:
    """Event-driven: a feed sample reaches the slot without waiting for the housekeeping tick."""
    path = tmp_path / "inputs.toml"
    path.write_text('[feeds.jog]\nkind = "twist"\nstale_after_s = 1.5\n')
    with opened_bridge(path) as (bridge, reader):
        requests: list[ConfigureInputs] = []
        bridge.start(request=requests.append)
        assert bridge.enable(True) == {"enabled": True, "sources": ["jog"]}
        assert requests == [ConfigureInputs(enable=True, sources=("jog",))]
        for x in (1.0, 2.0, 3.0):
            bridge.feeds.submit("jog", twist(x))
            deadline = time.monotonic() + 5.0
            cmd = reader.poll()
            while cmd is None and time.monotonic() < deadline:
                time.sleep(0.0005)
                cmd = reader.poll()
            assert cmd is not None and cmd.values[0] == x
        rows = {r["name"]: r for r in bridge.summary()["sources"]}
        assert rows["jog"]["active"] and not rows["jog"]["stale"]
    assert not any(a.running for a in bridge.adapters)


def test_configuration_errors_name_file_key_and_value(tmp_path: Path) -> None:
    path = tmp_path / "bad.toml"
    path.write_text("""
[feeds.jog]
kind = "twist"
[feeds.vision]
kind = "pose"

[[applications]]
name = "guide"
type = "admittance"
sources = { wrench = "jog" }

[[applications]]
name = "standoff"
type = "standoff"
sources = { operator = "nope" }
target_mm = 40.0

[[applications]]
name = "jog"
type = "tracking"
sources = { target = "vision", extra = "vision" }

[[applications]]
name = "x"
type = "teleport"
sources = {}
""")
    with pytest.raises(ConfigError) as ei:
        load_service_inputs(path)
    got = {(i.key, str(i.value)) for i in ei.value.issues}
    assert ("applications[0].sources.wrench", "jog") in got  # twist source for a wrench role
    assert ("applications[1].sources.distance", "<missing>") in got
    assert ("applications[1].sources.operator", "nope") in got
    assert ("applications[2].name", "jog") in got  # clashes with a feed
    assert ("applications[2].sources.extra", "vision") in got
    assert any(k.startswith("applications[3]") for k, _ in got)
    assert all(i.file == str(path) for i in ei.value.issues)


def test_every_example_configuration_loads() -> None:
    root = Path(__file__).resolve().parents[1] / "configs" / "inputs"
    files = sorted(root.glob("*.toml"))
    assert len(files) >= 5
    for f in files:
        load_service_inputs(f)


def test_a_write_caught_half_done_reads_as_nothing_new(tmp_path: Path) -> None:
    """The bridge is an ordinary thread: descheduled mid-write, the servo process must not wait or die."""
    path = tmp_path / "inputs.toml"
    path.write_text('[feeds.jog]\nkind = "twist"\n')
    clock = Clock()
    with opened_bridge(path, clock=clock) as (bridge, reader):
        bridge.feeds.submit("jog", twist(1.0, frame="base"))
        bridge.step(clock())
        assert reader.poll() is not None
        seq = bridge.writer.slot._seq
        seq[0] += 1  # the writer stopped between "odd" and "even"
        assert reader.poll() is None and reader.torn_reads == 0  # still the version taken: not even read
        seq[0] += 2  # a newer version written meanwhile, and the writer stopped in the one after it
        assert reader.poll() is None and reader.torn_reads == 1  # read, and given up: nothing new for now
        seq[0] -= 3
        clock.t += 0.01
        bridge.feeds.submit("jog", twist(2.0, frame="base"))
        bridge.step(clock())
        cmd = reader.poll()
        assert cmd is not None and cmd.values[0] == 2.0


def test_servo_app_run_refuses_a_bad_inputs_file_before_starting_anything(tmp_path: Path) -> None:
    bad = tmp_path / "inputs.toml"
    bad.write_text('[feeds.jog]\nkind = "twist"\n[[applications]]\nname = "s"\ntype = "standoff"\n'
                   'sources = { distance = "jog" }\ntarget_mm = 5\n')
    r = subprocess.run([sys.executable, "-m", "servo_app.cli", "run", "--inputs", str(bad), "--token", "t",
                        "--var-dir", str(tmp_path)], capture_output=True, text=True, timeout=60)
    assert r.returncode == 2, r.stdout + r.stderr
    assert f"{bad}: applications[0].sources.distance = 'jog': publishes twist samples" in r.stdout


def test_standoff_forgets_its_integral_while_the_distance_sensor_is_quiet(tmp_path: Path) -> None:
    """The distance sensor drops out for 2 s (the arm stops, naming it) and comes back 1 mm too far:
    the first command is the proportional term alone. The integral used to keep its value from
    before the gap and add the error times the whole gap, so the arm set off at the integral's
    limit (here 11 mm/s where 1 mm/s was due) and overshot the surface."""
    path = tmp_path / "inputs.toml"
    path.write_text('[feeds.gauge]\nkind = "measurement"\nstale_after_s = 0.2\n[[applications]]\nname = "standoff"\n'
                    'type = "standoff"\nsources = { distance = "gauge" }\ntarget_mm = 50.0\nkp = 1.0\nki = 5.0\n'
                    'max_speed_mm_s = 20.0\nintegral_limit_mm_s = 10.0\n')
    clock = Clock()
    with opened_bridge(path, clock=clock, stale_latch_s=0.05) as (bridge, reader):
        bridge.enabled = True  # stand-off commands: its integral gathers

        def reading(distance: float) -> InputCommand | None:
            clock.t += 0.02
            bridge.feeds.submit("gauge", {"kind": "measurement", "values": {"distance": distance}})
            bridge.step(clock())
            return reader.poll()

        for _ in range(5):
            cmd = reading(60.0)
        assert cmd is not None and cmd.values[2] > 10.0  # 10 mm too far: kp * 10 plus the integral
        clock.t += 2.0
        bridge.step(clock())
        cmd = reader.poll()
        assert cmd is not None and cmd.stale and bridge.source_names[cmd.source] == "gauge"
        for _ in range(3):  # back; the first command waits for the stale marker's latch
            cmd = reading(51.0) or cmd
        assert cmd is not None and not cmd.stale
        assert cmd.values[2] == pytest.approx(1.0 + 5.0 * 1.0 * 0.02 * 2)  # kp * 1 mm, and 40 ms of integral


def test_infinite_or_nan_settings_are_refused_when_the_file_is_read(tmp_path: Path) -> None:
    """TOML writes inf and nan. Accepted, ``stale_after_s = inf`` never went stale: the sensor went
    quiet and the bridge never sent the stop naming it, while the arm went on at 20 mm/s for the
    servo's longest hold; a NaN target made every command NaN, refused one by one at run time."""
    path = tmp_path / "inputs.toml"
    path.write_text('[feeds.gauge]\nkind = "measurement"\n[feeds.jog]\nkind = "twist"\nstale_after_s = inf\n'
                    '[[applications]]\nname = "standoff"\ntype = "standoff"\nsources = { distance = "gauge" }\n'
                    'target_mm = nan\nstale_after_s = inf\n'
                    '[[applications]]\nname = "guide"\ntype = "admittance"\nsources = { wrench = "gauge" }\n'
                    'linear_gain = inf\nsensor_rotation = [[1.0, 0.0, 0.0], [0.0, nan, 0.0], [0.0, 0.0, 1.0]]\n')
    with pytest.raises(ConfigError) as ei:
        load_service_inputs(path)
    got = {i.key: i for i in ei.value.issues}
    for key in ("feeds.jog.stale_after_s", "applications[0].target_mm",
                "applications[0].stale_after_s", "applications[1].linear_gain",
                "applications[1].sensor_rotation.1.1"):
        assert key in got and "finite" in got[key].reason, (key, sorted(got))
    assert str(got["feeds.jog.stale_after_s"].value) == "inf"


@pytest.mark.parametrize("rotation", ["[[1.0, 0.0], [0.0, 1.0]]", "[[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]]",
                                      "[[10.0, 0.0, 0.0], [0.0, 10.0, 0.0], [0.0, 0.0, 10.0]]",
                                      "[[1.0, 1.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]"])
def test_a_sensor_rotation_that_is_no_rotation_is_refused(tmp_path: Path, rotation: str) -> None:
    """A 2x2 matrix used to load, then raise IndexError on every force sample (hand guiding never
    moved, "error" in the bridge's problems); a scaled one silently multiplied the gains."""
    path = tmp_path / "inputs.toml"
    path.write_text('[feeds.ft]\nkind = "measurement"\n[[applications]]\nname = "guide"\ntype = "admittance"\n'
                    f'sources = {{ wrench = "ft" }}\nsensor_rotation = {rotation}\n')
    with pytest.raises(ConfigError) as ei:
        load_service_inputs(path)
    (issue,) = ei.value.issues
    assert issue.key == "applications[0].sensor_rotation" and issue.file == str(path)
    assert "3 rows of 3" in issue.reason or "rotation matrix" in issue.reason
    r = 0.7071  # a rotation of 45 degrees about z, as a person writes it, loads
    path.write_text('[feeds.ft]\nkind = "measurement"\n[[applications]]\nname = "guide"\ntype = "admittance"\n'
                    f'sources = {{ wrench = "ft" }}\nsensor_rotation = [[{r}, -{r}, 0], [{r}, {r}, 0], [0, 0, 1]]\n')
    load_service_inputs(path)


def test_standoff_takes_over_without_an_integral_gathered_while_it_did_not_command(tmp_path: Path) -> None:
    """The distance sensor streams all along, 1 mm too far, while input control is off and then while
    the operator's higher-priority jog has control: the arm does not move, so the error stays. When
    stand-off takes over, its first command is the proportional term; it used to carry the integral
    gathered meanwhile (at its limit, 11 mm/s where 1 mm/s was due) and overshoot the surface."""
    path = tmp_path / "inputs.toml"
    path.write_text('[feeds.gauge]\nkind = "measurement"\nstale_after_s = 0.2\n[feeds.pilot]\nkind = "twist"\n'
                    'stale_after_s = 0.1\npriority = 50\n[[applications]]\nname = "standoff"\ntype = "standoff"\n'
                    'sources = { distance = "gauge" }\ntarget_mm = 50.0\nkp = 1.0\nki = 5.0\nmax_speed_mm_s = 20.0\n'
                    'integral_limit_mm_s = 10.0\n')
    clock = Clock()
    with opened_bridge(path, clock=clock, stale_latch_s=0.05) as (bridge, reader):

        def reading(pilot: bool = False) -> InputCommand | None:
            clock.t += 0.02
            bridge.feeds.submit("gauge", {"kind": "measurement", "values": {"distance": 51.0}})
            if pilot:
                bridge.feeds.submit("pilot", twist(5.0))
            bridge.step(clock())
            return reader.poll()

        for _ in range(150):  # 3 s with input control off
            reading()
        bridge.enabled = True
        cmd = reading()
        assert cmd is not None and bridge.source_names[cmd.source] == "standoff"
        assert cmd.values[2] == pytest.approx(1.0)
        for _ in range(150):  # 3 s of the operator's jog in control
            cmd = reading(pilot=True) or cmd
        assert bridge.source_names[cmd.source] == "pilot"
        for _ in range(10):  # the jog stops: stand-off takes over when it goes stale
            cmd = reading() or cmd
            if bridge.source_names[cmd.source] == "standoff":
                break
        assert bridge.source_names[cmd.source] == "standoff" and not cmd.stale
        # In control since the jog's stale marker, whose latch held its first commands back: a few
        # passes of integral, not 3 s of it.
        assert cmd.values[2] == pytest.approx(1.0, abs=0.5)


def test_a_tracking_update_rate_faster_than_the_servo_reads_is_refused(tmp_path: Path) -> None:
    """update_hz = 100000 loaded, and the bridge's thread woke every 10 us to re-extrapolate for a servo
    that reads every 4 ms at best: a third of a core busy here, with the GIL the feeds and requests need."""
    path = tmp_path / "inputs.toml"
    body = ('[feeds.vision]\nkind = "pose"\n[[applications]]\nname = "t"\ntype = "tracking"\n'
            'sources = { target = "vision" }\n')
    path.write_text(body + "update_hz = 100000.0\n")
    with pytest.raises(ConfigError) as ei:
        load_service_inputs(path)
    (issue,) = ei.value.issues
    assert issue.key == "applications[0].update_hz" and issue.value == 100000.0 and "250" in issue.reason
    path.write_text(body + "update_hz = 250.0\n")
    load_service_inputs(path)


def test_admittance_keys_must_name_six_different_values(tmp_path: Path) -> None:
    """A name twice (a copy-paste slip: "tx" for Ty) loaded, and a torque about x turned the tool
    about y as well."""
    path = tmp_path / "inputs.toml"
    path.write_text('[feeds.ft]\nkind = "measurement"\n[[applications]]\nname = "guide"\ntype = "admittance"\n'
                    'sources = { wrench = "ft" }\nkeys = ["fx", "fy", "fz", "tx", "tx", "tz"]\n')
    with pytest.raises(ConfigError) as ei:
        load_service_inputs(path)
    (issue,) = ei.value.issues
    assert issue.key == "applications[0].keys" and issue.value == ["fx", "fy", "fz", "tx", "tx", "tz"]
    assert "six different" in issue.reason


def test_an_application_timeout_shorter_than_its_sensors_is_refused(tmp_path: Path) -> None:
    """An application goes stale with its inputs; its own stale_after_s sets how long each command holds
    the arm. Set to 0.1 s over a sensor of 0.5 s (one sample every 0.2 s, say), it loaded, and the
    servo's hold ran out between samples: the arm stopped, "hold-to-run expired", waiting for a resume."""
    path = tmp_path / "inputs.toml"
    body = ('[feeds.gauge]\nkind = "measurement"\nstale_after_s = 0.5\n[feeds.jog]\nkind = "twist"\n'
            'stale_after_s = 1.5\n[[applications]]\nname = "standoff"\ntype = "standoff"\n'
            'sources = { distance = "gauge", operator = "jog" }\ntarget_mm = 50.0\n')
    path.write_text(body + "stale_after_s = 0.1\n")
    with pytest.raises(ConfigError) as ei:
        load_service_inputs(path)
    (issue,) = ei.value.issues
    assert issue.key == "applications[0].stale_after_s" and issue.value == 0.1
    assert "input 'gauge''s stale_after_s 0.5" in issue.reason
    path.write_text(body + "stale_after_s = 0.5\n")  # the optional operator's longer timeout does not count
    load_service_inputs(path)
    bridge = InputsBridge.from_file(path, clock=Clock())
    try:
        assert bridge.application("standoff").stale_after_s == 0.5
    finally:
        bridge.close()


def test_feed_options_its_kind_ignores_are_refused(tmp_path: Path) -> None:
    """``limits`` on a twist feed and ``required`` on a pose or twist feed loaded and were never read: a
    jog feed "limited" to x <= 10 took 200 mm/s along x."""
    path = tmp_path / "inputs.toml"
    path.write_text('[feeds.jog]\nkind = "twist"\nlimits = { x = { max = 10.0 } }\n'
                    '[feeds.vision]\nkind = "pose"\nrequired = ["x"]\n')
    with pytest.raises(ConfigError) as ei:
        load_service_inputs(path)
    got = {i.key: i for i in ei.value.issues}
    assert set(got) == {"feeds.jog.limits", "feeds.vision.required"}, got
    assert "max_linear_mm_s" in got["feeds.jog.limits"].reason and got["feeds.jog.limits"].value == ["x"]
    assert "measurement feeds only" in got["feeds.vision.required"].reason


def test_an_application_refusing_fresh_input_is_named_when_it_goes_stale_not_its_sensor(tmp_path: Path) -> None:
    """Stand-off runs on a streaming gauge; the operator starts jogging in the base frame (a twist feed's
    default), which stand-off refuses. Its output goes stale and the arm stops: the stop used to name
    the gauge, which was streaming all along, sending the operator to check the wrong sensor. Now it
    names the application, whose errors say why; a gauge that does go quiet is still named."""
    path = tmp_path / "inputs.toml"
    path.write_text('[feeds.gauge]\nkind = "measurement"\nstale_after_s = 0.2\n[feeds.jog]\nkind = "twist"\n'
                    'stale_after_s = 0.2\n[[applications]]\nname = "standoff"\ntype = "standoff"\n'
                    'sources = { distance = "gauge", operator = "jog" }\ntarget_mm = 50.0\n')
    clock = Clock()
    with opened_bridge(path, clock=clock, stale_latch_s=0.05) as (bridge, reader):

        def run(steps: int, jog: dict[str, object] | None = None, gauge: bool = True) -> InputCommand | None:
            stale = None
            for _ in range(steps):
                clock.t += 0.05
                if gauge:
                    bridge.feeds.submit("gauge", {"kind": "measurement", "values": {"distance": 52.0}})
                if jog is not None:
                    bridge.feeds.submit("jog", jog)
                bridge.step(clock())
                cmd = reader.poll()
                stale = cmd if cmd is not None and cmd.stale else stale
            return stale

        assert run(5) is None
        stale = run(10, jog={"kind": "twist", "linear": [10.0, 0.0, 0.0]})  # frame "base"
        assert stale is not None and bridge.source_names[stale.source] == "standoff"
        row = next(r for r in bridge.describe()["sources"] if r["name"] == "standoff")
        assert row["errors"]["rejected"] > 0 and "frame 'base'" in row["last_error"]
        assert run(5, jog=twist(10.0)) is None  # tool frame: stand-off commands again
        stale = run(10, jog=twist(10.0), gauge=False)
        assert stale is not None and bridge.source_names[stale.source] == "gauge"
        assert bridge.describe()["stale_events"] == {"standoff": 1, "gauge": 1}


@pytest.mark.parametrize("target", ["-50.0", "0.0"])
def test_a_standoff_target_distance_at_or_below_zero_is_refused(tmp_path: Path, target: str) -> None:
    """A sign slip (-50 for 50) loaded: the sensor can never read it, so stand-off drove the tool toward
    the surface at its full speed until it touched."""
    path = tmp_path / "inputs.toml"
    path.write_text('[feeds.gauge]\nkind = "measurement"\n[[applications]]\nname = "standoff"\ntype = "standoff"\n'
                    f'sources = {{ distance = "gauge" }}\ntarget_mm = {target}\n')
    with pytest.raises(ConfigError) as ei:
        load_service_inputs(path)
    (issue,) = ei.value.issues
    assert issue.key == "applications[0].target_mm" and issue.value == float(target)
    assert "greater than 0" in issue.reason


def test_standoff_integral_does_not_gather_while_the_arm_is_stopped(tmp_path: Path) -> None:
    """Stand-off in control, then the operator stops the arm over REST for 3 s while the gauge streams
    (1 mm too far): the bridge still had stand-off in control, so its integral wound up to its limit
    against an arm that was not moving, and the resume set off at 11 mm/s where 1 mm/s was due. Now
    an application that integrates is idle while the servo process does not stream."""
    path = tmp_path / "inputs.toml"
    path.write_text('[feeds.gauge]\nkind = "measurement"\nstale_after_s = 0.2\n[[applications]]\nname = "standoff"\n'
                    'type = "standoff"\nsources = { distance = "gauge" }\ntarget_mm = 50.0\nkp = 1.0\nki = 5.0\n'
                    'max_speed_mm_s = 20.0\nintegral_limit_mm_s = 10.0\n')
    clock = Clock()
    with opened_bridge(path, clock=clock) as (bridge, reader):
        servo = {"state": "streaming"}
        bridge._pipeline.feedback = lambda: servo  # the servo process's published state, as the service gives it
        bridge.enabled = True

        def reading() -> InputCommand | None:
            clock.t += 0.02
            bridge.feeds.submit("gauge", {"kind": "measurement", "values": {"distance": 51.0}})
            bridge.step(clock())
            return reader.poll()

        for _ in range(10):
            cmd = reading()
        assert cmd is not None and cmd.values[2] > 1.0  # streaming: the integral gathers as it should
        servo["state"] = "stopped"
        for _ in range(150):
            reading()
        servo["state"] = "streaming"  # resumed
        cmd = reading()
        assert cmd is not None and cmd.values[2] == pytest.approx(1.0)


def test_zeroing_is_cancelled_when_the_force_sensor_goes_quiet_half_way(
        rig: tuple[InputsBridge, InputSlotReader, Clock]) -> None:
    """One of three zeroing samples read, then the sensor is unplugged; it comes back with a hand on the
    tool (12 N). Those readings used to finish the bias, so guiding pushed the other way on release;
    now the zeroing is cancelled, the bias stays, and the application's errors say to zero again."""
    bridge, reader, clock = rig
    guide = bridge.application("guide")
    bridge.feeds.submit("ft", wrench())
    bridge.step(clock())
    bridge.zero("guide")
    clock.t += 0.004
    bridge.feeds.submit("ft", wrench())
    bridge.step(clock())
    assert guide.describe()["zeroing"]
    clock.t += 0.5  # unplugged (stale after 0.05 s), then back under load
    for _ in range(3):
        clock.t += 0.004
        bridge.feeds.submit("ft", wrench(0.0, 12.0))
        bridge.step(clock())
    view = guide.describe()
    assert not view["zeroing"] and view["bias"] == [0.0] * 6
    row = next(r for r in bridge.describe()["sources"] if r["name"] == "guide")
    assert row["errors"] == {"zeroing_cancelled": 1} and "zero again" in row["last_error"]
    cmd = reader.poll()
    assert cmd is not None and cmd.values[1] > 0  # the push is a push: guiding moves along it


def test_a_timeout_longer_than_the_servos_longest_hold_is_refused(tmp_path: Path) -> None:
    """stale_after_s = 200 (meant as milliseconds) loaded: the servo holds an input command at most 2 s,
    so when the sensor went quiet the arm went on for 2 s at its last command and stopped with
    'hold-to-run expired', the bridge's 'input jog stale' coming 198 s later."""
    path = tmp_path / "inputs.toml"
    path.write_text('[feeds.jog]\nkind = "twist"\nstale_after_s = 200.0\n[feeds.gauge]\nkind = "measurement"\n'
                    '[[applications]]\nname = "standoff"\ntype = "standoff"\nsources = { distance = "gauge" }\n'
                    'target_mm = 50.0\nstale_after_s = 5.0\n')
    with pytest.raises(ConfigError) as ei:
        load_service_inputs(path)
    got = {i.key: i for i in ei.value.issues}
    assert set(got) == {"feeds.jog.stale_after_s", "applications[0].stale_after_s"}, got
    assert got["feeds.jog.stale_after_s"].value == 200.0 and got["applications[0].stale_after_s"].value == 5.0
    assert all("at most 1.9 (seconds, not milliseconds)" in i.reason for i in got.values())
    path.write_text('[feeds.jog]\nkind = "twist"\nstale_after_s = 1.9\n')
    load_service_inputs(path)
