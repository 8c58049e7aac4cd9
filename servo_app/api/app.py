"""The FastAPI application: REST, WebSocket telemetry, Prometheus metrics and the web console.

Thin by design: it validates, authenticates and forwards to :class:`~servo_app.service.ServoService`.
Reads are open (on the configured interface, 127.0.0.1 by default); anything that moves the arm,
writes I/O or changes state needs ``Authorization: Bearer <token>``, and motion also the control lease
(``X-Lease-Id``).
"""

# No `from __future__ import annotations` here: FastAPI resolves the `Depends(authed)` annotations of
# the closures inside create_app at runtime, and string annotations cannot see those locals (the
# dependencies would silently become required query parameters).
import asyncio
import contextlib
import math
import time
from collections.abc import AsyncIterator
from pathlib import Path
from typing import Annotated, Any, Literal

from fastapi import Depends, FastAPI, Header, HTTPException, Request, WebSocket, WebSocketDisconnect
from fastapi.concurrency import run_in_threadpool
from fastapi.encoders import jsonable_encoder
from fastapi.exceptions import RequestValidationError
from fastapi.responses import FileResponse, JSONResponse, PlainTextResponse, RedirectResponse
from fastapi.staticfiles import StaticFiles
from pydantic import BaseModel, Discriminator, Field, Tag, field_validator

from servo_app.api.auth import AuditLog, LeaseManager, RateLimiter, token_matches
from servo_app.api.metrics import Metrics
from servo_app.api.robot_view import robot_view
from servo_app.errors import CommandRejected
from servo_app.service import InvalidRequest, ServoService

WEB_DIR = Path(__file__).resolve().parents[2] / "web"


def _finite(name: str, values: list[float]) -> list[float]:
    for i, v in enumerate(values):
        if not math.isfinite(v):
            raise ValueError(f"{name}[{i}]={v} is not a finite number")
    return values


class TwistJog(BaseModel):
    model_config = {"extra": "forbid"}
    frame: Literal["base", "tool"] = "base"
    linear: list[float] = Field(min_length=3, max_length=3, description="mm/s along x y z")
    angular: list[float] = Field(default=[0.0, 0.0, 0.0], min_length=3, max_length=3, description="deg/s")
    hold_ms: float = Field(200.0, gt=0, le=2000, description="hold-to-run time: keep sending to keep moving")

    @field_validator("linear", "angular")
    @classmethod
    def _fin(cls, v: list[float], info: Any) -> list[float]:
        return _finite(info.field_name, v)


class JointJog(BaseModel):
    model_config = {"extra": "forbid"}
    joints: list[float] = Field(min_length=1, max_length=9, description=(
        "per axis: deg/s (FANUC J1..J6), or mm/s and deg/s (Janome X Y Z R); the backend checks the count"))
    hold_ms: float = Field(200.0, gt=0, le=2000)

    @field_validator("joints")
    @classmethod
    def _fin(cls, v: list[float]) -> list[float]:
        return _finite("joints", v)


class JointTarget(BaseModel):
    model_config = {"extra": "forbid"}
    joints: list[float] = Field(min_length=1, max_length=9, description=(
        "per axis: deg (FANUC convention), or mm and deg (Janome X Y Z R); the backend checks the count"))
    speed_scale: float = Field(1.0, gt=0, le=1)

    @field_validator("joints")
    @classmethod
    def _fin(cls, v: list[float]) -> list[float]:
        return _finite("joints", v)


class PoseTargetBody(BaseModel):
    model_config = {"extra": "forbid"}
    xyzwpr: list[float] = Field(min_length=6, max_length=6, description="TCP pose: X Y Z mm, W P R deg (world)")
    linear_speed: float = Field(100.0, gt=0, le=2000, description="mm/s")
    angular_speed: float = Field(30.0, gt=0, le=360, description="deg/s")

    @field_validator("xyzwpr")
    @classmethod
    def _fin(cls, v: list[float]) -> list[float]:
        return _finite("xyzwpr", v)


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


def _jog_kind(body: Any) -> str:
    # Pick the model by its key, so a bad value is reported against that model's field alone.
    return "joint" if isinstance(body, dict) and "joints" in body else "twist"


JogBody = Annotated[Annotated[JointJog, Tag("joint")] | Annotated[TwistJog, Tag("twist")], Discriminator(_jog_kind)]


class StopRequest(BaseModel):
    model_config = {"extra": "forbid"}
    fast: bool = False


class LeaseRequest(BaseModel):
    model_config = {"extra": "forbid"}
    client: str = Field(min_length=1, max_length=64)
    force: bool = False
    ttl_s: float | None = Field(None, gt=0, description="shorter than the server's TTL if given (never longer)")


class IoWrite(BaseModel):
    model_config = {"extra": "forbid"}
    type: str = Field(description="DO, RO, F, M, ...")
    index: int = Field(ge=1, le=65535)
    mask: int = Field(0xFFFF, ge=0, le=0xFFFF)
    value: int = Field(ge=0, le=0xFFFF)


class Ack(BaseModel):
    ok: bool = True
    detail: Any = None


def create_app(service: ServoService, token: str, *, jog_rate_per_s: int = 100,
               cors_origins: list[str] | None = None, lease_ttl_s: float = 10.0) -> FastAPI:
    leases = LeaseManager(ttl_s=lease_ttl_s)
    jog_limiter = RateLimiter(jog_rate_per_s)
    audit = AuditLog(service.cfg.var_dir / "audit.log")
    metrics = Metrics(lambda: (service.state_vector(), service.stops()))

    def stop_for_lost_lease(holder: str) -> None:
        if getattr(service, "inputs", None) is not None and service.inputs.enabled:  # a new holder enables afresh
            with contextlib.suppress(CommandRejected, TimeoutError, RuntimeError):
                service.inputs.enable(False)
        if service.state_vector().get("state") == "streaming":
            with contextlib.suppress(CommandRejected, TimeoutError, RuntimeError):
                service.request("lease_lost", holder=holder)
                audit.record("service", "lease.lost", True, holder)

    async def watch_lease() -> None:
        """A lease that expires, is released or is taken over stops the arm (softly; resumable): nobody
        may be left moving it without holding control."""
        seen: tuple[str, str] | None = None  # (lease id, client)
        while True:
            await asyncio.sleep(0.05)
            lease = leases.current()
            now = (lease.lease_id, lease.client) if lease else None
            if seen is not None and now != seen:
                await asyncio.to_thread(stop_for_lost_lease, seen[1])
            seen = now

    @contextlib.asynccontextmanager
    async def lifespan(_: FastAPI) -> AsyncIterator[None]:
        task = asyncio.create_task(watch_lease())
        try:
            yield
        finally:
            task.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await task

    app = FastAPI(title="servo_app", version="0.1.0", lifespan=lifespan,
                  description="Online servo control of industrial robot arms (FANUC Stream Motion J519).")
    app.state.service, app.state.leases, app.state.metrics = service, leases, metrics

    @app.exception_handler(RequestValidationError)
    async def invalid_request(request: Request, exc: RequestValidationError) -> JSONResponse:
        return JSONResponse(status_code=422, content={"detail": jsonable_encoder(_json_safe(list(exc.errors())))})

    def client_of(request: Request) -> str:
        host = request.client.host if request.client else "?"
        return f"{host}:{request.client.port if request.client else 0}"

    # The dependencies are async (they run on the event loop, no thread hop): a flood of jogs is
    # refused without tying up the worker threads the real requests need.
    async def authed(request: Request, authorization: Annotated[str | None, Header()] = None) -> str:
        if not token_matches(token, authorization):
            metrics.count("unauthorized")
            audit.record(client_of(request), f"{request.method} {request.url.path}", False, "bad token")
            raise HTTPException(401, "missing or wrong bearer token", headers={"WWW-Authenticate": "Bearer"})
        return client_of(request)

    async def controlling(request: Request, client: Annotated[str, Depends(authed)],
                          x_lease_id: Annotated[str | None, Header()] = None) -> str:
        try:
            lease = leases.check(x_lease_id)
        except PermissionError as exc:
            metrics.count("no_lease")
            audit.record(client, f"{request.method} {request.url.path}", False, str(exc))
            raise HTTPException(409, str(exc)) from None
        return f"{lease.client}@{client}"

    def forward(client: str, action: str, op: str, *, at: float | None = None, **kw: Any) -> Ack:
        return call(client, action, lambda: service.request(op, **kw), kw, at)

    def call(client: str, action: str, fn: Any, detail: Any = None, at: float | None = None) -> Ack:
        """Run a service call; refusals become 422 (invalid here), 409 (refused by the state) or 503.
        ``at``: when the request was admitted, for the audit line (default: now)."""
        at = time.time() if at is None else at
        try:
            result = fn()
        except InvalidRequest as exc:
            audit.record(client, action, False, str(exc), at)
            raise HTTPException(422, str(exc)) from None
        except CommandRejected as exc:
            audit.record(client, action, False, str(exc), at)
            raise HTTPException(409, str(exc)) from None
        except TimeoutError as exc:
            audit.record(client, action, False, str(exc), at)
            raise HTTPException(503, str(exc)) from None
        audit.record(client, action, True, detail or None, at)
        return Ack(detail=result)

    # ---------------------------------------------------------------- session
    @app.post("/api/session/start", tags=["session"])
    def session_start(client: Annotated[str, Depends(controlling)]) -> Ack:
        return forward(client, "session.start", "start")

    @app.post("/api/session/stop", tags=["session"])
    def session_stop(client: Annotated[str, Depends(authed)], body: StopRequest | None = None) -> Ack:
        # Any authenticated client may stop the arm, with or without the lease.
        fast = bool(body and body.fast)  # counted by reason in the servo process ("stop requested")
        return forward(client, "session.stop", "stop", fast=fast)

    @app.post("/api/session/resume", tags=["session"])
    def session_resume(client: Annotated[str, Depends(controlling)]) -> Ack:
        return forward(client, "session.resume", "resume")

    @app.post("/api/session/end", tags=["session"])
    def session_end(client: Annotated[str, Depends(authed)]) -> Ack:
        return forward(client, "session.end", "end")

    @app.post("/api/reset", tags=["session"])
    def reset(client: Annotated[str, Depends(controlling)]) -> Ack:
        try:
            service.reset()
        except CommandRejected as exc:
            raise HTTPException(409, str(exc)) from None
        audit.record(client, "reset", True)
        return Ack()

    # ----------------------------------------------------------------- motion
    @app.post("/api/jog", tags=["motion"])
    async def jog(body: JogBody, request: Request, client: Annotated[str, Depends(controlling)]) -> Ack:
        # Keyed by host, not host:port: a new connection must not buy a fresh allowance.
        if not jog_limiter.allow(client.split("@")[-1].rsplit(":", 1)[0]):
            metrics.count("rate_limited")
            audit.record(client, "jog", False, "rate limited")
            raise HTTPException(429, f"jog requests limited to {jog_limiter.per_second} per second per client")
        admitted = time.time()
        if isinstance(body, JointJog):
            return await run_in_threadpool(forward, client, "jog", "jog", at=admitted, joints=body.joints,
                                           hold_s=body.hold_ms / 1000)
        return await run_in_threadpool(forward, client, "jog", "twist", at=admitted, frame=body.frame,
                                       linear=body.linear, angular=body.angular, hold_s=body.hold_ms / 1000)

    @app.post("/api/target", tags=["motion"])
    def target(body: JointTarget | PoseTargetBody, client: Annotated[str, Depends(controlling)]) -> Ack:
        if isinstance(body, PoseTargetBody):
            return forward(client, "target", "pose", xyzwpr=body.xyzwpr, linear_speed=body.linear_speed,
                           angular_speed=body.angular_speed)
        return forward(client, "target", "target", joints=body.joints, speed_scale=body.speed_scale)

    # ------------------------------------------------------------------ lease
    @app.get("/api/lease", tags=["lease"])
    def lease_get() -> dict[str, Any]:
        lease = leases.current()
        return {"held": lease is not None, "client": lease.client if lease else None,
                "expires_in_s": round(lease.expires_at - time.monotonic(), 3) if lease else None}

    @app.post("/api/lease", tags=["lease"])
    def lease_acquire(body: LeaseRequest, client: Annotated[str, Depends(authed)]) -> dict[str, Any]:
        try:
            lease = leases.acquire(body.client, force=body.force, ttl_s=body.ttl_s)
        except PermissionError as exc:
            audit.record(client, "lease.acquire", False, str(exc))
            raise HTTPException(409, str(exc)) from None
        audit.record(client, "lease.acquire", True, {"client": body.client, "force": body.force})
        return {"lease_id": lease.lease_id, "client": lease.client, "ttl_s": lease.ttl_s}

    @app.post("/api/lease/renew", tags=["lease"])
    def lease_renew(client: Annotated[str, Depends(authed)],
                    x_lease_id: Annotated[str | None, Header()] = None) -> dict[str, Any]:
        try:
            lease = leases.renew(x_lease_id)
        except PermissionError as exc:
            raise HTTPException(409, str(exc)) from None
        return {"lease_id": lease.lease_id, "ttl_s": lease.ttl_s}

    @app.delete("/api/lease", tags=["lease"])
    def lease_release(client: Annotated[str, Depends(authed)],
                      x_lease_id: Annotated[str | None, Header()] = None) -> Ack:
        leases.release(x_lease_id)
        audit.record(client, "lease.release", True)
        return Ack()

    # ------------------------------------------------------------------ views
    @app.get("/api/health", tags=["state"])
    def health() -> dict[str, Any]:
        return {"ok": True}

    @app.get("/api/state", tags=["state"])
    def state() -> dict[str, Any]:
        s = service.state()
        lease = leases.current()
        s["lease"] = {"held": lease is not None, "client": lease.client if lease else None}
        s["stops_by_reason"] = service.stops()
        return s

    @app.get("/api/limits", tags=["state"])
    def limits() -> dict[str, Any]:
        return service.limits()

    @app.get("/api/robot", tags=["state"])
    def robot() -> dict[str, Any]:
        """Arm geometry for the console: profile dimensions, ranges, FK points of the current joints."""
        st = service.stream.state() if service.stream is not None else {}
        q = st.get("q_servo") if st.get("status_received") else st.get("q_cmd")
        return robot_view(service.profile, q or [0.0] * 6)

    @app.get("/api/io", tags=["io"])
    def io_read(type: str, index: int, client: Annotated[str, Depends(authed)], mask: int = 0xFFFF) -> Ack:
        """Read 16 points from ``index`` through the command packets (only while streaming)."""
        return call(client, "io.read", lambda: service.io_read(type, index, mask),
                    {"type": type, "index": index, "mask": mask})

    @app.post("/api/io", tags=["io"])
    def io_write(body: IoWrite, client: Annotated[str, Depends(controlling)]) -> Ack:
        """Write the masked points of the 16 from ``index`` with the next command packet."""
        return call(client, "io.write", lambda: service.io_write(body.type, body.index, body.mask, body.value),
                    body.model_dump())

    @app.get("/api/sessions", tags=["logs"])
    def sessions() -> list[dict[str, Any]]:
        return service.session_logs()

    @app.get("/api/sessions/{name}", tags=["logs"])
    def session_download(name: str) -> FileResponse:
        try:
            path = service.session_log_path(name)
        except FileNotFoundError as exc:
            raise HTTPException(404, str(exc)) from None
        return FileResponse(path, media_type="application/octet-stream", filename=name)

    @app.get("/metrics", tags=["state"], response_class=PlainTextResponse)
    def prometheus() -> PlainTextResponse:
        return PlainTextResponse(metrics.render(), media_type="text/plain; version=0.0.4")

    @app.websocket("/ws/telemetry")
    async def telemetry(ws: WebSocket, hz: float = 50.0) -> None:
        await ws.accept()
        period = 1.0 / min(max(hz, 1.0), 100.0)
        loop = asyncio.get_running_loop()
        due = loop.time()
        try:
            while True:
                s = await asyncio.to_thread(state)
                await ws.send_json(s)
                # Absolute deadlines, so the time spent reading and sending does not lower the rate;
                # after a stall, carry on from now rather than sending a burst.
                due = max(due + period, loop.time() - period)
                await asyncio.sleep(max(0.0, due - loop.time()))
        except (WebSocketDisconnect, RuntimeError, OSError):  # the client went away
            return

    if getattr(service, "inputs", None) is not None:  # servo-app run --inputs: feeds, sources, applications
        from servo_app.api.inputs_router import include_inputs

        include_inputs(app, service.inputs, token=token, controlling=controlling, call=call, metrics=metrics,
                       audit=audit)

    if WEB_DIR.is_dir():
        app.mount("/web", StaticFiles(directory=WEB_DIR, html=True), name="web")

        @app.get("/", include_in_schema=False)
        def index() -> RedirectResponse:
            return RedirectResponse("/web/")

    if cors_origins:  # added last: the outermost middleware, in front of the feed's fast path too
        from fastapi.middleware.cors import CORSMiddleware

        app.add_middleware(CORSMiddleware, allow_origins=cors_origins, allow_methods=["*"], allow_headers=["*"])
    return app
