"""The persistent QP solves exactly mink's diff-IK problem, with a fixed pattern and safe failure."""

from __future__ import annotations

import warnings

import mink
import numpy as np
import pytest

from servo_app.motion.diffik import DifferentialIK
from servo_app.motion.qp import PersistentQP, QpSettings
from servo_app.robots.profile import load_profile

DT = 0.008
# Velocity units (rad/s; the QP's increments are ~1e-3 rad per cycle): OSQP stops at eps 1e-6 on a
# problem scaled to velocities, DAQP is exact up to rounding.
TOL = {"osqp": 1e-4, "daqp": 1e-7}


@pytest.fixture(scope="module")
def ik() -> DifferentialIK:
    # Collision rows on: they switch between inactive (G = 0, h = inf) and active with the state.
    return DifferentialIK(load_profile("lrmate200id"), DT, collision=True)


def random_states(ik: DifferentialIK, n: int, seed: int):
    """Teleop-like states: a pose, last cycle's increment, a commanded TCP twist; yields mink inputs."""
    rng = np.random.default_rng(seed)
    lo, hi = np.radians(ik.profile.joint_min_deg), np.radians(ik.profile.joint_max_deg)
    made = 0
    while made < n:
        q = rng.uniform(lo * 0.85, hi * 0.85)
        if ik.condition_number(q) > 80.0:
            continue
        ik.reset(q)
        ik.configuration.update(q)
        dq_prev = rng.uniform(-1.0, 1.0, 6) * ik.vel * DT * rng.uniform(0.0, 0.8)
        ik.accel_limit.set_previous(dq_prev)
        tcp = ik.configuration.get_transform_frame_to_world(ik.site, "site")
        xi = np.concatenate([rng.normal(size=3) * rng.uniform(0.0, 1.0), rng.normal(size=3) * rng.uniform(0.0, 2.0)])
        target = tcp @ mink.SE3.exp(xi * DT)
        ik.frame_task.set_target(target)
        tasks = [ik.frame_task, ik.posture_task]
        p, c = ik.objective(tasks)
        ik.path_braking.set_direction(np.linalg.solve(p, -c))
        made += 1
        yield tasks


def mink_solution(ik: DifferentialIK, tasks, solver: str) -> np.ndarray | None:
    kwargs = {"eps_abs": 1e-11, "eps_rel": 1e-11, "max_iter": 200_000, "polishing": True} if solver == "osqp" else {}
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            v = mink.solve_ik(ik.configuration, tasks, DT, solver, damping=ik.settings.damping,
                              limits=ik.limits, **kwargs)
    except mink.NoSolutionFound:
        return None
    return v * DT


@pytest.mark.parametrize("backend", ["osqp", "daqp"])
@pytest.mark.parametrize("reference", ["daqp", "osqp"])
def test_persistent_solution_matches_mink_solve_ik(ik: DifferentialIK, backend: str, reference: str) -> None:
    qp: PersistentQP | None = None
    compared = binding = 0
    worst = 0.0
    for tasks in random_states(ik, 70, seed=7):
        p, c = ik.objective(tasks)
        g, h = ik.inequalities()
        if qp is None:  # ONE instance for every state: the pattern must survive rows switching on and off
            qp = PersistentQP(6, g.shape[0], backend, var_scale=DT)
        ours = qp.solve(p, c, g, h)
        ref = mink_solution(ik, tasks, reference)
        if ref is None:
            assert not ours.ok or float(np.max(g @ ours.x - h)) <= 1e-6
            continue
        assert ours.ok, ours.status
        compared += 1
        binding += bool(np.any(g @ ref >= h - 1e-9))
        worst = max(worst, float(np.max(np.abs(ours.x - ref))) / DT)
    assert compared >= 40
    assert binding >= 20  # the comparison covers states with active limits, not just free solves
    assert worst <= TOL[backend] + (TOL["osqp"] if reference == "osqp" else 0.0), worst


def test_fixed_pattern_survives_zero_rows_and_infinite_bounds() -> None:
    qp = PersistentQP(2, 2, "osqp")
    p = np.eye(2)
    q = np.array([-1.0, -1.0])
    first = qp.solve(p, q, np.zeros((2, 2)), np.array([np.inf, np.inf]))  # set up with all-zero rows
    assert first.ok and np.allclose(first.x, [1.0, 1.0], atol=1e-5)
    second = qp.solve(2.0 * p, q, np.array([[1.0, 0.0], [0.0, 1.0]]), np.array([0.2, np.inf]))
    assert second.ok and np.allclose(second.x, [0.2, 0.5], atol=1e-5)
    third = qp.solve(p, q, np.array([[1.0, 1.0], [0.0, 0.0]]), np.array([1.0, np.inf]))
    assert third.ok and np.allclose(third.x, [0.5, 0.5], atol=1e-5)


@pytest.mark.parametrize("backend", ["osqp", "daqp"])
def test_failure_returns_zero_and_a_status_never_nan(backend: str) -> None:
    qp = PersistentQP(2, 2, backend, settings=QpSettings(max_iter=400))
    infeasible = qp.solve(np.eye(2), np.zeros(2), np.array([[1.0, 0.0], [-1.0, 0.0]]), np.array([-1.0, -1.0]))
    assert not infeasible.ok and np.array_equal(infeasible.x, np.zeros(2)) and infeasible.status
    bad = qp.solve(np.eye(2), np.array([np.nan, 0.0]), np.zeros((2, 2)), np.ones(2))
    assert not bad.ok and np.array_equal(bad.x, np.zeros(2))
    ok = qp.solve(np.eye(2), np.array([-1.0, 0.0]), np.array([[1.0, 0.0], [0.0, 1.0]]), np.array([0.5, 1.0]))
    assert ok.ok and np.allclose(ok.x, [0.5, 0.0], atol=1e-5)  # usable again after failures
    assert qp.failures == 2 and qp.solves == 3


def test_shape_and_solver_are_checked() -> None:
    with pytest.raises(ValueError, match="solver"):
        PersistentQP(6, 4, "quadprog")  # type: ignore[arg-type]
    qp = PersistentQP(2, 1)
    with pytest.raises(ValueError, match="do not match"):
        qp.solve(np.eye(2), np.zeros(2), np.zeros((2, 2)), np.zeros(2))
