"""The WebSocket feed (``/ws/feed/{source}``) under random frames, on a real uvicorn server on 127.0.0.1.

Every frame, whatever it holds (text, binary, JSON with NaN or out-of-range values, wrong kinds, extra
or missing fields), is either answered (``?ack=true``) or closes the socket with a reason; a refused
sample names why and leaves the source's slot as it was; an accepted one is finite and within the
source's limits; the registry's counters account for every frame; the server keeps serving."""

from __future__ import annotations

import json
import math
import time
from collections.abc import Iterator
from typing import Any

import httpx
import pytest
from fastapi import FastAPI, HTTPException
from hypothesis import HealthCheck, event, given, settings
from hypothesis import strategies as st
from starlette.requests import HTTPConnection
from test_api_harness import LiveServer
from websockets.exceptions import ConnectionClosed
from websockets.sync.client import connect

from servo_app.inputs.feed import FeedRegistry, FeedSourceConfig
from servo_app.inputs.feed.router import feed_router

pytestmark = pytest.mark.e2e

TOKEN = "fuzz-token"
MAX_LINEAR = 250.0
Z_RANGE = (-200.0, 1500.0)
DISTANCE_RANGE = (0.0, 1000.0)
SOURCES = {
    "vision": FeedSourceConfig(kind="pose", limits={"z": {"min": Z_RANGE[0], "max": Z_RANGE[1]}}),
    "jog": FeedSourceConfig(kind="twist", max_linear_mm_s=MAX_LINEAR),
    "gauge": FeedSourceConfig(kind="measurement", required=["distance"],
                              limits={"distance": {"min": DISTANCE_RANGE[0], "max": DISTANCE_RANGE[1]}}),
}


def _auth(conn: HTTPConnection) -> str:
    if conn.query_params.get("token") != TOKEN:
        raise HTTPException(401, "missing or wrong token")
    return "fuzz"


@pytest.fixture(scope="module")
def server() -> Iterator[tuple[str, FeedRegistry]]:
    registry = FeedRegistry(SOURCES)
    app = FastAPI()
    app.include_router(feed_router(registry, _auth))
    live = LiveServer(app).start(timeout=20.0)
    try:
        yield f"127.0.0.1:{live.port}", registry
    finally:
        live.stop()


# -- frames ----------------------------------------------------------------------------------------

numbers = st.one_of(st.floats(allow_nan=True, allow_infinity=True), st.integers(-10**30, 10**30),
                    st.floats(-2000.0, 2000.0), st.sampled_from([0.0, -0.0, 1e308, -1e308, 5e-324]))
junk = st.one_of(st.none(), st.booleans(), st.text(max_size=8), numbers)
vectors = st.lists(st.one_of(numbers, junk), min_size=0, max_size=8)


@st.composite
def samples(draw: st.DrawFn) -> dict[str, Any]:
    """A feed message as a sender might get it wrong: any kind, fields of the right or wrong shape."""
    kind = draw(st.sampled_from(["pose", "twist", "measurement", "Twist", "", None, 3]))
    msg: dict[str, Any] = {"kind": kind}
    if draw(st.booleans()):
        msg["xyzwpr"] = draw(st.one_of(vectors, st.lists(st.floats(-1000.0, 1000.0), min_size=6, max_size=6)))
    if draw(st.booleans()):
        msg["linear"] = draw(st.one_of(vectors, st.lists(st.floats(-400.0, 400.0), min_size=3, max_size=3)))
    if draw(st.booleans()):
        msg["angular"] = draw(vectors)
    if draw(st.booleans()):
        msg["values"] = draw(st.dictionaries(st.sampled_from(["distance", "force", ""]), st.one_of(numbers, junk),
                                             max_size=3))
    if draw(st.booleans()):
        msg["frame"] = draw(st.sampled_from(["base", "tool", "world", "", 0]))
    if draw(st.booleans()):
        msg["stamp"] = draw(st.one_of(numbers, junk, st.just("now")))
    if draw(st.booleans()):
        msg["seq"] = draw(st.one_of(st.integers(-5, 10**6), junk))
    if draw(st.integers(0, 9)) == 0:
        msg[draw(st.text(min_size=1, max_size=6))] = draw(junk)
    return msg


def well_formed(source: str) -> st.SearchStrategy[dict[str, Any]]:
    """A message of the source's own kind and shape, its numbers anywhere: in range, out, or not finite."""
    near = st.one_of(st.floats(-400.0, 400.0), numbers)
    stamp = st.one_of(st.just("now"), st.none(), numbers)
    if source == "jog":
        body = st.fixed_dictionaries({"kind": st.just("twist"), "linear": st.lists(near, min_size=3, max_size=3)},
                                     optional={"angular": st.lists(near, min_size=3, max_size=3),
                                               "frame": st.sampled_from(["base", "tool", "world"]), "stamp": stamp})
    elif source == "vision":
        body = st.fixed_dictionaries(
            {"kind": st.just("pose"), "xyzwpr": st.lists(st.one_of(st.floats(-2000.0, 2000.0), numbers), min_size=6,
                                                           max_size=6)},
            optional={"frame": st.just("base"), "stamp": stamp})
    else:
        body = st.fixed_dictionaries(
            {"kind": st.just("measurement"),
             "values": st.fixed_dictionaries({"distance": st.one_of(st.floats(-100.0, 1500.0), numbers)},
                                             optional={"force": numbers})},
            optional={"stamp": stamp})
    return body.map(lambda m: {k: v for k, v in m.items() if v is not None})


def _as_text(msg: dict[str, Any]) -> str:
    if msg.get("stamp") == "now":
        msg = {**msg, "stamp": time.time()}
    return json.dumps(msg, allow_nan=True)  # NaN and Infinity as Python writes them: the parser reads them


def frames(source: str) -> st.SearchStrategy[str | bytes]:
    return st.one_of(
        well_formed(source).map(_as_text),
        well_formed(source).map(lambda m: _as_text(m).encode()),  # the same as a binary frame
        samples().map(_as_text),
        st.text(max_size=64),  # not JSON, or JSON that is no object
        st.binary(max_size=64),  # not UTF-8, mostly
        st.lists(junk, max_size=4).map(json.dumps),
    )


# -- the property ----------------------------------------------------------------------------------

def _within_limits(source: str, value: Any) -> None:
    if source == "jog":
        vec = list(value.linear)
        assert all(math.isfinite(v) for v in [*vec, *value.angular]), value
        assert math.sqrt(sum(v * v for v in vec)) <= MAX_LINEAR, value
    elif source == "vision":
        assert all(math.isfinite(v) for v in value.xyzwpr), value
        assert Z_RANGE[0] <= value.xyzwpr[2] <= Z_RANGE[1], value
    else:
        assert all(math.isfinite(v) for v in value.values.values()), value
        assert DISTANCE_RANGE[0] <= value.values["distance"] <= DISTANCE_RANGE[1], value


@settings(max_examples=80, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(data=st.data(), source=st.sampled_from(sorted(SOURCES)))
def test_every_frame_is_answered_or_closes_and_only_sound_samples_are_taken(
        server: tuple[str, FeedRegistry], data: st.DataObject, source: str) -> None:
    address, registry = server
    sent = data.draw(st.lists(frames(source), min_size=1, max_size=4), label="frames")
    before = registry.stats(source)
    accepted = refused = 0
    pending = list(sent)
    while pending:  # a socket per run of frames: an unreadable one closes it
        with connect(f"ws://{address}/ws/feed/{source}?token={TOKEN}&ack=true", open_timeout=10) as ws:
            while pending:
                frame = pending.pop(0)
                seq_before = registry.slot(source).seq
                value_before = registry.slot(source).read()
                ws.send(frame)
                try:
                    reply = json.loads(ws.recv(timeout=10))
                except ConnectionClosed as closed:
                    # Unreadable (not UTF-8, too deep, too big): closed with a code and the reason.
                    assert closed.rcvd is not None and closed.rcvd.code in (1007, 1009), closed
                    assert closed.rcvd.reason, closed
                    assert registry.slot(source).seq == seq_before
                    refused += 1
                    event("closed")
                    break
                assert reply["source"] == source
                if reply["accepted"]:
                    accepted += 1
                    event("accepted")
                    assert reply["seq"] == seq_before + 1 == registry.slot(source).seq, reply
                    _within_limits(source, registry.slot(source).read().value)
                else:
                    refused += 1
                    event("refused")
                    assert isinstance(reply["detail"], str) and reply["detail"], reply
                    assert reply["seq"] == seq_before == registry.slot(source).seq, reply
                    assert registry.slot(source).read() is value_before  # nothing of it was kept
    after = registry.stats(source)
    # Every frame counted once: taken, or refused (rejected, or out of order).
    assert after.accepted - before.accepted == accepted
    assert (after.rejected - before.rejected) + (after.out_of_order - before.out_of_order) == refused
    # Still serving: the statistics over plain HTTP.
    r = httpx.get(f"http://{address}/api/feed", params={"token": TOKEN}, timeout=10)
    assert r.status_code == 200 and {s["source"] for s in r.json()} == set(SOURCES)


@pytest.mark.parametrize("source", ["nope", "s" * 300])
def test_an_unknown_source_closes_with_1008_naming_it_whatever_its_length(server: tuple[str, FeedRegistry],
                                                                          source: str) -> None:
    """A source name long enough to make the reason over a close frame's 123 bytes made the close itself
    fail: the socket ended with no code and no reason (and the server logged a ProtocolError)."""
    address, _ = server
    with connect(f"ws://{address}/ws/feed/{source}?token={TOKEN}", open_timeout=10) as ws, \
            pytest.raises(ConnectionClosed) as closed:
        ws.recv(timeout=5)
    assert closed.value.rcvd is not None and closed.value.rcvd.code == 1008
    assert closed.value.rcvd.reason.startswith(f"unknown feed source '{source[:20]}"), closed.value.rcvd.reason
    assert len(closed.value.rcvd.reason.encode()) <= 123
    with connect(f"ws://{address}/ws/feed/jog?token={TOKEN}&ack=true", open_timeout=10) as ws:  # still serving
        ws.send(json.dumps({"kind": "twist", "linear": [0, 0, 0]}))
        assert json.loads(ws.recv(timeout=5))["accepted"]
