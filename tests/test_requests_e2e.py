"""Requests through the REST API end to end (issue 14): a refused request changes nothing, a bad one is
422 and names the field, the value and the limit, a refusal by the state is 409 and ends with the next
step, and I/O answers name what they wrote. One service for the module (uvicorn on loopback, the servo
process streaming to the embedded simulator over real UDP); each test takes the control lease itself."""

from __future__ import annotations

import time
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
from test_api_harness import AUTH, Rig, running_rig

from servo_app.service import ServiceConfig, ServoService

pytestmark = [pytest.mark.e2e, pytest.mark.timeout(120)]

START = "POST /api/session/start"
RESUME = "resume: POST /api/session/resume"


@pytest.fixture(scope="module")
def rig(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Rig]:
    with running_rig(tmp_path_factory.mktemp("requests")) as r:
        yield r
        assert r.sim_alarms() == [], r.sim_alarms()  # nothing here made the controller alarm


def hold_to_run_stop(rig: Rig, h: dict[str, str]) -> dict[str, object]:
    """Jog a little, let go: stopped by hold-to-run, at rest."""
    assert rig.jog_for(h, [0, 0, 0, 0, 0, 10.0], 0.2) >= 1
    s = rig.wait(lambda s: s["state"] == "stopped" and s["at_rest"], 5.0, "hold-to-run stop")
    assert s["stop_reason"] == "hold-to-run expired"
    return s


def refused(rig: Rig, path: str, body: object, headers: dict[str, str], code: int) -> str:
    r = rig.http.post(path, json=body, headers=headers)
    assert r.status_code == code, (path, body, r.status_code, r.text)
    detail = r.json()["detail"]
    assert isinstance(detail, str)
    return detail


# ------------------------------------------------------------------ a refused request changes nothing


def test_a_jog_with_the_wrong_count_is_422_and_changes_nothing(rig: Rig) -> None:
    h = rig.streaming()
    s0 = hold_to_run_stop(rig, h)
    detail = refused(rig, "/api/jog", {"joints": [10.0]}, h, 422)
    assert "joints has 1 values, expected 6" in detail, detail
    # Not resumed, no hold-to-run timer: still stopped where it was.
    s = rig.state()
    assert s["state"] == "stopped" and s["stop_reason"] == "hold-to-run expired", s["state"]
    assert s["stops"] == s0["stops"] and s["q_cmd"] == s0["q_cmd"]
    # A joint target right after is not cut short by a hold-to-run the refused jog started.
    goal = list(s["q_cmd"])
    goal[0] += 3.0
    rig.post("/api/target", h, {"joints": goal, "speed_scale": 0.2})
    s = rig.wait(lambda s: (s["at_rest"] and np.allclose(s["q_cmd"], goal, atol=1e-3))
                 or s["state"] != "streaming", 10.0, "the target reached")
    assert s["state"] == "streaming" and np.allclose(s["q_cmd"], goal, atol=1e-3), (s["state"], s["stop_reason"])


# ------------------------------------------------------------------------------------- 422 vs 409


@pytest.mark.parametrize(("path", "body", "words"), [
    ("/api/jog", {"linear": [10000.0, 0.0, 0.0]}, ["linear[0]=10000.0 mm/s is outside [-4000.0, 4000.0]"]),
    ("/api/jog", {"linear": [0.0, 0.0, 0.0], "angular": [0.0, 5000.0, 0.0]}, ["angular[1]"]),
    ("/api/jog", {"linear": [3500.0, 0.0, 0.0]}, ["flange-speed cap", "; send at most"]),
    ("/api/target", {"joints": [400.0, 0, 0, 0, -90.0, 0]}, ["joints[0]", "joint range"]),
    ("/api/target", {"joints": [0.0, 0.0, 0.0]}, ["joints has 3 values, expected 6"]),
    ("/api/target", {"xyzwpr": [400.0, 0.0, 300.0, 500.0, 0.0, 0.0]}, ["xyzwpr[3]", "360"]),
])
def test_bad_values_are_422_and_change_nothing(rig: Rig, path: str, body: dict[str, object],
                                               words: list[str]) -> None:
    h = rig.streaming()
    s0 = rig.wait(lambda s: s["at_rest"], 10.0, "rest")
    detail = refused(rig, path, body, h, 422)
    for w in words:
        assert w in detail, (w, detail)
    s = rig.state()
    assert s["state"] == "streaming" and s["at_rest"] and s["q_cmd"] == s0["q_cmd"]


def test_refusals_by_the_state_are_409_and_end_with_the_next_step(rig: Rig) -> None:
    h = rig.streaming()
    # Stopped by request: motion says resume.
    rig.post("/api/session/stop", h)
    rig.wait_state("stopped")
    for path, body in (("/api/jog", {"joints": [5.0, 0, 0, 0, 0, 0]}), ("/api/jog", {"linear": [10.0, 0, 0]}),
                       ("/api/target", {"joints": rig.state()["q_cmd"]})):
        detail = refused(rig, path, body, h, 409)
        assert "stopped" in detail and detail.endswith(RESUME), detail
    detail = refused(rig, "/api/reset", None, h, 409)
    assert detail.endswith(RESUME), detail
    # A fast stop: acknowledge, then resume.
    rig.post("/api/session/resume", h)
    rig.post("/api/session/stop", h, {"fast": True})
    rig.wait(lambda s: s["state"] == "stopped" and s["at_rest"], 5.0, "fast stop")
    detail = refused(rig, "/api/jog", {"joints": [5.0, 0, 0, 0, 0, 0]}, h, 409)
    assert detail.endswith("POST /api/reset, then resume: POST /api/session/resume"), detail
    detail = refused(rig, "/api/session/resume", None, h, 409)
    assert detail.startswith("resume refused in stopped") and detail.endswith(RESUME), detail
    rig.post("/api/reset", h)
    rig.post("/api/session/resume", h)
    # Streaming: a second start says how to end this one.
    detail = refused(rig, "/api/session/start", None, h, 409)
    assert detail.endswith("end it first: POST /api/session/end"), detail
    # Ended: start a new session.
    rig.end_and_wait(h)
    for path, body in (("/api/jog", {"linear": [10.0, 0, 0]}), ("/api/jog", {"joints": [5.0, 0, 0, 0, 0, 0]}),
                       ("/api/target", {"xyzwpr": [400.0, 0.0, 300.0, 180.0, 0.0, 0.0]})):
        detail = refused(rig, path, body, h, 409)
        assert "refused in ended" in detail and detail.endswith(START), detail
    detail = refused(rig, "/api/session/resume", None, h, 409)
    assert detail.endswith(START), detail
    # I/O is only while streaming.
    r = rig.http.get("/api/io", params={"type": "DO", "index": 1}, headers=AUTH)
    assert r.status_code == 409 and r.json()["detail"].endswith(START), r.text
    detail = refused(rig, "/api/io", {"type": "DO", "index": 1, "value": 1}, h, 409)
    assert detail.endswith(START), detail


# ---------------------------------------------------------------- a target resumes a hold-to-run stop


def test_a_pose_target_after_a_hold_to_run_stop_resumes(rig: Rig) -> None:
    h = rig.streaming()
    s = hold_to_run_stop(rig, h)
    goal = list(s["cart_servo"])
    goal[2] += 20.0
    rig.post("/api/target", h, {"xyzwpr": goal, "linear_speed": 100.0})
    assert rig.state()["state"] == "streaming"
    s = rig.wait(lambda s: (s["at_rest"] and np.allclose(s["cart_servo"][:3], goal[:3], atol=0.2))
                 or s["state"] != "streaming", 10.0, "the pose reached")
    assert s["state"] == "streaming", s["stop_reason"]


# ----------------------------------------------------------------------------------- plausibility


def test_a_joint_jog_faster_than_the_axis_limit_is_refused_naming_the_limit(rig: Rig) -> None:
    h = rig.streaming()
    s0 = rig.wait(lambda s: s["at_rest"], 10.0, "rest")
    vel = rig.http.get("/api/limits").json()["vel_deg_s"]
    for v in (5000.0, 1e308, -(vel[0] + 1.0)):
        detail = refused(rig, "/api/jog", {"joints": [v, 0, 0, 0, 0, 0]}, h, 422)
        assert "J1's speed limit" in detail and f"{vel[0]:.4g} deg/s" in detail, detail
    s = rig.state()
    assert s["state"] == "streaming" and s["at_rest"] and s["q_cmd"] == s0["q_cmd"]
    # Within the limits it is taken.
    rig.post("/api/jog", h, {"joints": [0, 0, 0, 0, 0, 0.0]})


@pytest.mark.parametrize(("xyz", "words"), [
    ([2000.0, 0.0, 300.0], ["out of the LR Mate 200iD's reach of 747 mm"]),
    ([0.0, 0.0, -1500.0], ["reach of 747 mm"]),
    ([0.4, 0.0, 0.3], ["units are mm"]),
    ([-5.0, 5.0, 0.0], ["units are mm"]),
])
def test_a_pose_target_out_of_reach_or_in_metres_is_refused_up_front(rig: Rig, xyz: list[float],
                                                                     words: list[str]) -> None:
    h = rig.streaming()
    s0 = rig.wait(lambda s: s["at_rest"], 10.0, "rest")
    detail = refused(rig, "/api/target", {"xyzwpr": [*xyz, 180.0, 0.0, 0.0]}, h, 422)
    for w in words:
        assert w in detail, (w, detail)
    time.sleep(0.1)  # a target taken would have moved the arm by now
    s = rig.state()
    assert s["state"] == "streaming" and s["at_rest"] and s["q_cmd"] == s0["q_cmd"]


# -------------------------------------------------------------------------------------------- I/O


def test_every_io_type_the_limits_allow_can_be_written_and_read(rig: Rig) -> None:
    h = rig.streaming()
    allow = rig.http.get("/api/limits").json()["io_allow"]
    assert allow, allow
    for io_type, (first, _last) in allow.items():
        r = rig.http.post("/api/io", json={"type": io_type, "index": first, "mask": 0x0003, "value": 0x0001},
                          headers=h)
        assert r.status_code == 200, (io_type, r.text)
        assert r.json() == {"ok": True, "type": io_type, "index": first, "mask": 3, "value": 1}, r.json()
        r = rig.http.get("/api/io", params={"type": io_type.lower(), "index": first, "mask": 0x0003}, headers=AUTH)
        assert r.status_code == 200, (io_type, r.text)
        body = r.json()
        assert (body["type"], body["index"], body["value"]) == (io_type, first, 1), body
    assert rig.sim_alarms() == []  # no PRIO-023


@pytest.mark.parametrize(("io_allow", "named"), [
    ({"do": 512}, "io_allow key 'do' (value 512) is not a FANUC I/O type (write 'DO')"),
    ({"DOUT": 512}, "io_allow key 'DOUT' (value 512) is not a FANUC I/O type; the types are DI, DO"),
    ({"DO": 0}, "io_allow['DO']=0: must be the number of DO points assigned, a whole number in 16..65535"),
    ({"DO": 8}, "io_allow['DO']=8: must be"),
    ({"F": 70000}, "io_allow['F']=70000: must be"),
    ({"M": "1024"}, "io_allow['M']='1024': must be"),
    ({"DI": True}, "io_allow['DI']=True: must be"),
])
def test_a_bad_io_allow_is_refused_at_start_naming_the_key(tmp_path: Path, io_allow: dict, named: str) -> None:
    """Checked when the service is made, before anything starts (old code: taken, and every access to
    the type refused later, or a 500 for a count that is not a number)."""
    with pytest.raises(ValueError) as err:
        ServoService(ServiceConfig(var_dir=tmp_path, io_allow=io_allow))
    assert named in str(err.value)


def test_an_io_allow_is_checked_for_the_backend(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match="the janome backend has no I/O through its stream; leave io_allow out"):
        ServoService(ServiceConfig(robot="janome:127.0.0.1:0", var_dir=tmp_path, io_allow={"DO": 512}))
    # A good one is taken as written; none at all is the backend's default.
    assert ServoService(ServiceConfig(var_dir=tmp_path, io_allow={"DO": 32, "F": 16})).backend.io_allow() == \
        {"DO": 32, "F": 16}
    assert ServoService(ServiceConfig(var_dir=tmp_path, io_allow={})).backend.io_allow() == {}
    janome = ServoService(ServiceConfig(robot="janome:127.0.0.1:0", var_dir=tmp_path, io_allow={}))
    assert janome.backend.io_allow() == {}
