"""Every refusal of a bad motion request says what to do next, through the REST API end to end: one
bad request of each kind, each answered with the field and the value it refuses and, after "; ", the
next step (a verb: send, give, drop, add, widen), and nothing changed (the arm at rest where it was,
the same stream, tools and trajectory state). One service for the module (uvicorn on loopback, the
servo process streaming to the embedded simulator over real UDP).

Before, these ended at the fact: "joints[0]=200.000 deg (...) is outside the joint range [-169.5, 169.5]",
"linear[0]=10000.0 mm/s is outside [-4000.0, 4000.0]", a blended path through two waypoints 2e-6 deg
apart was planned through a turn on the spot (or refused as "TOPP-RA found no timing", naming no
waypoint), ..."""

from __future__ import annotations

import re
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from test_api_harness import AUTH, Rig, running_rig
from test_trajectory_e2e import HOME, at_home

pytestmark = [pytest.mark.e2e, pytest.mark.timeout(180)]

VIA = [[20.0, 20.0, -5.0, 10.0, -70.0, 30.0], [35.0, 10.0, 5.0, 0.0, -85.0, 0.0]]
NEXT_STEP = re.compile(r"; (send|give|drop|add|widen) ")


@pytest.fixture(scope="module")
def rig(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Rig]:
    with running_rig(tmp_path_factory.mktemp("refusal-words")) as r:
        yield r
        assert r.sim_alarms() == [], r.sim_alarms()  # nothing here made the controller alarm


def snapshot(rig: Rig) -> tuple[Any, ...]:
    s = rig.state()
    tools = rig.http.get("/api/tools", headers=AUTH).json()
    return (s["state"], s["q_cmd"], s["at_rest"], s["stops"], (s.get("trajectory") or {}).get("state"), tools)


def offset(q: list[float], **by: float) -> list[float]:
    """``q`` with joint J<n> moved by ``by['j<n>']`` deg."""
    out = list(q)
    for k, v in by.items():
        out[int(k[1:]) - 1] += v
    return out


# (method, path, json body, status, the field and value named, the next step said)
CASES: list[tuple[str, str, dict[str, Any], int, str, str]] = [
    # joint targets: outside the range; across the held configuration (J5 through 0: the wrist flips)
    ("POST", "/api/target", {"joints": [200.0, 10.0, -10.0, 0.0, -80.0, 0.0]}, 422,
     "joints[0]=200", "; send a value within the range"),
    ("POST", "/api/target", {"joints": [0.0, 10.0, -10.0, 0.0, 80.0, 0.0]}, 422,
     "joints=[0.0, 10.0, -10.0, 0.0, 80.0, 0.0]", "; send a target the arm reaches in that configuration"),
    # jogs: faster than the axis's limit (J1: 450 deg/s); a twist beyond the plausible bound
    ("POST", "/api/jog", {"joints": [900.0, 0.0, 0.0, 0.0, 0.0, 0.0]}, 422,
     "joints[0]=900 deg/s", "; send at most 450 deg/s"),
    ("POST", "/api/jog", {"linear": [10000.0, 0.0, 0.0]}, 422,
     "linear[0]=10000.0 mm/s", "; send a value within it"),
    # pose targets: out of reach; an angle beyond a turn
    ("POST", "/api/target", {"xyzwpr": [2000.0, 0.0, 300.0, 180.0, 0.0, 0.0]}, 422,
     "xyzwpr X=2000 Y=0 Z=300", "; send a pose within reach"),
    ("POST", "/api/target", {"xyzwpr": [400.0, 0.0, 300.0, 500.0, 0.0, 0.0]}, 422,
     "xyzwpr[3]=500.0 deg", "; send an angle within it"),
    # I/O: a type the service does not allow; an index whose 16 points pass the last DO
    ("POST", "/api/io", {"type": "SO", "index": 1, "value": 1}, 422, "type='SO'", "; send an allowed type: DI 1..512"),
    ("POST", "/api/io", {"type": "DO", "index": 500, "value": 1}, 422, "index=500", "; send an index in 1..497"),
    # tools: heavier than the robot's maximum payload; an angle beyond a turn
    ("POST", "/api/tools", {"name": "anvil", "xyzwpr": [0.0, 0.0, 100.0, 0.0, 0.0, 0.0], "payload_kg": 30.0}, 422,
     "payload_kg=30 kg", "; send at most 7 kg"),
    ("POST", "/api/tools", {"name": "bent", "xyzwpr": [0.0, 0.0, 100.0, 400.0, 0.0, 0.0], "payload_kg": 1.0}, 422,
     "W=400 deg", "; send an angle within it"),
    # trajectories
    ("POST", "/api/trajectory", {"joints": [HOME, [0.0, 10.0, -10.0, 0.0, -80.0, 500.0]]}, 422,
     "joints[1]=[0.0, 10.0, -10.0, 0.0, -80.0, 500.0]", "; send it within them"),
    ("POST", "/api/trajectory", {"poses": [[-400.0, 0.0, 300.0, 180.0, 0.0, 0.0]]}, 422,
     "poses[0]=[-400.0, 0.0, 300.0, 180.0, 0.0, 0.0]", "; send a pose the arm reaches in that configuration"),
    # (a straight line over the base: the wrist centre crosses the J1 axis)
    ("POST", "/api/trajectory", {"poses": [[0.0, 400.0, 300.0, 180.0, 0.0, 0.0],
                                           [0.0, -400.0, 300.0, 180.0, 0.0, 0.0]]}, 422,
     "poses[0] -> poses[1]", "; add a pose between them"),
    ("POST", "/api/trajectory", {"joints": [HOME, offset(HOME, j1=60.0)], "times": [0.1, 0.2]}, 422,
     "times[1]", "; give it at least"),
    ("POST", "/api/trajectory", {"log": "any.srvlog", "times": [1.0]}, 422, "times", "; drop times"),
    # blend through two waypoints 2e-6 deg apart (above the 1e-6 "same point"), and from where the arm rests
    ("POST", "/api/trajectory", {"joints": [VIA[0], offset(VIA[0], j1=2e-6), VIA[1]], "blend": True}, 422,
     "joints[0] and joints[1] are 2e-06 deg apart", "; send them as one waypoint, or send blend=false"),
    ("POST", "/api/trajectory", {"joints": [offset(HOME, j2=0.1), *VIA], "blend": True}, 422,
     "the start (where the arm rests) and joints[0] are 0.1 deg apart", "; drop joints[0], or send blend=false"),
]


@pytest.mark.parametrize(("method", "path", "body", "status", "names", "step"), CASES,
                         ids=[f"{c[1]}-{i}" for i, c in enumerate(CASES)])
def test_a_bad_request_is_refused_naming_the_field_the_value_and_what_to_do(
        rig: Rig, method: str, path: str, body: dict[str, Any], status: int, names: str, step: str) -> None:
    h = at_home(rig)
    before = snapshot(rig)
    r = rig.http.request(method, path, json=body, headers=h)
    assert r.status_code == status, r.text
    detail = r.json()["detail"]
    assert isinstance(detail, str), detail
    assert names in detail, detail
    assert step in detail and NEXT_STEP.search(detail), detail
    assert snapshot(rig) == before


def test_a_log_window_too_short_says_to_widen_it(rig: Rig) -> None:
    """A window of the running stream's own log holding one command or none."""
    h = at_home(rig)
    rig.end_and_wait(h)
    name = rig.http.get("/api/sessions").json()[0]["name"]
    h = at_home(rig)
    before = snapshot(rig)
    r = rig.http.post("/api/trajectory", json={"log": name, "from_s": 0.1, "to_s": 0.102}, headers=h)
    assert r.status_code == 422, r.text
    detail = r.json()["detail"]
    assert "from_s=0.1..to_s=0.102 holds" in detail and "; widen the window" in detail, detail
    assert snapshot(rig) == before


def test_jogs_over_the_rate_limit_say_how_to_keep_jogging(tmp_path: Path) -> None:
    """A service taking 5 jogs a second a client: refused ones (a wrong count: 422, nothing moves)
    count too, so the sixth within a second is 429."""
    with running_rig(tmp_path, jog_rate_per_s=5) as rig:
        jog_over_the_rate_limit(rig)


def jog_over_the_rate_limit(rig: Rig) -> None:
    h = rig.streaming()
    rig.wait(lambda s: s["at_rest"], 15.0, "at rest")
    before = snapshot(rig)
    codes = []
    for _ in range(12):
        r = rig.http.post("/api/jog", json={"joints": [1.0]}, headers=h)
        codes.append(r.status_code)
        if r.status_code == 429:
            detail = r.json()["detail"]
            assert "limited to 5 per second" in detail and "; send them less often" in detail, detail
            assert NEXT_STEP.search(detail), detail
            break
    assert 429 in codes, codes
    assert snapshot(rig) == before
