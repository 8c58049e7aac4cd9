"""``POST /api/trajectory``: replay joint or Cartesian waypoints, a CSV or a recorded session log, timed
so that every controller limit holds (``docs/trajectory.md``). Token and lease.

The body is JSON (:class:`TrajectoryBody`) or, with ``Content-Type: text/csv``, a CSV in the form
``servo-app check`` reads. The request is validated and planned completely (in a worker thread: the
timing takes up to a few hundred ms) before anything moves; a refusal changes nothing: 422 names the
field and value, 409 says what to do first. The body may be up to :data:`MAX_BODY_BYTES` (the API's
other routes take 64 KiB): enough for :data:`MAX_WAYPOINTS` waypoints with their times at full float
precision. A longer path is replayed from a session log by name (``{"log": ...}``), which needs no
upload.
"""

# No `from __future__ import annotations`: FastAPI reads the dependency annotations at runtime.
import json
from typing import Annotated, Any, Literal

from fastapi import APIRouter, Depends, Query, Request
from fastapi.concurrency import run_in_threadpool
from fastapi.exceptions import RequestValidationError
from pydantic import BaseModel, ConfigDict, Field, ValidationError, model_validator

from servo_app.api.deps import Authed, Calls, Controlling, Service
from servo_app.api.models import REFUSALS, TOO_DEEP, Ack
from servo_app.motion.commands import MIN_SPEED_SCALE
from servo_app.service.trajectory import TrajectoryInput, plan_trajectory

router = APIRouter(tags=["motion"])

MAX_WAYPOINTS = 10_000
# 10,000 six-value waypoints and their times, every value at full float precision: 1.3 MB.
MAX_BODY_BYTES = 2 * 1024 * 1024
# JSON is parsed holding the interpreter (1.2 MB of one-value lists took 0.4 s here, the event loop
# waiting): a body with more values than the largest valid one (9 values a waypoint, its time) is
# refused before it is parsed, by its separators.
_MAX_JSON_VALUES = MAX_WAYPOINTS * 10


class TrajectoryBody(BaseModel):
    """One of ``joints``, ``poses`` or ``log``; ``times`` only with waypoints. Strict types, as every
    request's (api.models): "5" or true is not a number."""

    model_config = ConfigDict(extra="forbid", strict=True)
    joints: list[list[float]] | None = Field(None, max_length=MAX_WAYPOINTS, description=(
        "joint waypoints, FANUC J1..J6 deg: straight joint-space segments, at rest at each waypoint"))
    poses: list[list[float]] | None = Field(None, max_length=MAX_WAYPOINTS, description=(
        "TCP waypoints X Y Z mm, W P R deg (world): straight Cartesian segments in the held configuration"))
    times: list[float] | None = Field(None, max_length=MAX_WAYPOINTS, description=(
        "s at which each waypoint is reached (increasing; times[0] at the first waypoint, after the "
        "approach); a segment that cannot be done that fast within the limits is refused (422), a slower "
        "one is stretched to the time given"))
    log: str | None = Field(None, max_length=255, description=(
        "a recorded session log's name (GET /api/sessions): replay its commanded path (record and replay)"))
    from_s: float | None = Field(None, description="with log: start of the window, s after its first command")
    to_s: float | None = Field(None, description="with log: end of the window (default: the log's end)")
    from_unix: float | None = Field(None, description="with log: the window's start as wall-clock time (Unix s)")
    to_unix: float | None = Field(None, description="with log: the window's end as wall-clock time (Unix s)")
    speed_scale: float = Field(1.0, ge=MIN_SPEED_SCALE, le=1, description="share of the joint speed limits")
    pace: Literal["recorded", "limits"] = Field("recorded", description=(
        "with log: 'recorded' replays no faster along the path than it was recorded (times speed_scale), "
        "'limits' as fast as the controller's limits allow"))
    blend: bool = Field(False, description=(
        "with joints: pass through the waypoints without stopping (blending: FANUC's CNT, not FINE): one "
        "cubic spline in joint space from where the arm rests through every waypoint, at rest only at the "
        "last; it may bulge past a straight line between two waypoints, and one that would leave the "
        "joint ranges or the held configuration is refused (422, naming the two waypoints: add one between "
        "them). Not with poses, log or times. false (default): straight segments, at rest at each waypoint"))

    @model_validator(mode="after")
    def _one_source(self) -> "TrajectoryBody":
        given = [k for k in ("joints", "poses", "log") if getattr(self, k) is not None]
        if len(given) != 1:
            raise ValueError(f"give exactly one of joints, poses or log (got {given or 'none'}); "
                             "or send a CSV body with Content-Type: text/csv")
        window = (self.from_s, self.to_s, self.from_unix, self.to_unix)
        if any(v is not None for v in window) and self.log is None:
            raise ValueError("from_s, to_s, from_unix and to_unix select a window of a log: give log too")
        return self


def _documented_schema() -> dict[str, Any]:
    """TrajectoryBody's JSON schema with the rules plan_trajectory checks (its messages name the value):
    six values a waypoint, at least one waypoint and time, a window not before the log's start, exactly
    one of joints, poses and log, the window only with log, times only with waypoints and blend only with
    joints and no times. Documentation
    only: a client or fuzzer working from the schema sends what the service takes."""
    schema = TrajectoryBody.model_json_schema()
    props = schema["properties"]
    for key in ("joints", "poses"):  # FANUC J1..J6 or X Y Z W P R: trajectories are FANUC's alone
        rows = props[key]["anyOf"][0]
        rows["minItems"] = 1
        rows["items"].update(minItems=6, maxItems=6)
    props["times"]["anyOf"][0]["minItems"] = 1
    props["from_s"]["anyOf"][0]["minimum"] = 0
    props["to_s"]["anyOf"][0]["exclusiveMinimum"] = 0

    def given(key: str) -> dict[str, Any]:
        return {"required": [key], "properties": {key: {"not": {"type": "null"}}}}

    def absent(*keys: str) -> dict[str, Any]:
        return {"properties": {k: {"type": "null"} for k in keys}}

    schema["oneOf"] = [given("joints"), given("poses"), given("log")]
    no_blend = {"properties": {"blend": {"const": False}}}
    schema["allOf"] = [{"anyOf": [given("log"), absent("from_s", "to_s", "from_unix", "to_unix")]},
                       {"anyOf": [absent("log"), absent("times")]},
                       {"anyOf": [given("joints"), no_blend]}, {"anyOf": [absent("times"), no_blend]}]
    return schema


# The query's speed_scale is checked where it is used (a CSV body: check_speed_scale, naming the value);
# documented here with the same range.
_SCALE_RANGE = {"minimum": MIN_SPEED_SCALE, "maximum": 1}

_CSV_FORM = ("A CSV body (Content-Type: text/csv) in `servo-app check`'s form: one row per line, J1..J6 "
             "(FANUC deg) or, with the header x,y,z,w,p,r, flange poses; `speed_scale` and `pace` (recorded: no "
             "faster than one row per interval; limits: as fast as the limits allow) as query parameters.")


def _parse_json(raw: bytes) -> TrajectoryBody:
    """The JSON body, validated (a worker thread: up to 2 MB), or RequestValidationError naming the field."""
    if raw.count(b",") >= _MAX_JSON_VALUES:
        raise RequestValidationError([{"type": "too_long", "loc": ("body",), "input": None, "msg": (
            f"the body holds more than {_MAX_JSON_VALUES} values: a trajectory takes at most {MAX_WAYPOINTS} "
            "waypoints of at most 9 values and their times; replay a longer path from a session log")}])
    try:
        return TrajectoryBody.model_validate(json.loads(raw))
    except ValidationError as exc:
        errors = [{**e, "loc": ("body", *e["loc"])} for e in exc.errors()]
        raise RequestValidationError(errors) from None
    except ValueError as exc:  # (json's and a bad UTF-8's)
        raise RequestValidationError([{"type": "json_invalid", "loc": ("body",),
                                       "msg": f"the body is not JSON ({exc}): send JSON or text/csv",
                                       "input": None}]) from None
    except RecursionError:  # json's parser on thousands of nested brackets
        raise RequestValidationError([{"type": "json_invalid", "loc": ("body",), "msg": TOO_DEEP,
                                       "input": None}]) from None


async def uploaded(request: Request, _: Authed) -> bytes:
    """The body, read (after the token check) before the lease's: a take-over waits for this request
    once its lease check has passed, and must not wait for a slow upload."""
    return await request.body()


@router.post("/api/trajectory", summary="Replay waypoints, a CSV or a session log within the limits",
             responses=REFUSALS, openapi_extra={"requestBody": {"required": True, "content": {
                 "application/json": {"schema": _documented_schema()},
                 "text/csv": {"schema": {"type": "string", "description": _CSV_FORM}}}}})
async def trajectory(request: Request, raw: Annotated[bytes, Depends(uploaded)], client: Controlling,
                     calls: Calls, service: Service,
                     speed_scale: Annotated[float, Query(json_schema_extra=_SCALE_RANGE, description=(
                         "with a CSV body: share of the joint speed limits"))] = 1.0,
                     pace: Literal["recorded", "limits"] = "recorded") -> Ack:
    """Plan the path from where the arm rests (an approach move first if it does not start there),
    timed by TOPP-RA with a jerk bound and checked as the controller checks a stream, then replay it
    one position per cycle. A stop pauses along the path, resume continues it; a fast stop, a fault or
    another motion command ends it. Progress: ``trajectory`` in GET /api/state. Token and lease."""
    if request.headers.get("content-type", "").split(";")[0].strip().lower() == "text/csv":
        req = TrajectoryInput(csv_text=raw.decode("utf-8", errors="replace"), speed_scale=speed_scale, pace=pace)
    else:
        body = await run_in_threadpool(_parse_json, raw)
        req = TrajectoryInput(joints=body.joints, poses=body.poses, times=body.times, log=body.log,
                              from_s=body.from_s, to_s=body.to_s, from_unix=body.from_unix, to_unix=body.to_unix,
                              speed_scale=body.speed_scale, pace=body.pace, blend=body.blend)
    detail = {"source": "csv" if req.csv_text is not None else ("log" if req.log else
                                                                  "joints" if req.joints else "poses")}

    def plan_and_send() -> dict[str, Any]:
        message, summary = plan_trajectory(service, req)
        reply = service.request(message)
        return {**summary, **(reply or {})}

    return await run_in_threadpool(calls.call, client, "trajectory", plan_and_send, detail)
