"""``/api/lease``: the control lease (one holder at a time; it expires unless renewed), and the watch
that stops the arm when the lease changes hands."""

# No `from __future__ import annotations`: FastAPI reads the dependency annotations at runtime.
import asyncio
import contextlib
import time
from typing import Annotated

from fastapi import APIRouter, Header, HTTPException

from servo_app import messages as msg
from servo_app.api.deps import ApiContext, Audit, Authed, Leases
from servo_app.api.models import Ack, LeaseGranted, LeaseRenewed, LeaseRequest, LeaseView, Problem
from servo_app.errors import CommandRejected

router = APIRouter(tags=["lease"])
_NO_TOKEN = {401: {"model": Problem, "description": "missing or wrong bearer token"}}


@router.get("/api/lease")
def lease_get(leases: Leases) -> LeaseView:
    lease = leases.current()
    if lease is None:
        return LeaseView(held=False)
    return LeaseView(held=True, client=lease.client, expires_in_s=round(lease.expires_at - time.monotonic(), 3))


@router.post("/api/lease", responses={**_NO_TOKEN, 409: {"model": Problem, "description": "held by another client"}})
def lease_acquire(body: LeaseRequest, client: Authed, leases: Leases, audit: Audit) -> LeaseGranted:
    try:
        lease = leases.acquire(body.client, force=body.force, ttl_s=body.ttl_s)
    except PermissionError as exc:
        audit.record(client, "lease.acquire", False, str(exc))
        raise HTTPException(409, str(exc)) from None
    audit.record(client, "lease.acquire", True, {"client": body.client, "force": body.force})
    return LeaseGranted(lease_id=lease.lease_id, client=lease.client, ttl_s=lease.ttl_s)


@router.post("/api/lease/renew",
             responses={**_NO_TOKEN, 409: {"model": Problem, "description": "not the holder, or expired"}})
def lease_renew(client: Authed, leases: Leases, x_lease_id: Annotated[str | None, Header()] = None) -> LeaseRenewed:
    try:
        lease = leases.renew(x_lease_id)
    except PermissionError as exc:
        raise HTTPException(409, str(exc)) from None
    return LeaseRenewed(lease_id=lease.lease_id, ttl_s=lease.ttl_s)


@router.delete("/api/lease", responses=_NO_TOKEN)
def lease_release(client: Authed, leases: Leases, audit: Audit,
                  x_lease_id: Annotated[str | None, Header()] = None) -> Ack:
    leases.release(x_lease_id)
    audit.record(client, "lease.release", True)
    return Ack()


def stop_for_lost_lease(api: ApiContext, holder: str) -> None:
    """The holder lost control: input sources stop commanding, and a streaming arm stops (softly)."""
    service = api.service
    if getattr(service, "inputs", None) is not None and service.inputs.enabled:  # a new holder enables afresh
        with contextlib.suppress(CommandRejected, TimeoutError, RuntimeError):
            service.inputs.enable(False)
    if service.state_vector().get("state") == "streaming":
        # A refusal is in the audit log already; RuntimeError: the service is closing.
        with contextlib.suppress(HTTPException, RuntimeError):
            api.calls.forward("service", "lease.lost", msg.LeaseLost(holder=holder))


async def watch_lease(api: ApiContext) -> None:
    """A lease that expires, is released or is taken over stops the arm (softly; resumable): nobody
    may be left moving it without holding control."""
    seen: tuple[str, str] | None = None  # (lease id, client)
    while True:
        await asyncio.sleep(0.05)
        lease = api.leases.current()
        now = (lease.lease_id, lease.client) if lease else None
        if seen is not None and now != seen:
            await asyncio.to_thread(stop_for_lost_lease, api, seen[1])
        seen = now
