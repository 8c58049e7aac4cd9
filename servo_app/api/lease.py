"""``/api/lease``: the control lease (one holder at a time; it expires unless renewed).

A lease that changes hands stops the arm (softly; resumable): nobody may be left moving it without
holding control. A take-over and a release stop it in their own request, before answering, so the
new holder's first jog cannot be accepted into the old holder's motion; an expiry is found by
:func:`watch_lease`.
"""

# No `from __future__ import annotations`: FastAPI reads the dependency annotations at runtime.
import asyncio
import contextlib
import time
from typing import Annotated

from fastapi import APIRouter, Header, HTTPException

from servo_app import messages as msg
from servo_app.api.deps import NO_BODY, ApiContext, Audit, Authed, Context, Leases
from servo_app.api.models import Ack, LeaseGranted, LeaseRenewed, LeaseRequest, LeaseView, Problem
from servo_app.errors import CommandRejected

router = APIRouter(tags=["lease"])
_NO_TOKEN = {401: {"model": Problem, "description": "missing or wrong bearer token"}}


@router.get("/api/lease", summary="Who holds the control lease")
def lease_get(leases: Leases) -> LeaseView:
    """The holder's name and how long until its lease expires unless renewed (open: no token)."""
    lease = leases.current()
    if lease is None:
        return LeaseView(held=False)
    return LeaseView(held=True, client=lease.client, expires_in_s=round(lease.expires_at - time.monotonic(), 3))


@router.post("/api/lease", summary="Take the control lease",
             responses={**_NO_TOKEN, 409: {"model": Problem, "description": "held by another client: the text "
                                                                            "says how to take it over"}})
def lease_acquire(body: LeaseRequest, client: Authed, api: Context) -> LeaseGranted:
    """Take control: motion, I/O writes, start, resume, end and reset need the returned ``lease_id``
    as ``X-Lease-Id``. Refused (409) while another lease is live unless ``force`` is true; a
    take-over stops the old holder's motion (softly; resumable) before this request answers."""
    try:
        # The stop comes after any action the old holder's check let through (handing_over waits).
        with api.leases.handing_over(lambda: api.leases.take(body.client, force=body.force, ttl_s=body.ttl_s)) \
                as (lease, displaced):
            api.audit.record(client, "lease.acquire", True, {"client": body.client, "force": body.force})
            if displaced is not None:
                stop_for_lost_lease(api, displaced.client)
    except PermissionError as exc:  # from take: held by another, nothing changed
        api.audit.record(client, "lease.acquire", False, str(exc))
        raise HTTPException(409, str(exc)) from None
    return LeaseGranted(lease_id=lease.lease_id, client=lease.client, ttl_s=lease.ttl_s)


@router.post("/api/lease/renew", summary="Renew the control lease", dependencies=NO_BODY,
             responses={**_NO_TOKEN, 409: {"model": Problem, "description": "not the holder, or expired"}})
def lease_renew(client: Authed, leases: Leases, x_lease_id: Annotated[str | None, Header()] = None) -> LeaseRenewed:
    """Push the expiry of the lease named by ``X-Lease-Id`` one TTL ahead (send it well within the TTL)."""
    try:
        lease = leases.renew(x_lease_id)
    except PermissionError as exc:
        raise HTTPException(409, str(exc)) from None
    return LeaseRenewed(lease_id=lease.lease_id, ttl_s=lease.ttl_s)


@router.delete("/api/lease", summary="Release the control lease", dependencies=NO_BODY,
               responses={**_NO_TOKEN, 409: {"model": Problem, "description": "the X-Lease-Id is not the holder's"}})
def lease_release(client: Authed, api: Context, audit: Audit,
                  x_lease_id: Annotated[str | None, Header()] = None) -> Ack:
    """Give up control (the lease named by ``X-Lease-Id``): a streaming arm stops softly first. Refused
    (409) when another client holds the lease; nothing to release (nobody holds it) is no error."""
    try:
        with api.leases.handing_over(lambda: api.leases.release(x_lease_id)) as released:
            audit.record(client, "lease.release", True, {"client": released.client} if released else None)
            if released is not None:
                stop_for_lost_lease(api, released.client)
    except PermissionError as exc:  # from release: another's lease, nothing released
        audit.record(client, "lease.release", False, str(exc))
        raise HTTPException(409, str(exc)) from None
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
    """A lease that expires stops the arm (softly; resumable). Take-overs and releases stop it in
    their own requests (see :func:`lease_acquire`): only an expiry nobody followed up comes here."""
    while True:
        await asyncio.sleep(0.05)
        if api.leases.expired_unstopped():
            await asyncio.to_thread(_stop_expired, api)


def _stop_expired(api: ApiContext) -> None:
    # Popped in the hand-over: after the expired lease's actions let through before it, and, if a
    # take-over came first (and stopped it itself), nothing.
    with api.leases.handing_over(api.leases.pop_expired) as lost:
        if lost is not None:
            stop_for_lost_lease(api, lost.client)
