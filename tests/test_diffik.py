"""Differential IK: commanded motion, path keeping, limits, configuration, singularities, collisions."""

from __future__ import annotations

import itertools
import math
from collections.abc import Callable

import mujoco
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from servo_app.motion import diffik as diffik_module
from servo_app.motion.commands import Command, JointJog, JointTarget, PoseTarget, Twist
from servo_app.motion.diffik import DifferentialIK, IkFlag, IkResult, IkSettings
from servo_app.motion.qp import QpSolution
from servo_app.robots.configuration import configuration_of, wrist_centre_offset
from servo_app.robots.conventions import matrix_to_xyzwpr, model_rad_to_fanuc_deg, xyzwpr_to_matrix
from servo_app.robots.kinematics import ArmKinematics
from servo_app.robots.profile import load_profile


def rotation_vector(r: np.ndarray) -> np.ndarray:
    return Rotation.from_matrix(r).as_rotvec()


PROFILE = load_profile("lrmate200id")
KIN = ArmKinematics(PROFILE)
DT = 0.008
HOME = np.radians([0.0, 0.0, 0.0, 0.0, -90.0, 0.0])  # tool pointing down, N U T
LO, HI = np.radians(PROFILE.joint_min_deg), np.radians(PROFILE.joint_max_deg)


def twist(linear=(0.0, 0.0, 0.0), angular=(0.0, 0.0, 0.0), frame="base") -> Twist:
    return Twist(linear=linear, angular=angular, frame=frame, source="test", stamp=0.0)


def run(ik: DifferentialIK, q: np.ndarray, command: Command | Callable[[int], Command | None] | None, n: int
        ) -> tuple[np.ndarray, list[IkResult], list[np.ndarray]]:
    """n cycles; returns the final q, the results and the joint positions (q0 first)."""
    results, qs = [], [q]
    for k in range(n):
        cmd = command(k) if callable(command) else command
        r = ik.step(q, cmd)
        q = r.q_next
        results.append(r)
        qs.append(q)
    return q, results, qs


def angle_deg(a: np.ndarray, b: np.ndarray) -> float:
    c = float(a @ b) / (float(np.linalg.norm(a)) * float(np.linalg.norm(b)))
    return math.degrees(math.acos(min(1.0, max(-1.0, c))))


def new_ik(**kwargs) -> DifferentialIK:
    return DifferentialIK(PROFILE, DT, **kwargs)


def rates(ik: DifferentialIK, qs: list[np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """FANUC-convention joint velocity and acceleration by finite differences (as the controller)."""
    v = np.array([ik.c @ (b - a) / DT for a, b in itertools.pairwise(qs)])
    a = np.diff(np.vstack([np.zeros(6), v]), axis=0) / DT
    return v, a


# ------------------------------------------------------------------------------- commanded motion
@pytest.mark.parametrize(
    ("linear", "angular"),
    [((200.0, 0.0, 0.0), (0.0, 0.0, 0.0)), ((0.0, -150.0, 80.0), (0.0, 0.0, 0.0)),
     ((-120.0, 60.0, -90.0), (0.0, 0.0, 0.0)), ((100.0, 0.0, 0.0), (20.0, 0.0, -30.0))],
)
def test_twist_moves_tcp_in_direction_at_speed_after_ramp(linear, angular) -> None:
    ik = new_ik()
    ik.reset(HOME)
    _, results, qs = run(ik, HOME, twist(linear, angular), 60)
    v_cmd = np.array(linear)
    for k, (a, b) in enumerate(itertools.pairwise(qs)):
        dp = (KIN.fk(b)[:3, 3] - KIN.fk(a)[:3, 3]) * 1000.0
        assert angle_deg(dp, v_cmd) < 0.3, k  # also during the ramp: the whole increment is scaled
    for a, b in zip(qs[-20:-1], qs[-19:], strict=True):
        ta, tb = KIN.fk(a), KIN.fk(b)
        assert np.allclose((tb[:3, 3] - ta[:3, 3]) * 1000.0 / DT, v_cmd, rtol=0, atol=0.5)
        w = np.degrees(rotation_vector(tb[:3, :3] @ ta[:3, :3].T)) / DT
        assert np.allclose(w, angular, atol=0.1)
    assert results[0].flags & IkFlag.ACCEL_LIMIT and results[0].scale < 1.0  # a ramp, not a step
    assert results[-1].scale == pytest.approx(1.0) and not results[-1].limit_binding


def test_tool_frame_twist_and_rotation_about_the_tcp() -> None:
    tool = (0.0, 0.0, 100.0, 0.0, 0.0, 0.0)  # a 100 mm tool along the flange z (pointing down at HOME)
    ik = new_ik(tool_xyzwpr=tool)
    kin = ArmKinematics(PROFILE, tool)
    ik.reset(HOME)
    _, _, qs = run(ik, HOME, twist((0.0, 0.0, 100.0), frame="tool"), 40)  # along the tool: down
    dp = (kin.fk_tcp(qs[-1])[:3, 3] - kin.fk_tcp(qs[-2])[:3, 3]) * 1000.0 / DT
    assert np.allclose(dp, [0.0, 0.0, -100.0], atol=0.3)
    ik.reset(qs[-1])
    start = kin.fk_tcp(qs[-1])
    _, _, qs2 = run(ik, qs[-1], twist(angular=(0.0, 0.0, 45.0), frame="tool"), 60)
    end = kin.fk_tcp(qs2[-1])
    assert np.linalg.norm(end[:3, 3] - start[:3, 3]) * 1000.0 < 0.05  # the TCP stays put
    turned = rotation_vector(start[:3, :3].T @ end[:3, :3])  # in the tool frame
    assert abs(math.degrees(turned[2])) > 15.0 and abs(turned[0]) + abs(turned[1]) < 1e-4


def test_velocity_limit_scales_the_whole_increment_and_keeps_the_direction() -> None:
    ik = new_ik(settings=IkSettings(vel_fraction=0.1))  # J1 may only turn at 45 deg/s here
    ik.reset(HOME)
    v_cmd = np.array([150.0, 500.0, -100.0])
    _, results, qs = run(ik, HOME, twist(tuple(v_cmd)), 80)
    assert any(r.flags & IkFlag.VELOCITY_LIMIT for r in results[-20:])
    for a, b in itertools.pairwise(qs):
        dp = KIN.fk(b)[:3, 3] - KIN.fk(a)[:3, 3]
        if np.linalg.norm(dp) > 1e-9:
            assert angle_deg(dp, v_cmd) < 0.5
    speed = np.linalg.norm(KIN.fk(qs[-1])[:3, 3] - KIN.fk(qs[-2])[:3, 3]) * 1000.0 / DT
    assert speed < 0.8 * np.linalg.norm(v_cmd)
    assert results[-1].scale == pytest.approx(speed / np.linalg.norm(v_cmd), abs=0.02)
    v, _ = rates(ik, qs)
    assert np.all(np.abs(v) <= ik.vel * (1 + 1e-9))


def test_joint_jog_scaled_together_when_one_joint_is_too_fast() -> None:
    ik = new_ik()
    q0 = np.radians([-160.0, 0.0, 0.0, 0.0, -90.0, 0.0])
    ik.reset(q0)
    jog = JointJog(velocity=(600.0, 150.0, 0.0, 0.0, 0.0, 0.0), source="t", stamp=0)  # J1 above its limit
    _, results, qs = run(ik, q0, jog, 60)
    v, _ = rates(ik, qs)
    assert results[-1].flags & IkFlag.VELOCITY_LIMIT
    assert np.degrees(v[-1][0]) == pytest.approx(PROFILE.vel_limit[0] * ik.settings.vel_fraction, rel=1e-6)
    for row in v[1:]:
        assert row[1] / row[0] == pytest.approx(150.0 / 600.0, rel=1e-9)  # the jog direction is kept


def test_reversal_and_stop_stay_on_the_line() -> None:
    ik = new_ik()
    ik.reset(HOME)
    x = np.array([1.0, 0.0, 0.0])

    def cmd(k: int) -> Twist | None:
        return twist((300.0, 0.0, 0.0)) if k < 40 else twist((-300.0, 0.0, 0.0)) if k < 90 else None

    _, results, qs = run(ik, HOME, cmd, 130)
    p0 = KIN.fk(HOME)[:3, 3]
    for a, b in itertools.pairwise(qs):
        dp = KIN.fk(b)[:3, 3] - KIN.fk(a)[:3, 3]
        lateral = float(np.linalg.norm(dp - (dp @ x) * x))
        assert lateral < 0.01 * float(np.linalg.norm(dp)) or lateral < 5e-6  # 0.6 deg, or a few microns
        off = KIN.fk(b)[:3, 3] - p0
        assert np.linalg.norm(off - (off @ x) * x) < 50e-6  # never 50 um off the line (pulled back in 30 ms)
    assert all(r.flags & IkFlag.NO_COMMAND for r in results[90:])
    assert np.allclose(results[-1].dq, 0.0)  # at rest
    _, acc = rates(ik, qs)
    assert np.all(np.abs(acc) <= ik.acc * (1 + 1e-6))


def test_pose_target_arrives_without_overshoot_within_its_caps() -> None:
    ik = new_ik()
    ik.reset(HOME)
    start = matrix_to_xyzwpr(KIN.fk(HOME))
    goal = start + np.array([60.0, -90.0, 40.0, 8.0, -5.0, 20.0])
    cmd = PoseTarget(xyzwpr=tuple(goal), linear_speed=150.0, angular_speed=30.0, source="t", stamp=0)
    target = xyzwpr_to_matrix(goal)
    _, results, qs = run(ik, HOME, cmd, 400)
    assert results[-1].arrived
    dist = [np.linalg.norm(KIN.fk(q)[:3, 3] - target[:3, 3]) for q in qs]
    ang = [np.linalg.norm(rotation_vector(target[:3, :3] @ KIN.fk(q)[:3, :3].T)) for q in qs]
    assert all(b <= a + 1e-9 for a, b in itertools.pairwise(dist))  # never overshoots
    assert all(b <= a + 1e-9 for a, b in itertools.pairwise(ang))
    assert dist[-1] < 2e-5 and math.degrees(ang[-1]) < 0.02
    speeds = np.abs(np.diff(dist)) * 1000.0 / DT
    assert speeds.max() <= 150.0 * 1.01
    assert math.degrees(np.max(np.abs(np.diff(ang)))) / DT <= 30.0 * 1.01


def test_joint_target_arrives_synchronised_without_overshoot() -> None:
    ik = new_ik()
    ik.reset(HOME)
    goal_model = np.radians([25.0, 15.0, 10.0, 30.0, -60.0, 80.0])
    goal = model_rad_to_fanuc_deg(goal_model, PROFILE.j23_factor)
    cmd = JointTarget(position=tuple(goal), speed_scale=0.3, source="t", stamp=0)
    _, results, qs = run(ik, HOME, cmd, 500)
    assert results[-1].arrived
    err = np.array([ik.c @ (goal_model - q) for q in qs])
    assert np.all(err * np.sign(err[0]) >= -1e-9)  # no joint passes its target
    v, _ = rates(ik, qs)
    assert np.all(np.abs(v) <= ik.vel * 0.3 * (1 + 1e-9))
    moving = np.abs(err[0]) > 0
    ratio = err[:, moving] / err[0, moving]
    assert np.allclose(ratio, ratio[:, :1], atol=1e-6)  # a straight joint-space line


# ---------------------------------------------------------------------- configuration, singularity
def test_wrist_singularity_slows_the_approach_but_lets_the_arm_leave() -> None:
    ik = new_ik()
    q0 = np.radians([0.0, 0.0, 0.0, 0.0, -20.0, 0.0])
    ik.reset(q0)
    toward = twist(angular=(0.0, -40.0, 0.0))  # turns J5 toward 0 (and through, if it could)
    q, results, qs = run(ik, q0, toward, 250)
    assert all(configuration_of(x, KIN) == configuration_of(q0, KIN) for x in qs)
    assert any(r.flags & IkFlag.SINGULARITY_SLOWDOWN for r in results)
    assert q[4] < 0.0 and ik.condition_number(q) <= ik.settings.singularity_stop
    a, b = KIN.fk(qs[-2]), KIN.fk(qs[-1])
    late = np.degrees(np.linalg.norm(rotation_vector(b[:3, :3] @ a[:3, :3].T))) / DT
    assert late < 0.05 * 40.0  # almost stopped: approached smoothly, never past the guard
    assert results[-1].scale < 0.05
    # The same pose, commanded away from the singularity: full speed after the ramp.
    _, away, qs2 = run(ik, q, twist(angular=(0.0, 40.0, 0.0)), 40)
    assert away[-1].scale == pytest.approx(1.0)
    a, b = KIN.fk(qs2[-2]), KIN.fk(qs2[-1])
    w = np.degrees(rotation_vector(b[:3, :3] @ a[:3, :3].T)) / DT
    assert np.allclose(w, [0.0, 40.0, 0.0], atol=0.5)  # the commanded rotation, at full speed


def test_elbow_and_shoulder_singularities_keep_the_configuration() -> None:
    for q0, v in ((HOME, (400.0, 0.0, 0.0)),  # stretch the arm: elbow
                  (np.radians([0.0, -30.0, -30.0, 0.0, -60.0, 0.0]), (-300.0, 0.0, 0.0))):  # over the J1 axis
        ik = new_ik()
        ik.reset(q0)
        q, results, qs = run(ik, q0, twist(v), 300)
        cfg = configuration_of(q0, KIN)
        assert all(configuration_of(x, KIN) == cfg for x in qs)
        assert any(r.configuration_guard for r in results)
        speed = np.linalg.norm(KIN.fk(qs[-1])[:3, 3] - KIN.fk(qs[-2])[:3, 3]) * 1000.0 / DT
        assert speed < 0.5  # mm/s: stopped before the singularity, not sliding round it
    assert wrist_centre_offset(q[1], q[2], KIN) >= ik.settings.margins.shoulder_m - 1e-4


def test_collision_limit_keeps_the_wrist_above_the_floor() -> None:
    q0 = np.radians([0.0, 30.0, 0.0, 0.0, -60.0, 0.0])
    down = twist((0.0, 0.0, -400.0))
    lowest = {}
    for enabled in (False, True):
        ik = new_ik(collision=enabled)
        ik.reset(q0)
        model = ik.model
        data = mujoco.MjData(model)
        floor = model.geom("floor").id
        geoms = [model.geom(n).id for n in ("link4_forearm", "link5_wrist", "link6_flange")]
        fromto = np.zeros(6)
        _, results, qs = run(ik, q0, down, 250)
        worst = math.inf
        for q in qs:
            data.qpos[:] = q
            mujoco.mj_kinematics(model, data)
            worst = min(worst, *(mujoco.mj_geomDistance(model, data, floor, g, 1.0, fromto) for g in geoms))
        lowest[enabled] = worst
        if enabled:
            assert any(r.collision_guard for r in results)
    assert lowest[False] < 0.0  # without the limit the wrist would go through the floor
    assert lowest[True] >= 0.0099  # minimum distance 10 mm, linearised per cycle


def test_random_command_stream_respects_limits_and_configuration() -> None:
    """Seeded random stream: jumps, reversals, all command kinds, starts near singular poses."""
    starts = [HOME, np.radians([0.0, 10.0, 20.0, 0.0, -3.0, 0.0]),  # wrist nearly singular
              np.radians([20.0, 40.0, 75.0, 30.0, -40.0, 10.0]),  # elbow nearly stretched
              np.radians([0.0, -30.0, -35.0, 0.0, -60.0, 0.0]),  # wrist centre near the J1 axis
              np.radians([-60.0, 20.0, 10.0, 170.0, 40.0, -170.0])]  # J4/J6 near their turn boundaries
    speeds = st.floats(-1500.0, 1500.0, allow_nan=False)
    rot = st.floats(-300.0, 300.0, allow_nan=False)
    vec3 = st.tuples(speeds, speeds, speeds)
    segment = st.one_of(
        st.tuples(st.just("twist"), vec3, st.tuples(rot, rot, rot), st.sampled_from(["base", "tool"]),
                  st.integers(1, 40)),
        st.tuples(st.just("reverse"), st.integers(1, 30)),
        st.tuples(st.just("jog"), st.lists(st.floats(-500.0, 500.0, allow_nan=False), min_size=6, max_size=6),
                  st.integers(1, 40)),
        st.tuples(st.just("pose"), vec3, st.tuples(rot, rot, rot), st.integers(1, 40)),
        st.tuples(st.just("target"), st.lists(st.floats(-1.0, 1.0), min_size=6, max_size=6),
                  st.floats(0.05, 1.0), st.integers(1, 40)),
        st.tuples(st.just("none"), st.integers(1, 20)),
        st.tuples(st.just("nan"), st.integers(0, 5)),
    )

    @settings(max_examples=60, deadline=None, derandomize=True,
              suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])
    @given(start=st.sampled_from(range(len(starts))), segments=st.lists(segment, min_size=1, max_size=8))
    def check(start: int, segments: list) -> None:
        ik = new_ik()
        q = starts[start].copy()
        ik.reset(q)
        cfg = configuration_of(q, KIN)
        cmd: Command | None = None
        v_prev = np.zeros(6)
        for seg in segments:
            kind = seg[0]
            if kind == "twist":
                cmd = twist(seg[1], seg[2], seg[3])
            elif kind == "reverse" and isinstance(cmd, Twist):
                cmd = twist(tuple(-x for x in cmd.linear), tuple(-x for x in cmd.angular), cmd.frame)
            elif kind == "jog":
                cmd = JointJog(velocity=tuple(seg[1]), source="h", stamp=0)
            elif kind == "pose":
                x = matrix_to_xyzwpr(KIN.fk(q))
                x[:3] += np.array(seg[1]) * 0.2
                x[3:] += np.array(seg[2]) * 0.1
                cmd = PoseTarget(xyzwpr=tuple(x), linear_speed=500.0, angular_speed=90.0, source="h", stamp=0)
            elif kind == "target":
                goal = LO + (np.array(seg[1]) + 1.0) * 0.5 * (HI - LO)
                cmd = JointTarget(position=tuple(model_rad_to_fanuc_deg(goal, PROFILE.j23_factor)),
                                  speed_scale=seg[2], source="h", stamp=0)
            elif kind == "none":
                cmd = None
            elif kind == "nan":  # rejected upstream: the previous command stays in force
                with pytest.raises(ValueError):
                    Twist(linear=(math.nan, 0.0, 0.0), source="h", stamp=0)
            for _ in range(seg[-1]):
                r = ik.step(q, cmd)
                assert np.all(np.isfinite(r.q_next))
                assert np.all(r.q_next >= LO - 1e-9) and np.all(r.q_next <= HI + 1e-9)
                v = ik.c @ r.dq / DT
                assert np.all(np.abs(v) <= ik.vel * (1 + 1e-6) + 1e-9)
                assert np.all(np.abs(v - v_prev) / DT <= ik.acc * (1 + 1e-3) + 1e-6)  # OSQP tolerance
                assert configuration_of(r.q_next, KIN) == cfg, (kind, np.degrees(r.q_next))
                q, v_prev = r.q_next, v

    check()


def test_step_again_is_the_step_the_other_command_would_have_been() -> None:
    """``step_again`` (an input that arrived while the servo process solved) must leave the IK exactly
    where a step with that command in the first place would have: same result, same next cycles."""
    speeds = st.floats(-400.0, 400.0, allow_nan=False)
    vec3 = st.tuples(speeds, speeds, speeds)
    command = st.one_of(
        st.tuples(st.just("twist"), vec3, st.tuples(*[st.floats(-60.0, 60.0)] * 3), st.sampled_from(["base", "tool"])),
        st.tuples(st.just("pose"), vec3, st.tuples(*[st.floats(-30.0, 30.0)] * 3)),
        st.tuples(st.just("none")),
    )

    def make(c: tuple, q: np.ndarray) -> Command | None:
        if c[0] == "twist":
            return twist(c[1], c[2], c[3])
        if c[0] == "pose":
            x = matrix_to_xyzwpr(KIN.fk(q))
            x[:3] += np.array(c[1]) * 0.1
            x[3:] += np.array(c[2]) * 0.1
            return PoseTarget(xyzwpr=tuple(x), linear_speed=300.0, angular_speed=60.0, source="h", stamp=0)
        return None

    @settings(max_examples=40, deadline=None, derandomize=True, suppress_health_check=[HealthCheck.too_slow])
    @given(before=st.lists(command, min_size=0, max_size=4), first=command, late=command,
           after=st.lists(command, min_size=1, max_size=3), cycles=st.integers(1, 12))
    def check(before: list, first: tuple, late: tuple, after: list, cycles: int) -> None:
        told, direct = new_ik(), new_ik()
        q = HOME.copy()
        told.reset(q)
        direct.reset(q)
        for c in before:  # the same history for both
            cmd = make(c, q)
            for _ in range(cycles):
                r = told.step(q, cmd)
                assert np.array_equal(direct.step(q, cmd).dq, r.dq)
                q = r.q_next
        late_cmd = make(late, q)
        told.step(q, make(first, q))
        a, b = told.step_again(q, late_cmd), direct.step(q, late_cmd)
        assert np.array_equal(a.dq, b.dq) and a.flags == b.flags and a.mode == b.mode
        q = a.q_next
        for c in after:
            cmd = make(c, q)
            for _ in range(cycles):
                a, b = told.step(q, cmd), direct.step(q, cmd)
                np.testing.assert_allclose(a.dq, b.dq, rtol=0, atol=1e-12)
                q = a.q_next

    check()
    with pytest.raises(RuntimeError, match="step_again"):
        new_ik().step_again(HOME, None)


# ------------------------------------------------------------------------------------ fallbacks
def test_qp_fallback_and_solver_failure_never_give_nan(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(diffik_module, "_path_scale", lambda *a: None)  # force the QP path
    for solver in ("osqp", "daqp"):
        ik = new_ik(solver=solver)
        # The one-call Cartesian step off (an empty table): its line is not _path_scale's call.
        ik._fast_table = np.zeros((0, 3), dtype=np.int64)
        monkeypatch.setattr(ik, "_blend", lambda *a: None)
        monkeypatch.setattr(ik, "_line_past_braking", lambda *a: None)  # (the line at its braking rows' cost)
        ik.reset(HOME)
        _, results, qs = run(ik, HOME, twist((200.0, 0.0, 0.0)), 30)
        assert all(r.flags & IkFlag.QP_FALLBACK for r in results)
        speed = np.linalg.norm(KIN.fk(qs[-1])[:3, 3] - KIN.fk(qs[-2])[:3, 3]) * 1000.0 / DT
        assert speed == pytest.approx(200.0, rel=1e-3)
        assert ik.qp is not None and ik.qp.solver == solver
        # Now the solver fails too: the motion brakes at the acceleration limit; finite, flagged.
        monkeypatch.setattr(ik.qp, "solve", lambda *a: QpSolution(np.zeros(6), False, "forced", 0))
        dq0 = ik.previous_increment
        _, failed, qs2 = run(ik, qs[-1], twist((200.0, 0.0, 0.0)), 40)
        assert all(r.flags & IkFlag.SOLVER_FAILED for r in failed)
        assert all(np.all(np.isfinite(r.q_next)) for r in failed)
        assert np.allclose(failed[-1].dq, 0.0)
        # ... every joint in proportion (the TCP keeps its line; old code: each joint at its own limit).
        for r in failed:
            k = float(r.dq @ dq0) / float(dq0 @ dq0)
            assert 0.0 <= k < 1.0
            np.testing.assert_allclose(r.dq, k * dq0, rtol=0, atol=1e-12)
        _, acc = rates(ik, [qs[-2], *qs2])
        assert np.all(np.abs(acc[1:]) <= ik.acc * (1 + 1e-9))


@pytest.mark.parametrize("solver", ["osqp", "daqp"])
def test_a_joint_past_its_braking_curve_brakes_hardest_in_the_qp(solver: str) -> None:
    """J1 19.5 deg from its range at its full speed (braking needs ~90): its own braking row is out of
    the acceleration's reach. The QP is solved with that row at the hardest brake there is (old code:
    infeasible, SOLVER_FAILED, every joint braking on its own), tracking the command otherwise."""
    ik = new_ik(solver=solver)
    q = HOME.copy()
    q[0] = math.radians(150.0)
    dq_prev = np.zeros(6)
    dq_prev[0] = ik.vel[0] * DT
    ik.reset(q, dq_prev)
    r = ik.step(q, twist((0.0, 0.0, 50.0)))
    assert r.flags & IkFlag.QP_FALLBACK and not r.flags & IkFlag.SOLVER_FAILED, r.flags
    assert r.dq[0] == pytest.approx(dq_prev[0] - ik.acc[0] * DT * DT, abs=1e-6 * dq_prev[0])


_rows = st.lists(st.floats(-1.0, 1.0), min_size=6, max_size=6)


@settings(max_examples=200, deadline=None)
@given(st.lists(_rows, min_size=1, max_size=8), st.lists(st.floats(-0.05, 0.05), min_size=8, max_size=8),
       st.lists(st.floats(-0.03, 0.03), min_size=6, max_size=6), st.lists(st.floats(1e-6, 0.01), min_size=6,
                                                                        max_size=6))
def test_within_reach_raises_only_the_rows_the_acceleration_cannot_reach(
        rows: list[list[float]], h_rows: list[float], p: list[float], da: list[float]) -> None:
    """diffik._within_reach: a row the acceleration box (C dq within p +- da, FANUC axes) can meet keeps
    its bound; one it cannot is raised to the least it reaches (plus the margin): met at a corner of the
    box, so the QP is asked for the hardest brake there is; the box's own rows stay."""
    ik = new_ik()
    c, c_inv = ik.c, ik.c_inv
    p_, da_ = np.array(p), np.array(da)
    g = np.vstack([np.array(rows), c, -c])
    n = len(rows)
    h = np.concatenate([np.array(h_rows[:n]), p_ + da_, -(p_ - da_)])
    acc = slice(n, n + 12)
    margin = 1e-9
    out = diffik_module._within_reach(g, h, acc, c_inv, margin)
    assert np.array_equal(out[acc], h[acc])
    # dq at the box's 64 corners (C dq at each end of each joint's interval)
    corners = np.array(list(itertools.product(*zip(p_ - da_, p_ + da_, strict=True)))) @ c_inv.T
    least = np.min(corners @ g[:n].T, axis=0)
    np.testing.assert_allclose(out[:n], np.maximum(h[:n], least + margin), rtol=0, atol=1e-12)


def test_invalid_inputs_are_rejected() -> None:
    ik = new_ik()
    with pytest.raises(ValueError, match=r"q_model_rad\[2\]=nan"):
        ik.step(np.array([0.0, 0.0, math.nan, 0.0, 0.0, 0.0]), None)
    with pytest.raises(ValueError, match="shape"):
        ik.step(np.zeros(5), None)
    with pytest.raises(TypeError):
        ik.step(HOME, "jog")  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="dt"):
        DifferentialIK(PROFILE, 0.0)
    with pytest.raises(ValueError, match="solver"):
        DifferentialIK(PROFILE, DT, solver="cvxopt")  # type: ignore[arg-type]


def test_what_holds_a_motion_back_in_words() -> None:
    assert diffik_module.holding_back(0) == []
    flags = IkFlag.ACCEL_LIMIT | IkFlag.SINGULARITY_SLOWDOWN | IkFlag.CONFIGURATION | IkFlag.NO_COMMAND
    assert diffik_module.holding_back(int(flags)) == ["singularity", "configuration boundary"]  # ramps are normal
    assert diffik_module.holding_back(int(IkFlag.JOINT_LIMIT | IkFlag.COLLISION)) == ["joint limit", "collision guard"]
