"""The compiled region test and flange position (servo_app.robots.kernels) against their numpy readings."""

import math

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from servo_app.robots.configuration import ConfigurationRegion, boundary_distances, wrist_centre_offset
from servo_app.robots.conventions import fanuc_deg_to_model_rad
from servo_app.robots.kernels import (
    fanuc_deg_in_region,
    fanuc_deg_to_model_rad_into,
    flange_distance_mm,
    flange_point_mm,
    pack_dims,
)
from servo_app.robots.kinematics import ArmKinematics
from servo_app.robots.profile import load_profile

PROFILE = load_profile("lrmate200id")
KIN = ArmKinematics(PROFILE)
DIMS = pack_dims(KIN.a1, KIN.a2, KIN.a3, KIN.d4, KIN.d6)
LO, HI = np.array(PROFILE.joint_min_rad), np.array(PROFILE.joint_max_rad)

fanuc_joints = st.lists(st.floats(-200.0, 200.0), min_size=6, max_size=6).map(np.array)
unit_offsets = st.lists(st.floats(-1.0, 1.0), min_size=6, max_size=6).map(np.array)


def contains_oracle(region: ConfigurationRegion, q_model_rad: np.ndarray) -> np.ndarray:
    """ConfigurationRegion.contains as numpy computed it before the kernel."""
    q = np.atleast_2d(q_model_rad)[:, :6]
    ok = np.all((q >= region.lower) & (q <= region.upper), axis=1)
    x = wrist_centre_offset(q[:, 1], q[:, 2], region.kin)
    side = x > 0.0 if region.reference.top else x <= 0.0
    return ok & side & (np.abs(x) >= region.top_margin_m)


def region_around(q_fanuc_deg: np.ndarray, margin_deg: float = 1.0) -> ConfigurationRegion:
    """The region ServoCycle.begin builds for a stream starting at ``q``."""
    q = fanuc_deg_to_model_rad(q_fanuc_deg, PROFILE.j23_factor)
    margins = np.minimum(math.radians(margin_deg), boundary_distances(q, KIN) * 0.999)
    return ConfigurationRegion.around(q, KIN, margins).within(LO, HI)


@settings(max_examples=300, deadline=None)
@given(fanuc_joints, st.lists(unit_offsets, min_size=1, max_size=20), st.floats(1.0, 200.0), st.booleans())
def test_region_test_matches_numpy(start, offsets, spread_deg, j23):
    """Rows around a start, many across a boundary: the kernel and numpy agree on every row, also in
    the FANUC-degree entry the servo cycle uses (with either J2/J3 convention)."""
    region = region_around(start)
    points = np.array([start + spread_deg * o for o in offsets])
    factor = 1.0 if j23 else 0.0
    model = fanuc_deg_to_model_rad(points, factor)
    expected = contains_oracle(region, model)
    assert region.contains(model).tolist() == expected.tolist()
    assert [bool(fanuc_deg_in_region(p, factor, region.packed)) for p in points] == expected.tolist()


def test_region_test_has_both_answers():
    """Not vacuous: the generated kind of rows lands on both sides."""
    region = region_around(np.array([0.0, 10.0, -10.0, 0.0, -70.0, 0.0]))
    inside = fanuc_deg_to_model_rad(np.array([0.0, 10.0, -10.0, 0.0, -70.0, 0.0]), 1.0)
    flipped = fanuc_deg_to_model_rad(np.array([0.0, 10.0, -10.0, 0.0, 20.0, 0.0]), 1.0)
    assert region.contains(np.stack([inside, flipped])).tolist() == [True, False]


@settings(max_examples=300, deadline=None)
@given(fanuc_joints, fanuc_joints, st.sampled_from([0.0, 1.0]))
def test_flange_position_matches_python(q0, q1, j23):
    kin = ArmKinematics(PROFILE)
    kin.j23_factor = j23
    assert list(flange_point_mm(q1, j23, DIMS)) == kin.flange_xyz_mm_fanuc_deg(q1).tolist()
    distance = float(np.linalg.norm(kin.flange_xyz_mm_fanuc_deg(q1) - kin.flange_xyz_mm_fanuc_deg(q0)))
    assert math.isclose(flange_distance_mm(q0, q1, j23, DIMS), distance, rel_tol=1e-14, abs_tol=1e-11)


@settings(max_examples=300, deadline=None)
@given(fanuc_joints, st.sampled_from([0.0, 1.0]))
def test_joint_conversion_matches_numpy(q, j23):
    out = np.empty(6)
    fanuc_deg_to_model_rad_into(q, j23, out)
    assert out.tolist() == fanuc_deg_to_model_rad(q, j23).tolist()
