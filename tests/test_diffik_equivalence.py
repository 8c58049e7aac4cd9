"""The diff-IK that assembles its own QP (issue 15) against the one built from mink objects.

``tests/diffik_reference.py`` is the implementation before issue 15, verbatim. Both are stepped side
by side through random states and command sequences (twists in base and tool frame, pose targets,
joint jogs, stops, with and without collision rows, both QP back-ends): each cycle must give the
same increment within the solver's tolerance wherever both found one, the same flags, the same
condition number, and every limit row (the reference's rows at that state) must hold.
"""

from __future__ import annotations

import math
import sys
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from servo_app.motion.commands import Command, JointJog, PoseTarget, Twist
from servo_app.motion.diffik import LINE_BRAKE_LATE_S, DifferentialIK, IkFlag, _within_reach
from servo_app.motion.qp import QpSettings
from servo_app.robots.conventions import matrix_to_xyzwpr
from servo_app.robots.profile import load_profile

sys.path.insert(0, str(Path(__file__).parent))
from diffik_reference import DifferentialIK as ReferenceIK
from mink_rows import assert_collision_rows_equal

DT = 0.008
PROFILE = load_profile("lrmate200id")
# Increment tolerance, rad per cycle. The line, the blend and the stop are closed-form (equal to
# rounding); a QP fallback is equal within the solver's tolerance (DAQP exact, OSQP eps 1e-6 on
# velocities: 1e-6 rad/s * dt, with margin) -- where it converged: an OSQP answer at its iteration
# limit has no tolerance to compare within, and two IKs whose warm starts drifted apart (each solves
# the QP in its own cycles) stop at different iterates (hypothesis seeds 9 and 53: 1.3e-6 and 5.8e-4
# rad/cycle apart). Such an answer must still keep every limit row (checked below). Nor has an OSQP
# answer to a QP fallback near a singularity: the QP is ill-conditioned there, and OSQP stops on its
# residuals, not on the distance to the optimum; two converged answers were 2.9e-6 and 1.6e-5
# rad/cycle apart (random seeds, rarely). DAQP's exact answers to the same QPs are compared
# to rounding, and every row is checked for both solvers.
TOL = {"daqp": 1e-9, "osqp": 1e-6}
SCALE_TOL = {"daqp": 1e-6, "osqp": 1e-4}
ROW_TOL = 1e-9  # rad (or m) per cycle: a limit row "holds" within this ...
# ... or, for a QP fallback, within the violation its solver accepts, as the reference's own answer
# does: OSQP's is PersistentQP's (QpSettings.feasibility_tol); DAQP's is its primal tolerance
# (daqp.solve's primal_tol, 1e-6) in the variables it solves for, velocities (var_scale = dt), so
# 1e-6 * dt per cycle (seen: 1.4e-9 rad on a joint jog's fallback, at a row whose bound is 0).
QP_ROW_TOL = {"daqp": 1e-6 * DT, "osqp": QpSettings().feasibility_tol}


@pytest.fixture(scope="module")
def pairs() -> dict[tuple[str, bool], tuple[DifferentialIK, ReferenceIK]]:
    out = {}
    for solver in ("daqp", "osqp"):
        for collision in (True, False):
            out[(solver, collision)] = (DifferentialIK(PROFILE, DT, solver=solver, collision=collision),
                                        ReferenceIK(PROFILE, DT, solver=solver, collision=collision))
    return out


finite = {"allow_nan": False, "allow_infinity": False}
twists = st.builds(
    lambda lin, ang, frame: Twist(source="test", stamp=0.0, linear=lin, angular=ang, frame=frame),
    st.tuples(*[st.floats(-400.0, 400.0, **finite)] * 3),
    st.tuples(*[st.floats(-90.0, 90.0, **finite)] * 3),
    st.sampled_from(["base", "tool"]),
)
jogs = st.builds(lambda v: JointJog(source="test", stamp=0.0, velocity=v),
                 st.tuples(*[st.floats(-60.0, 60.0, **finite)] * 6))


@st.composite
def scenarios(draw: st.DrawFn) -> tuple[np.ndarray, np.ndarray, list[tuple[str, object, int]]]:
    lo, hi = np.asarray(PROFILE.joint_min_deg, float), np.asarray(PROFILE.joint_max_deg, float)
    u = np.array(draw(st.lists(st.floats(0.02, 0.98), min_size=6, max_size=6)))
    q0 = np.radians(lo + u * (hi - lo))
    vfrac = np.array(draw(st.lists(st.floats(-0.6, 0.6), min_size=6, max_size=6)))
    segments = draw(st.lists(
        st.tuples(st.sampled_from(["twist", "pose", "jog", "stop"]),
                  st.one_of(twists, jogs, st.tuples(*[st.floats(-40.0, 40.0, **finite)] * 6)),
                  st.integers(1, 25)),
        min_size=1, max_size=4))
    return q0, vfrac, segments


def _command(kind: str, payload: object, ik: DifferentialIK, q: np.ndarray) -> Command | None:
    if kind == "stop":
        return None
    if kind == "twist":
        return payload if isinstance(payload, Twist) else Twist(source="test", stamp=0.0, linear=(80.0, 0.0, 0.0))
    if kind == "jog":
        return payload if isinstance(payload, JointJog) else JointJog(source="test", stamp=0.0,
                                                                     velocity=(20.0, 0, 0, 0, 0, 0))
    offset = np.asarray(payload if isinstance(payload, tuple) else (10.0,) * 6, float) * [1, 1, 1, 0.3, 0.3, 0.3]
    here = matrix_to_xyzwpr(ik.kin.fk_tcp(q))
    return PoseTarget(source="test", stamp=0.0, xyzwpr=tuple(here + offset), linear_speed=200.0, angular_speed=40.0)


@pytest.mark.parametrize("solver", ["daqp", "osqp"])
@pytest.mark.parametrize("collision", [True, False])
@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(scenario=scenarios())
def test_same_increment_as_the_reference(pairs, solver: str, collision: bool, scenario) -> None:
    ik, ref = pairs[(solver, collision)]
    q0, vfrac, segments = scenario
    if ref.condition_number(q0) > 1e3:
        return  # a singular start: both refuse nothing, but the comparison says little there
    dq_prev = vfrac * ref.vel * DT
    ik.reset(q0, dq_prev)
    ref.reset(q0, dq_prev)
    q = q0.copy()
    for kind, payload, n in segments:
        cmd = _command(kind, payload, ik, q)
        for _ in range(n):
            a = ik.step(q, cmd)
            b = ref.step(q, cmd)
            assert a.mode == b.mode
            assert math.isclose(a.condition, b.condition, rel_tol=1e-9), (a.condition, b.condition)
            failed = bool(a.flags & IkFlag.SOLVER_FAILED) or bool(int(b.flags) & int(IkFlag.SOLVER_FAILED))
            unconverged = "maximum iterations" in f"{a.solver_status} {b.solver_status}"
            ill_conditioned = solver == "osqp" and bool((a.flags | int(b.flags)) & IkFlag.QP_FALLBACK) and bool(
                (a.flags | int(b.flags)) & IkFlag.NEAR_SINGULARITY)
            # OSQP on rows raised to the acceleration's reach (a corner of its box): its 1e-6 accuracy
            # moved dq by up to 5e-6 rad between the two solvers' warm starts (seeds 3, 4).
            ill_conditioned |= solver == "osqp" and "within reach" in f"{a.solver_status} {b.solver_status}"
            if not failed and not unconverged and not ill_conditioned:
                assert np.max(np.abs(a.dq - b.dq)) <= TOL[solver], (a.dq - b.dq, a.flags, b.flags)
                if bool(a.flags & IkFlag.QP_FALLBACK) == bool(int(b.flags) & int(IkFlag.QP_FALLBACK)) and \
                        solver == "daqp":
                    assert int(a.flags) == int(b.flags), (a.flags, b.flags)
                # The delivered share is dq's projection on the command: DAQP to rounding; OSQP's 1e-6
                # rad/cycle in dq moves it by up to ~1e-5 near a singularity (seeds 61, 66: 1.7e-6, 5.8e-6).
                assert math.isclose(a.scale, b.scale, rel_tol=SCALE_TOL[solver], abs_tol=SCALE_TOL[solver]), (
                    a.scale, b.scale)
            if not failed:
                # Every limit row of the reference at this state holds for the new increment (a row the
                # state has already outrun: at the hardest brake the acceleration allows, _within_reach).
                g, h = ref.inequalities()
                h = _within_reach(g, h, ref._accel_rows, ref.c_inv, ref.settings.binding_tol)
                tol = np.full(len(h), QP_ROW_TOL[solver] if a.flags & IkFlag.QP_FALLBACK else ROW_TOL)
                # A line braking for a joint bound may start a joint's own stop late (_line_past_braking).
                tol[ref._braking_rows] += np.tile(ref.acc * DT * LINE_BRAKE_LATE_S, 2)
                assert np.all(g @ a.dq <= h + tol + 1e-6 * np.abs(h)), np.max(g @ a.dq - h)
            # Both continue from the same state (the reference's increment), so one difference
            # within tolerance cannot grow over the sequence.
            ik._dq_prev = b.dq.copy()
            q = q + b.dq


def test_assembled_rows_are_the_limits_rows() -> None:
    """The rows assembled in place equal the limits' own compute_qp_inequalities, to the bit, at
    random states (collision rows switching on and off, configuration restricted or not); the
    collision rows' G to a few ulps, as the reference's BLAS sums them (mink_rows)."""
    ik = DifferentialIK(PROFILE, DT, collision=True)
    collision_row = np.concatenate([np.full(n, lim is ik.collision_limit) for lim, n in
                                    zip(ik.limits, ik._row_counts, strict=True)])
    assert collision_row.any() and not collision_row.all()
    rng = np.random.default_rng(3)
    lo, hi = np.radians(PROFILE.joint_min_deg), np.radians(PROFILE.joint_max_deg)
    for k in range(300):
        q = rng.uniform(lo * 0.95, hi * 0.95)
        if k % 3 == 0:
            ik.reset(q)
        ik.configuration.update(q)
        ik.accel_limit.set_previous(rng.uniform(-1, 1, 6) * ik.vel * DT)
        ik.path_braking.set_direction(rng.normal(size=6) if k % 4 else None)
        g, h = ik.inequalities()
        hp = ik._hp.copy()
        rows = [lim.compute_qp_inequalities(ik.configuration, DT) for lim in ik.limits]
        g_ref = np.vstack([r.G for r in rows if r.G is not None])
        h_ref = np.concatenate([r.h for r in rows if r.h is not None])
        np.testing.assert_array_equal(g[~collision_row], g_ref[~collision_row])
        assert_collision_rows_equal(g[collision_row], g_ref[collision_row])
        np.testing.assert_array_equal(h, h_ref)
        hp_ref = h_ref.copy()
        start = 0
        for lim, n in zip(ik.limits, ik._row_counts, strict=True):
            if getattr(lim, "h_path", None) is not None:
                hp_ref[start:start + n] = lim.h_path
            start += n
        np.testing.assert_allclose(hp, hp_ref, rtol=1e-12, atol=1e-15)
        # The walk jumps across the workspace: the collision cache must have refreshed for those.
        assert ik.collision_limit is not None and ik.collision_limit.refreshes > 0
