"""``/api/session/*`` and ``/api/reset``: start, stop, resume and end a stream, leave a fault.

Starting, resuming, ending and resetting need the control lease; any authenticated client may stop
the arm, with or without it (a stop must never wait for control). A take-over waits for the old
holder's resume, end or reset let through before it (see servo_app.api.deps.controlling), not for a
start: a start moves nothing (the stream holds the arm where it is) and may take the start timeout,
seconds, which a take-over (the way to take control from a holder gone astray) must not wait behind.
"""

# No `from __future__ import annotations`: FastAPI reads the dependency annotations at runtime.
from fastapi import APIRouter

from servo_app import messages as msg
from servo_app.api.deps import NO_BODY, Authed, Calls, Controlling, LeaseChecked, Service
from servo_app.api.models import REFUSALS, Ack, StopRequest

router = APIRouter(tags=["session"], responses=REFUSALS)


@router.post("/api/session/start", summary="Start a stream", dependencies=NO_BODY)
def session_start(client: LeaseChecked, calls: Calls) -> Ack:
    """Open the link if needed and start streaming, holding the current position (token and lease)."""
    return calls.forward(client, "session.start", msg.Start())


@router.post("/api/session/stop", summary="Stop the arm (any authenticated client)")
def session_stop(client: Authed, calls: Calls, body: StopRequest | None = None) -> Ack:
    """Decelerate to rest and hold there, the stream alive. ``fast``: the shortest ramp, and a reset
    (POST /api/reset) is needed before resuming. Needs the token only, not the lease."""
    fast = bool(body and body.fast)  # counted by reason in the servo process ("stop requested")
    return calls.forward(client, "session.stop", msg.Stop(fast=fast))


@router.post("/api/session/resume", summary="Resume after a stop", dependencies=NO_BODY)
def session_resume(client: Controlling, calls: Calls) -> Ack:
    """Move on from a soft stop (an interrupted target continues); token and lease."""
    return calls.forward(client, "session.resume", msg.Resume())


@router.post("/api/session/end", summary="End the stream", dependencies=NO_BODY)
def session_end(client: Controlling, calls: Calls) -> Ack:
    """Decelerate, send last data at rest and close the stream and its session log (token and lease:
    ending takes the arm away from whoever controls it; to stop it, any client may POST
    /api/session/stop)."""
    return calls.forward(client, "session.end", msg.End())


@router.post("/api/reset", summary="Leave a fault or acknowledge a fast stop", dependencies=NO_BODY)
def reset(client: Controlling, service: Service, calls: Calls) -> Ack:
    """Leave a fault (the embedded simulator's alarm too, as an operator at the pendant would), or
    acknowledge a fast stop before resuming; token and lease."""
    return calls.call(client, "reset", service.reset)
