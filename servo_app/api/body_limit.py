"""A size limit on request bodies, in front of everything else (routing, authentication, parsing).

Pure ASGI: a ``Content-Length`` over the limit is answered 413 at once, before the app reads a byte
of the body; a body without one (chunked) is counted as it is received, and refused as soon as it
passes the limit. The server then drops the rest of the body unparsed as it arrives (uvicorn does),
so the client, which sends its whole body before it reads the answer, gets the 413 on a connection
that stays open; a declared body over :data:`CLOSE_ABOVE_BYTES` is not worth reading even to drop
it: ``Connection: close``. Before the
limit, one 2-million-element array from the lease holder held the event loop 16 s in the JSON parser
(no stop, no telemetry, no lease watch meanwhile), and 10 MB bodies without a token slowed
``/api/health`` to 1.3 s.

The limit, :data:`MAX_BODY_BYTES` (64 KiB), is far above the largest legitimate body of a command or
a sample. A jog, a target or a lease request is under 300 bytes; the largest samples are the feed's
(``POST /api/feed/{source}``), and among them a measurement, a map of named values: a 6-axis
force/torque sensor's is about 150 bytes, and even 500 named channels fit in about 16 KiB. The one
upload, ``POST /api/trajectory``, has a limit of its own (``routes``), sized for its largest valid
body: at 64 KiB a CSV of only ~1000 rows fitted, below the route's own 10,000 waypoints.
"""

from __future__ import annotations

import json
from collections.abc import Callable, Mapping

from starlette.exceptions import HTTPException
from starlette.types import ASGIApp, Message, Receive, Scope, Send

MAX_BODY_BYTES = 64 * 1024
CLOSE_ABOVE_BYTES = 1024 * 1024


class BodyTooLarge(HTTPException):
    """Raised from ``receive`` when a body without a Content-Length passes the limit. An HTTPException,
    so request parsers that turn other errors into a 400 (FastAPI's) pass it on as it is."""

    def __init__(self, limit: int, received: int) -> None:
        super().__init__(413, too_large_detail(limit, received, counted=True))


def too_large_detail(limit: int, size: int, *, counted: bool = False) -> str:
    what = f"more than {size} bytes received" if counted else f"Content-Length {size}"
    return (f"request body too large: {what}, the API takes at most {limit} bytes per request "
            + ("(one command or one sample per request)" if limit <= MAX_BODY_BYTES else "on this route"))


Refused = Callable[[Scope, str], None]


class BodyLimit:
    """ASGI middleware: bodies of HTTP requests larger than ``limit`` bytes are answered 413, or than
    ``routes[path]`` on the paths it names.

    ``on_refused(scope, detail)`` is called for each refusal (the app writes motion routes' refusals
    to the audit log)."""

    def __init__(self, app: ASGIApp, limit: int = MAX_BODY_BYTES, on_refused: Refused | None = None,
                 routes: Mapping[str, int] | None = None) -> None:
        self.app = app
        self.limit = limit
        self.on_refused = on_refused
        self.routes = dict(routes or {})

    def _note(self, scope: Scope, detail: str) -> None:
        if self.on_refused is not None:
            self.on_refused(scope, detail)

    async def _refuse(self, scope: Scope, send: Send, detail: str, close: bool = False) -> None:
        body = json.dumps({"detail": detail}).encode()
        headers = [(b"content-type", b"application/json"), (b"content-length", str(len(body)).encode())]
        await send({"type": "http.response.start", "status": 413,
                    "headers": [*headers, (b"connection", b"close")] if close else headers})
        await send({"type": "http.response.body", "body": body})

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        limit = self.routes.get(scope["path"], self.limit)
        for name, value in scope["headers"]:
            if name == b"content-length":
                try:
                    size = int(value)
                except ValueError:
                    break  # the server refuses a malformed Content-Length itself
                if size > limit:
                    detail = too_large_detail(limit, size)
                    self._note(scope, detail)
                    await self._refuse(scope, send, detail, close=size > max(CLOSE_ABOVE_BYTES, limit))
                    return
                break

        received = 0
        started = False

        async def counted_receive() -> Message:
            nonlocal received
            message = await receive()
            if message["type"] == "http.request":
                received += len(message.get("body", b""))
                if received > limit:
                    exc = BodyTooLarge(limit, limit)
                    self._note(scope, str(exc.detail))
                    raise exc
            return message

        async def watched_send(message: Message) -> None:
            nonlocal started
            started = started or message["type"] == "http.response.start"
            await send(message)

        try:
            await self.app(scope, counted_receive, watched_send)
        except BodyTooLarge as exc:  # nothing in the app answered it (noted when raised)
            if started:
                raise
            await self._refuse(scope, send, str(exc.detail))
