"""A gamepad (Xbox, PlayStation, generic) through SDL2's GameController API, hold-to-run.

The adapter's thread starts SDL's game controller subsystem (headless), opens the first pad SDL has
a mapping for (or the first named like `match`) that no other gamepad input reads, and reads its state
every `poll_timeout_s` (at most a quarter of `stale_after_s`). The mapping
(servo_app.inputs.gamepad.mapping) turns the state into a twist and the button edges into events; the
twist is zero unless the deadman button is held.

Rest versus stale: while the twist and frame stay the same the sample is refreshed four times per
`stale_after_s`, so the source stays fresh at rest and while held steady; a pad unplugged mid-jog
publishes nothing more, its source goes stale and the arm stops, and the reconnect attempts report
why it cannot be opened (`failure`). On a new fault in the robot's state the pad rumbles, if it can.
"""

from __future__ import annotations

import logging
import time
from typing import Any, Literal

from pydantic import Field, PositiveFloat, field_validator, model_validator

from servo_app.inputs.adapter import Clock, InputAdapter, JogDeviceConfig
from servo_app.inputs.device_failure import DeviceFailure
from servo_app.inputs.errors import KeyedError
from servo_app.inputs.gamepad.mapping import (
    BUTTON_NAMES,
    COMPONENTS,
    FaultWatch,
    PadLogic,
    PadMapping,
    PadState,
    button_index,
    check_pad_action,
    parse_source,
)
from servo_app.inputs.gamepad.sdl import NoPad, SdlControllers, SdlPad
from servo_app.inputs.samples import TwistSample

# Left stick: X forward/back, Y left/right; right stick: Z up/down and yaw; triggers roll; D-pad pitch.
DEFAULT_AXES = {"x": "-lefty", "y": "-leftx", "z": "-righty", "rx": "righttrigger-lefttrigger", "ry": "dpup-dpdown",
                "rz": "-rightx"}
ROBOT_STATE_PERIOD_S = 0.1  # how often the robot's state is looked at for a new fault (rumble)


class GamepadConfig(JogDeviceConfig):
    device = "gamepad"
    type: Literal["gamepad"] = "gamepad"
    match: str | None = None  # part of the pad's name (any case); unset: the first pad SDL can map
    deadband: float = Field(0.1, ge=0.0, lt=1.0)  # fraction of full deflection; worn sticks rest off centre
    expo: float = Field(0.5, ge=0.0, le=1.0)  # cubic blend: fine near centre, full speed at the stop
    yield_when_idle: bool = True  # deadman released or sticks centred: lower-priority sources may command
    # SDL is read, not waited on: one read per period (a pad reports every 4-8 ms; a press is longer).
    poll_timeout_s: PositiveFloat = 0.008
    translation: bool = True
    rotation: bool = True
    dominant_axis: bool = False
    max_linear_mm_s: PositiveFloat = 100.0
    max_angular_deg_s: PositiveFloat = 30.0
    frames: list[str] = Field(default_factory=lambda: ["base", "tool"], min_length=1)
    deadman: str = "leftshoulder"  # hold-to-run: held (and pressed since the pad appeared), or no motion
    axes: dict[str, str] = Field(default_factory=lambda: dict(DEFAULT_AXES))  # twist component -> source
    buttons: dict[str, str] = Field(default_factory=dict)  # button name -> action
    rumble_on_fault: bool = True
    rumble_strength: float = Field(1.0, gt=0.0, le=1.0)
    rumble_s: PositiveFloat = 0.5
    # One overall speed factor: above 0, since a negative one reverses every stick (a leading "-" in
    # axes flips one) and 0 makes a live source that never moves.
    scale: float = Field(1.0, gt=0.0)  # type: ignore[assignment]

    @field_validator("axes")
    @classmethod
    def _sources(cls, v: dict[str, str]) -> dict[str, str]:
        for component, source in v.items():
            if component not in COMPONENTS:
                raise ValueError(f"{component!r} is not a twist component: one of {', '.join(COMPONENTS)}")
            parse_source(source)
        return v

    @field_validator("deadman")
    @classmethod
    def _button(cls, v: str) -> str:
        button_index(v)
        return v

    @field_validator("buttons")
    @classmethod
    def _actions(cls, v: dict[str, str]) -> dict[str, str]:
        for button, action in v.items():
            try:
                button_index(button)
                check_pad_action(action)
            except ValueError as exc:
                raise ValueError(f"button {button}: {exc}") from None
        return v

    @model_validator(mode="after")
    def _one_use_per_button(self) -> GamepadConfig:
        """The deadman, the axis buttons and the action buttons are all different; a clash names the key
        and the button (from the whole table, it said neither)."""
        if self.deadman in self.buttons:
            raise KeyedError(f"buttons.{self.deadman}", self.buttons[self.deadman],
                             f"{self.deadman!r} is the deadman button: it cannot also have an action")
        for component, source in self.axes.items():
            for term in parse_source(source):
                name = BUTTON_NAMES[term.index] if term.kind == "button" else None
                if name is not None and name == self.deadman:
                    raise KeyedError(f"axes.{component}", source, f"{name!r} is the deadman button: it cannot "
                                     "also drive an axis")
                if name is not None and name in self.buttons:
                    raise KeyedError(f"buttons.{name}", self.buttons[name], f"{name!r} drives axis {component} "
                                     f"({source!r}): it cannot also have an action; map the action to another "
                                     f"button or set axes.{component}")
        self.mapping()
        return self

    def mapping(self) -> PadMapping:
        return PadMapping.from_names(
            self.axes, self.deadman, self.buttons, deadband=self.deadband, expo=self.expo,
            max_linear_mm_s=self.max_linear_mm_s, max_angular_deg_s=self.max_angular_deg_s,
            scale=self.scale,
        )


def gamepad_failure(name: str, match: str | None, exc: BaseException) -> DeviceFailure:
    device = "game controller (SDL)" + (f" named like {match!r}" if match else "")
    raw = f"{type(exc).__name__}: {exc}"
    section = f"[adapters.{name}]"
    if isinstance(exc, RuntimeError) and "pysdl2" in str(exc):
        return DeviceFailure(device, "pysdl2 or its SDL library is not installed",
                             "pip install 'servo_app[gamepad]'", raw)
    if isinstance(exc, NoPad) and exc.taken:
        pads = ", ".join(f"{pad} by input {holder!r}" for pad, holder in exc.taken)
        return DeviceFailure(device, f"every pad that would do is already read by another input ({pads})",
                             "plug in another pad, or set match = \"...\" in each gamepad's section to part of its "
                             f"pad's name ({section} included)", raw)
    if isinstance(exc, NoPad):
        mapped = [n for _, n, m in exc.seen if m]
        unmapped = [n for _, n, m in exc.seen if not m]
        if mapped:
            return DeviceFailure(device, f"none is named like that (SDL sees {', '.join(mapped)})",
                                 f"set match = \"...\" in {section} to part of one of those names, or remove it", raw)
        if unmapped:
            return DeviceFailure(device, f"SDL has no controller mapping for {', '.join(unmapped)}",
                                 "give SDL the pad's mapping line in the SDL_GAMECONTROLLERCONFIG environment "
                                 "variable (SDL's community gamecontrollerdb.txt has most pads)", raw)
        return DeviceFailure(device, "no game controller is plugged in (SDL sees no joystick)",
                             "plug it in (USB, or pair it over Bluetooth); the user running servo-app must be able "
                             "to read /dev/input/event* (the input group)", raw)
    return DeviceFailure(device, f"cannot open it ({raw})", f"check the pad and {section}", raw)


class GamepadAdapter(InputAdapter):
    config_model = GamepadConfig
    config: GamepadConfig

    def __init__(self, config: GamepadConfig, *, clock: Clock = time.monotonic) -> None:
        super().__init__(config, clock=clock)
        self.logic = PadLogic(config.mapping(), config.name, config.frames, translation=config.translation,
                              rotation=config.rotation, dominant_axis=config.dominant_axis)
        self.pad_name: str | None = None  # as SDL names the open pad
        self.rumbles = 0  # rumbles the pad accepted
        self._controllers: SdlControllers | None = None
        self._pad: SdlPad | None = None
        self._refresh_s = config.stale_after_s / 4.0
        self._sent: tuple[Any, ...] | None = None  # the last published twist and frame
        self._sent_at = -float("inf")
        self._faults = FaultWatch()
        self._robot_checked_at = -float("inf")

    def _run(self) -> None:
        try:
            super()._run()
        finally:  # SDL is started in this thread (on the first open) and stopped in it
            if self._controllers is not None:
                self._controllers.close()
                self._controllers = None

    def _open(self) -> None:
        if self._controllers is None:
            self._controllers = SdlControllers()
        self._pad = SdlPad(self._controllers, self.config.match, self.name)
        self.pad_name = self._pad.name
        self.logic.connect(self._pad.read())  # what is held now is no press: the deadman must be pressed anew
        self._sent = None
        self.log.info("game controller %r open (rumble: %s)", self._pad.name, self._pad.has_rumble)

    def explain_open_failure(self, exc: BaseException) -> DeviceFailure:
        return gamepad_failure(self.name, self.config.match, exc)

    def _close(self) -> None:
        pad, self._pad = self._pad, None
        if pad is not None:
            pad.close()

    def _poll(self) -> None:
        # The pad is refreshed at most once per poll: a poll longer than the refresh period (a quarter
        # of stale_after_s) would let a pad at rest go stale between polls and stop the arm.
        if self._stop.wait(min(self.config.poll_timeout_s, self._refresh_s)):
            return
        assert self._pad is not None
        now = self.clock()
        self.process(self._pad.read(), now)
        if now - self._robot_checked_at >= ROBOT_STATE_PERIOD_S:
            self._robot_checked_at = now
            self._rumble_on_fault()

    def process(self, state: PadState, now: float) -> None:
        """One reading of the pad: its button events, then its twist when it changed or is due again."""
        (linear, angular), events = self.logic.step(state, now)
        for ev in events:
            self._emit(ev)
        sent = (linear, angular, self.logic.frame, self.logic.stopped)
        if sent != self._sent or now - self._sent_at >= self._refresh_s:
            self._publish(TwistSample(linear, angular, self.logic.frame, now, self.name, stop=self.logic.stopped))
            self._sent, self._sent_at = sent, now

    def _rumble_on_fault(self) -> None:
        robot_state = self.robot_state
        if not self.config.rumble_on_fault or robot_state is None or self._pad is None:
            return
        try:
            state = robot_state()
        except (OSError, RuntimeError, TimeoutError, ValueError):  # the servo process is being replaced
            return
        if self._faults.observe(state):
            if self._pad.rumble(self.config.rumble_strength, round(self.config.rumble_s * 1000)):
                self.rumbles += 1
            self.log.log(logging.INFO, "robot fault: rumble %s", "sent" if self._pad.has_rumble else "(pad has none)")
