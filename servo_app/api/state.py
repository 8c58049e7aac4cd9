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
    return s


@router.get("/api/health")
def health() -> Health:
    return Health()


# Async, with the service read in a worker thread: the response is then validated and encoded on the
# event loop (a plain route would hop to a thread for the read and again for the validation).
# exclude_unset: a key the service did not send stays absent rather than becoming null.
@router.get("/api/state", response_model=StateView, response_model_exclude_unset=True)
async def state(api: Context) -> dict[str, Any]:
    return await run_in_threadpool(state_snapshot, api)


@router.get("/api/limits", response_model=LimitsView, response_model_exclude_unset=True)
def limits(service: Service) -> dict[str, Any]:
    return service.limits()


@router.get("/api/robot", response_model=RobotView, response_model_exclude_unset=True)
def robot(service: Service) -> dict[str, Any]:
    """Arm geometry for the console: profile dimensions, ranges, FK points of the current joints."""
    return service.robot_view()


@router.get("/metrics", response_class=PlainTextResponse)
def prometheus(metrics: MetricsDep) -> PlainTextResponse:
    return PlainTextResponse(metrics.render(), media_type="text/plain; version=0.0.4")
