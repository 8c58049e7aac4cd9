"""GET /api/robot's drawing data (each backend's view: servo_app.fanuc.view, servo_app.janome.view): the
points agree with the kinematics."""

from __future__ import annotations

import math

import numpy as np
import pytest

from servo_app.fanuc.view import fanuc_view
from servo_app.janome.profile import load_janome_profile
from servo_app.janome.view import janome_view
from servo_app.robots.kinematics import ArmKinematics
from servo_app.robots.profile import available_profiles, load_profile


def _points(view: dict) -> dict[str, np.ndarray]:
    return {p["name"]: np.array(p["xyz_mm"]) for p in view["points"]}


@pytest.mark.parametrize("model", available_profiles())
def test_fanuc_points_follow_fk(model: str) -> None:
    profile = load_profile(model)
    kin = ArmKinematics(profile)
    q = [30.0, -20.0, 15.0, 40.0, -60.0, 90.0]
    view = fanuc_view(profile, q)
    pts = _points(view)
    assert view["backend"] == "fanuc" and [a["name"] for a in view["axes"]] == [f"J{i}" for i in range(1, 7)]
    np.testing.assert_allclose(pts["flange"], kin.fk_fanuc_deg(q)[:3, 3] * 1000.0, atol=1e-9)
    np.testing.assert_allclose(view["points"][-1]["approach"], kin.fk_fanuc_deg(q)[:3, 2], atol=1e-12)
    d = profile.dims
    # Link lengths are the profile's, whatever the joints: upper arm a2, forearm offset a3 then d4.
    assert np.linalg.norm(pts["J3"] - pts["J2"]) == pytest.approx(d.a2 * 1000.0)
    assert np.linalg.norm(pts["J4"] - pts["J3"]) == pytest.approx(d.a3 * 1000.0)
    assert np.linalg.norm(pts["J5"] - pts["J4"]) == pytest.approx(d.d4 * 1000.0)
    assert np.linalg.norm(pts["flange"] - pts["J5"]) == pytest.approx(d.d6 * 1000.0)
    # J3 (FANUC, from the horizontal) becomes J3 + J2 in the model convention the ranges use.
    assert view["q_model_deg"][2] == pytest.approx(15.0 + profile.j23_factor * -20.0)


def test_fanuc_zero_pose_is_the_profile_drawing() -> None:
    profile = load_profile("lrmate200id")
    d = profile.dims
    pts = _points(fanuc_view(profile, [0.0] * 6))
    np.testing.assert_allclose(pts["base"], [0, 0, -d.d1 * 1000])
    np.testing.assert_allclose(pts["flange"], [(d.a1 + d.d4 + d.d6) * 1000, 0, (d.a2 + d.a3) * 1000], atol=1e-9)


def test_janome_cartesian_tool_is_the_position() -> None:
    profile = load_janome_profile("jr3000")
    view = janome_view(profile, [150.0, 160.0, 50.0, 10.0, 0.0, 0.0])
    assert view["backend"] == "janome" and view["kind"] == "cartesian"
    assert [a["name"] for a in view["axes"]] == ["X", "Y", "Z", "R"]
    np.testing.assert_allclose(_points(view)["tool"], [150.0, 160.0, 50.0])


def test_janome_scara_elbow_on_the_first_arm() -> None:
    profile = load_janome_profile("js3")
    assert profile.arm is not None
    x, y, z = 200.0, 150.0, 50.0  # the profile's home: J1 = 0, J2 = +90
    pts = _points(janome_view(profile, [x, y, z, 0.0]))
    assert janome_view(profile, [x, y, z, 0.0])["kind"] == "scara"
    assert np.linalg.norm(pts["J2"][:2]) == pytest.approx(profile.arm.l1)
    assert math.dist(pts["J2"][:2], (x, y)) == pytest.approx(profile.arm.l2)
    np.testing.assert_allclose(pts["tool"], [x, y, z])
