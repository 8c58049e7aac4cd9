"""The Janome motion stage alone (pure): a held jog against the work envelope's edge."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from servo_app.errors import CommandRejected, InvalidRequest
from servo_app.janome.motion import JanomeMotion, stream_speeds
from servo_app.janome.profile import JanomeProfile, load_janome_profile
from servo_app.janome.protocol import RobotKind
from servo_app.janome.supervisor import JanomeSupervisor
from servo_app.messages import Jog, Twist

PROFILES = {name: load_janome_profile(name) for name in ("jr3000", "js3")}


def start_of(profile: JanomeProfile, u: list[float]) -> np.ndarray:
    """A position inside the envelope with its margin, from four numbers in [0, 1]."""
    lo, hi = np.array(profile.axis_min) + 1.0, np.array(profile.axis_max) - 1.0
    p = lo + (hi - lo) * np.array(u)
    if profile.kind == RobotKind.SCARA:  # X Y from joint angles inside the ranges (righty: J2 > 0)
        a = profile.arm
        assert a is not None
        j1 = a.j1_min + 1.0 + (a.j1_max - a.j1_min - 2.0) * u[0]
        j2 = a.singular_margin_deg + 1.0 + (a.j2_max - a.singular_margin_deg - 2.0) * u[1]
        p[:2] = a.fk(j1, j2)
    return p


def held_jog(profile: JanomeProfile, p0: np.ndarray, jogs: list[tuple[int, np.ndarray]], cycles: int
             ) -> tuple[list[tuple[int, np.ndarray]], JanomeMotion]:
    """Every step a held jog sends, renewed each cycle as a held button is (the latest of ``jogs``
    from its cycle on); each step is checked as the robot checks it (its stroke, the line to it)."""
    m = JanomeMotion(profile)
    m.begin(p0, int(profile.elbow))
    hard = profile.workspace()
    sent: list[tuple[int, np.ndarray]] = []
    last = p0
    for k in range(cycles):
        v = [jv for at, jv in jogs if at <= k][-1]
        m.jog(v)
        step = m.next_step()  # no CommandRejected: the jog never makes a step the robot refuses
        if step is not None:
            q = np.array(step.xyzr)
            why = hard.check_path(last, q, int(profile.elbow))
            assert why is None, f"step {k} {q} would be refused: {why.message}"
            sent.append((k, q))
            last = q
    return sent, m


velocity = st.lists(st.floats(-1500.0, 1500.0), min_size=4, max_size=4).filter(
    lambda v: max(abs(x) for x in v) > 100.0)  # (slower ones can take longer than the test to the edge)


@settings(max_examples=60, deadline=None)
@given(name=st.sampled_from(sorted(PROFILES)), u=st.lists(st.floats(0.0, 1.0), min_size=4, max_size=4),
       v1=velocity, v2=velocity, switch=st.integers(0, 30))
def test_a_held_jog_stops_at_the_envelope_edge_without_a_refused_step(
        name: str, u: list[float], v1: list[float], v2: list[float], switch: int) -> None:
    """Also when the jog changes direction on the way (the shaper then curves off the jog's line)."""
    profile = PROFILES[name]
    p0 = start_of(profile, u)
    v = np.array(v2)
    try:
        sent, m = held_jog(profile, p0, [(0, np.array(v1)), (switch, v)], 230)
    except CommandRejected as exc:
        raise AssertionError(f"the jog ended with an error: {exc}") from exc
    assert m.at_rest(), "the jog is still moving after 230 cycles"
    assert not sent or sent[-1][0] < 200, f"a jog held at the edge went on creeping: {sent[-3:]}"
    rest = sent[-1][1] if sent else p0
    # it rests at the edge: 1 mm (deg) further along the jog leaves the envelope with its margin
    ahead = rest + v / np.linalg.norm(v)
    assert m.ws.check_path(rest, ahead, int(profile.elbow)) is not None, f"rested at {rest}, short of the edge"


@pytest.mark.parametrize("angle", [95.0, 115.0, 245.0, 265.0])
def test_a_held_scara_jog_meeting_the_reach_at_a_slant_rests_on_it(angle: float) -> None:
    """JS3 from X=300 Y=0 at 100 mm/s: the jog's target, found again from each position, crept back
    while the shaper braked to it, which overshot it past the reach (350.04 mm) or the stretched-arm
    limit (J2 1.85 deg, under 2): "step refused", the jog stopped dead 2-3 mm short."""
    profile = PROFILES["js3"]
    a = np.radians(angle)
    sent, m = held_jog(profile, np.array([300.0, 0.0, 50.0, 0.0]),
                       [(0, np.array([100.0 * np.cos(a), 100.0 * np.sin(a), 0.0, 0.0]))], 80)
    assert m.at_rest() and sent[-1][0] < 60
    rest = sent[-1][1]
    _j1, j2, _, _ = profile.workspace().joints(rest, 1)
    assert np.hypot(*rest[:2]) > 349.9 and 2.0 < j2 < 2.6  # on the limit, with its margin


def test_the_stream_s_speeds_are_the_tighter_of_the_profile_s_share_and_the_link_s_step() -> None:
    """Per axis and along the X Y Z line, each limit with where it comes from: JR3000's X Y R are held to
    the link's step (10 mm, 20 deg per 0.1 s), a slower Z and line by the profile's share (0.9)."""
    p = replace(PROFILES["jr3000"], speed=(800.0, 800.0, 50.0, 1000.0), cp_speed=90.0)
    sp = stream_speeds(p, 0.1, 0.9)
    assert sp.vel.tolist() == pytest.approx([100.0, 100.0, 45.0, 200.0]) and sp.cp_speed == pytest.approx(81.0)
    assert sp.vel_source == ("the link's step: link.max_step_mm 10 mm per 0.1 s step",) * 2 + (
        "0.9 of the profile's axes.speed[2] 50 mm/s", "the link's step: link.max_step_deg 20 deg per 0.1 s step")
    assert sp.cp_source == "0.9 of the profile's cp.speed_mm_s 90"
    m = JanomeMotion(p)
    assert m.vel.tolist() == sp.vel.tolist() and m.cp_speed == sp.cp_speed
    with pytest.raises(InvalidRequest) as exc:  # refused before any stream: nothing to change
        JanomeSupervisor(m).request(Jog(joints=(0.0, 0.0, -45.5, 0.0)), 0.0)
    assert str(exc.value) == ("joints[2]=-45.5 mm/s is faster than Z's speed limit 45 mm/s (0.9 of the profile's "
                              "axes.speed[2] 50 mm/s); send at most 45 mm/s, as GET /api/limits says (speed)")
    with pytest.raises(InvalidRequest, match=r"82.7 mm/s along X Y Z is above the line speed limit 81 mm/s \(0.9 "
                       r"of the profile's cp.speed_mm_s 90\); send at most 81 mm/s"):
        JanomeSupervisor(m).request(Twist(linear=(70.0, 0.0, 44.0)), 0.0)


@settings(max_examples=200, deadline=None)
@given(name=st.sampled_from(sorted(PROFILES)), u=st.lists(st.floats(-1.2, 1.2), min_size=4, max_size=4))
def test_a_jog_accepted_is_run_as_asked(name: str, u: list[float]) -> None:
    """Whatever jog the supervisor accepts, the motion runs unscaled: no silent slow-down."""
    p = PROFILES[name]
    m = JanomeMotion(p)
    v = np.array(u) * m.vel
    try:
        JanomeSupervisor(m)._check_jog(v)
    except InvalidRequest:
        assert np.any(np.abs(v) > m.vel) or np.linalg.norm(v[:3]) > m.cp_speed
        return
    m.begin(p.home, int(p.elbow))
    m.jog(v)
    assert m._jog is not None and np.allclose(m._jog, v, rtol=1e-9, atol=0.0)  # (the check allows 1e-9 over)
