"""The compiled collision, Jacobian, limit-row and QP-data kernels of the IK (servo_app.motion.ik_kernels)
against MuJoCo, mink and numpy on random arm states: Jacobians and rows to the bit, distances within
rounding, and the collision screen never ruling out a pair the narrow phase finds within reach."""

from __future__ import annotations

import math
import sys
from pathlib import Path

import mujoco
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays
from mink.limits.collision_avoidance_limit import compute_contact_normal_jacobian

from servo_app.motion import ik_kernels as k
from servo_app.motion.diffik import DifferentialIK
from servo_app.motion.ik_limits import CollisionLimit, _geom_shapes, default_collision_pairs, jacobian_tree
from servo_app.robots.model import load_spec
from servo_app.robots.profile import load_profile

sys.path.insert(0, str(Path(__file__).parent))
from mink_rows import assert_collision_rows_equal

PROFILE = load_profile("lrmate200id")
DT = 0.008
IK = DifferentialIK(PROFILE, DT, collision=True)
MODEL = IK.model
unit = st.floats(0.0, 1.0)
joints = arrays(np.float64, 6, elements=unit)


def _pose(data: mujoco.MjData, u: np.ndarray) -> np.ndarray:
    lo, hi = np.radians(PROFILE.joint_min_deg), np.radians(PROFILE.joint_max_deg)
    q = lo + u * (hi - lo)
    data.qpos[:] = q
    mujoco.mj_kinematics(MODEL, data)
    mujoco.mj_comPos(MODEL, data)
    return q


@settings(max_examples=200, deadline=None)
@given(u=joints, point=arrays(np.float64, 3, elements=st.floats(-1.5, 1.5)), body=st.integers(0, MODEL.nbody - 1))
def test_point_jacobian_is_mj_jac_to_the_bit(u: np.ndarray, point: np.ndarray, body: int) -> None:
    data = mujoco.MjData(MODEL)
    _pose(data, u)
    tree, dof_parentid = jacobian_tree(MODEL)
    ours, ref = np.full((3, MODEL.nv), np.nan), np.zeros((3, MODEL.nv))
    k.point_jacobian(ours, data.cdof, data.subtree_com, tree, dof_parentid, point, body)
    mujoco.mj_jac(MODEL, data, ref, None, point, body)
    np.testing.assert_array_equal(ours, ref)


@settings(max_examples=100, deadline=None)
@given(u=joints)
def test_site_objective_is_mj_jac_site_and_the_cartesian_objective(u: np.ndarray) -> None:
    data = mujoco.MjData(MODEL)
    q = _pose(data, u)
    tree, dof_parentid = jacobian_tree(MODEL)
    site = IK._site_id
    target = np.array([1.0, 0.0, 0.0, 0.0, 0.3, 0.1, 0.5])
    args = (target, target, False, np.ones(6), 1.0, np.full(6, 0.03), 0.1, q * 0.9, q, 1e-8, 0.25)
    jac = np.zeros((6, MODEL.nv))
    out = [np.zeros((6, 6)), np.zeros(6), np.zeros(6), np.zeros((6, 6)), np.zeros((2, 6))]  # p, c, c_frame, wjac, d
    ok = k.site_objective(data.cdof, data.subtree_com, tree, dof_parentid, int(MODEL.site_bodyid[site]),
                          data.site_xmat, data.site_xpos, site, jac, *args, *out)
    ref_jac = np.zeros((6, MODEL.nv))
    mujoco.mj_jacSite(MODEL, data, ref_jac[:3], ref_jac[3:], site)
    np.testing.assert_array_equal(jac, ref_jac)
    ref = [np.zeros((6, 6)), np.zeros(6), np.zeros(6), np.zeros((6, 6)), np.zeros((2, 6))]
    ok_ref = k.cartesian_objective(data.site_xmat[site], data.site_xpos[site], ref_jac, *args, *ref)
    assert ok == ok_ref
    for a, b in zip(out, ref, strict=True):
        np.testing.assert_array_equal(a, b)


def _screen(model: mujoco.MjModel, data: mujoco.MjData, limit: CollisionLimit, distmax: float, tol: float
            ) -> tuple[np.ndarray, list[int]]:
    n = limit.max_num_contacts
    lower, cand = np.zeros(n), np.zeros(n, dtype=np.int64)
    g, h, hp = np.ones((n, model.nv)), np.zeros(n), np.zeros(n)
    shape, radius, half = _geom_shapes(model)
    pairs = np.array(limit.geom_id_pairs, dtype=np.int64)
    count = k.collision_screen(shape, radius, half, np.ascontiguousarray(model.geom_rbound), pairs[:, 0].copy(),
                               pairs[:, 1].copy(), limit._exact, data.geom_xpos, data.geom_xmat, tol, distmax,
                               lower, cand, g, h, hp)
    # Every row reset to inactive for the rows kernel to fill.
    assert not g.any() and np.all(h == math.inf) and np.all(hp == math.inf)
    return lower, cand[:count].tolist()


@settings(max_examples=300, deadline=None)
@given(u=joints)
def test_collision_screen_bounds_the_narrow_phase_and_keeps_every_pair_within_reach(u: np.ndarray) -> None:
    data = mujoco.MjData(MODEL)
    _pose(data, u)
    limit = IK.collision_limit
    assert limit is not None and limit._exact.all()  # the arm's capsules and the floor: all known exactly
    distmax, tol = limit.collision_detection_distance, limit.screen_tolerance
    lower, cand = _screen(MODEL, data, limit, distmax, tol)
    fromto = np.zeros(6)
    for i, (g1, g2) in enumerate(limit.geom_id_pairs):
        far = mujoco.mj_geomDistance(MODEL, data, g1, g2, 10.0, fromto)
        if far > 0.0:  # apart: the closed form is the distance (penetration depths are measured otherwise)
            assert abs(lower[i] + tol - far) < 1e-9, (i, lower[i] + tol, far)
        reach = mujoco.mj_geomDistance(MODEL, data, g1, g2, distmax, fromto)
        if abs(reach - distmax) >= 1e-12:  # the reference makes a row: the screen must name the pair
            assert i in cand
        assert (i in cand) == (lower[i] <= distmax)


def test_pairs_of_other_shapes_keep_the_cache_and_give_the_references_rows() -> None:
    """A box fixture in the cell: its pairs are not known in closed form, so the drift cache screens
    them (refreshing as the arm sweeps past); the rows still equal mink's (h to the bit, G as mink_rows says)."""
    spec = load_spec(PROFILE)
    spec.worldbody.add_geom(name="fixture", type=mujoco.mjtGeom.mjGEOM_BOX, size=[0.08, 0.08, 0.15],
                            pos=[0.35, 0.0, 0.15])
    model = spec.compile()
    ik = DifferentialIK(PROFILE, DT, collision=True, model=model,
                        collision_pairs=default_collision_pairs(model))
    limit = ik.collision_limit
    assert limit is not None and not limit._exact.all() and limit._exact.any()
    rng = np.random.default_rng(7)
    lo, hi = np.radians(PROFILE.joint_min_deg), np.radians(PROFILE.joint_max_deg)
    q = rng.uniform(lo * 0.5, hi * 0.5)
    active = 0
    for step in range(400):
        q = q + rng.normal(scale=0.05, size=6) if step % 50 else rng.uniform(lo * 0.6, hi * 0.6)
        q = np.clip(q, lo, hi)
        ik.configuration.update(q)
        ik.path_braking.set_direction(rng.normal(size=6) if step % 3 else None)
        n = limit.max_num_contacts
        g, h, hp = np.zeros((n, model.nv)), np.full(n, math.inf), np.full(n, math.inf)
        limit.fill(ik.configuration.data, q, DT, g, h, hp)
        ref = limit.compute_qp_inequalities(ik.configuration, DT)
        assert_collision_rows_equal(g, ref.G)
        np.testing.assert_array_equal(h, ref.h)
        np.testing.assert_allclose(hp, limit.h_path, rtol=1e-12, atol=1e-15)
        active += int(np.isfinite(h[~limit._exact]).sum())
    assert limit.refreshes > 1  # the cache followed the jumps
    assert active > 0  # the fixture's rows were exercised, not only skipped


@settings(max_examples=100, deadline=None)
@given(u=joints, direction=arrays(np.float64, 6, elements=st.floats(-1.0, 1.0)), with_path=st.booleans())
def test_collision_rows_are_minks_rows(u: np.ndarray, direction: np.ndarray, with_path: bool) -> None:
    data = mujoco.MjData(MODEL)
    _pose(data, u)
    limit = IK.collision_limit
    assert limit is not None
    tree, dof_parentid = jacobian_tree(MODEL)
    n = limit.max_num_contacts
    fromtos, dists = np.zeros((n, 6)), np.zeros(n)
    pairs = np.arange(n, dtype=np.int64)
    for i, (g1, g2) in enumerate(limit.geom_id_pairs):
        dists[i] = mujoco.mj_geomDistance(MODEL, data, g1, g2, 10.0, fromtos[i])
    b1 = np.array([MODEL.geom_bodyid[a] for a, _ in limit.geom_id_pairs], dtype=np.int64)
    b2 = np.array([MODEL.geom_bodyid[b] for _, b in limit.geom_id_pairs], dtype=np.int64)
    g, h, hp = np.zeros((n, MODEL.nv)), np.zeros(n), np.zeros(n)
    gain, min_dist, relax, brake, lag, rate, floor = 0.85, 0.01, 0.0, 3.0, 0.02, 40.0, 0.05
    k.collision_rows(n, pairs, dists, fromtos, data.cdof, data.subtree_com, tree, dof_parentid, b1, b2,
                     np.zeros((3, MODEL.nv)), np.zeros((3, MODEL.nv)), gain, min_dist, relax, brake, DT, DT + lag,
                     with_path, direction, rate, floor, g, h, hp)
    jac1, jac2, normal = np.zeros((3, MODEL.nv)), np.zeros((3, MODEL.nv)), np.zeros(3)
    for i, (g1, g2) in enumerate(limit.geom_id_pairs):
        row = compute_contact_normal_jacobian(MODEL, data, g1, g2, fromtos[i], normal, jac1, jac2)
        assert_collision_rows_equal(g[i], (-1.0 if dists[i] >= 0 else 1.0) * row)
        h0 = gain * (dists[i] - min_dist) + relax if dists[i] > min_dist else relax
        gap = max((h0 - relax) / gain, 0.0)
        speed = brake * (math.sqrt((DT + lag) ** 2 + 2.0 * gap / brake) - (DT + lag))
        assert h[i] == min(h0, DT * speed + relax)
        if with_path:
            acc = min(brake, max(rate * abs(float(g[i] @ direction)), floor * brake))
            speed = acc * (math.sqrt((DT + lag) ** 2 + 2.0 * gap / acc) - (DT + lag))
            assert math.isclose(hp[i], min(h0, DT * speed + relax), rel_tol=1e-12, abs_tol=1e-15)
        else:
            assert hp[i] == h0


@settings(max_examples=100, deadline=None)
@given(u=joints, prev=arrays(np.float64, 6, elements=st.floats(-1.0, 1.0)),
       direction=arrays(np.float64, 6, elements=st.floats(-1.0, 1.0)), with_path=st.booleans(),
       restrict=st.booleans())
def test_limit_rows_are_the_limits_own_rows(u: np.ndarray, prev: np.ndarray, direction: np.ndarray, with_path: bool,
                                            restrict: bool) -> None:
    ik = DifferentialIK(PROFILE, DT)
    lo, hi = np.radians(PROFILE.joint_min_deg), np.radians(PROFILE.joint_max_deg)
    q = lo + (0.05 + 0.9 * u) * (hi - lo)
    ik.reset(q if restrict else 0.5 * (lo + hi))  # the configuration latched here, or elsewhere
    ik.configuration.update(q)
    ik.accel_limit.set_previous(prev * ik.vel * DT)
    ik.path_braking.set_direction(direction if with_path and direction.any() else None)
    g, h = ik.inequalities()
    hp = ik._hp.copy()
    rows = [lim.compute_qp_inequalities(ik.configuration, DT) for lim in ik.limits]
    np.testing.assert_array_equal(g, np.vstack([r.G for r in rows]))
    np.testing.assert_array_equal(h, np.concatenate([r.h for r in rows]))
    start, hp_ref = 0, np.concatenate([r.h for r in rows])
    for lim, n in zip(ik.limits, ik._row_counts, strict=True):
        if getattr(lim, "h_path", None) is not None:
            hp_ref[start:start + n] = lim.h_path
        start += n
    np.testing.assert_allclose(hp, hp_ref, rtol=1e-12, atol=1e-15)


@given(p=arrays(np.float64, (6, 6), elements=st.floats(-3, 3)), q=arrays(np.float64, 6, elements=st.floats(-3, 3)),
       g=arrays(np.float64, (5, 6), elements=st.floats(-3, 3)),
       h=arrays(np.float64, 5, elements=st.one_of(st.floats(-3, 3), st.just(math.inf), st.just(-math.inf))),
       bad=st.sampled_from(["none", "p", "q", "g", "h"]), scale=st.sampled_from([0.004, 0.008, 1.0]))
def test_scaled_qp_data_matches_numpy(p, q, g, h, bad: str, scale: float) -> None:
    if bad != "none":
        {"p": p, "q": q, "g": g, "h": h}[bad].flat[0] = math.nan
    qs, hs = np.zeros(6), np.zeros(5)
    ok = k.scaled_qp_data(p, q, g, h, scale, 1e30, qs, hs)
    q_ref, h_ref = q / scale, np.minimum(h / scale, 1e30)
    expected = bool(np.isfinite(p).all() and np.isfinite(q_ref).all() and np.isfinite(g).all()
                    and not np.isnan(h_ref).any())
    assert ok == expected
    if ok:
        np.testing.assert_array_equal(qs, q_ref)
        np.testing.assert_array_equal(hs, h_ref)


@pytest.mark.parametrize("kind", ["capsule", "sphere"])
def test_segment_distance_of_capsules_and_spheres(kind: str) -> None:
    """The closed forms on two free geoms placed at random: the narrow phase's distance when apart."""
    spec = mujoco.MjSpec()
    size = [0.05, 0.2, 0] if kind == "capsule" else [0.07, 0, 0]
    gtype = mujoco.mjtGeom.mjGEOM_CAPSULE if kind == "capsule" else mujoco.mjtGeom.mjGEOM_SPHERE
    for name in ("a", "b"):
        body = spec.worldbody.add_body(name=name)
        body.add_freejoint()
        body.add_geom(name=name, type=gtype, size=size)
    spec.worldbody.add_geom(name="plane", type=mujoco.mjtGeom.mjGEOM_PLANE, size=[1, 1, 0.1])
    model = spec.compile()
    data = mujoco.MjData(model)
    shape, radius, half = _geom_shapes(model)
    rng = np.random.default_rng(5)
    fromto = np.zeros(6)
    for _ in range(500):
        for b in (0, 1):
            data.qpos[7 * b: 7 * b + 3] = rng.uniform(-0.4, 0.4, 3) + np.array([0.0, 0.0, 0.5])
            quat = rng.normal(size=4)
            data.qpos[7 * b + 3: 7 * b + 7] = quat / np.linalg.norm(quat)
        mujoco.mj_kinematics(model, data)
        a, b, plane = model.geom("a").id, model.geom("b").id, model.geom("plane").id
        ref = mujoco.mj_geomDistance(model, data, a, b, 10.0, fromto)
        ours = k.segment_distance(data.geom_xpos, data.geom_xmat, a, half[a], b, half[b]) - radius[a] - radius[b]
        if ref > 0.0:
            assert abs(ours - ref) < 1e-9
        ref = mujoco.mj_geomDistance(model, data, plane, a, 10.0, fromto)
        ours = k.plane_segment_distance(data.geom_xpos, data.geom_xmat, plane, a, half[a]) - radius[a]
        if ref > 0.0:
            assert abs(ours - ref) < 1e-9
    assert shape[model.geom("a").id] == k.SHAPE_SEGMENT and shape[model.geom("plane").id] == k.SHAPE_PLANE
