"""The FastAPI application: REST, WebSocket telemetry, Prometheus metrics and the web console.

Thin by design: it validates, authenticates and forwards to :class:`~servo_app.service.ServoService`.
Reads are open (on the configured interface, 127.0.0.1 by default); anything that moves the arm,
writes I/O or changes state needs ``Authorization: Bearer <token>``, and motion also the control lease
(``X-Lease-Id``).

One router per resource (session, motion, lease, state, io, logs, telemetry); the routes reach the
app's objects through the dependencies of :mod:`servo_app.api.deps` (``app.state.api``), answer with
the models of :mod:`servo_app.api.models`, and send every request to the servo process through
:meth:`servo_app.api.calls.ServiceCalls.forward`.
"""

from __future__ import annotations

import asyncio
import contextlib
import math
from collections.abc import AsyncIterator
from pathlib import Path
from typing import Any

from fastapi import FastAPI, Request
from fastapi.encoders import jsonable_encoder
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse, RedirectResponse
from fastapi.staticfiles import StaticFiles

from servo_app.api import io, lease, logs, motion, session, state, telemetry
from servo_app.api.auth import AuditLog, LeaseManager, RateLimiter
from servo_app.api.calls import ServiceCalls
from servo_app.api.deps import ApiContext, controlling
from servo_app.api.metrics import Metrics
from servo_app.service import ServoService

WEB_DIR = Path(__file__).resolve().parents[2] / "web"


def _json_safe(value: Any) -> Any:
    """A validation error echoes its input: NaN or Infinity there would make the 422 itself fail to
    encode (a 500). Non-finite numbers become their names, exceptions their messages."""
    if isinstance(value, float) and not math.isfinite(value):
        return str(value)
    if isinstance(value, BaseException):
        return str(value)
    if isinstance(value, dict):
        return {k: _json_safe(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_json_safe(v) for v in value]
    return value


async def _invalid_request(request: Request, exc: Exception) -> JSONResponse:
    assert isinstance(exc, RequestValidationError)
    return JSONResponse(status_code=422, content={"detail": jsonable_encoder(_json_safe(list(exc.errors())))})


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

    app = FastAPI(title="servo_app", version="0.1.0", lifespan=lifespan,
                  description="Online servo control of industrial robot arms (FANUC Stream Motion J519).")
    app.state.api = api
    app.state.service, app.state.leases, app.state.metrics = service, api.leases, api.metrics
    app.add_exception_handler(RequestValidationError, _invalid_request)

    for module in (session, motion, lease, state, io, logs, telemetry):
        app.include_router(module.router)

    if getattr(service, "inputs", None) is not None:  # servo-app run --inputs: feeds, sources, applications
        from servo_app.api.inputs_router import include_inputs

        include_inputs(app, service.inputs, token=token, controlling=controlling, call=api.calls.call,
                       metrics=api.metrics, audit=audit)

    if WEB_DIR.is_dir():
        app.mount("/web", StaticFiles(directory=WEB_DIR, html=True), name="web")

        @app.get("/", include_in_schema=False)
        def index() -> RedirectResponse:
            return RedirectResponse("/web/")

    if cors_origins:  # added last: the outermost middleware, in front of the feed's fast path too
        from fastapi.middleware.cors import CORSMiddleware

        app.add_middleware(CORSMiddleware, allow_origins=cors_origins, allow_methods=["*"], allow_headers=["*"])
    return app
