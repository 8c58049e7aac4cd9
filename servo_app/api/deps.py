"""The routers' dependencies: the app's objects (reached through ``app.state.api``, so the routers
need no closures), the bearer token check and the control lease.

The dependencies are coroutines on purpose: they run on the event loop, with no hop to a worker
thread, so a flood of jogs is refused without tying up the threads the real requests need.
"""

# No `from __future__ import annotations`: FastAPI reads these annotations at runtime.
import contextlib
import secrets
from collections.abc import AsyncIterator, Iterator
from dataclasses import dataclass, field
from typing import Annotated

from fastapi import Depends, Header, HTTPException, Request
from fastapi.exceptions import RequestValidationError
from starlette.requests import HTTPConnection

from servo_app.api.auth import AuditLog, LeaseManager, RateLimiter, token_matches
from servo_app.api.calls import ServiceCalls
from servo_app.api.metrics import Metrics
from servo_app.service import ServoService


@dataclass
class ApiContext:
    """Everything the routes share; one per app, at ``app.state.api``."""

    service: ServoService
    token: str
    leases: LeaseManager
    jog_limiter: RateLimiter
    audit: AuditLog
    metrics: Metrics
    calls: ServiceCalls
    # This run of the service: a client whose telemetry came back tells a restarted service (its leases
    # gone with the old one) from a network loss by it changing.
    run_id: str = field(default_factory=lambda: secrets.token_hex(8))


def api_of(conn: HTTPConnection) -> ApiContext:
    return conn.app.state.api  # type: ignore[no-any-return]


def client_of(conn: HTTPConnection) -> str:
    host = conn.client.host if conn.client else "?"
    return f"{host}:{conn.client.port if conn.client else 0}"


async def context(conn: HTTPConnection) -> ApiContext:
    return api_of(conn)


async def service(conn: HTTPConnection) -> ServoService:
    return api_of(conn).service


async def leases(conn: HTTPConnection) -> LeaseManager:
    return api_of(conn).leases


async def audit(conn: HTTPConnection) -> AuditLog:
    return api_of(conn).audit


async def metrics(conn: HTTPConnection) -> Metrics:
    return api_of(conn).metrics


async def jog_limiter(conn: HTTPConnection) -> RateLimiter:
    return api_of(conn).jog_limiter


async def calls(conn: HTTPConnection) -> ServiceCalls:
    return api_of(conn).calls


async def authed(conn: HTTPConnection, authorization: Annotated[str | None, Header()] = None) -> str:
    """The bearer token; returns the client (host:port)."""
    api = api_of(conn)
    if not token_matches(api.token, authorization):
        api.metrics.count("unauthorized")
        method = conn.scope.get("method", "WS")
        api.audit.record(client_of(conn), f"{method} {conn.url.path}", False, "bad token")
        raise HTTPException(401, "missing or wrong bearer token", headers={"WWW-Authenticate": "Bearer"})
    return client_of(conn)


async def controlling(conn: HTTPConnection, client: Annotated[str, Depends(authed)],
                      x_lease_id: Annotated[str | None, Header()] = None) -> AsyncIterator[str]:
    """The token and the control lease; gives ``lease-holder@host:port``. The request counts as
    acting under the lease until it has answered: a take-over, release or expiry stop waits for it
    (:meth:`LeaseManager.handing_over`), so the old holder's resume or target whose check passed
    just before cannot be carried out after that stop, moving the arm under the new holder's lease.
    Only a short lock on the event loop: a request checked after the hand-over began is refused (409)."""
    api = api_of(conn)
    action = f"{conn.scope.get('method', 'WS')} {conn.url.path}"
    if conn.scope["type"] == "websocket":  # check only: a socket held open would hold off every take-over
        yield lease_holder(api, client, x_lease_id, action)
        return
    with acting_as(api, client, x_lease_id, action) as holder:
        yield holder


async def lease_checked(conn: HTTPConnection, client: Annotated[str, Depends(authed)],
                        x_lease_id: Annotated[str | None, Header()] = None) -> str:
    """The token and the control lease, checked only (a take-over does not wait for the request): for
    a start, which moves nothing and may take the start timeout (seconds) to answer."""
    return lease_holder(api_of(conn), client, x_lease_id, f"{conn.scope.get('method', 'WS')} {conn.url.path}")


async def no_body(request: Request) -> None:
    """For a route that takes no body: refuse one (422), so a request meant for another route, or
    malformed, is not carried out as if it were empty. Nothing, blanks, ``{}`` and ``null`` are no body
    (what clients send for none)."""
    body = await request.body()
    if body.strip() in (b"", b"{}", b"null"):
        return
    raise RequestValidationError([{
        "type": "no_body_expected", "loc": ("body",), "input": None,
        "msg": f"{request.method} {request.url.path} takes no body ({len(body)} bytes sent): send none"}])


def lease_holder(api: ApiContext, client: str, lease_id: str | None, action: str) -> str:
    """``lease-holder@client`` if ``lease_id`` is the current lease's, else 409 (counted and audited)."""
    try:
        lease = api.leases.check(lease_id)
    except PermissionError as exc:
        raise _no_lease(api, client, action, exc) from None
    return f"{lease.client}@{client}"


@contextlib.contextmanager
def acting_as(api: ApiContext, client: str, lease_id: str | None, action: str) -> Iterator[str]:
    """:func:`lease_holder`, and the block counted as acting under the lease (:meth:`LeaseManager.acting`):
    a hand-over's stop comes after it. Shared with the Zenoh interface (servo_app/zenoh_api.py): one
    rule for both."""
    try:
        lease = api.leases.admit(lease_id)
    except PermissionError as exc:
        raise _no_lease(api, client, action, exc) from None
    try:
        yield f"{lease.client}@{client}"
    finally:
        api.leases.done(lease)


def _no_lease(api: ApiContext, client: str, action: str, exc: PermissionError) -> HTTPException:
    api.metrics.count("no_lease")
    api.audit.record(client, action, False, str(exc))
    return HTTPException(409, str(exc))


Context = Annotated[ApiContext, Depends(context)]
Service = Annotated[ServoService, Depends(service)]
Leases = Annotated[LeaseManager, Depends(leases)]
Audit = Annotated[AuditLog, Depends(audit)]
MetricsDep = Annotated[Metrics, Depends(metrics)]
JogLimiter = Annotated[RateLimiter, Depends(jog_limiter)]
Calls = Annotated[ServiceCalls, Depends(calls)]
Authed = Annotated[str, Depends(authed)]
Controlling = Annotated[str, Depends(controlling)]
LeaseChecked = Annotated[str, Depends(lease_checked)]
NO_BODY = [Depends(no_body)]  # a route's ``dependencies`` when it takes no body
