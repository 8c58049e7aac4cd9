"""The OpenAPI document's request schemas state what the service takes: a body or query the service
refuses for its own values (422) is one the documented schema refuses too, and a body it takes
validates. A client generated from the document, or schemathesis (tests/test_api_fuzz.py), otherwise
sends requests the document allows and the service refuses: a 5-joint jog to a 6-axis arm, I/O type
SO, a 90 kg tool, a trajectory row of 5 values.

Against a running service (the embedded FANUC simulator, streaming), each sample sent for real; the
schemas checked with jsonschema_rs (Draft 2020-12, OpenAPI 3.1's dialect)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import httpx
import jsonschema_rs
import pytest
import test_api_schema as api_schema
from test_api_harness import AUTH, Rig, running_janome_rig

pytestmark = [pytest.mark.e2e, pytest.mark.timeout(120)]

HOME = [0.0, 0.0, 0.0, 0.0, -90.0, 0.0]
TOOL = [0.0, 0.0, 100.0, 0.0, 0.0, 0.0]
CSV = "j1,j2,j3,j4,j5,j6\n0,0,0,0,-90,0\n1,0,0,0,-90,0\n"

# (operation, what is sent: a JSON body, or {"query": ..., "csv": ...}, words of the refusal)
REFUSED: list[tuple[str, dict[str, Any], list[str]]] = [
    ("POST /api/io", {"type": "SO", "index": 1, "value": 1}, ["type='SO'", "not allowed"]),
    ("POST /api/io", {"type": "DO", "index": 500, "value": 1}, ["index=500", "1..497"]),
    ("GET /api/io", {"query": {"type": "XX", "index": 1}}, ["type='XX'", "not an I/O type"]),
    ("GET /api/io", {"query": {"type": "DO", "index": 0}}, ["index=0", "1..497"]),
    ("POST /api/jog", {"joints": [1.0, 0.0, 0.0, 0.0, 0.0]}, ["joints", "5 values", "expected 6"]),
    ("POST /api/jog", {"linear": [5000.0, 0.0, 0.0]}, ["linear[0]=5000.0", "outside"]),
    ("POST /api/target", {"joints": [0.0] * 7}, ["joints", "7 values", "expected 6"]),
    ("POST /api/target", {"xyzwpr": [400.0, 0.0, 300.0, 500.0, 0.0, 0.0]}, ["xyzwpr[3]=500.0", "[-360, 360]"]),
    ("POST /api/target", {"joints": [200.0, 0.0, 0.0, 0.0, -90.0, 0.0]}, ["joints[0]=200", "outside the joint range"]),
    ("POST /api/tools", {"name": "heavy", "xyzwpr": TOOL, "payload_kg": 90.0},
     ["payload_kg=90", "maximum payload"]),
    ("POST /api/tools", {"name": "Flange", "xyzwpr": TOOL, "payload_kg": 1.0}, ["'Flange'", "only in case"]),
    ("POST /api/tools", {"name": "bent", "xyzwpr": [0.0, 0.0, 100.0, 400.0, 0.0, 0.0], "payload_kg": 1.0},
     ["W=400", "-360..360"]),
    ("POST /api/trajectory", {"joints": [[1.0, 0.0, 0.0, 0.0, -90.0]]}, ["joints[0] has 5 values, expected 6"]),
    ("POST /api/trajectory", {"joints": [[0.0, 0.0, 0.0, 0.0, -90.0, 400.0]]}, ["J6=400", "joint ranges"]),
    ("POST /api/trajectory", {"poses": []}, ["poses is empty"]),
    ("POST /api/trajectory", {"joints": [[1.0, 0.0, 0.0, 0.0, -90.0, 0.0]], "times": []}, ["times has 0 values"]),
    ("POST /api/trajectory", {"log": "any.srvlog", "times": [1.0]}, ["times: only with joints or poses"]),
    ("POST /api/trajectory", {"joints": [HOME], "poses": [[400.0, 0.0, 300.0, 180.0, 0.0, 0.0]]},
     ["give exactly one of joints, poses or log"]),
    ("POST /api/trajectory", {"joints": [HOME], "from_s": 1.0}, ["select a window of a log: give log too"]),
    ("POST /api/trajectory", {"query": {"speed_scale": 5.0}, "csv": CSV}, ["speed_scale=5.0", "[0.001, 1.0]"]),
    ("POST /api/trajectory", {"poses": [[400.0, 0.0, 300.0, 180.0, 0.0, 0.0]], "blend": True},
     ["blend=true: only with joints"]),
    ("POST /api/trajectory", {"joints": [[2.0, 0.0, 0.0, 0.0, -90.0, 0.0], HOME], "times": [1.0, 2.0], "blend": True},
     ["times: not with blend=true"]),
]

# What the service takes (200), each leaving the arm where it was.
ACCEPTED: list[tuple[str, dict[str, Any]]] = [
    ("POST /api/io", {"type": "DO", "index": 1, "mask": 1, "value": 0}),
    ("POST /api/io", {"type": "do", "index": 497, "mask": 0, "value": 0}),
    ("GET /api/io", {"query": {"type": "F", "index": 1009}}),
    ("POST /api/jog", {"joints": [0.0] * 6, "hold_ms": 100.0}),
    ("POST /api/jog", {"linear": [0.0, 0.0, 0.0], "angular": [0.0, 0.0, 0.0], "frame": "tool"}),
    ("POST /api/target", {"joints": HOME, "speed_scale": 0.5}),
    ("POST /api/tools", {"name": "gripper", "xyzwpr": [0.0, 0.0, 150.0, 0.0, 0.0, 90.0], "payload_kg": 2.0}),
    ("POST /api/trajectory", {"joints": [[2.0, 0.0, 0.0, 0.0, -90.0, 0.0], HOME], "times": [1.0, 2.0]}),
    ("POST /api/trajectory", {"joints": [[2.0, 0.0, 0.0, 0.0, -90.0, 0.0], [2.0, 2.0, 0.0, 0.0, -90.0, 0.0], HOME],
                              "blend": True}),
    ("POST /api/trajectory", {"query": {"speed_scale": 0.5, "pace": "limits"}, "csv": CSV + "0,0,0,0,-90,0\n"}),
]


# test_api_schema.py's fixtures (a running service on the embedded simulator, its document), found by
# pytest under these names.
rig = api_schema.rig
openapi = api_schema.openapi


def schema_errors(doc: dict[str, Any], operation: str, sent: dict[str, Any]) -> list[str]:
    """Where ``sent`` breaks the operation's documented request schema (its body's, its query's)."""
    method, path = operation.lower().split()
    op = doc["paths"][path][method]
    if "query" in sent:
        params = [p for p in op.get("parameters", []) if p["in"] == "query"]
        schema: dict[str, Any] = {"type": "object", "properties": {p["name"]: p["schema"] for p in params},
                                  "required": [p["name"] for p in params if p.get("required")],
                                  "additionalProperties": False}
        instance: Any = sent["query"]
    else:
        schema, instance = op["requestBody"]["content"]["application/json"]["schema"], sent
    validator = jsonschema_rs.Draft202012Validator({**schema, "components": doc["components"]})
    return [f"{list(e.instance_path)}: {e.message}" for e in validator.iter_errors(instance)]


def send(rig: Rig, headers: dict[str, str], operation: str, sent: dict[str, Any]) -> httpx.Response:
    method, path = operation.split()
    if method == "GET":
        return rig.http.get(path, params=sent["query"], headers=AUTH)
    if "csv" in sent:
        return rig.http.post(path, params=sent["query"], content=sent["csv"],
                             headers={**headers, "Content-Type": "text/csv"})
    return rig.http.post(path, json=sent, headers=headers)


def _settled_at_home(rig: Rig, headers: dict[str, str]) -> None:
    """Streaming, at rest at HOME (a replay sample ends there)."""
    def resting(s: dict[str, Any]) -> bool:  # (a replay rests at each waypoint on its way)
        replay = s.get("trajectory") or {}
        return s["state"] != "streaming" or (bool(s.get("at_rest")) and replay.get("state") in (None, "done", "ended"))

    s = rig.wait(resting, 15.0, "at rest, no replay under way")
    assert s["state"] == "streaming", s
    assert max(abs(a - b) for a, b in zip(s["q_cmd"], HOME, strict=False)) < 1e-6, s["q_cmd"]


@pytest.mark.parametrize(("operation", "sent", "words"), REFUSED,
                         ids=[f"{op}-{i}" for i, (op, _, _) in enumerate(REFUSED)])
def test_the_schema_refuses_what_the_service_refuses(rig: Rig, openapi: dict[str, Any], operation: str,
                                                     sent: dict[str, Any], words: list[str]) -> None:
    h = rig.streaming()
    _settled_at_home(rig, h)
    r = send(rig, h, operation, sent)
    assert r.status_code == 422, r.text
    for w in words:  # the refusal names the field and value (unchanged by the schema's constraints)
        assert w in r.text, (w, r.text)
    assert schema_errors(openapi, operation, sent), f"{operation}: the schema allows {sent}, refused: {r.text}"
    assert rig.state()["state"] == "streaming"  # a refusal changes nothing


@pytest.mark.parametrize(("operation", "sent"), ACCEPTED, ids=[f"{op}-{i}" for i, (op, _) in enumerate(ACCEPTED)])
def test_the_schema_takes_what_the_service_takes(rig: Rig, openapi: dict[str, Any], operation: str,
                                                 sent: dict[str, Any]) -> None:
    h = rig.streaming()
    _settled_at_home(rig, h)
    assert schema_errors(openapi, operation, sent) == [], sent
    r = send(rig, h, operation, sent)
    assert r.status_code == 200, r.text
    _settled_at_home(rig, h)


def test_the_schema_has_the_configured_robots_axes_and_no_io_without_it(tmp_path: Path) -> None:
    """A Janome robot (X Y Z R): 4 values a jog or target, a target within its work envelope's box, which
    the service refuses otherwise; no I/O types are listed (it has none) and no payload bound (its tools
    carry none)."""
    with running_janome_rig(tmp_path) as (rig, _):
        doc = rig.http.get("/openapi.json").json()
        h = rig.lease()
        rig.start_streaming(h)
        for op, body in (("POST /api/jog", {"joints": [10.0, 0.0, 0.0]}),
                         ("POST /api/target", {"joints": [0.0] * 6}),
                         ("POST /api/target", {"joints": [100.0, 100.0, 500.0, 0.0]})):
            r = send(rig, h, op, body)
            assert r.status_code == 422 and ("expected 4" in r.text or "Z=500" in r.text), r.text
            assert schema_errors(doc, op, body), (op, body)
        for op, body in (("POST /api/jog", {"joints": [0.0] * 4}),
                         ("POST /api/target", {"joints": [100.0, 100.0, 50.0, 0.0]})):
            assert schema_errors(doc, op, body) == [], (op, body)
            r = send(rig, h, op, body)
            assert r.status_code == 200, r.text
        write = doc["components"]["schemas"]["IoWrite"]
        assert "pattern" not in write["properties"]["type"] and "allOf" not in write, write
        assert "maximum" not in doc["components"]["schemas"]["DefineTool"]["properties"]["payload_kg"]
