"""The FastAPI application: REST, WebSocket telemetry, Prometheus metrics and the web console.

Thin by design: it validates, authenticates and forwards to :class:`~servo_app.service.ServoService`.
Reads are open (on the configured interface, 127.0.0.1 by default); anything that moves the arm,
writes I/O or changes state needs ``Authorization: Bearer <token>``, and motion also the control lease
(``X-Lease-Id``).

One router per resource (session, motion, lease, state, io, logs, telemetry); the routes reach the
app's objects through the dependencies of :mod:`servo_app.api.deps` (``app.state.api``), answer with
the models of :mod:`servo_app.api.models`, and send every request to the servo process through
:meth:`servo_app.api.calls.ServiceCalls.forward`.

In front of everything, :class:`~servo_app.api.body_limit.BodyLimit` refuses bodies over
:data:`~servo_app.api.body_limit.MAX_BODY_BYTES` (413; the trajectory upload has a limit of its own)
before any parsing or authentication. The
interactive documentation (``/docs``) is served from the ``fastapi-offline`` package's copy of
Swagger UI: no CDN, so it works on a machine cut off from the internet.
"""

from __future__ import annotations

import asyncio
import contextlib
from collections.abc import AsyncIterator
from pathlib import Path
from typing import Any

from fastapi import FastAPI, Request
from fastapi.encoders import jsonable_encoder
from fastapi.exception_handlers import http_exception_handler
from fastapi.exceptions import RequestValidationError
from fastapi.openapi.docs import get_swagger_ui_html, get_swagger_ui_oauth2_redirect_html
from fastapi.responses import HTMLResponse, JSONResponse, RedirectResponse
from fastapi.staticfiles import StaticFiles
from starlette.exceptions import HTTPException as StarletteHTTPException
from starlette.types import Scope

from servo_app.api import io, lease, logs, motion, points, session, state, telemetry, tools, trajectory
from servo_app.api.auth import AuditLog, LeaseManager, RateLimiter
from servo_app.api.body_limit import MAX_BODY_BYTES, BodyLimit
from servo_app.api.calls import ServiceCalls
from servo_app.api.deps import ApiContext, api_of, client_of, controlling
from servo_app.api.metrics import Metrics
from servo_app.api.models import TOO_DEEP
from servo_app.api.openapi_doc import document_robot
from servo_app.errors import validation_errors
from servo_app.service import ServoService

WEB_DIR = Path(__file__).resolve().parents[2] / "web"


def audited(method: str, path: str) -> bool:
    """Requests that move the arm or change state (motion, session, lease, I/O writes, inputs): their
    refusals go to the audit log too. Feed samples do not (a sensor streams hundreds a second)."""
    return method in ("POST", "PUT", "DELETE") and path.startswith("/api/") and not path.startswith("/api/feed/")


def _client_of_scope(scope: Scope) -> str:
    client = scope.get("client")
    return f"{client[0]}:{client[1]}" if client else "?:0"


async def _invalid_request(request: Request, exc: Exception) -> JSONResponse:
    assert isinstance(exc, RequestValidationError)
    detail = jsonable_encoder(validation_errors(list(exc.errors())))
    if audited(request.method, request.url.path):
        api = api_of(request)
        api.metrics.count("invalid")
        api.audit.record(client_of(request), f"{request.method} {request.url.path}", False,
                         {"status": 422, "errors": [{"loc": e.get("loc"), "msg": e.get("msg")} for e in detail]})
    return JSONResponse(status_code=422, content={"detail": detail})


async def _http_error(request: Request, exc: Exception) -> Any:
    """A body that is not text (not UTF-8), or nested too deep to parse, is a bad request like any
    other: 422 naming it, not FastAPI's 400 "There was an error parsing the body" (a JSON syntax error
    is a 422 already)."""
    assert isinstance(exc, StarletteHTTPException)
    if exc.status_code == 400 and isinstance(exc.__cause__, RecursionError):
        return await _invalid_request(request, RequestValidationError([{
            "type": "json_invalid", "loc": ("body",), "msg": TOO_DEEP, "input": None}]))
    if exc.status_code == 400 and isinstance(exc.__cause__, UnicodeDecodeError):
        err = exc.__cause__
        return await _invalid_request(request, RequestValidationError([{
            "type": "json_invalid", "loc": ("body", err.start),
            "msg": f"the body is not UTF-8 text (byte {err.object[err.start:err.start + 1]!r} at {err.start}): "
                   "send JSON", "input": None}]))
    return await http_exception_handler(request, exc)


def _offline_docs(app: FastAPI) -> None:
    """Swagger UI at /docs from the fastapi-offline package's files (FastAPI's own page loads them, and
    the favicon, from CDNs: a blank page without internet). No /redoc: its page loads a logo from a
    CDN whatever the options."""
    import fastapi_offline

    assets = Path(fastapi_offline.__file__).resolve().parent / "static"
    app.mount("/docs-assets", StaticFiles(directory=assets), name="docs-assets")
    oauth2 = app.swagger_ui_oauth2_redirect_url or "/docs/oauth2-redirect"

    @app.get("/docs", include_in_schema=False)
    def swagger_ui() -> HTMLResponse:
        return get_swagger_ui_html(openapi_url=str(app.openapi_url), title=f"{app.title} - API",
                                   oauth2_redirect_url=oauth2, swagger_js_url="/docs-assets/swagger-ui-bundle.js",
                                   swagger_css_url="/docs-assets/swagger-ui.css",
                                   swagger_favicon_url="/docs-assets/favicon.png")

    @app.get(oauth2, include_in_schema=False)
    def swagger_ui_redirect() -> HTMLResponse:
        return get_swagger_ui_oauth2_redirect_html()


def create_app(service: ServoService, token: str, *, jog_rate_per_s: int = 100,
               cors_origins: list[str] | None = None, lease_ttl_s: float = 10.0) -> FastAPI:
    audit = AuditLog(service.cfg.var_dir / "audit.log")
    api = ApiContext(service=service, token=token, leases=LeaseManager(ttl_s=lease_ttl_s),
                     jog_limiter=RateLimiter(jog_rate_per_s), audit=audit,
                     metrics=Metrics(lambda: (service.state_vector(), service.stops())),
                     calls=ServiceCalls(service, audit))

    @contextlib.asynccontextmanager
    async def lifespan(_: FastAPI) -> AsyncIterator[None]:
        task = asyncio.create_task(lease.watch_lease(api))
        try:
            yield
        finally:
            task.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await task

    app = FastAPI(title="servo_app", version="0.1.0", lifespan=lifespan, docs_url=None, redoc_url=None,
                  description="Online servo control of industrial robot arms (FANUC Stream Motion J519, "
                              "Janome). Reads are open; anything that moves the arm or changes state needs "
                              "`Authorization: Bearer <token>`, and most also the control lease "
                              "(`X-Lease-Id`, from `POST /api/lease`). Request bodies: at most "
                              f"{MAX_BODY_BYTES} bytes, {trajectory.MAX_BODY_BYTES} for `POST /api/trajectory` "
                              "(413).")
    _offline_docs(app)
    app.state.api = api
    app.state.service, app.state.leases, app.state.metrics = service, api.leases, api.metrics
    app.add_exception_handler(RequestValidationError, _invalid_request)
    app.add_exception_handler(StarletteHTTPException, _http_error)

    for module in (session, motion, lease, state, io, logs, telemetry, points, tools, trajectory):
        app.include_router(module.router)

    plain_openapi = app.openapi

    def openapi() -> dict[str, Any]:
        # The configured robot's axis count, I/O and payload, once (FastAPI caches the document).
        if app.openapi_schema is None:
            document_robot(plain_openapi(), service.backend, service.tools.max_payload_kg)
        return app.openapi_schema  # type: ignore[return-value]

    app.openapi = openapi  # type: ignore[method-assign]

    if getattr(service, "inputs", None) is not None:  # servo-app run --inputs: feeds, sources, applications
        from servo_app.api.inputs_router import include_inputs

        include_inputs(app, service.inputs, token=token, controlling=controlling, call=api.calls.call,
                       metrics=api.metrics, audit=audit)

    if WEB_DIR.is_dir():
        app.mount("/web", StaticFiles(directory=WEB_DIR, html=True), name="web")

        @app.get("/", include_in_schema=False)
        def index() -> RedirectResponse:
            return RedirectResponse("/web/")

    def body_refused(scope: Scope, detail: str) -> None:
        api.metrics.count("too_large")
        if audited(scope["method"], scope["path"]):
            audit.record(_client_of_scope(scope), f"{scope['method']} {scope['path']}", False,
                         {"status": 413, "detail": detail})

    # In front of the feed's fast path and of every route: before authentication and parsing.
    app.add_middleware(BodyLimit, limit=MAX_BODY_BYTES, on_refused=body_refused,
                       routes={"/api/trajectory": trajectory.MAX_BODY_BYTES})  # the one upload

    if cors_origins:  # added last: the outermost middleware, in front of the feed's fast path too
        from fastapi.middleware.cors import CORSMiddleware

        app.add_middleware(CORSMiddleware, allow_origins=cors_origins, allow_methods=["*"], allow_headers=["*"])
    return app
