"""``/api/session/*`` and ``/api/reset``: start, stop, resume and end a stream, leave a fault.

Starting, resuming and resetting need the control lease; any authenticated client may stop the arm
or end the stream, with or without it.
"""

# No `from __future__ import annotations`: FastAPI reads the dependency annotations at runtime.
from fastapi import APIRouter

from servo_app import messages as msg
from servo_app.api.deps import Authed, Calls, Controlling, Service
from servo_app.api.models import REFUSALS, Ack, StopRequest

router = APIRouter(tags=["session"], responses=REFUSALS)


@router.post("/api/session/start")
def session_start(client: Controlling, calls: Calls) -> Ack:
    return calls.forward(client, "session.start", msg.Start())


@router.post("/api/session/stop")
def session_stop(client: Authed, calls: Calls, body: StopRequest | None = None) -> Ack:
    # Any authenticated client may stop the arm, with or without the lease.
    fast = bool(body and body.fast)  # counted by reason in the servo process ("stop requested")
    return calls.forward(client, "session.stop", msg.Stop(fast=fast))


@router.post("/api/session/resume")
def session_resume(client: Controlling, calls: Calls) -> Ack:
    return calls.forward(client, "session.resume", msg.Resume())


@router.post("/api/session/end")
def session_end(client: Authed, calls: Calls) -> Ack:
    return calls.forward(client, "session.end", msg.End())


@router.post("/api/reset")
def reset(client: Controlling, service: Service, calls: Calls) -> Ack:
    """Leave a fault (the embedded simulator's alarm too, as an operator at the pendant would)."""
    return calls.call(client, "reset", service.reset)
