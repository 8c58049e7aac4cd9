"""``/api/jog`` (hold-to-run velocity, joint or Cartesian) and ``/api/target`` (joint or pose target).
Both need the token and the control lease."""

# No `from __future__ import annotations`: FastAPI reads the dependency annotations at runtime.
import time

from fastapi import APIRouter, HTTPException, Request
from fastapi.concurrency import run_in_threadpool

from servo_app import messages as msg
from servo_app.api.deps import ApiContext, Calls, Controlling, api_of
from servo_app.api.models import (
    REFUSALS,
    Ack,
    JogBody,
    JointJog,
    JointTarget,
    PoseTargetBody,
    Problem,
    TargetBody,
    TwistJog,
)

router = APIRouter(tags=["motion"], responses=REFUSALS)


@router.post("/api/jog", summary="Jog: hold-to-run velocity, joint or Cartesian",
             responses={429: {"model": Problem, "description": "too many jog requests"}})
async def jog(body: JogBody, client: Controlling, request: Request) -> Ack:
    """Move at a velocity for ``hold_ms``: keep sending (every 50-100 ms) to keep moving; when the
    requests stop, the arm decelerates to rest by itself. ``{"joints": [...]}`` per axis (deg/s, or
    mm/s for a linear axis) or ``{"linear": [x, y, z], "angular": [...], "frame": "base"|"tool"}`` (mm/s,
    deg/s). Resumes a hold-to-run stop. Token and lease; limited per client (a token bucket: 429)."""
    # Async: the rate limit is checked on the event loop, before a worker thread is taken. The app's
    # objects straight from the request, not through one more dependency: this route is the one
    # clients hit 100 times a second, and each dependency costs the solver some tens of us.
    api = api_of(request)
    admitted = admit_jog(api, client)
    return await run_in_threadpool(api.calls.forward, client, "jog", jog_request(body), at=admitted)


def admit_jog(api: ApiContext, client: str) -> float:
    """The jog rate limit (429 past it); returns when the jog was admitted. Shared with the Zenoh
    interface (servo_app/zenoh_api.py), which admits its jogs by the same rule."""
    # One clock reading for the limiter and the audit line: with two (a monotonic one and the wall
    # clock), a jog admitted as the window's oldest expired showed as the 101st within a second in
    # the audit log.
    admitted = time.time()
    # Keyed by host, not host:port: a new connection must not buy a fresh allowance.
    if not api.jog_limiter.allow(client.split("@")[-1].rsplit(":", 1)[0], admitted):
        api.metrics.count("rate_limited")
        api.audit.record(client, "jog", False, "rate limited", admitted)
        raise HTTPException(429, f"jog requests limited to {api.jog_limiter.per_second} per second per client; "
                                 "send them less often (hold_ms keeps a jog going between them)")
    return admitted


def jog_request(body: JointJog | TwistJog) -> msg.Request:
    """The servo process's request for a validated jog body (REST and Zenoh)."""
    message: msg.Request
    if isinstance(body, JointJog):
        message = msg.Jog(joints=tuple(body.joints), hold_s=body.hold_ms / 1000)
    else:
        message = msg.Twist(frame=body.frame, linear=(body.linear[0], body.linear[1], body.linear[2]),
                            angular=(body.angular[0], body.angular[1], body.angular[2]),
                            hold_s=body.hold_ms / 1000)
    return message


@router.post("/api/target", summary="Move to a joint or pose target")
def target(body: TargetBody, client: Controlling, calls: Calls) -> Ack:
    """Go to ``{"joints": [...]}`` (deg, or mm for a linear axis) or ``{"xyzwpr": [X, Y, Z, W, P, R]}``
    (mm, deg; world frame) along a jerk-limited path; a pose out of reach, or given in metres, is
    refused up front (422). Resumes a hold-to-run stop. Token and lease."""
    return calls.forward(client, "target", target_request(body))


def target_request(body: JointTarget | PoseTargetBody) -> msg.Request:
    """The servo process's request for a validated target body (REST and Zenoh)."""
    if isinstance(body, PoseTargetBody):
        return msg.PoseTarget(xyzwpr=tuple(body.xyzwpr), linear_speed=body.linear_speed,
                              angular_speed=body.angular_speed)
    return msg.JointTarget(joints=tuple(body.joints), speed_scale=body.speed_scale)
