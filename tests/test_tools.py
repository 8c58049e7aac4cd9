"""Tools (TCP frames): the tools file's checks, the pose math, the model's tcp site moved in place, and
the servo cycle's TCP changed at rest (pure: no sockets, no processes)."""

import math

import mujoco
import numpy as np
import pytest
from hypothesis import assume, example, given, settings
from hypothesis import strategies as st

from servo_app.errors import CommandRejected
from servo_app.motion.checker import ControllerLimitChecker
from servo_app.motion.commands import PoseTarget, Twist
from servo_app.motion.servo import ServoCycle, ServoSettings
from servo_app.robots.conventions import fanuc_deg_to_model_rad, matrix_to_xyzwpr, xyzwpr_to_matrix
from servo_app.robots.kinematics import ArmKinematics
from servo_app.robots.model import TCP_SITE, load_model, mujoco_fk, set_model_tool
from servo_app.robots.profile import load_profile
from servo_app.robots.tool import FLANGE, MAX_OFFSET_MM, ToolError, flange_pose, load_tools, tcp_pose

PROFILE = load_profile("lrmate200id")  # max payload 7 kg
HOME = np.array([0.0, 0.0, 0.0, 0.0, -90.0, 0.0])
GRIPPER = (0.0, 0.0, 150.0, 0.0, 0.0, 0.0)

offsets = st.tuples(*[st.floats(-300, 300)] * 3, *[st.floats(-180, 180)] * 3)
poses = st.tuples(*[st.floats(-1500, 1500)] * 3, st.floats(-180, 180), st.floats(-89, 89), st.floats(-180, 180))
joints = st.lists(st.floats(-math.pi, math.pi), min_size=6, max_size=6)


# ---------------------------------------------------------------------------------- the tools file
def _load(text: str, **kw: object):
    return load_tools(text, max_payload_kg=PROFILE.max_payload_kg, source="tools.toml", **kw)  # type: ignore[arg-type]


def test_the_example_file_loads_with_the_flange_built_in():
    with open("configs/tools/example.toml", encoding="utf-8") as f:
        tools = _load(f.read())
    assert next(iter(tools.tools)) == FLANGE and tools.tools[FLANGE].is_flange
    assert tools.active == "gripper"
    assert tools.tools["gripper"].xyzwpr == (0.0, 0.0, 150.0, 0.0, 0.0, 0.0)
    assert tools.tools["gripper"].payload_kg == 2.5


def test_no_file_is_the_flange_at_the_configured_payload():
    tools = _load("", flange_payload_kg=3.0)
    assert tools.active == FLANGE and list(tools.tools) == [FLANGE]
    assert tools.tools[FLANGE].payload_kg == 3.0


def test_tool_option_overrides_the_files_active():
    text = ('active = "a"\n[tools.a]\nxyzwpr = [0,0,100,0,0,0]\npayload_kg = 1\n'
            '[tools.b]\nxyzwpr = [0,0,200,0,0,0]\npayload_kg = 2\n')
    assert _load(text, active="b").active == "b"
    assert _load(text, active=FLANGE).active == FLANGE


@pytest.mark.parametrize(("text", "words"), [
    ('[tools.g]\nxyzwpr = [0,0,150,0,0,0]\npayload_kg = 9.5\n',
     ["tools.g.payload_kg=9.5", "maximum payload of 7 kg"]),
    ('[tools.g]\nxyzwpr = [0,0,150,0,0,0]\npayload_kg = 0\n', ["tools.g.payload_kg=0", "above 0"]),
    ('[tools.g]\nxyzwpr = [0,0,150,0,0]\npayload_kg = 1\n', ["tools.g.xyzwpr=", "6 numbers"]),
    ('[tools.g]\nxyzwpr = [0,0,"a",0,0,0]\npayload_kg = 1\n', ["tools.g.xyzwpr Z='a'", "finite"]),
    ('[tools.g]\nxyzwpr = [0,0,nan,0,0,0]\npayload_kg = 1\n', ["tools.g.xyzwpr Z=nan"]),
    ('[tools.g]\nxyzwpr = [0,0,2500,0,0,0]\npayload_kg = 1\n', ["tools.g.xyzwpr X Y Z", "2500 mm", "2000"]),
    ('[tools.g]\nxyzwpr = [0,0,150,0,400,0]\npayload_kg = 1\n', ["tools.g.xyzwpr P=400"]),
    ('[tools.g]\nxyzwpr = [0,0,150,0,0,0]\n', ["tools.g.payload_kg is missing"]),
    ('[tools.g]\nxyzwpr = [0,0,150,0,0,0]\npayload_kg = 1\nmass = 2\n', ["tools.g: unknown key 'mass'"]),
    ('[tools.flange]\nxyzwpr = [0,0,150,0,0,0]\npayload_kg = 1\n', ["tools.flange", "built in"]),
    ('[tools.FLANGE]\nxyzwpr = [0,0,150,0,0,0]\npayload_kg = 1\n', ["tools.FLANGE", "'flange' only in case",
                                                                  "name the tool otherwise"]),
    ('[tools.Gripper]\nxyzwpr = [0,0,150,0,0,0]\npayload_kg = 1\n[tools.gripper]\nxyzwpr = [0,0,90,0,0,0]\n'
     'payload_kg = 1\n', ["tools.gripper", "differs from tool 'Gripper' only in case"]),
    ('active = "nope"\n', ["active='nope'", "not a defined tool"]),
    ('colour = 1\n', ["unknown key 'colour'"]),
    ('[tools\n', ["not valid TOML"]),
])
def test_a_bad_file_is_refused_naming_the_key_and_value(text: str, words: list[str]):
    with pytest.raises(ToolError) as exc:
        _load(text)
    assert str(exc.value).startswith("tools.toml")
    for w in words:
        assert w in str(exc.value)


def test_a_payload_option_above_the_maximum_is_refused():
    with pytest.raises(ToolError, match=r"--payload-kg=8 kg is above the robot's maximum payload of 7 kg"):
        _load("", flange_payload_kg=8.0)


def test_the_offset_bound_is_sensible():
    assert 1000.0 <= MAX_OFFSET_MM <= 3000.0


# ------------------------------------------------------------------------------------ the pose math
@settings(max_examples=80, deadline=None)
@given(offsets, poses)
def test_tcp_is_flange_times_tool_and_back(tool: tuple[float, ...], flange: tuple[float, ...]):
    tcp = tcp_pose(flange, tool)
    want = xyzwpr_to_matrix(flange) @ xyzwpr_to_matrix(tool)
    np.testing.assert_allclose(xyzwpr_to_matrix(tcp), want, atol=1e-9)
    np.testing.assert_allclose(xyzwpr_to_matrix(flange_pose(tcp, tool)), xyzwpr_to_matrix(flange), atol=1e-9)


@settings(max_examples=60, deadline=None)
@given(offsets, joints)
def test_kinematics_tool_change_round_trips_through_ik_tcp(tool: tuple[float, ...], q: list[float]):
    kin = ArmKinematics(PROFILE)
    kin.set_tool(tool)
    q = np.array(q)
    tcp = kin.fk_tcp(q)
    np.testing.assert_allclose(tcp, kin.fk(q) @ xyzwpr_to_matrix(tool), atol=1e-12)
    np.testing.assert_allclose(tcp, ArmKinematics(PROFILE, tool).fk_tcp(q), atol=1e-12)
    assume(abs(math.sin(q[4])) > 0.05)  # off the wrist singularity, where J4 + J6 alone is defined
    solutions = kin.ik_tcp(tcp, with_turns=True)
    assert solutions, "the TCP pose of a joint vector has an IK solution"
    for sol in solutions:
        np.testing.assert_allclose(kin.fk_tcp(sol.q_model_rad), tcp, atol=1e-9)
    def apart(a: np.ndarray) -> float:  # joint angles compared modulo a turn
        return float(np.abs(np.angle(np.exp(1j * (a - q)))).max())

    assert min(apart(s.q_model_rad) for s in solutions) < 1e-6, "q itself is among the solutions"


@settings(max_examples=40, deadline=None)
@given(offsets, offsets, joints)
# A first tool turned 180 deg about W compiles a site in its body's frame (site_sameframe), which the
# kinematics then skipped after the move.
@example(first=(0.0, 0.0, 0.0, 180.0, 0.0, 0.0), tool=(0.0, 0.0, 0.0, 0.0, 90.0, 0.0), q=[0.0] * 6)
def test_site_update_equals_a_model_compiled_with_that_tool(first: tuple[float, ...], tool: tuple[float, ...],
                                                            q: list[float]):
    moved = load_model(PROFILE, first, verify=False)
    set_model_tool(moved, tool)
    compiled = load_model(PROFILE, tool, verify=False)
    sid = moved.site(TCP_SITE).id
    np.testing.assert_allclose(moved.site_pos[sid], compiled.site_pos[sid], atol=1e-12)
    # A quaternion and its negative are the same rotation: compare the poses.
    a = mujoco_fk(moved, mujoco.MjData(moved), q, TCP_SITE)
    b = mujoco_fk(compiled, mujoco.MjData(compiled), q, TCP_SITE)
    np.testing.assert_allclose(a, b, atol=1e-12)
    np.testing.assert_allclose(a, ArmKinematics(PROFILE, tool).fk_tcp(q), atol=1e-6)


# ------------------------------------------------------------------------ the servo cycle's tool
def _streaming_cycle(tool: tuple[float, ...] | None = None, payload: float | None = None) -> ServoCycle:
    cycle = ServoCycle(PROFILE, 0.008, ServoSettings(collision=False))
    cycle.begin(HOME.copy(), None)
    cycle.set_tool(tool, payload)
    return cycle


def _run(cycle: ServoCycle, n: int) -> list[np.ndarray]:
    return [cycle.next_command(None) for _ in range(n)]


def _tcp(cycle: ServoCycle, q_fanuc: np.ndarray) -> np.ndarray:
    return cycle.ik.kin.fk_tcp(fanuc_deg_to_model_rad(q_fanuc[:6], PROFILE.j23_factor))


# About x the 150 mm tool swings the flange round the TCP; about z it only turns it, so that case also
# runs with a tool off the flange's axis (the flange then circles the TCP).
@pytest.mark.parametrize(("axis", "tool"), [(0, GRIPPER), (2, GRIPPER), (2, (40.0, 0.0, 150.0, 0.0, 0.0, 0.0))])
def test_rotation_about_the_tool_axis_keeps_the_tcp_still(axis: int, tool: tuple[float, ...]):
    cycle = _streaming_cycle(tool, 2.5)
    start = _tcp(cycle, HOME)
    angular = [0.0, 0.0, 0.0]
    angular[axis] = 20.0
    cycle.twist(Twist(source="test", stamp=0.0, linear=(0.0, 0.0, 0.0), angular=tuple(angular), frame="tool"))  # type: ignore[arg-type]
    qs = _run(cycle, 150)
    f0, f1 = cycle.ik.kin.fk_fanuc_deg(HOME), cycle.ik.kin.fk_fanuc_deg(qs[-1])
    if tool[0] or axis == 0:
        assert np.linalg.norm(f1[:3, 3] - f0[:3, 3]) * 1000 > 10.0, "the flange swings round the TCP"
    drift = max(float(np.linalg.norm(_tcp(cycle, q)[:3, 3] - start[:3, 3])) for q in qs) * 1000
    assert drift < 1.0, f"the TCP moved {drift:.2f} mm"
    turned = np.degrees(np.arccos(np.clip((np.trace(f0[:3, :3].T @ f1[:3, :3]) - 1) / 2, -1, 1)))
    assert turned > 10.0, "the flange turned"
    axis_now = _tcp(cycle, qs[-1])[:3, axis]
    assert float(axis_now @ start[:3, axis]) > 0.9999, "the turn is about the tool's own axis"


def test_linear_tool_jog_moves_the_tcp_along_the_tools_axis():
    tool = (0.0, 0.0, 150.0, 0.0, 30.0, 0.0)  # tilted: its z is not the flange's
    cycle = _streaming_cycle(tool, 2.5)
    start = _tcp(cycle, HOME)
    cycle.twist(Twist(source="test", stamp=0.0, linear=(0.0, 0.0, 50.0), angular=(0.0, 0.0, 0.0), frame="tool"))
    qs = _run(cycle, 100)
    moved = (_tcp(cycle, qs[-1])[:3, 3] - start[:3, 3]) * 1000
    along = float(moved @ start[:3, 2])
    assert along > 20.0
    assert np.linalg.norm(moved - along * start[:3, 2]) < 0.5, moved
    flange_z = cycle.ik.kin.fk_fanuc_deg(HOME)[:3, 2]
    assert abs(float(start[:3, 2] @ flange_z)) < 0.9, "the tool's axis differs from the flange's"


def test_a_pose_target_reaches_the_tcp_pose():
    cycle = _streaming_cycle(GRIPPER, 2.5)
    goal = matrix_to_xyzwpr(_tcp(cycle, HOME)) + np.array([30.0, -20.0, 10.0, 0.0, 0.0, 5.0])
    cycle.pose_target(PoseTarget(source="test", stamp=0.0, xyzwpr=tuple(goal), linear_speed=200.0, angular_speed=60.0))  # type: ignore[arg-type]
    qs = _run(cycle, 500)
    assert cycle.at_rest()
    got = matrix_to_xyzwpr(_tcp(cycle, qs[-1]))
    np.testing.assert_allclose(got[:3], goal[:3], atol=0.05)
    flange = matrix_to_xyzwpr(cycle.ik.kin.fk_fanuc_deg(qs[-1]))
    assert np.linalg.norm(flange[:3] - goal[:3]) > 100.0


def test_tool_change_refused_while_moving_changes_nothing():
    cycle = _streaming_cycle()
    cycle.jog_joints(np.array([10.0, 0, 0, 0, 0, 0]))
    _run(cycle, 20)
    limits, tool = cycle.limits, cycle.ik.kin.tool.copy()
    with pytest.raises(CommandRejected, match="the arm is moving"):
        cycle.set_tool(GRIPPER, 1.0)
    assert cycle.limits is limits and cycle.settings.payload_kg is None and cycle.settings.tool_xyzwpr is None
    np.testing.assert_array_equal(cycle.ik.kin.tool, tool)


def test_payload_rebuilds_the_limits_at_rest():
    cycle = _streaming_cycle()
    heavy = np.asarray(cycle.limits[1]).copy()  # None: the maximum payload
    cycle.set_tool(GRIPPER, 0.5)
    light = np.asarray(cycle.limits[1])
    assert np.all(light >= heavy) and np.any(light > heavy), "a lighter payload has higher limits (Appendix B)"
    assert cycle.shaper is not None and np.allclose(cycle.shaper.limits.acc, light)
    cycle.set_tool(GRIPPER, PROFILE.max_payload_kg)
    np.testing.assert_allclose(cycle.limits[1], heavy)


# ------------------------------------------------------------------- the simulator follows the payload
@pytest.mark.parametrize("payload", [0.5, 3.0, None])
def test_the_controller_checker_at_a_new_payload_is_one_built_for_it(payload: float | None):
    moved = ControllerLimitChecker.for_profile(PROFILE, payload_kg=7.0)
    moved.set_payload(payload)
    built = ControllerLimitChecker.for_profile(PROFILE, payload_kg=payload)
    assert moved.payload_kg == payload
    for a, b in zip(moved._stages, built._stages, strict=True):
        np.testing.assert_array_equal(a, b)
    for name in ("vel_lim", "acc1", "jrk1", "first_jump", "jump"):
        np.testing.assert_array_equal(getattr(moved, name), getattr(built, name))


def test_a_turn_about_a_long_tool_counts_the_flanges_swing_against_the_speed_cap():
    """The cap and the Appendix B tables are the flange's: turning about a TCP r mm away swings the
    flange at up to |w| r on top of the TCP's speed. A twist within the cap at the TCP but over it at
    the flange is refused and changes nothing; the same twist with the flange as the tool is taken."""
    long_tool = (0.0, 0.0, 1500.0, 0.0, 0.0, 0.0)
    cycle = _streaming_cycle(long_tool)
    limit = cycle.cap * cycle.settings.flange_speed_margin
    linear = 0.8 * limit
    angular = math.degrees(0.3 * limit / 1500.0)  # the swing alone: 0.3 of the limit
    twist = Twist(source="test", stamp=0.0, linear=(linear, 0.0, 0.0), angular=(0.0, 0.0, angular), frame="tool")
    with pytest.raises(CommandRejected, match="flange-speed cap") as refused:
        cycle.twist(twist)
    assert "1500 mm from the flange" in str(refused.value)
    assert not cycle.ik_active and cycle.at_rest()
    target = PoseTarget(source="test", stamp=0.0, xyzwpr=tuple(matrix_to_xyzwpr(_tcp(cycle, cycle.shaper.state[0]))),
                        linear_speed=linear, angular_speed=angular)
    with pytest.raises(CommandRejected, match="flange-speed cap"):
        cycle.pose_target(target)
    assert not cycle.ik_active
    # Slower turns fit: the same linear speed with a tenth of the swing is taken.
    slower = Twist(source="test", stamp=0.0, linear=(linear, 0.0, 0.0), angular=(0.0, 0.0, angular / 10), frame="tool")
    cycle.twist(slower)
    assert cycle.ik_active
    flange_cycle = _streaming_cycle(None)
    flange_cycle.twist(twist)
    assert flange_cycle.ik_active
