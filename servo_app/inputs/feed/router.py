"""FastAPI router for the feeds: POST /api/feed/{source} and WS /ws/feed/{source}.

`auth_dependency` guards both endpoints. It must work for WebSockets too, so it should take
`starlette.requests.HTTPConnection` (not `Request`) and read the token from a header or, because
browsers cannot set headers on a WebSocket, from a query parameter.

Validation errors are rendered by this router, not FastAPI's default handler: the default echoes the
offending input, and a NaN in it makes the JSON encoder fail with a 500 instead of the 422 we want.

A WebSocket message the socket cannot read closes it with a close frame and a reason, never an
exception: too large (1009, over :data:`MAX_FEED_MESSAGE_BYTES`, the HTTP body limit too), nested
too deeply for the JSON parser (1007: Python's parser raised RecursionError, which used to end the
socket without a close frame), or binary data that is not UTF-8 (1007).
"""

from __future__ import annotations

import asyncio
import inspect
import json
from collections.abc import Callable, Coroutine
from dataclasses import asdict
from typing import Any

from fastapi import APIRouter, Depends, HTTPException, Request, Response, WebSocket, WebSocketDisconnect, status
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse
from fastapi.routing import APIRoute
from pydantic import ValidationError
from starlette.types import ASGIApp, Receive, Scope, Send

from servo_app.errors import ECHO_CHARS, close_reason, echoed, json_safe
from servo_app.inputs.feed.models import FeedAck
from servo_app.inputs.feed.registry import _MESSAGE, FeedRegistry, FeedRejected, UnknownSource, field_path

MAX_FEED_MESSAGE_BYTES = 64 * 1024  # one sample per message; as servo_app.api.body_limit.MAX_BODY_BYTES


class Unreadable(ValueError):
    """A WebSocket message that ends the socket: ``code`` and ``reason`` go into the close frame."""

    def __init__(self, code: int, reason: str) -> None:
        super().__init__(reason)
        self.code = code
        self.reason = reason


def _validation_detail(errors: Any) -> list[dict[str, Any]]:
    out = []
    for e in errors:
        shown = repr(e.get("input"))
        if len(shown) > ECHO_CHARS:
            shown = f"{shown[:ECHO_CHARS]}... ({len(shown)} characters in all)"
        out.append({
            "loc": list(e.get("loc", ())), "type": e.get("type"), "msg": e.get("msg"), "input": echoed(e.get("input")),
            "message": f"field {field_path(e.get('loc', ()))!r} value {shown}: {e.get('msg')}",
        })
    return out


def _inlined(schema: dict[str, Any]) -> dict[str, Any]:
    """A JSON schema with its local ``$defs`` written in place: the route declares its body itself, so
    the definitions are not among the document's components."""
    defs = schema.get("$defs", {})

    def walk(node: Any) -> Any:
        if isinstance(node, dict):
            ref = node.get("$ref", "")
            if ref.startswith("#/$defs/"):
                return walk(defs[ref.removeprefix("#/$defs/")])
            return {k: walk(v) for k, v in node.items() if k not in ("$defs", "discriminator")}
        if isinstance(node, list):
            return [walk(v) for v in node]
        return node

    return walk(schema)  # type: ignore[no-any-return]


_FEED_BODY: dict[str, Any] = {"requestBody": {"required": True, "content": {"application/json": {
    "schema": _inlined(_MESSAGE.json_schema())}}}}


def _route_class(registry: FeedRegistry) -> type[APIRoute]:
    class FeedRoute(APIRoute):
        def get_route_handler(self) -> Callable[[Request], Coroutine[Any, Any, Response]]:
            handler = super().get_route_handler()

            async def guarded(request: Request) -> Response:
                try:
                    return await handler(request)
                except RequestValidationError as exc:
                    detail = _validation_detail(exc.errors())
                    source = request.path_params.get("source")
                    if source:
                        registry.note_rejected(source, "; ".join(d["message"] for d in detail))
                    return JSONResponse({"detail": detail}, status_code=422)

            return guarded

    return FeedRoute


FeedPost = Callable[[str, Request], Coroutine[Any, Any, Response]]


def feed_post_handler(registry: FeedRegistry, auth_dependency: Callable[..., Any] | None = None) -> FeedPost:
    """``POST /api/feed/{source}``: every answer (401, 404, 422 included) is a response, not an exception,
    so :class:`FeedPostFastPath` can serve it without FastAPI's exception handlers around it."""

    async def post_feed(source: str, request: Request) -> Response:
        try:
            if auth_dependency is not None and inspect.isawaitable(checked := auth_dependency(request)):
                await checked
            try:
                message = _MESSAGE.validate_json(await request.body())
            except ValidationError as exc:
                detail = _validation_detail([{**e, "loc": ("body", *e["loc"])} for e in exc.errors()])
                registry.note_rejected(source, "; ".join(d["message"] for d in detail))
                return JSONResponse({"detail": detail}, status_code=422)
            try:
                ack = registry.submit(source, message)
            except UnknownSource as exc:
                raise HTTPException(404, str(exc.args[0])) from None
            except FeedRejected as exc:
                raise HTTPException(422, str(exc)) from None
        except HTTPException as exc:
            return JSONResponse({"detail": exc.detail}, status_code=exc.status_code, headers=exc.headers)
        return Response(ack.model_dump_json(), media_type="application/json")

    return post_feed


class FeedPostFastPath:
    """ASGI middleware: ``POST /api/feed/{source}`` goes straight to the feed's handler, past Starlette's
    routing and FastAPI's request machinery, which took 0.4 ms of a sample's 0.8 ms way from the
    client's socket to the servo's slot (bench/input_latency.py). The route stays declared (same
    handler) for the OpenAPI document; everything else passes through to the app."""

    PREFIX = "/api/feed/"

    def __init__(self, app: ASGIApp, handler: FeedPost) -> None:
        self.app = app
        self.handler = handler

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] == "http" and scope["method"] == "POST":
            path: str = scope["path"]
            source = path[len(self.PREFIX):]
            if path.startswith(self.PREFIX) and source and "/" not in source:
                response = await self.handler(source, Request(scope, receive))
                await response(scope, receive, send)
                return
        await self.app(scope, receive, send)


def feed_router(registry: FeedRegistry, auth_dependency: Callable[..., Any] | None = None) -> APIRouter:
    deps = [Depends(auth_dependency)] if auth_dependency is not None else []
    router = APIRouter(tags=["feeds"], route_class=_route_class(registry))
    handler = feed_post_handler(registry, auth_dependency)

    @router.post("/api/feed/{source}", response_model=FeedAck, openapi_extra=_FEED_BODY, summary="Send one feed sample",
                 responses={401: {"description": "missing or wrong token"}, 404: {"description": "unknown source"},
                            413: {"description": "body too large"}, 422: {"description": "rejected sample"}})
    async def post_feed(source: str, request: Request) -> Response:
        """One sample (pose, twist or measurement; its kind must be the source's), stamped with the
        sender's wall clock if it can. Token only (a sensor holds no lease). The answer says whether
        it was taken (``accepted``), the slot's sequence number and the measured latency."""
        # The token and the body are checked in the handler (the body in pydantic's JSON parser), not
        # through FastAPI's dependency and body machinery; with FeedPostFastPath installed the
        # handler is reached without this route.
        return await handler(source, request)

    @router.get("/api/feed", dependencies=deps, summary="Feed statistics")
    async def feed_stats() -> list[dict[str, Any]]:
        """Per feed source: samples accepted, rejected, out of order and resynchronised, the rate, the
        latency (last, mean, max) and the last error. Token only."""
        return [json_safe(asdict(s)) for s in registry.all_stats()]

    @router.websocket("/ws/feed/{source}", dependencies=deps)
    async def ws_feed(ws: WebSocket, source: str, ack: bool = False) -> None:
        """One JSON feed message per text frame. Replies only to rejected messages unless ?ack=true."""
        await ws.accept()
        if source not in registry.names():
            await ws.close(code=1008, reason=close_reason(f"unknown feed source {source!r}"))
            return
        try:
            while True:
                message = await ws.receive()
                if message["type"] == "websocket.disconnect":
                    return
                try:
                    reply = _submit_text(registry, source, _frame_text(message))
                except Unreadable as exc:
                    registry.note_rejected(source, exc.reason)
                    await ws.close(code=exc.code, reason=close_reason(exc.reason))
                    return
                if ack or not reply["accepted"]:
                    await ws.send_text(json.dumps(reply, allow_nan=False))
                # Let the event loop run between messages: with frames queued (a sender in a loop without
                # a pause), receive() returns without suspending, and this socket alone held the loop:
                # every other request (a stop among them) waited, up to 5.6 s seen.
                await asyncio.sleep(0)
        except WebSocketDisconnect:
            return

    return router


def _frame_text(message: Any) -> str:
    """The text of a WebSocket message (a binary frame must be UTF-8 JSON too); Unreadable if not."""
    text = message.get("text")
    if text is None:
        data = message.get("bytes") or b""
        if len(data) > MAX_FEED_MESSAGE_BYTES:
            raise Unreadable(status.WS_1009_MESSAGE_TOO_BIG, _too_big(len(data)))
        try:
            text = data.decode()
        except UnicodeDecodeError:
            raise Unreadable(status.WS_1007_INVALID_FRAME_PAYLOAD_DATA, "binary message is not UTF-8 JSON") from None
    if len(text) > MAX_FEED_MESSAGE_BYTES:
        raise Unreadable(status.WS_1009_MESSAGE_TOO_BIG, _too_big(len(text)))
    return str(text)


def _too_big(size: int) -> str:
    return f"message of {size} bytes: a feed message is one sample, at most {MAX_FEED_MESSAGE_BYTES} bytes"


def _submit_text(registry: FeedRegistry, source: str, text: str) -> dict[str, Any]:
    def rejected(detail: str) -> dict[str, Any]:
        return {"source": source, "accepted": False, "seq": registry.slot(source).seq, "latency_ms": None,
                "detail": detail}

    try:
        try:
            payload = json.loads(text)  # Python's parser accepts NaN, so it is rejected by name in submit
        except ValueError as exc:
            detail = f"not JSON: {exc}"
        else:
            if isinstance(payload, dict):
                try:
                    return registry.submit(source, payload).model_dump()
                except FeedRejected as exc:  # already counted by the registry
                    return rejected(str(exc))
            detail = f"message must be a JSON object, got {type(payload).__name__}"
    except RecursionError:  # the parser (or the error's description) went too deep
        raise Unreadable(status.WS_1007_INVALID_FRAME_PAYLOAD_DATA,
                         "message nested too deeply: a feed sample is a flat JSON object") from None
    registry.note_rejected(source, detail)
    return rejected(detail)
