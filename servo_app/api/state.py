"""Open reads: ``/api/health``, ``/api/state``, ``/api/limits``, ``/api/robot`` and ``/metrics``."""

# No `from __future__ import annotations`: FastAPI reads the dependency annotations at runtime.
from typing import Any

from fastapi import APIRouter
from fastapi.concurrency import run_in_threadpool
from fastapi.responses import PlainTextResponse

from servo_app.api.deps import ApiContext, Context, MetricsDep, Service
from servo_app.api.models import Health, LimitsView, RobotView, StateView

router = APIRouter(tags=["state"])


def state_snapshot(api: ApiContext) -> dict[str, Any]:
    """The service's state with the API's lease and the stops by reason (blocks briefly: a thread)."""
    s = api.service.state()
    lease = api.leases.current()
    s["lease"] = {"held": lease is not None, "client": lease.client if lease else None}
    s["stops_by_reason"] = api.service.stops()
    s["service_id"] = api.run_id
    return s


@router.get("/api/health", summary="Is the API up")
def health() -> Health:
    """Answers ``{"ok": true}`` while the API serves requests (it says nothing about the robot: see
    GET /api/state)."""
    return Health()


# Async, with the service read in a worker thread: the response is then validated and encoded on the
# event loop (a plain route would hop to a thread for the read and again for the validation).
# exclude_unset: a key the service did not send stays absent rather than becoming null.
@router.get("/api/state", response_model=StateView, response_model_exclude_unset=True,
            summary="The stream, the link, the arm and its alarms")
async def state(api: Context) -> dict[str, Any]:
    """What the operator needs: the safety state and its stop reason, a fault's cause and remedy, the
    link, joints and pose (commanded and fed back), at rest and settled, active alarms and their
    history, the lease holder. The same view streams on the WebSocket /ws/telemetry."""
    return await run_in_threadpool(state_snapshot, api)


@router.get("/api/limits", response_model=LimitsView, response_model_exclude_unset=True,
            summary="The limits the service streams within")
def limits(service: Service) -> dict[str, Any]:
    """Joint ranges and the velocity, acceleration and jerk tables (from the controller when it sent
    them, else the profile's), the flange speed cap and the I/O that may be read and written."""
    return service.limits()


@router.get("/api/robot", response_model=RobotView, response_model_exclude_unset=True,
            summary="The arm's geometry for drawing it")
def robot(service: Service) -> dict[str, Any]:
    """Arm geometry for the console: profile dimensions, ranges, FK points of the current joints."""
    return service.robot_view()


@router.get("/metrics", response_class=PlainTextResponse, summary="Prometheus metrics")
def prometheus(metrics: MetricsDep) -> PlainTextResponse:
    """Counters and gauges in the Prometheus text format: cycles, stops by reason, alarms by code,
    faults by cause, refused requests, link health."""
    return PlainTextResponse(metrics.render(), media_type="text/plain; version=0.0.4")
