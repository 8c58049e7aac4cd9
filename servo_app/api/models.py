"""The API's contract: pydantic models of every request body and every JSON response.

Requests forbid unknown keys (a typo must not be silently ignored on a robot) and are strict about
types: ``"1"`` is no number, ``true`` no integer and ``"1"`` no boolean (``{"fast": "1"}`` once made
a fast stop); an integer is still a number where a float is expected. Views of the service's
state allow extra keys (``model_config = {"extra": "allow"}``), so a field the service adds later
passes through before it is described here; their routes answer with ``exclude_unset``, so a key the
service did not send is not invented as ``null`` either.
"""

from __future__ import annotations

import math
from typing import Annotated, Any, Literal

from pydantic import BaseModel, ConfigDict, Discriminator, Field, Tag, ValidationInfo, field_validator

from servo_app.motion.commands import (
    MAX_ANGULAR_DEG_S,
    MAX_LINEAR_MM_S,
    MAX_POSITION_MM,
    MIN_ANGULAR_DEG_S,
    MIN_LINEAR_MM_S,
    MIN_SPEED_SCALE,
)
from servo_app.robots.tool import FLANGE, MAX_OFFSET_MM
from servo_app.state import MODES, PHASES

_OPEN = ConfigDict(extra="allow")
_CLOSED = ConfigDict(extra="forbid", strict=True)  # requests


def bounded(*limits: float) -> dict[str, Any]:
    """The schema of a fixed-length list whose values the service bounds (``prefixItems``: value i
    within +-limits[i]). Documentation only: the service's own check, with its message, refuses them."""
    return {"prefixItems": [{"type": "number", "minimum": -lim, "maximum": lim} for lim in limits]}


def _finite(name: str, values: list[float]) -> list[float]:
    for i, v in enumerate(values):
        if not math.isfinite(v):
            raise ValueError(f"{name}[{i}]={v} is not a finite number")
    return values


# ------------------------------------------------------------------------------------------ requests


class TwistJog(BaseModel):
    model_config = _CLOSED
    frame: Literal["base", "tool"] = "base"
    # The bounds are the servo process's (servo_app.motion.commands.Twist); a faster TCP than the
    # flange-speed cap is refused there too.
    linear: list[float] = Field(min_length=3, max_length=3, description="mm/s along x y z",
                                json_schema_extra=bounded(*[MAX_LINEAR_MM_S] * 3))
    angular: list[float] = Field(default=[0.0, 0.0, 0.0], min_length=3, max_length=3, description="deg/s",
                                 json_schema_extra=bounded(*[MAX_ANGULAR_DEG_S] * 3))
    hold_ms: float = Field(200.0, gt=0, le=2000, description="hold-to-run time: keep sending to keep moving")

    @field_validator("linear", "angular")
    @classmethod
    def _fin(cls, v: list[float], info: ValidationInfo) -> list[float]:
        return _finite(str(info.field_name), v)


class JointJog(BaseModel):
    model_config = _CLOSED
    joints: list[float] = Field(min_length=1, max_length=9, description=(
        "per axis: deg/s (FANUC J1..J6), or mm/s and deg/s (Janome X Y Z R); the backend checks the count"))
    hold_ms: float = Field(200.0, gt=0, le=2000)

    @field_validator("joints")
    @classmethod
    def _fin(cls, v: list[float]) -> list[float]:
        return _finite("joints", v)


def _jog_kind(body: Any) -> str:
    # Pick the model by its key, so a bad value is reported against that model's field alone. Tagged
    # with the models' names, as a plain union's errors are ("loc": ["body", "TwistJog", "linear"]):
    # clients drop the capitalised tag (servo_app.client: field "body.linear").
    return "JointJog" if isinstance(body, dict) and "joints" in body else "TwistJog"


JogBody = Annotated[Annotated[JointJog, Tag("JointJog")] | Annotated[TwistJog, Tag("TwistJog")],
                    Discriminator(_jog_kind)]


class JointTarget(BaseModel):
    model_config = _CLOSED
    joints: list[float] = Field(min_length=1, max_length=9, description=(
        "per axis: deg (FANUC convention), or mm and deg (Janome X Y Z R); the backend checks the count"))
    speed_scale: float = Field(1.0, ge=MIN_SPEED_SCALE, le=1)

    @field_validator("joints")
    @classmethod
    def _fin(cls, v: list[float]) -> list[float]:
        return _finite("joints", v)


class PoseTargetBody(BaseModel):
    model_config = _CLOSED
    xyzwpr: list[float] = Field(min_length=6, max_length=6, description="TCP pose: X Y Z mm, W P R deg (world)",
                                json_schema_extra=bounded(*[MAX_POSITION_MM] * 3, *[360.0] * 3))
    linear_speed: float = Field(100.0, ge=MIN_LINEAR_MM_S, le=2000, description="mm/s")
    angular_speed: float = Field(30.0, ge=MIN_ANGULAR_DEG_S, le=360, description="deg/s")

    @field_validator("xyzwpr")
    @classmethod
    def _fin(cls, v: list[float]) -> list[float]:
        return _finite("xyzwpr", v)


def _target_kind(body: Any) -> str:
    # As _jog_kind: a bad pose is reported against PoseTargetBody's fields alone, not also as a
    # JointTarget missing its joints.
    return "JointTarget" if isinstance(body, dict) and "joints" in body else "PoseTargetBody"


TargetBody = Annotated[Annotated[JointTarget, Tag("JointTarget")] | Annotated[PoseTargetBody, Tag("PoseTargetBody")],
                       Discriminator(_target_kind)]


class StopRequest(BaseModel):
    model_config = _CLOSED
    fast: bool = False


class LeaseRequest(BaseModel):
    model_config = _CLOSED
    client: str = Field(min_length=1, max_length=64)
    force: bool = False
    # At least 0.1 s: a lease must outlive a renewal's round trip (a client renews every third of it;
    # 1e-6 s had it renew in a busy loop, and a forced take stopped the holder for a lease gone at once).
    ttl_s: float | None = Field(None, ge=0.1, description="shorter than the server's TTL if given (never longer), "
                                                          "at least 0.1 s")


class IoWrite(BaseModel):
    model_config = _CLOSED
    type: str = Field(description="DO, RO, F, M, ...")
    index: int = Field(ge=1, le=65535)
    mask: int = Field(0xFFFF, ge=0, le=0xFFFF)
    value: int = Field(ge=0, le=0xFFFF)


class SelectTool(BaseModel):
    model_config = _CLOSED
    name: str = Field(min_length=1, max_length=64, description="a tool of GET /api/tools")


class DefineTool(BaseModel):
    model_config = _CLOSED
    # The built-in flange tool cannot be redefined, in any case (servo_app.service.tools).
    name: str = Field(min_length=1, max_length=64, pattern=r"^[A-Za-z0-9][A-Za-z0-9_.-]{0,63}$",
                      json_schema_extra={"not": {"pattern": "^" + "".join(f"[{c.upper()}{c}]" for c in FLANGE) + "$"}})
    # X Y Z within MAX_OFFSET_MM of the flange (each within it is what a schema can say), W P R within 360.
    xyzwpr: list[float] = Field(min_length=6, max_length=6,
                                description="the TCP from the flange: X Y Z mm, W P R deg (FANUC UTOOL data)",
                                json_schema_extra=bounded(*[MAX_OFFSET_MM] * 3, *[360.0] * 3))
    payload_kg: float = Field(gt=0, description="the tool's weight; at most the robot's maximum payload")

    @field_validator("xyzwpr")
    @classmethod
    def _fin(cls, v: list[float]) -> list[float]:
        return _finite("xyzwpr", v)


# ----------------------------------------------------------------------------------------- responses


class Ack(BaseModel):
    """A request carried out."""

    ok: bool = Field(True, description="always true: a refusal is an HTTP error with a `detail` message")
    detail: Any = Field(None, description="what the service answered, if anything")


class IoValue(Ack):
    detail: int | None = Field(None, description="the 16 points read from `index` (bit 0: the point at `index`)")


class Problem(BaseModel):
    """Why a request was refused (401, 409, 413, 422 from the service, 429, 503)."""

    detail: str


class FieldError(BaseModel):
    """One schema error of a request: where (``loc``), what (``msg``) and the value sent (``input``)."""

    model_config = _OPEN
    loc: list[str | int]
    msg: str
    type: str
    input: Any = None


class Invalid(BaseModel):
    """422: the request itself is bad. A schema error lists the fields (``detail`` is a list); a value
    the service checks (a range, a joint count, plausibility) comes as one sentence naming the field."""

    detail: str | list[FieldError]


class Health(BaseModel):
    ok: bool = True


class LeaseHolder(BaseModel):
    held: bool = Field(description="someone holds the control lease")
    client: str | None = Field(None, description="the holder's name, as it gave it when acquiring")


class LeaseView(LeaseHolder):
    expires_in_s: float | None = Field(None, description="until the lease expires unless renewed")


class LeaseGranted(BaseModel):
    lease_id: str = Field(description="send it as X-Lease-Id with every motion request")
    client: str
    ttl_s: float = Field(description="the lease expires this long after the last renewal")


class LeaseRenewed(BaseModel):
    lease_id: str
    ttl_s: float


class SessionLogInfo(BaseModel):
    name: str = Field(description="file name, for GET /api/sessions/{name}")
    bytes: int
    modified_unix: float


class LimitsView(BaseModel):
    """The limits the service streams within: FANUC joint tables, or the Janome profile's axes."""

    model_config = _OPEN
    model: str
    source: str = Field(description="where the limits come from (controller tables or the configured profile)")
    backend: str | None = Field(None, description="the robot backend's registered name")
    # FANUC
    interval_ms: int | None = Field(None, description="FANUC: the stream's command interval")
    limit_fraction: float | None = Field(None, description="FANUC: share of the limits the motion may use")
    joint_min_deg: list[float] | None = None
    joint_max_deg: list[float] | None = None
    vel_deg_s: list[float] | None = None
    acc_deg_s2: list[float] | None = None
    jerk_deg_s3: list[float] | None = None
    max_flange_speed_mm_s: float | None = Field(
        None, description="FANUC: the flange-speed cap in force, the configured cap held to the controller's $MAX_SPD "
        "(the profile's before a start has read the controller's tables); twists may use 0.8 of it")
    max_flange_speed_source: str | None = Field(None, description="FANUC: where max_flange_speed_mm_s comes from")
    io_allow: dict[str, list[int]] | None = Field(None, description="I/O type -> [first, last] point allowed")
    tool: str | None = Field(None, description="the active tool, whose payload the tables are taken at")
    payload_kg: float | None = Field(None, description="the active tool's payload (null: the maximum)")
    # Janome
    axes: list[str] | None = Field(None, description="Janome: X Y Z R")
    axis_min: list[float] | None = None
    axis_max: list[float] | None = None
    speed: list[float] | None = Field(None, description=(
        "Janome: the fastest each axis is commanded (mm/s, deg/s), the tighter of the profile's share and the "
        "link's step; a jog asking more is refused"))
    speed_source: list[str] | None = Field(None, description="Janome: where each of speed's limits comes from")
    accel: list[float] | None = None
    cp_speed_mm_s: float | None = Field(None, description=(
        "Janome: the fastest along the X Y Z line (mm/s), the tighter of the profile's share and the link's step"))
    cp_speed_source: str | None = Field(None, description="Janome: where cp_speed_mm_s comes from")
    profile_speed: list[float] | None = Field(None, description="Janome: the profile's axes.speed")
    profile_cp_speed_mm_s: float | None = Field(None, description="Janome: the profile's cp.speed_mm_s")
    speed_fraction: float | None = Field(None, description="Janome: share of the profile's speeds the motion may use")
    step_s: float | None = None
    max_step_mm: float | None = None
    max_step_deg: float | None = None


class AxisView(BaseModel):
    model_config = _OPEN
    name: str
    unit: str = Field(description="deg or mm")
    min: float
    max: float
    speed: float


class DrawingPoint(BaseModel):
    model_config = _OPEN
    name: str
    xyz_mm: list[float] = Field(description="in the robot's world frame")
    approach: list[float] | None = Field(None, description="the tool's pointing direction (unit vector)")


class ViewBox(BaseModel):
    min: list[float]
    max: list[float]


class TcpPoint(BaseModel):
    """The active tool's TCP for the arm view."""

    tool: str
    xyz_mm: list[float]
    axes: list[list[float]] = Field(description="the TCP's x, y, z axes (unit vectors, world)")


class RobotView(BaseModel):
    """What the web console draws: the axes and a stick figure of the current position."""

    model_config = _OPEN
    backend: str = Field(description="the robot backend's registered name (fanuc, janome, ...)")
    kind: str = Field(description="what is drawn: arm6, scara, cartesian, or the backend's own kind")
    model: str
    display_name: str
    dof: int
    joint_names: list[str]
    axes: list[AxisView]
    axis_label: str | None = Field(None, description="what the console calls an axis (Joint, Axis)")
    pose_names: list[str] | None = Field(None, description="names of the feedback pose's components")
    pose_caption: str | None = None
    cartesian_jog: bool | None = Field(None, description="the backend takes twists (Cartesian jog)")
    j23_factor: float | None = Field(None, description="FANUC: the J2/J3 coupling of the joint convention")
    q: list[float] = Field(description="current positions in the backend's units (FANUC joints in deg, ...)")
    points: list[DrawingPoint]
    view_box_mm: ViewBox
    dims_mm: dict[str, float] | None = None
    joint_min_deg: list[float] | None = None
    joint_max_deg: list[float] | None = None
    vel_limit_deg_s: list[float] | None = None
    max_flange_speed_mm_s: float | None = Field(
        None, description="FANUC: the flange-speed cap in force, the configured cap held to the controller's $MAX_SPD "
        "(the profile's before a start has read the controller's tables); twists may use 0.8 of it")
    max_flange_speed_source: str | None = Field(None, description="FANUC: where max_flange_speed_mm_s comes from")
    q_fanuc_deg: list[float] | None = None
    q_model_deg: list[float] | None = None
    tcp: TcpPoint | None = Field(None, description="the active tool's TCP, drawn from the flange (FANUC)")


# ---------------------------------------------------------------------------------------- the state

Mode = Literal[MODES]  # type: ignore[valid-type]  # one source of truth: servo_app.state
Phase = Literal[PHASES]  # type: ignore[valid-type]


class FaultView(BaseModel):
    """Why the stream died; for controller alarms the manual's cause and remedy."""

    model_config = _OPEN
    message: str
    code: str | None = Field(None, description="controller alarm code (e.g. MOTN-603); null: our own detection")
    cause: str | None = None
    remedy: str | None = None
    during: str | None = Field(None, description="the safety state the fault interrupted")


class WarningView(BaseModel):
    model_config = _OPEN
    code: str | None = None
    message: str
    t: float | None = Field(None, description="servo-process clock, s (Janome)")
    time_unix: float | None = Field(None, description="wall clock (Unix s) at the warning, from t")


class McapErrorView(BaseModel):
    """A live MCAP (``servo-app run --mcap``) that stopped short: its file ends where the writer stopped."""

    model_config = _OPEN
    file: str = Field(description="the .mcap file cut short")
    error: str = Field(description="why the writer stopped (e.g. No space left on device)")
    remedy: str = Field(description="what to do: the .srvlog is complete and servo-app export converts it")


class AlarmView(BaseModel):
    """A controller alarm or warning (the embedded simulator's alarm list, or a robot error reported over
    the link), or a fault the service detected itself (its cause as ``code``)."""

    model_config = _OPEN
    code: str
    message: str
    time_s: float | None = None
    axis: int | None = None
    seq: int | None = None
    cause: str | None = None
    remedy: str | None = None
    warning: bool | None = Field(None, description="posted but does not stop the robot")
    time_unix: float | None = Field(None, description="wall clock (Unix s) when the service saw it")
    controller_time_ms: int | None = Field(None, description="the controller's own time stamp at the alarm "
                                                             "(FANUC: the status packet clock); null if none")


class CartesianView(BaseModel):
    model_config = _OPEN
    scale: float = Field(description="share of the commanded Cartesian motion delivered")
    condition: float = Field(description="condition number of the normalised flange Jacobian")
    held_back_by: list[str] = Field(description="why it goes slower than asked, most specific first")


class TrajectoryProgress(BaseModel):
    """A trajectory replay's progress (POST /api/trajectory)."""

    model_config = _OPEN
    state: str = Field(description="playing, pausing, paused, resuming, done, or ended (left by a fast stop, "
                                   "a fault or another motion command)")
    index: int = Field(description="the sample being played (fractional during a pause or resume ramp: floored)")
    total: int = Field(description="samples in the plan, one per cycle")
    time_s: float = Field(description="the plan's time at the sample played, s")
    total_s: float = Field(description="the plan's duration, s")
    paused: bool = Field(description="paused at rest on the path: resume continues it")
    reason: str | None = Field(None, description="why an ended replay left its path before the end")


class InputLatency(BaseModel):
    last: float | None = None
    mean: float | None = None
    max: float | None = None


class InputSourceSummary(BaseModel):
    model_config = _OPEN
    name: str
    kind: str | None = None
    rate_hz: float | None = None
    age_s: float | None = Field(None, description="age of the newest sample; null before the first")
    stale: bool | None = None
    active: bool | None = Field(None, description="this source commands the arm now")
    latency_ms: InputLatency | None = Field(None, description="feeds: sender to slot")


class InputsSummary(BaseModel):
    model_config = _OPEN
    enabled: bool = Field(description="the input sources may move the arm")
    active: str | None = Field(None, description="the source commanding now")
    owner: str | None = Field(None, description="the one source allowed to command; null: all, by priority")
    sources: list[InputSourceSummary] = []


class ToolView(BaseModel):
    """A tool: the TCP relative to the flange and the payload the limit tables are taken at."""

    name: str
    xyzwpr: list[float] = Field(description="the TCP from the flange: X Y Z mm, W P R deg")
    payload_kg: float | None = Field(description="kg; null: the robot's maximum (the controller's assumption)")


class ToolsView(BaseModel):
    """``GET /api/tools``: every tool (the built-in flange first) and the active one."""

    active: str
    tools: list[ToolView]


class StateView(BaseModel):
    """``GET /api/state`` and each ``/ws/telemetry`` message: the servo process's published state, its
    safety view, the service's additions and the API's lease.

    Only ``state``, ``link``, ``lease``, ``stops_by_reason`` and ``service_id`` are always there: while the service has
    no servo process the rest is absent. Keys not described here pass through unchanged.
    """

    model_config = _OPEN

    state: Mode = Field(description="the safety state")
    link: Phase = Field(description="the stream (link) phase")

    # The published state vector (servo_app.state), one copy per cycle.
    published_unix: float | None = Field(None, description="when the servo process published this (Unix s)")
    session_time: float | None = Field(None, description="s since the servo process started")
    status_seq: int | None = Field(None, description="sequence number of the last status packet")
    status_bits: int | None = Field(None, description="the live status packets' status bits; null while "
                                                      "status packets do not arrive")
    status_live: bool | None = Field(None, description="status packets are arriving now")
    status_age_s: float | None = Field(None, description="since the last status packet (null: none yet)")
    status_bits_last: int | None = Field(None, description="the last status bits seen, stale while not live")
    status_unix: float | None = Field(None, description="wall clock of the last status packet (0: none)")
    status_time_ms: int | None = Field(None, description="the controller's time stamp in the last status")
    commands_sent: int | None = Field(None, description="command packets sent")
    status_received: int | None = Field(None, description="status packets received")
    status_lost: int | None = Field(None, description="status packets lost (gaps in the sequence)")
    status_duplicated: int | None = Field(None, description="duplicated or reordered status packets")
    malformed: int | None = Field(None, description="datagrams from the controller that did not decode")
    late_commands: int | None = Field(None, description="commands sent over half an interval after their status")
    late_inputs: int | None = Field(None, description="IK solves repeated for an input that arrived during one")
    ik_active: bool | None = Field(None, description="the last cycle was a Cartesian one")
    ik_flags: int | None = Field(None, description="its IkFlag bits")
    ik_scale: float | None = Field(None, description="share of the commanded Cartesian motion delivered")
    ik_condition: float | None = Field(None, description="condition number of the normalised flange Jacobian")
    latency_last_us: float | None = Field(None, description="status receipt to command send, last command")
    latency_p50_us: float | None = Field(None, description="median over the last 4096 commands")
    latency_p99_us: float | None = Field(None, description="99th percentile over the last 4096 commands")
    latency_max_us: float | None = Field(None, description="maximum over the last 4096 commands")
    status_interval_last_ms: float | None = Field(None, description="last interval between status packets")
    io_read_value: int | None = Field(None, description="the 16 points the status echoes")
    io_read_type: int | None = Field(None, description="I/O type of the echoed read (IoType)")
    io_read_index: int | None = Field(None, description="index of the echoed read")
    io_read_mask: int | None = Field(None, description="mask of the echoed read")
    latency_sum_us: float | None = Field(None, description="sum of all latencies (never reset)")
    latency_hist: list[int] | None = Field(None, description="commands per latency bucket (not cumulative)")
    at_rest: bool | None = Field(None, description="the commanded motion is at rest")
    settled: bool | None = Field(None, description="at rest, and the controller's feedback has stopped moving")
    stopped: bool | None = Field(None, description="the motion is stopped")
    tables_from_controller: bool | None = Field(None, description="the limits come from the controller")
    q_cmd: list[float] | None = Field(None, description="commanded position: FANUC J1..J6 deg, Janome X Y Z R 0 0")
    q_servo: list[float] | None = Field(None, description="position the robot reports")
    cart_servo: list[float] | None = Field(None, description="the active tool's TCP pose from the robot's "
                                                            "feedback: X Y Z mm, W P R deg (world)")
    flange_pose: list[float] | None = Field(None, description="the flange pose the robot reports: X Y Z mm, "
                                                             "W P R deg")
    tool: ToolView | None = Field(None, description="the active tool (GET /api/tools)")
    vel: list[float] | None = Field(None, description="commanded velocity per axis (/s)")
    acc: list[float] | None = Field(None, description="commanded acceleration per axis (/s^2)")
    jerk: list[float] | None = Field(None, description="commanded jerk per axis (/s^3)")
    vel_limit: list[float] | None = Field(None, description="velocity limit per axis (/s)")
    acc_limit: list[float] | None = Field(None, description="acceleration limit per axis (/s^2)")
    jerk_limit: list[float] | None = Field(None, description="jerk limit per axis (/s^3)")

    # The servo process's safety view (its last safety event).
    stop_reason: str | None = Field(None, description="why the arm stopped (stopping, stopped, ending, ended)")
    stop_fast: bool | None = Field(None, description="the stop used the fast ramp (a reset is needed after)")
    resumable: bool | None = Field(None, description="POST /api/session/resume would move on")
    shutdown: bool | None = Field(None, description="a signal asked the servo process to exit")
    fault: FaultView | None = Field(None, description="set in the fault state")
    stops: dict[str, int] | None = Field(None, description="the servo process's stops by reason")
    warnings: list[WarningView] | None = Field(None, description="the servo process's active warnings (the last "
                                                                 "10): since the last reset or new stream")
    warning_history: list[WarningView] | None = Field(None, description="the servo process's last 20 warnings, "
                                                                        "kept across resets")
    start_pending: bool | None = Field(None, description="a start waits for the controller (until the stream runs)")
    start_error: str | None = Field(None, description="why the last start was given up")
    not_ready: str | None = Field(None, description="why a start would wait now: the controller's status "
                                                    "flows but does not show it waiting for a stream (null: "
                                                    "ready, streaming, or no status)")
    link_error: str | None = Field(None, description="the link's fault reason or last error (since the last "
                                                    "reset or connection)")
    inputs_enabled: bool | None = Field(None, description="FANUC: the servo process takes the input slot")
    input_error: str | None = Field(None, description="FANUC: why the inputs were last refused")
    robot_connected: bool | None = Field(None, description="Janome: the robot's point job is connected")

    # The service's additions.
    backend: str | None = Field(None, description="the robot backend's registered name (fanuc, janome, ...)")
    servo_process: str | None = Field(None, description="running, or how it ended (e.g. 'ended by signal 9', "
                                          "'stalled: it ran no cycle for 1.1 s (stall time 1 s, ...)')")
    servo_starts: int | None = Field(None, description="servo processes started (a reset after one died starts one)")
    model: str | None = Field(None, description="the robot profile")
    cartesian: CartesianView | None = Field(None, description="why a Cartesian motion is held back (null: none)")
    trajectory: TrajectoryProgress | None = Field(None, description="the replay in this stream (null: none)")
    robot: str | None = Field(None, description="the controller's (FANUC) or our listening (Janome) host:port")
    simulated: bool | None = Field(None, description="the robot is the embedded simulator")
    alarms: list[AlarmView] | None = Field(None, description="the active alarms and warnings, oldest first: "
                                                             "since the last reset or new stream")
    alarm_history: list[AlarmView] | None = Field(None, description="the last 50 alarms and warnings, oldest "
                                                                    "first, kept across resets")
    faults: list[AlarmView] | None = Field(None, description="recent alarms that stopped the robot")
    alarm_poll_error: str | None = Field(None, description="the embedded controller's alarm list cannot be "
                                                           "read now, and why (new alarms are listed once "
                                                           "it answers); null: it answers")
    mcap_error: McapErrorView | None = Field(None, description="the last live MCAP (servo-app run --mcap) that "
                                                               "stopped short, until a later one is written whole "
                                                               "(also listed as an MCAP-LIVE warning); null: none")
    inputs: InputsSummary | None = Field(None, description="the input sources (servo-app run --inputs)")

    # The API's own.
    lease: LeaseHolder = Field(description="who holds the control lease")
    stops_by_reason: dict[str, int] = Field(description="all stops by reason (without its particulars: "
                                                    "`stop_reason` has them): servo process and API")
    service_id: str | None = Field(None, description="this run of the service: another after a restart (the "
                                                     "control lease ended with the old one)")


class InputsView(BaseModel):
    """``GET /api/inputs``: sources with rate, age, staleness and errors, applications, the last command."""

    model_config = _OPEN
    enabled: bool
    active: str | None = None
    owner: str | None = None
    slot: str | None = Field(None, description="the shared-memory input slot the servo process reads")
    servo_sources: list[str] | None = None
    sources: list[dict[str, Any]] | None = None
    applications: list[dict[str, Any]] | None = None


# A body nested deeper than the JSON parser recurses (thousands of brackets): its 422's message.
TOO_DEEP = ("the body nests lists or objects thousands of levels deep, too deep to parse; no request nests more "
            "than three: send the documented shape")

# What the routes that change something may answer besides 200 (and 422 for a malformed body).
REFUSALS: dict[int | str, dict[str, Any]] = {
    401: {"model": Problem, "description": "missing or wrong bearer token"},
    409: {"model": Problem, "description": "refused: no control lease, or not in this state; the text ends with "
                                           "the next step"},
    413: {"model": Problem, "description": "the request body is larger than the API takes (MAX_BODY_BYTES)"},
    422: {"model": Invalid, "description": "the request itself is bad: schema, type, range or plausibility"},
    503: {"model": Problem, "description": "the servo process did not answer"},
}
