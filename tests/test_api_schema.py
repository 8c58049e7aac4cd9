"""The API's contract: the OpenAPI document describes every JSON answer under /api with a model, and
what a running service answers validates against those models (StateView above all: the web console,
the telemetry socket and any client read it)."""

from __future__ import annotations

import json
from collections.abc import Iterator
from typing import Any

import pytest
import websockets.sync.client
from test_api_harness import Rig, running_rig

from servo_app.api.models import LeaseView, LimitsView, RobotView, SessionLogInfo, StateView

pytestmark = [pytest.mark.e2e, pytest.mark.timeout(120)]

# Answers that are not JSON documents: a session log download, the Prometheus text.
NOT_JSON = {("get", "/api/sessions/{name}"), ("get", "/metrics")}


@pytest.fixture(scope="module")
def rig(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Rig]:
    with running_rig(tmp_path_factory.mktemp("schema")) as r:
        yield r


@pytest.fixture(scope="module")
def openapi(rig: Rig) -> dict[str, Any]:
    r = rig.http.get("/openapi.json")
    assert r.status_code == 200
    return r.json()  # type: ignore[no-any-return]


def _resolve(doc: dict[str, Any], schema: dict[str, Any]) -> dict[str, Any]:
    while "$ref" in schema:
        name = schema["$ref"].removeprefix("#/components/schemas/")
        schema = doc["components"]["schemas"][name]
    return schema


def _ok_schema(doc: dict[str, Any], path: str, method: str) -> dict[str, Any]:
    responses = doc["paths"][path][method]["responses"]
    ok = responses.get("200") or responses.get("201")
    assert ok is not None, f"{method.upper()} {path}: no success response"
    content = ok.get("content", {}).get("application/json")
    assert content is not None, f"{method.upper()} {path}: the success response is not described as JSON"
    return content.get("schema", {})  # type: ignore[no-any-return]


def test_the_state_has_a_response_schema_with_its_fields(openapi: dict[str, Any]) -> None:
    schema = _ok_schema(openapi, "/api/state", "get")
    assert schema.get("$ref", "").endswith("/StateView"), schema
    state = _resolve(openapi, schema)
    props = state["properties"]
    for key in ("state", "link", "fault", "q_cmd", "q_servo", "vel_limit", "lease", "stops_by_reason", "stop_reason",
                "resumable", "alarms", "warnings", "cartesian", "servo_process", "latency_hist", "status_seq"):
        assert key in props, key
        assert props[key].get("description"), f"{key}: no description"
    assert set(state["required"]) == {"state", "link", "lease", "stops_by_reason"}
    assert state.get("additionalProperties") is True  # fields the service adds later pass through
    # The safety states and link phases are enumerated.
    assert "streaming" in _resolve(openapi, props["state"])["enum"]
    assert "fetching_tables" in _resolve(openapi, props["link"])["enum"]
    # Nested views are models too, not bare objects.
    fault = next(s for s in props["fault"]["anyOf"] if s.get("$ref"))
    assert {"message", "code", "cause", "remedy", "during"} <= set(_resolve(openapi, fault)["properties"])
    assert _resolve(openapi, props["lease"])["properties"].keys() >= {"held", "client"}


def test_every_api_route_answers_a_model(openapi: dict[str, Any]) -> None:
    seen = 0
    for path, ops in openapi["paths"].items():
        for method in ops:
            if not path.startswith("/api") or (method, path) in NOT_JSON:
                continue
            seen += 1
            schema = _ok_schema(openapi, path, method)
            if schema.get("type") == "array":
                schema = schema["items"]
            assert "$ref" in schema, f"{method.upper()} {path}: untyped answer {schema}"
            model = _resolve(openapi, schema)
            assert model.get("type") == "object" and model.get("properties"), f"{method.upper()} {path}: {model}"
    assert seen >= 15, seen


def test_routes_have_a_summary_and_a_description(openapi: dict[str, Any]) -> None:
    """/docs lists each operation by its summary and explains it by its description (the docstring):
    every operation of the document (the feeds' and inputs' are checked where those routes run)."""
    ops = [(method, path, op) for path, item in openapi["paths"].items() for method, op in item.items()]
    assert len(ops) >= 20, [(m, p) for m, p, _ in ops]
    for method, path, op in ops:
        assert op.get("summary") and op["summary"] != op["operationId"], (method, path, op.get("summary"))
        assert len(op.get("description", "")) > 20, (method, path, op.get("description"))
    # The refusals are documented with the bodies they have: 422 is a field list or one sentence.
    responses = openapi["paths"]["/api/session/end"]["post"]["responses"]
    assert {"401", "409", "413", "422"} <= set(responses)
    invalid = _resolve(openapi, responses["422"]["content"]["application/json"]["schema"])
    assert {s.get("type") for s in invalid["properties"]["detail"]["anyOf"]} == {"string", "array"}


def test_live_answers_validate_against_the_models(rig: Rig) -> None:
    s = rig.state()
    view = StateView.model_validate(s)
    assert view.state == s["state"] and view.lease.held is False
    assert view.q_cmd is not None and len(view.q_cmd) == 6
    # Nothing the service sent was lost or invented on the way (absent keys stay absent).
    assert set(view.model_dump(exclude_unset=True)) == set(s)
    LimitsView.model_validate(rig.http.get("/api/limits").json())
    RobotView.model_validate(rig.http.get("/api/robot").json())
    LeaseView.model_validate(rig.http.get("/api/lease").json())
    for row in rig.http.get("/api/sessions").json():
        SessionLogInfo.model_validate(row)


def test_a_streaming_state_and_the_telemetry_validate(rig: Rig) -> None:
    h = rig.lease("schema")
    rig.start_streaming(h)
    try:
        r = rig.http.post("/api/jog", json={"joints": [0, 0, 0, 0, 0, 2.0], "hold_ms": 100}, headers=h)
        assert r.status_code == 200 and r.json() == {"ok": True, "detail": None}
        s = StateView.model_validate(rig.state())
        assert s.state in ("streaming", "stopping", "stopped") and s.lease.held and s.lease.client == "schema"
        assert s.vel_limit is not None and all(v > 0 for v in s.vel_limit)
        with websockets.sync.client.connect(f"{rig.ws_url}/ws/telemetry?hz=50") as ws:
            for _ in range(3):
                msg = json.loads(ws.recv(timeout=5))
                t = StateView.model_validate(msg)
                assert t.link is not None and t.lease.client == "schema"
    finally:
        rig.end_and_wait(h)
        rig.http.request("DELETE", "/api/lease", headers=h)
