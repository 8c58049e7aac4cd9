"""FANUC <-> model joint conventions and XYZWPR <-> matrix."""

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from servo_app.robots.conventions import (
    fanuc_deg_to_model_rad,
    matrix_to_xyzwpr,
    model_rad_to_fanuc_deg,
    rot_x,
    rot_y,
    rot_z,
    xyzwpr_to_matrix,
)

angle = st.floats(-179.999, 179.999)
mm = st.floats(-3000, 3000)


def test_j23_conversion_matches_manual_definition():
    # J2 = 30, J3 (FANUC, from the horizontal) = 10 -> model q3 = J3 + J2 = 40 deg.
    q = fanuc_deg_to_model_rad([0, 30, 10, 0, 0, 0], 1.0)
    assert np.degrees(q) == pytest.approx([0, 30, 40, 0, 0, 0])
    assert model_rad_to_fanuc_deg(q, 1.0) == pytest.approx([0, 30, 10, 0, 0, 0])
    # Factor 0: a controller that already streams model-convention joints.
    assert np.degrees(fanuc_deg_to_model_rad([0, 30, 10, 0, 0, 0], 0.0)) == pytest.approx([0, 30, 10, 0, 0, 0])


def test_conversion_does_not_modify_input_and_keeps_extra_axes():
    q = np.array([1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0])
    out = model_rad_to_fanuc_deg(q, 1.0)
    assert q.tolist() == [1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0]
    assert out[6] == pytest.approx(math.degrees(7.0))


@settings(max_examples=200, deadline=None)
@given(st.lists(st.floats(-400, 400), min_size=6, max_size=6), st.sampled_from([0.0, 1.0, -1.0, 0.5]))
def test_joint_conversion_round_trip(q_deg, factor):
    back = model_rad_to_fanuc_deg(fanuc_deg_to_model_rad(q_deg, factor), factor)
    assert back == pytest.approx(q_deg, abs=1e-9)


def test_wpr_is_fixed_axes_xyz():
    w, p, r = 10.0, 20.0, 30.0
    t = xyzwpr_to_matrix([1, 2, 3, w, p, r])
    expected = rot_z(math.radians(r)) @ rot_y(math.radians(p)) @ rot_x(math.radians(w))
    assert t[:3, :3] == pytest.approx(expected, abs=1e-15)
    assert t[:3, 3] == pytest.approx([0.001, 0.002, 0.003])
    assert t[3].tolist() == [0, 0, 0, 1]


@settings(max_examples=300, deadline=None)
@given(mm, mm, mm, angle, st.floats(-89.9, 89.9), angle)
def test_xyzwpr_round_trip(x, y, z, w, p, r):
    out = matrix_to_xyzwpr(xyzwpr_to_matrix([x, y, z, w, p, r]))
    assert out[:3] == pytest.approx([x, y, z], abs=1e-9)
    assert out[3:] == pytest.approx([w, p, r], abs=1e-7)


@settings(max_examples=200, deadline=None)
@given(angle, st.sampled_from([90.0, -90.0, 89.9999999999, -89.99999999999]), angle)
def test_gimbal_lock_never_nan_and_same_rotation(w, p, r):
    t = xyzwpr_to_matrix([0, 0, 0, w, p, r])
    out = matrix_to_xyzwpr(t)
    assert np.all(np.isfinite(out))
    assert xyzwpr_to_matrix(out)[:3, :3] == pytest.approx(t[:3, :3], abs=1e-6)


def test_slightly_non_orthonormal_input_gives_no_nan():
    t = xyzwpr_to_matrix([0, 0, 0, 0, -90, 0])
    t[2, 0] = 1.0 + 1e-12  # rounding noise outside [-1, 1]
    assert np.all(np.isfinite(matrix_to_xyzwpr(t)))
