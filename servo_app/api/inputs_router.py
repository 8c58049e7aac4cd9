"""Routes of the inputs bridge: the feeds, the input sources' view, enabling input control, bias zeroing.

- ``POST /api/feed/{source}``, ``WS /ws/feed/{source}``: sensor and tracker streams (token only: a
  sensor process holds no lease; the lease holder decides whether inputs move the arm);
- ``GET /api/inputs``: sources with rate, age, staleness and errors, applications, tracking error;
- ``POST /api/inputs/enable``: token and lease; the servo process then takes the input slot;
- ``POST /api/inputs/owner``: token and lease; one source gets exclusive control (null: all, by priority);
- ``POST /api/inputs/{app}/zero``: token and lease; a force/torque application re-zeroes its bias.

A browser cannot set headers on a WebSocket, so the feed socket also takes ``?token=``; plain HTTP
does not (a token in a URL ends up in logs and browser history).
"""

# No `from __future__ import annotations`: FastAPI resolves the dependency annotations at runtime.
import secrets
from collections.abc import Awaitable, Callable
from typing import Annotated, Any

from fastapi import APIRouter, Depends, FastAPI, HTTPException, WebSocketException, status
from pydantic import BaseModel, Field
from starlette.requests import HTTPConnection

from servo_app.api.auth import token_matches
from servo_app.api.models import Ack, InputsView
from servo_app.inputs.bridge import InputsBridge
from servo_app.inputs.bridge.core import InputNotLive
from servo_app.inputs.feed.router import FeedPostFastPath, feed_post_handler, feed_router


class EnableInputs(BaseModel):
    model_config = {"extra": "forbid", "strict": True}
    enable: bool


class InputsOwner(BaseModel):
    model_config = {"extra": "forbid", "strict": True}
    source: str | None = Field(description="the one source that may command (an application or a direct "
                                           "source); null: every source, by priority")


class ZeroRequest(BaseModel):
    model_config = {"extra": "forbid", "strict": True}
    samples: int | None = Field(None, ge=1, le=1000, description="samples averaged into the bias (default: configured)")


def connection_auth(token: str, on_refused: Callable[[HTTPConnection], None]
                    ) -> Callable[[HTTPConnection], Awaitable[str]]:
    """Bearer header for HTTP; bearer header or ``?token=`` for WebSockets.

    A coroutine on purpose: FastAPI runs a plain-function dependency in its thread pool, and that
    hop (and the GIL hand-overs around it) sat in front of every feed sample's latency."""

    async def check(conn: HTTPConnection) -> str:
        ok = token_matches(token, conn.headers.get("authorization"))
        is_ws = conn.scope["type"] == "websocket"
        query = conn.query_params.get("token")
        if not ok and is_ws and query:
            ok = secrets.compare_digest(query.encode(), token.encode())
        if not ok:
            on_refused(conn)
            if is_ws:
                raise WebSocketException(status.WS_1008_POLICY_VIOLATION, "missing or wrong token")
            raise HTTPException(401, "missing or wrong bearer token", headers={"WWW-Authenticate": "Bearer"})
        client = conn.client
        return f"{client.host}:{client.port}" if client else "?"

    return check


def include_inputs(app: FastAPI, bridge: InputsBridge, *, token: str, controlling: Callable[..., Any],
                   call: Callable[..., Any], metrics: Any, audit: Any) -> None:
    """Mount the feeds and the inputs routes; `controlling` and `call` are the app's lease dependency
    (servo_app.api.deps: a take-over waits for the routes it let through) and its audited service-call
    helper (ServiceCalls.call, which answers an Ack)."""

    def refused(conn: HTTPConnection) -> None:
        metrics.count("unauthorized")
        client = f"{conn.client.host}:{conn.client.port}" if conn.client else "?"
        audit.record(client, f"{conn.scope['type']} {conn.url.path}", False, "bad token")

    auth = connection_auth(token, refused)
    app.include_router(feed_router(bridge.feeds, auth))
    app.add_middleware(FeedPostFastPath, handler=feed_post_handler(bridge.feeds, auth))
    router = APIRouter(tags=["inputs"])

    @router.get("/api/inputs", response_model=InputsView, response_model_exclude_unset=True,
                summary="Input sources, feeds and applications")
    def inputs() -> dict[str, Any]:
        """Each source with its rate, age, staleness and errors, and a device that cannot be opened with
        the reason and the fix; the applications and their tracking error; whether inputs command."""
        return bridge.describe()

    @router.post("/api/inputs/enable", summary="Let the input sources move the arm (or stop them)")
    def enable(body: EnableInputs, client: Annotated[str, Depends(controlling)]) -> Ack:
        """``{"enable": true}``: the servo process takes its commands from the input sources (by priority,
        or the owner's); the answer lists configured sources that cannot be opened. Token and lease."""

        def run() -> dict[str, Any]:
            try:
                return bridge.enable(body.enable)
            except RuntimeError as exc:
                raise TimeoutError(str(exc)) from None
        return call(client, "inputs.enable", run, {"enable": body.enable})

    @router.post("/api/inputs/owner", summary="Give one input source exclusive control")
    def owner(body: InputsOwner, client: Annotated[str, Depends(controlling)]) -> Ack:
        """``{"source": name}``: only that source commands; ``null``: every source, by priority. Token and
        lease."""
        if body.source is not None and body.source not in bridge.specs:
            raise HTTPException(404, f"no input source {body.source!r}; sources: {sorted(bridge.specs)}")
        return call(client, "inputs.owner", lambda: bridge.set_owner(body.source), {"source": body.source})

    @router.post("/api/inputs/{name}/zero", summary="Re-zero a force/torque application's bias")
    def zero(name: str, client: Annotated[str, Depends(controlling)], body: ZeroRequest | None = None) -> Ack:
        """Average the next ``samples`` readings into the application's bias (hold the sensor unloaded).
        Refused (409, nothing changes) while its sensor is not sending. Token and lease."""
        try:
            bridge.application(name)
        except KeyError as exc:
            raise HTTPException(404, str(exc.args[0])) from None
        try:
            bridge.zero(name, body.samples if body else None)
        except ValueError as exc:
            raise HTTPException(422, str(exc)) from None
        except InputNotLive as exc:
            raise HTTPException(409, str(exc)) from None
        return call(client, "inputs.zero", lambda: {"application": name, "zeroing": True}, {"application": name})

    app.include_router(router)
