"""Closed-form IK: every branch reproduces the pose, configurations and turn numbers, degenerate poses."""

import functools
import math

import numpy as np
import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st

from servo_app.robots.configuration import ArmConfiguration, configuration_of
from servo_app.robots.kinematics import ArmKinematics
from servo_app.robots.profile import load_profile

MODELS = ["lrmate200id", "lrmate200id7l", "m10ia", "m20ia", "r2000ic165f"]
unit = st.lists(st.floats(0.0, 1.0), min_size=6, max_size=6)


@functools.cache
def _kin(name: str) -> ArmKinematics:
    return ArmKinematics(load_profile(name))


def _in_limits(kin: ArmKinematics, u: list[float]) -> np.ndarray:
    return kin.q_min + np.asarray(u) * (kin.q_max - kin.q_min)


def _assert_same_pose(a: np.ndarray, b: np.ndarray) -> None:
    assert np.abs(a[:3, 3] - b[:3, 3]).max() < 1e-9
    assert np.abs(a[:3, :3] - b[:3, :3]).max() < 1e-9


@pytest.mark.parametrize("name", MODELS)
@settings(max_examples=80, deadline=None)
@given(u=unit)
def test_every_branch_reproduces_the_pose(name, u):
    kin = _kin(name)
    q = _in_limits(kin, u)
    pose = kin.fk(q)
    sols = kin.ik(pose)
    assert 1 <= len(sols) <= 8
    branches = {(s.config.flip, s.config.up, s.config.top) for s in sols}
    assert len(branches) == len(sols)  # one solution per branch
    for s in sols:
        assert np.all(np.isfinite(s.q_model_rad))
        assert np.all(np.abs(s.q_model_rad[[0, 3, 5]]) <= math.pi + 1e-12)  # turn 0 for J1, J4, J6
        _assert_same_pose(kin.fk(s.q_model_rad), pose)
        assert s.config == configuration_of(s.q_model_rad, kin)
        assert s.within_limits == kin.within_limits(s.q_model_rad)
    # The generating configuration is among the solutions (up to turn numbers).
    cfg = configuration_of(q, kin)
    assert any(s.config.same_branch(cfg) for s in sols)


@pytest.mark.parametrize("name", MODELS)
@settings(max_examples=60, deadline=None)
@given(u=unit)
def test_nearest_with_requested_configuration(name, u):
    kin = _kin(name)
    q = _in_limits(kin, u)
    pose = kin.fk(q)
    cfg = configuration_of(q, kin)
    found = kin.ik_nearest(pose, q, cfg)
    assume(found is not None)  # only when q sits on a wrist/elbow singularity (measure zero)
    assert found == pytest.approx(q, abs=1e-7)
    # Every other in-limits configuration, asked for by name, comes back with that configuration
    # (same seed for both calls: at a wrist singularity J4 is taken from it).
    for s in kin.ik(pose, with_turns=True, within_limits=True, seed=q):
        got = kin.ik_nearest(pose, q, s.config)
        assert got is not None
        assert configuration_of(got, kin) == s.config
        _assert_same_pose(kin.fk(got), pose)


def test_generic_pose_has_eight_solutions():
    kin = _kin("lrmate200id")
    pose = kin.fk(np.radians([20, 10, 30, 40, -60, 50]))
    sols = kin.ik(pose)
    assert len(sols) == 8
    assert {str(s.config)[:5] for s in sols} == {f"{f} {u} {t}" for f in "NF" for u in "UD" for t in "TB"}


def test_turn_variants_of_big_wrist_ranges():
    kin = _kin("r2000ic165f")  # J1 +-185, J4 and J6 +-360
    q = np.radians([178.0, 10.0, 20.0, 100.0, -40.0, -150.0])
    pose = kin.fk(q)
    variants = [s for s in kin.ik(pose, with_turns=True, within_limits=True)
                if s.config.same_branch(configuration_of(q, kin))]
    turns = {(s.config.turn1, s.config.turn4, s.config.turn6) for s in variants}
    assert turns == {(t1, t4, t6) for t1 in (0, -1) for t4 in (0, -1) for t6 in (0, 1)}
    for s in variants:
        assert s.within_limits
        _assert_same_pose(kin.fk(s.q_model_rad), pose)
    want = ArmConfiguration(flip=False, up=True, top=True, turn1=-1, turn4=-1, turn6=1)
    got = kin.ik_nearest(pose, q, want)
    assert got is not None
    assert np.degrees(got) == pytest.approx([178 - 360, 10, 20, 100 - 360, -40, -150 + 360], abs=1e-7)


def test_j3_range_beyond_180_uses_the_in_range_copy():
    kin = _kin("m10ia")  # J3 -180 .. 264
    q = np.radians([0.0, 30.0, 200.0, 0.0, -30.0, 0.0])
    got = kin.ik_nearest(kin.fk(q), q)
    assert got is not None
    assert np.degrees(got) == pytest.approx(np.degrees(q), abs=1e-7)


@pytest.mark.parametrize("name", MODELS)
def test_unreachable_pose_gives_nothing(name):
    kin = _kin(name)
    far = np.eye(4)
    far[:3, 3] = (10.0, 0.0, 0.0)
    assert kin.ik(far) == []
    assert kin.ik_nearest(far, np.zeros(6)) is None
    bad = np.full((4, 4), np.nan)
    assert kin.ik(bad) == []
    assert kin.ik(np.eye(3)) == []


def test_just_beyond_full_stretch_is_unreachable_not_nan():
    kin = _kin("lrmate200id")
    psi = math.atan2(kin.a3, kin.d4)
    stretched = kin.fk([0.2, 0.3, math.pi / 2 - psi, 0.1, -0.5, 0.2])
    sols = kin.ik(stretched)
    assert sols and all(np.all(np.isfinite(s.q_model_rad)) for s in sols)
    for s in sols:
        _assert_same_pose(kin.fk(s.q_model_rad), stretched)
    assert any(s.singular for s in sols)
    beyond = stretched.copy()
    beyond[:3, 3] *= 1.001
    assert all(np.all(np.isfinite(s.q_model_rad)) for s in kin.ik(beyond))
    assert not any(s.config.top for s in kin.ik(beyond))


def test_wrist_singularity_keeps_seed_j4():
    kin = _kin("lrmate200id")
    q = np.array([0.1, 0.2, 0.3, 0.0, 0.0, 0.5])  # J5 = 0: only J4 + J6 is defined
    pose = kin.fk(q)
    sols = kin.ik(pose)
    assert all(np.all(np.isfinite(s.q_model_rad)) for s in sols)
    assert any(s.singular for s in sols)
    seed = np.array([0.1, 0.2, 0.3, 0.3, 0.0, 0.2])
    got = kin.ik_nearest(pose, seed)
    assert got is not None
    assert got[3] == pytest.approx(0.3)
    assert got[5] == pytest.approx(0.2)
    _assert_same_pose(kin.fk(got), pose)


def test_shoulder_singularity_keeps_seed_j1():
    kin = _kin("lrmate200id")
    pose = np.eye(4)
    # Identity rotation: tool z points up, so the wrist centre is d6 below the flange.
    pose[:3, 3] = (0.0, 0.0, 0.3 + kin.d6)  # wrist centre on the J1 axis
    sols = kin.ik(pose, seed=[0.7, 0, 0, 0, 0, 0])
    assert sols
    for s in sols:
        assert np.all(np.isfinite(s.q_model_rad))
        assert s.singular
        _assert_same_pose(kin.fk(s.q_model_rad), pose)
    assert any(s.q_model_rad[0] == pytest.approx(0.7) for s in sols)
