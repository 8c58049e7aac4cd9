"""What the HID and the spacenavd SpaceMouse adapters share: configuration, axis state, modes, buttons.

Buttons map to action names (:mod:`servo_app.inputs.actions`). A few act on the SpaceMouse itself
(`toggle_frame`, `toggle_translation`, `toggle_rotation`, `toggle_dominant`); every press and
release, those included, is also published as a ButtonEvent, and the inputs bridge carries out the
output actions (e.g. "toggle_output:DO[1]") through the service.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import replace

from pydantic import Field, PositiveFloat, field_validator

from servo_app.inputs.actions import LOCAL_ACTIONS, parse_action
from servo_app.inputs.adapter import JogDeviceConfig
from servo_app.inputs.samples import ButtonEvent, TwistSample
from servo_app.inputs.spacemouse.shaping import DEFAULT_AXIS_SIGNS, Shaping, shape


class SpaceMouseConfig(JogDeviceConfig):
    device = "SpaceMouse"
    deadband: float = Field(0.05, ge=0.0, lt=1.0)  # fraction of full scale
    yield_when_idle: bool = True  # a cap at rest lets lower-priority sources command
    full_scale: PositiveFloat = 350.0  # counts at full deflection (some units: 500)
    curve: float = Field(0.0, ge=0.0, le=1.0)
    dominant_axis: bool = False
    translation: bool = True
    rotation: bool = True
    max_linear_mm_s: PositiveFloat = 100.0
    max_angular_deg_s: PositiveFloat = 30.0
    axis_map: list[int] = Field(default_factory=lambda: [0, 1, 2, 3, 4, 5], min_length=6, max_length=6)
    axis_signs: list[int] = Field(default_factory=lambda: list(DEFAULT_AXIS_SIGNS), min_length=6, max_length=6)
    frames: list[str] = Field(default_factory=lambda: ["base", "tool"], min_length=1)
    buttons: dict[int, str] = Field(default_factory=dict)
    # One overall speed factor: above 0, since a negative one reverses every direction of the cap
    # (axis_signs flips single axes) and 0 makes a live source that never moves.
    scale: float = Field(1.0, gt=0.0)  # type: ignore[assignment]

    @field_validator("buttons")
    @classmethod
    def _actions(cls, v: dict[int, str]) -> dict[int, str]:
        for button, action in v.items():
            try:
                parse_action(action)
            except ValueError as exc:
                raise ValueError(f"button {button}: {exc}") from None
        return v

    @field_validator("axis_map")
    @classmethod
    def _permutation(cls, v: list[int]) -> list[int]:
        if sorted(v) != [0, 1, 2, 3, 4, 5]:
            raise ValueError("must be a permutation of 0..5")
        return v

    @field_validator("axis_signs")
    @classmethod
    def _signs(cls, v: list[int]) -> list[int]:
        if any(s not in (-1, 1) for s in v):
            raise ValueError("each sign must be 1 or -1")
        return v



class SpaceMouseCore:
    def __init__(self, cfg: SpaceMouseConfig, publish: Callable[[TwistSample], None],
                 emit: Callable[[ButtonEvent], None]) -> None:
        self.cfg = cfg
        self._publish = publish
        self._emit = emit
        self.raw: list[int] = [0] * 6
        self.buttons = 0
        self.frame_index = 0
        self.shaping = Shaping(
            full_scale=cfg.full_scale, deadband=cfg.deadband, curve=cfg.curve, dominant_axis=cfg.dominant_axis,
            translation=cfg.translation, rotation=cfg.rotation, max_linear_mm_s=cfg.max_linear_mm_s,
            max_angular_deg_s=cfg.max_angular_deg_s, axis_map=tuple(cfg.axis_map),
            axis_signs=tuple(cfg.axis_signs), scale=cfg.scale,
        )

    @property
    def rest_wait_s(self) -> float:
        """How long one poll waits for the device. A cap at rest is refreshed once per poll, so the wait
        is at most a quarter of stale_after_s whatever poll_timeout_s says: a poll as long as the
        staleness timeout let the resting source go stale between polls, and each time it was in
        control the arm was stopped for a lost input nobody had touched."""
        return min(self.cfg.poll_timeout_s, self.cfg.stale_after_s / 4.0)

    @property
    def frame(self) -> str:
        return self.cfg.frames[self.frame_index]

    @property
    def at_rest(self) -> bool:
        return not any(self.raw)

    def reset(self) -> None:
        """A device (re)opened: nothing is deflected or held. The device reports buttons only when they
        change, so a mask kept from before an unplug would swallow the next press of a button held then."""
        self.raw = [0] * 6
        self.buttons = 0

    def set_axes(self, translation: Sequence[int] | None, rotation: Sequence[int] | None) -> None:
        if translation is not None:
            self.raw[0:3] = list(translation)
        if rotation is not None:
            self.raw[3:6] = list(rotation)

    def publish(self, stamp: float) -> TwistSample:
        lin, ang = shape(self.raw, self.shaping)
        sample = TwistSample(lin, ang, self.frame, stamp, self.cfg.name)
        self._publish(sample)
        return sample

    def set_buttons(self, mask: int, stamp: float) -> None:
        changed = mask ^ self.buttons
        self.buttons = mask
        bit = 0
        while changed >> bit:
            if (changed >> bit) & 1:
                self.button(bit, bool((mask >> bit) & 1), stamp)
            bit += 1

    def button(self, number: int, pressed: bool, stamp: float) -> None:
        action = self.cfg.buttons.get(number)
        if pressed and action in LOCAL_ACTIONS:
            self._apply(action)
        self._emit(ButtonEvent(number, pressed, action, stamp, self.cfg.name))

    def _apply(self, action: str) -> None:
        s = self.shaping
        if action == "toggle_frame":
            self.frame_index = (self.frame_index + 1) % len(self.cfg.frames)
        elif action == "toggle_translation":
            self.shaping = replace(s, translation=not s.translation)
        elif action == "toggle_rotation":
            self.shaping = replace(s, rotation=not s.rotation)
        elif action == "toggle_dominant":
            self.shaping = replace(s, dominant_axis=not s.dominant_axis)
