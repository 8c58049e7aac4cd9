"""Janome profiles (validated on load) and kinematics: cartesian box, SCARA IK/FK and arm configuration."""

from __future__ import annotations

import itertools
import math
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from servo_app.janome.kinematics import ScaraArm, ScaraWorkspace, Unreachable
from servo_app.janome.profile import available_janome_profiles, load_janome_profile
from servo_app.janome.protocol import Arm, ErrorCode, RobotKind
from servo_app.janome.trapezoid import covered, move_time
from servo_app.robots.profile import ProfileError

JS3 = load_janome_profile("js3")
ARM = JS3.arm
assert ARM is not None


def test_shipped_profiles_load() -> None:
    assert {"jr3000", "jc3", "js3"} <= set(available_janome_profiles())
    jr = load_janome_profile("jr3000")
    assert jr.kind == RobotKind.CARTESIAN and jr.arm is None and jr.axis_max[0] == 300.0
    assert JS3.kind == RobotKind.SCARA and ARM.l1 == 200.0 and ARM.l2 == 150.0 and JS3.elbow == Arm.RIGHTY


def _write(tmp_path: Path, text: str) -> Path:
    p = tmp_path / "bad.toml"
    p.write_text(text)
    return p


BASE = (Path(__file__).resolve().parents[1] / "configs/robots/janome/jr3000.toml").read_text()
SCARA = (Path(__file__).resolve().parents[1] / "configs/robots/janome/js3.toml").read_text()


@pytest.mark.parametrize(("text", "message"), [
    (BASE.replace('type = "cartesian"', 'type = "delta"'), r"key 'type' = 'delta' must be one of 'cartesian', 'scara'"),
    (BASE.replace("max   = [300.0", "max   = [-1.0"), r"key 'axes.min\[0\]' = 0.0 is not below axes.max\[0\] = -1.0"),
    (BASE.replace("speed = [800.0", "speed = [0"), r"key 'axes.speed\[0\]' = 0 must be > 0"),
    (BASE.replace("accel = [3000.0, 3000.0, 1500.0, 5000.0]", "accel = [1, 2]"),
     r"key 'axes.accel' = \[1, 2\] must be a list of 4 numbers"),
    (BASE.replace("speed_mm_s = 800.0", 'speed_mm_s = "fast"'), r"key 'cp.speed_mm_s' = 'fast' is not a finite"),
    (BASE.replace("home = [150.0, 160.0, 50.0, 0.0]", "home = [150.0, 400.0, 50.0, 0.0]"),
     r"key 'home' = \[150.0, 400.0, 50.0, 0.0\] is not reachable: Y=400.000 mm is outside the stroke"),
    (BASE.replace("step_s = 0.1 ", "step_s = 5.0 "), r"key 'link.step_s' = 5.0 must be in 0.02..2 s"),
    (BASE.replace('name = "jr3000"\n', ""), r"missing key 'name'"),
    (SCARA.replace("l2_mm = 150.0", "l2_mm = -150.0"), r"key 'arm.l2_mm' = -150.0 must be > 0"),
    (SCARA.replace('elbow = "righty"', 'elbow = "up"'), r"key 'arm.elbow' = 'up' must be one of 'righty', 'lefty'"),
    (SCARA.replace("home = [200.0, 150.0, 50.0, 0.0]", "home = [10.0, 0.0, 50.0, 0.0]"),
     r"key 'home' .* inside the inner radius \|l1 - l2\| = 50 mm"),
    (SCARA.split("[arm]")[0] + "[cp]" + SCARA.split("[cp]")[1], r"missing key 'arm'"),
])
def test_errors_name_file_key_and_value(tmp_path: Path, text: str, message: str) -> None:
    p = _write(tmp_path, text)
    with pytest.raises(ProfileError, match=message) as info:
        load_janome_profile(p)
    assert str(p) in str(info.value)


def test_unknown_model_lists_the_known_ones() -> None:
    with pytest.raises(ProfileError, match=r"'nope' is unknown \(known: .*jr3000.*js3"):
        load_janome_profile("nope")


# ------------------------------------------------------------------------------- kinematics

joint1 = st.floats(ARM.j1_min, ARM.j1_max)
joint2 = st.floats(ARM.j2_min, ARM.j2_max).filter(lambda v: abs(v) > 0.5)


@given(joint1, joint2)
def test_scara_fk_ik_round_trip_keeps_the_configuration(j1: float, j2: float) -> None:
    arm = Arm.RIGHTY if j2 > 0 else Arm.LEFTY
    x, y = ARM.fk(j1, j2)
    k1, k2 = ARM.ik(x, y, arm)
    assert k1 == pytest.approx(j1, abs=1e-6) and k2 == pytest.approx(j2, abs=1e-6)
    assert np.hypot(*np.subtract(ARM.fk(k1, k2), (x, y))) < 1e-9


@given(joint1, joint2)
def test_the_other_configuration_reaches_the_same_point(j1: float, j2: float) -> None:
    x, y = ARM.fk(j1, j2)
    other = Arm.LEFTY if j2 > 0 else Arm.RIGHTY
    k1, k2 = ARM.ik(x, y, other)
    assert k2 == pytest.approx(-j2, abs=1e-6)  # the mirror elbow
    assert np.allclose(ARM.fk(k1, k2), (x, y), atol=1e-9)


def test_righty_elbow_lies_right_of_the_reach_line() -> None:
    j1, j2 = ARM.ik(250.0, 0.0, Arm.RIGHTY)
    elbow = (ARM.l1 * math.cos(math.radians(j1)), ARM.l1 * math.sin(math.radians(j1)))
    assert j2 > 0 and elbow[1] < 0  # reaching along +X, the elbow is at -Y (the right, seen from above)


def test_scara_unreachable_points_name_the_reason() -> None:
    with pytest.raises(Unreachable, match=r"beyond the reach l1 \+ l2 = 350 mm"):
        ARM.ik(400.0, 0.0, Arm.RIGHTY)
    with pytest.raises(Unreachable, match=r"inside the inner radius"):
        ARM.ik(10.0, 0.0, Arm.RIGHTY)
    ws = JS3.workspace()
    v = ws.check(np.array([349.99, 0.0, 50.0, 0.0]), Arm.RIGHTY)
    assert v is not None and v.code == ErrorCode.UNREACHABLE and "stretched arm" in v.message
    v = ws.check(np.array([200.0, 150.0, 500.0, 0.0]), Arm.RIGHTY)
    assert v is not None and v.code == ErrorCode.OUT_OF_RANGE and v.axis == 3 and "Z=500.000 mm" in v.message


def test_scara_clip_stops_at_the_workspace_edge_in_the_same_configuration() -> None:
    ws = JS3.workspace(margin=0.5)
    assert isinstance(ws, ScaraWorkspace)
    p0 = np.array([200.0, 150.0, 50.0, 0.0])
    end = ws.clip_segment(p0, np.array([600.0, 150.0, 50.0, 0.0]), Arm.RIGHTY)
    assert 200.0 < end[0] < 350.0 and ws.check(end, Arm.RIGHTY) is None
    assert ws.check_path(p0, end, Arm.RIGHTY) is None
    j2 = ws.joints(end, Arm.RIGHTY)[1]
    assert 2.5 - 1e-3 <= j2 < 4.0  # stopped at the singular margin, still righty


def test_cartesian_clip_stays_in_the_box() -> None:
    ws = load_janome_profile("jr3000").workspace()
    end = ws.clip_segment(np.array([150.0, 160.0, 50.0, 0.0]), np.array([450.0, 160.0, 50.0, 30.0]))
    assert end[0] == pytest.approx(300.0) and end[3] == pytest.approx(15.0)


def test_scara_arm_validates_configuration() -> None:
    with pytest.raises(Unreachable, match=r"arm=0 must be 1 \(righty\) or -1 \(lefty\)"):
        ScaraArm(200, 150, -125, 125, -145, 145).ik(200.0, 150.0, 0)


@given(st.floats(0, 500), st.floats(1, 1000), st.floats(10, 10000))
def test_trapezoid_covers_the_distance_in_its_time(d: float, v: float, a: float) -> None:
    t = move_time(d, v, a)
    assert covered(t, d, v, a) == pytest.approx(d)
    assert t >= d / v - 1e-12  # never faster than the speed allows
    ts = np.linspace(0, t, 20)
    s = [covered(x, d, v, a) for x in ts]
    assert all(b >= a_ - 1e-9 for a_, b in itertools.pairwise(s))  # monotonic
