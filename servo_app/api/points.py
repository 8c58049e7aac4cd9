"""``/api/points``: teach points. Teach the arm's current joints and TCP pose under a name, list them,
delete them, and move back to one (a joint target: the arm returns in the configuration it was
taught in, whatever IK would pick for the pose).

Teaching and moving need the token and the control lease; listing is open. The points live in
``points.json`` under the service's var directory (:class:`servo_app.service.points.PointStore`).
Refusals follow the targets' rules: 422 for a bad name or body, 404 for a point nobody taught (the
text says how to teach it), 409 when the state does not allow it (the text ends with the next step).
"""

# No `from __future__ import annotations`: FastAPI reads the dependency annotations at runtime.
import time
from typing import Annotated, Any

from fastapi import APIRouter, HTTPException, Query
from fastapi import Path as PathParam
from pydantic import BaseModel, ConfigDict, Field

from servo_app import messages as msg
from servo_app.api.deps import NO_BODY, Calls, Controlling, Service
from servo_app.api.models import REFUSALS, Ack, Problem
from servo_app.errors import CommandRejected
from servo_app.motion.commands import MIN_SPEED_SCALE
from servo_app.service import ServoService
from servo_app.service.points import POINT_NAME_PATTERN, TaughtPoint

router = APIRouter(tags=["points"])

PointName = Annotated[str, PathParam(pattern=POINT_NAME_PATTERN, min_length=1, max_length=64, description=(
    "letters, digits, '_', '.', '-'; starting with a letter or digit; at most 64 characters"))]
_UNKNOWN = {404: {"model": Problem, "description": "no point of that name: the text says how to teach it"}}
# States in which the controller reports where the arm is (the pose comes from its status packets).
_TEACHABLE = ("streaming", "stopped")


class PointView(TaughtPoint):
    """A taught point."""


class MoveToPoint(BaseModel):
    model_config = ConfigDict(extra="forbid", strict=True)
    speed_scale: float = Field(1.0, ge=MIN_SPEED_SCALE, le=1, description="share of the joint speed limits")


def _unknown(name: str) -> HTTPException:
    return HTTPException(404, f"no teach point named {name!r}: list them with GET /api/points, or move the "
                              f"arm there and teach it: POST /api/points/{name}")


def _capture(service: ServoService, name: str, client: str, replace: bool) -> dict[str, Any]:
    """The point as the arm stands now; refused unless the controller reports a settled arm, or if a
    point of that name exists and ``replace`` is not set."""
    s = service.state()
    state = s["state"]
    if state not in _TEACHABLE or not s.get("status_live"):
        raise CommandRejected(f"teach refused in {state}: the controller reports the arm's pose only while a "
                              "stream runs; start one: POST /api/session/start")
    if not s.get("settled"):
        raise CommandRejected("teach refused: the arm is moving (not settled), and a pose taken now would not "
                              "match its joints; wait until GET /api/state shows settled, then teach again")
    dof = len(service.backend.axes())
    point = {"name": name, "joints": [float(q) for q in s["q_cmd"][:dof]],
             "xyzwpr": [float(v) for v in s.get("cart_servo") or []], "tool": service.tools.active.name,
             "model": service.profile.name,
             "backend": service.backend.name, "taught_unix": time.time(), "taught_by": client}
    service.points.save(point, replace=replace)
    return point


@router.get("/api/points", summary="List the teach points", response_model=list[PointView])
def points_list(service: Service) -> list[dict[str, Any]]:
    """Every taught point, by name, with its joints, TCP pose, robot model and when it was taught
    (open: no token). A points file that cannot be read is 409, naming it and what is wrong."""
    try:
        points = service.points.all()  # each checked by the store: the one check, shared with every route
    except CommandRejected as exc:
        raise HTTPException(409, str(exc)) from None
    return points


@router.post("/api/points/{name}", summary="Teach a point: save the arm's current joints and pose",
             responses=REFUSALS, dependencies=NO_BODY)
def point_teach(name: PointName, client: Controlling, service: Service, calls: Calls,
                replace: Annotated[bool, Query(description=(
                    "replace a point of that name; without it such a point is kept and the teach refused (409)"))]
                = False) -> PointView:
    """Save the commanded joints and the pose the controller reports under ``name``, with the robot
    model and the time. A point of that name is refused (409, naming it) unless ``?replace=true``.
    Only while a stream runs and the arm has settled (409 otherwise, saying what to wait for). Token
    and lease."""
    ack = calls.call(client, "points.teach", lambda: _capture(service, name, client, replace),
                     {"name": name, "replace": replace})
    return PointView.model_validate(ack.detail)


@router.delete("/api/points/{name}", summary="Delete a teach point", responses={**REFUSALS, **_UNKNOWN},
               dependencies=NO_BODY)
def point_delete(name: PointName, client: Controlling, service: Service, calls: Calls) -> Ack:
    """Forget the point ``name`` (404 if nobody taught it). Token and lease."""
    if not calls.call(client, "points.delete", lambda: service.points.delete(name), {"name": name}).detail:
        raise _unknown(name)
    return Ack()


@router.post("/api/points/{name}/move", summary="Move to a teach point (a joint target)",
             responses={**REFUSALS, **_UNKNOWN})
def point_move(name: PointName, client: Controlling, service: Service, calls: Calls,
               body: MoveToPoint | None = None) -> Ack:
    """Go to the point's joints along a jerk-limited path, as ``POST /api/target`` with ``{"joints":
    [...]}`` would (the configuration exactly as taught; refused in the same states; resumes a
    hold-to-run stop). A point taught on another robot model is refused (409). Token and lease."""
    try:
        point = service.points.get(name)
    except CommandRejected as exc:  # the file cannot be read: as every refusal, audited with its reason
        calls.audit.record(client, "points.move", False, str(exc))
        raise HTTPException(409, str(exc)) from None
    if point is None:
        calls.audit.record(client, "points.move", False, f"no teach point named {name!r}")
        raise _unknown(name)
    if point.get("model") != service.profile.name:
        detail = (f"point {name!r} was taught on a {point.get('model')}, and this service drives a "
                  f"{service.profile.name}; teach it again on this robot: POST /api/points/{name}")
        calls.audit.record(client, "points.move", False, detail)
        raise HTTPException(409, detail)
    speed_scale = body.speed_scale if body is not None else 1.0
    return calls.forward(client, "points.move", msg.JointTarget(joints=tuple(point["joints"]),
                                                                 speed_scale=speed_scale))
