"""Teach points: ``/api/points`` end to end against a running service (teach, list, move to, delete,
every refusal), and the store's file kept whole through every change."""

from __future__ import annotations

import contextlib
import json
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from test_api_harness import AUTH, TOKEN, Rig, running_rig

from servo_app.client import RefusedError, ServoClient
from servo_app.errors import CommandRejected
from servo_app.service.points import POINT_NAME, PointStore

HOME = [0.0, 0.0, 0.0, 0.0, -90.0, 0.0]


@pytest.fixture(scope="module")
def rig(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Rig]:
    with running_rig(tmp_path_factory.mktemp("points")) as r:
        yield r


def settled_streaming(rig: Rig) -> dict[str, str]:
    """The lease and a stream, with the arm settled (an earlier test may have left it moving)."""
    h = rig.streaming("points")
    rig.wait(lambda s: s["settled"], 15.0, "settled")
    return h


def _clear(rig: Rig, headers: dict[str, str]) -> None:
    for p in rig.http.get("/api/points").json():
        rig.http.request("DELETE", f"/api/points/{p['name']}", headers=headers)


# ----------------------------------------------------------------------------------------- the store
names = st.from_regex(POINT_NAME, fullmatch=True)


def stored(name: str, joints: list[float]) -> dict[str, object]:
    """A whole point as the service teaches it."""
    return {"name": name, "joints": joints, "xyzwpr": [400.0, 0.0, 300.0, 180.0, 0.0, 0.0], "tool": "flange",
            "model": "lrmate200id", "backend": "fanuc", "taught_unix": 1.7e9, "taught_by": "ann@10.0.0.1:5000"}


@settings(max_examples=50, deadline=None)
@given(name=names, joints=st.lists(st.floats(-180, 180, allow_nan=False), min_size=6, max_size=6))
def test_a_saved_point_reads_back_and_the_file_stays_whole(tmp_path_factory: pytest.TempPathFactory, name: str,
                                                           joints: list[float]) -> None:
    d = tmp_path_factory.mktemp("store")
    store = PointStore(d / "points.json")
    store.save(stored("other", [0.0] * 6))
    store.save(stored(name, joints), replace=name == "other")
    again = PointStore(d / "points.json")  # a new service reading the same file
    assert again.get(name) == stored(name, joints)
    assert [p["name"] for p in again.all()] == sorted({"other", name})
    assert [p.name for p in d.iterdir()] == ["points.json"]  # no temporary file left behind
    assert json.loads((d / "points.json").read_text())["version"] == 1
    assert again.delete(name) is True and again.get(name) is None and again.delete(name) is False
    assert (again.get("other") is None) == (name == "other")


def test_a_name_already_taught_is_replaced_only_when_asked(tmp_path: Path) -> None:
    store = PointStore(tmp_path / "points.json")
    store.save(stored("p", [1.0]))
    before = (tmp_path / "points.json").read_bytes()
    with pytest.raises(CommandRejected, match=r"^a point named 'p' is already taught \(by ann@10.0.0.1:5000 at "
                                              r".*replace=true$"):
        store.save(stored("p", [2.0]))
    assert (tmp_path / "points.json").read_bytes() == before
    store.save(stored("p", [2.0]), replace=True)
    assert store.get("p") == stored("p", [2.0])


def test_a_damaged_file_is_refused_with_what_to_do(tmp_path: Path) -> None:
    path = tmp_path / "points.json"
    path.write_text("{not json")
    with pytest.raises(CommandRejected, match=r"cannot be read .*fix it or move it away"):
        PointStore(path).all()


# ------------------------------------------------------------------------------------------ the API
def test_teach_list_and_move_to_with_zero_alarms(rig: Rig) -> None:
    with ServoClient(rig.base_url, TOKEN, name="teacher", take_over=True) as arm:
        arm.ensure_streaming()
        for p in arm.points():
            arm.delete_point(p.name)
        arm.move_joints([25.0, 5.0, -10.0, 0.0, -75.0, 30.0])
        a = arm.teach("corner_A")
        arm.move_joints(HOME)
        b = arm.teach("home.1")
        assert [p.name for p in arm.points()] == ["corner_A", "home.1"]
        np.testing.assert_allclose(a.joints, [25.0, 5.0, -10.0, 0.0, -75.0, 30.0], atol=1e-3)
        assert a.model == "lrmate200id" and len(a.pose) == 6 and a.pose != b.pose

        s = arm.move_to("corner_A", speed_scale=0.7)
        assert s is not None
        np.testing.assert_allclose(s.joints, a.joints, atol=1e-3)
        reached = arm.wait_settled().pose
        assert reached is not None and np.abs(np.subtract(reached[:3], a.pose[:3])).max() < 0.5
        arm.move_to("home.1")
        np.testing.assert_allclose(arm.state().joints, b.joints, atol=1e-3)

        on_disk = json.loads((rig.var_dir / "points.json").read_text())["points"]
        assert set(on_disk) == {"corner_A", "home.1"}
        assert on_disk["corner_A"]["taught_by"].startswith("teacher@127.0.0.1:")
        assert on_disk["corner_A"]["joints"] == list(a.joints)
        arm.delete_point("corner_A")
        assert [p.name for p in arm.points()] == ["home.1"]
    assert rig.sim_alarms() == []
    assert rig.state()["alarms"] == []


def test_teaching_a_name_again_is_refused_409_unless_replace(rig: Rig) -> None:
    """A second teach under the same name replaced the first point silently: an operator lost a taught
    point to a name typed twice. Now it is refused, naming the point and how to replace it."""
    with ServoClient(rig.base_url, TOKEN, name="twice", take_over=True) as arm:
        arm.ensure_streaming()
        arm.move_joints([10.0, 0.0, 0.0, 0.0, -90.0, 0.0])
        with contextlib.suppress(RefusedError):
            arm.delete_point("twice")
        first = arm.teach("twice")
        arm.move_joints(HOME)
        with pytest.raises(RefusedError) as exc:
            arm.teach("twice")
        assert exc.value.status == 409
        assert str(exc.value).startswith("a point named 'twice' is already taught (by twice@127.0.0.1:"), exc.value
        assert str(exc.value).endswith("teach it again with replace: POST /api/points/twice?replace=true")
        kept = {p.name: p for p in arm.points()}["twice"]
        assert kept == first  # nothing changed
        again = arm.teach("twice", replace=True)
        np.testing.assert_allclose(again.joints, HOME, atol=1e-3)
        assert {p.name: p for p in arm.points()}["twice"] == again
        arm.delete_point("twice")


@pytest.mark.parametrize("name", ["../etc", ".hidden", "-x", "a" * 65, "with space", "semi;colon", "ä"])
def test_bad_names_are_refused_422(rig: Rig, name: str) -> None:
    h = rig.lease("points")
    for method, path in (("POST", f"/api/points/{name}"), ("POST", f"/api/points/{name}/move"),
                         ("DELETE", f"/api/points/{name}")):
        r = rig.http.request(method, path, headers=h)
        assert r.status_code in (404, 422), (method, name, r.status_code, r.text)
        if r.status_code == 404:  # "../etc" is resolved by the URL itself: no route, never a file
            assert "/" in name
        else:
            assert r.json()["detail"][0]["loc"] == ["path", "name"], r.text
    assert not (rig.var_dir / "etc").exists()


def test_unknown_points_are_404_with_how_to_teach_them(rig: Rig) -> None:
    h = settled_streaming(rig)
    r = rig.http.post("/api/points/nowhere/move", headers=h)
    assert r.status_code == 404
    assert r.json()["detail"] == ("no teach point named 'nowhere': list them with GET /api/points, or move the "
                                  "arm there and teach it: POST /api/points/nowhere")
    r = rig.http.request("DELETE", "/api/points/nowhere", headers=h)
    assert r.status_code == 404 and "POST /api/points/nowhere" in r.json()["detail"]


def test_teaching_and_moving_need_the_lease(rig: Rig) -> None:
    h = settled_streaming(rig)
    rig.post("/api/points/leased", h)
    for method, path in (("POST", "/api/points/leased"), ("POST", "/api/points/leased/move"),
                         ("DELETE", "/api/points/leased")):
        assert rig.http.request(method, path).status_code == 401
        r = rig.http.request(method, path, headers=AUTH)
        assert r.status_code == 409 and "X-Lease-Id" in r.json()["detail"], r.text
    assert rig.http.get("/api/points").status_code == 200  # listing is open


def test_the_state_refuses_with_the_next_step_409(rig: Rig) -> None:
    h = settled_streaming(rig)
    _clear(rig, h)
    rig.post("/api/points/p1", h)
    # Moving: a pose taken now would not match the joints.
    rig.post("/api/target", h, {"joints": [40.0, 0.0, 0.0, 0.0, -90.0, 0.0], "speed_scale": 0.3})
    rig.wait(lambda s: not s["at_rest"], 5.0, "moving")
    r = rig.http.post("/api/points/p2", headers=h)
    assert r.status_code == 409 and r.json()["detail"].startswith("teach refused: the arm is moving"), r.text
    rig.wait(lambda s: s["settled"], 15.0, "settled")
    # Ended: no pose from the controller, and no target either.
    rig.end_and_wait(h)
    r = rig.http.post("/api/points/p2", headers=h)
    assert r.status_code == 409
    assert r.json()["detail"] == ("teach refused in ended: the controller reports the arm's pose only while a "
                                  "stream runs; start one: POST /api/session/start")
    r = rig.http.post("/api/points/p1/move", headers=h)
    assert r.status_code == 409 and r.json()["detail"].endswith("start a new session: POST /api/session/start")
    assert [p["name"] for p in rig.http.get("/api/points").json()] == ["p1"]


def test_a_point_taught_on_another_model_is_refused_409(rig: Rig) -> None:
    h = settled_streaming(rig)
    _clear(rig, h)
    rig.post("/api/points/elsewhere", h)
    path = rig.var_dir / "points.json"
    doc = json.loads(path.read_text())
    doc["points"]["elsewhere"]["model"] = "m20id25"
    path.write_text(json.dumps(doc))
    r = rig.http.post("/api/points/elsewhere/move", headers=h)
    assert r.status_code == 409
    assert r.json()["detail"] == ("point 'elsewhere' was taught on a m20id25, and this service drives a "
                                  "lrmate200id; teach it again on this robot: POST /api/points/elsewhere")


def _entry(**change: object) -> str:
    """A points file whose one point, a1, is a whole one with ``change`` (None: the field left out)."""
    point = {**stored("a1", [0, 0, 0, 0, -90, 0]), **change}
    return json.dumps({"version": 1, "points": {"a1": {k: v for k, v in point.items() if v is not None}}})


@pytest.mark.parametrize("text, what", [
    ('{"version": 1, "points": {"a1": {"name": "a1", "joints": [0', "cannot be read"),  # cut short
    ('{"version": 1, "points": {"a1": 5}}', "points.a1=5: not a point (an object with name, joints, "
                                              "xyzwpr, tool, model, backend, taught_unix, taught_by)"),
    (_entry(joints=[0, "x"]), 'points.a1.joints.1="x": Input should be a valid number'),
    (_entry(xyzwpr=None), "points.a1.xyzwpr: Field required"),
    (_entry(taught_unix="yesterday"), 'points.a1.taught_unix="yesterday": Input should be a valid number'),
    (_entry(name="b2"), 'points.a1.name="b2": not the name it is filed under'),
])
def test_a_damaged_points_file_is_refused_409_by_every_route_and_left_alone(rig: Rig, text: str, what: str) -> None:
    """The file was checked twice, by the store and again by the list's route: a point missing its pose
    or with a date in words was refused by the list (so the console showed no points at all) and taken
    by move and delete. One check now, the same refusal from every route."""
    h = settled_streaming(rig)
    path = rig.var_dir / "points.json"
    path.write_text(text)
    try:
        r = rig.http.get("/api/points")  # was a 500 (an exception or the response model's)
        assert r.status_code == 409, r.text
        detail = r.json()["detail"]
        assert detail == f"the teach point file {path}: {what}; fix it or move it away, then teach again" or (
            what == "cannot be read" and what in detail), detail
        for method, route in (("POST", "/api/points/a1/move"), ("POST", "/api/points/a1"),
                              ("DELETE", "/api/points/a1")):
            r = rig.http.request(method, route, headers=h)
            assert r.status_code == 409 and r.json()["detail"] == detail, (method, route, r.text)
        assert path.read_text() == text  # nothing lost: the file is left for the operator to fix
        assert rig.state()["at_rest"]
    finally:
        path.unlink()


def test_a_bad_move_body_is_refused_422(rig: Rig) -> None:
    h = settled_streaming(rig)
    rig.post("/api/points/body", h)
    for body in ({"speed_scale": 0}, {"speed_scale": 1.5}, {"speed_scale": "1"}, {"speed": 1}):
        r = rig.http.post("/api/points/body/move", json=body, headers=h)
        assert r.status_code == 422, (body, r.text)
    assert rig.http.post("/api/points/body/move", json={"speed_scale": 0.5}, headers=h).status_code == 200
