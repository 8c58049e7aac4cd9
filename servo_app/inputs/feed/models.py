"""Request and response models of the HTTP/WebSocket feeds (they are the OpenAPI contract).

`stamp` is the sender's wall-clock time (Unix seconds) when the value was measured; the registry
uses it for the latency and to place the sample on the service's monotonic clock. Without a stamp
the receive time is used and the latency is unknown.
"""

from __future__ import annotations

from typing import Annotated, Literal

from pydantic import BaseModel, ConfigDict, Field, model_validator

from servo_app.inputs.errors import KeyedError, check_stale_after
from servo_app.inputs.fields import FieldConfig

Finite = Annotated[float, Field(allow_inf_nan=False)]
Vec3 = tuple[Finite, Finite, Finite]


class _Feed(BaseModel):
    model_config = ConfigDict(extra="forbid")

    stamp: Finite | None = Field(None, description="sender wall-clock time of the value, Unix seconds")
    seq: int | None = Field(None, strict=True, description=(
        "sender's counter: a sample a little behind the last one (within the source's seq_window) is a late "
        "one and dropped; one further behind is taken as the sender's counter restarting (resynchronised)"))


class PoseFeed(_Feed):
    kind: Literal["pose"]
    xyzwpr: tuple[Finite, Finite, Finite, Finite, Finite, Finite] = Field(
        description="X Y Z in mm, W P R in deg (rotations about fixed X, Y, Z)")
    # Poses are commanded in the base frame (servo_app.motion.commands); another name was accepted
    # here, then dropped by tracking or the bridge, so the sender heard "accepted" and nothing moved.
    frame: Literal["base"] = Field("base", description="base (world): the frame poses are commanded in")


class TwistFeed(_Feed):
    kind: Literal["twist"]
    linear: Vec3 = Field(description="mm/s")
    angular: Vec3 = Field((0.0, 0.0, 0.0), description="deg/s")
    # The frames the servo commands twists in (servo_app.motion.commands); another name was once
    # accepted here and then dropped further on, so nothing moved.
    frame: Literal["base", "tool"] = Field("base", description="base (world) or tool")


class MeasurementFeed(_Feed):
    kind: Literal["measurement"]
    values: dict[str, Finite] = Field(min_length=1)


FeedMessage = Annotated[PoseFeed | TwistFeed | MeasurementFeed, Field(discriminator="kind")]


class FeedAck(BaseModel):
    source: str
    accepted: bool = True
    seq: int = Field(description="the source slot's sequence number after this sample")
    latency_ms: float | None = Field(None, description="receive time minus the sample's stamp")
    detail: str | None = Field(None, description="why a sample was dropped, or that the sequence was resynchronised")
    resynced: bool = Field(False, description="the sender's seq restarted or jumped: taken as the new sequence")


class FeedSourceConfig(BaseModel):
    """One feed source in the service configuration ([feeds.<name>])."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)  # stale_after_s = inf never went stale

    kind: Literal["pose", "twist", "measurement"]
    priority: int = 0
    stale_after_s: float = Field(0.2, gt=0.0)
    yield_when_idle: bool = False
    max_future_s: float = Field(0.5, ge=0.0, description="reject stamps further ahead than this (clock skew)")
    seq_window: int = Field(100, ge=1, description=(
        "a seq at most this far behind the last is a late sample (dropped); further behind, the sender's "
        "counter restarted: the sample is accepted and the sequence resynchronised"))
    max_linear_mm_s: float | None = Field(None, gt=0.0)  # twist feeds: reject faster commands
    max_angular_deg_s: float | None = Field(None, gt=0.0)
    # Pose feeds: limits per axis name x y z w p r; measurement feeds: per value name.
    limits: dict[str, FieldConfig] = Field(default_factory=dict)
    required: list[str] = Field(default_factory=list)  # measurement names every sample must carry

    @model_validator(mode="after")
    def _kind_options(self) -> FeedSourceConfig:
        check_stale_after(self.stale_after_s)
        if self.kind != "twist" and (self.max_linear_mm_s or self.max_angular_deg_s):
            raise KeyedError("kind", self.kind, "max_linear_mm_s / max_angular_deg_s apply to twist feeds only")
        if self.kind == "pose" and set(self.limits) - set("xyzwpr"):
            raise KeyedError("limits", sorted(self.limits), "pose limits take the axes x y z w p r")
        # Both were read only for the kinds below and silently ignored otherwise: a twist feed "limited"
        # to x <= 10 mm/s took any speed.
        if self.kind == "twist" and self.limits:
            raise KeyedError("limits", sorted(self.limits), "a twist feed is limited by max_linear_mm_s and "
                             "max_angular_deg_s (limits apply to pose axes and measurement values)")
        if self.kind != "measurement" and self.required:
            raise KeyedError("required", self.required, "names the values every measurement must carry: "
                             "measurement feeds only")
        return self
