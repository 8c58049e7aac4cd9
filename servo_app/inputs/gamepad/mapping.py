"""From a gamepad's state to a twist and button events (pure: no SDL, no I/O, no threads).

SDL's GameController mapping makes every pad look like an Xbox pad: six axes and up to 21 buttons
under fixed names, numbered in SDL's order (below). A pad's state is read whole each poll; this
module turns it into a twist and the button edges into events and local actions.

Hold-to-run: the twist is zero unless the deadman button is held, and it must have been *pressed*
while the pad was connected: a pad that appears with the deadman already held (a reconnect, a stuck
or taped button) does not move the arm until the button is released and pressed again. The ``stop``
action also zeroes the twist until the deadman is pressed again, and meanwhile the pad keeps control
(its zero twist is marked ``stop``): the arm stays stopped even where a lower-priority source is live.
"""

from __future__ import annotations

import re
from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass, field

from servo_app.inputs.actions import parse_action
from servo_app.inputs.samples import ButtonEvent
from servo_app.inputs.shaping import clamp, cubic_blend, deadband_normalized

# SDL_GameControllerAxis and SDL_GameControllerButton, in SDL's order, under SDL's own names
# (SDL_GameControllerGetStringForAxis/Button; a test checks them against the library).
AXIS_NAMES = ("leftx", "lefty", "rightx", "righty", "lefttrigger", "righttrigger")
BUTTON_NAMES = ("a", "b", "x", "y", "back", "guide", "start", "leftstick", "rightstick", "leftshoulder",
                "rightshoulder", "dpup", "dpdown", "dpleft", "dpright", "misc1", "paddle1", "paddle2", "paddle3",
                "paddle4", "touchpad")
TRIGGERS = frozenset({4, 5})  # axis indices that rest at 0 and read 0..1, not -1..1
COMPONENTS = ("x", "y", "z", "rx", "ry", "rz")  # linear mm/s, then angular deg/s
PAD_ACTIONS = ("stop",)  # the pad's own actions, beyond the shared ones (servo_app.inputs.actions)
AXIS_FULL_SCALE = 32767  # SDL reads sticks as int16 and triggers as 0..32767

_TERM = r"\s*([a-z0-9]+)\s*"
_SOURCE = re.compile(rf"\s*([+-]?){_TERM}(?:([+-]){_TERM})?")


@dataclass(frozen=True, slots=True)
class PadState:
    axes: tuple[float, ...]  # six values, AXIS_NAMES order: sticks -1..1 (up and left negative), triggers 0..1
    buttons: int  # bit i set: button BUTTON_NAMES[i] held

    def held(self, button: int) -> bool:
        return bool((self.buttons >> button) & 1)


def normalize_axes(raw: Sequence[int]) -> tuple[float, ...]:
    """SDL's integer axis readings as fractions of full deflection (-32768 reads as -1, not below)."""
    return tuple(clamp(v / AXIS_FULL_SCALE, -1.0, 1.0) for v in raw)


@dataclass(frozen=True, slots=True)
class Term:
    sign: int  # +1 or -1
    kind: str  # "axis" or "button"
    index: int  # in AXIS_NAMES or BUTTON_NAMES

    def value(self, state: PadState) -> float:
        v = state.axes[self.index] if self.kind == "axis" else float(state.held(self.index))
        return self.sign * v


def _term(sign: str, name: str, text: str) -> Term:
    s = -1 if sign == "-" else 1
    if name in AXIS_NAMES:
        return Term(s, "axis", AXIS_NAMES.index(name))
    if name in BUTTON_NAMES:
        return Term(s, "button", BUTTON_NAMES.index(name))
    raise ValueError(f"{text!r}: {name!r} is neither an axis ({', '.join(AXIS_NAMES)}) nor a button "
                     f"({', '.join(BUTTON_NAMES)})")


def parse_source(text: str) -> tuple[Term, ...]:
    """What drives one twist component: an axis or button, signed, or the difference or sum of two
    ("-lefty", "righttrigger-lefttrigger", "dpup-dpdown"). ValueError naming the value otherwise."""
    m = _SOURCE.fullmatch(text)
    if m is None:
        raise ValueError(f"{text!r} is not an axis source: NAME, -NAME, or NAME-NAME / NAME+NAME "
                         f"(axes {', '.join(AXIS_NAMES)}; buttons {', '.join(BUTTON_NAMES)})")
    terms = [_term(m.group(1), m.group(2), text)]
    if m.group(3):
        terms.append(_term(m.group(3), m.group(4), text))
    return tuple(terms)


def button_index(name: str) -> int:
    if name not in BUTTON_NAMES:
        raise ValueError(f"{name!r} is not a button: one of {', '.join(BUTTON_NAMES)}")
    return BUTTON_NAMES.index(name)


def check_pad_action(text: str) -> str:
    """A button's configured action: a shared action (servo_app.inputs.actions) or a pad action."""
    if text in PAD_ACTIONS:
        return text
    try:
        parse_action(text)
    except ValueError as exc:
        raise ValueError(f"{exc}; or {', '.join(PAD_ACTIONS)}") from None
    return text


@dataclass(frozen=True)
class PadMapping:
    """Everything that decides the twist and the actions; built from the configuration."""

    sources: tuple[tuple[Term, ...], ...]  # per COMPONENTS entry; () leaves that component at 0
    deadman: int  # button index
    actions: Mapping[int, str] = field(default_factory=dict)  # button index -> action name
    deadband: float = 0.1  # fraction of full deflection
    expo: float = 0.5  # cubic blend: 0 linear, 1 pure cubic
    max_linear_mm_s: float = 100.0
    max_angular_deg_s: float = 30.0
    scale: float = 1.0

    @classmethod
    def from_names(cls, axes: Mapping[str, str], deadman: str, buttons: Mapping[str, str], **kw: float) -> PadMapping:
        unknown = set(axes) - set(COMPONENTS)
        if unknown:
            raise ValueError(f"unknown twist components {sorted(unknown)}; expected {', '.join(COMPONENTS)}")
        sources = tuple(parse_source(axes[c]) if c in axes else () for c in COMPONENTS)
        dm = button_index(deadman)
        actions = {button_index(b): check_pad_action(a) for b, a in buttons.items()}
        if dm in actions:
            raise ValueError(f"the deadman button {deadman!r} cannot also have an action")
        driving = {t.index for terms in sources for t in terms if t.kind == "button"}
        if dm in driving or driving & set(actions):
            raise ValueError("a button that drives an axis cannot also be the deadman or have an action")
        return cls(sources, dm, actions, **kw)


def shape_pad(state: PadState, m: PadMapping, *, translation: bool = True, rotation: bool = True,
              dominant_axis: bool = False) -> tuple[tuple[float, float, float], tuple[float, float, float]]:
    """The twist (mm/s, deg/s) the sticks ask for: deadband, expo, groups, dominant axis, speeds."""
    u = [cubic_blend(deadband_normalized(clamp(sum(t.value(state) for t in terms), -1.0, 1.0), m.deadband), m.expo)
         for terms in m.sources]
    if not translation:
        u[0:3] = [0.0, 0.0, 0.0]
    if not rotation:
        u[3:6] = [0.0, 0.0, 0.0]
    if dominant_axis and any(u):
        k = max(range(6), key=lambda i: abs(u[i]))
        u = [x if i == k else 0.0 for i, x in enumerate(u)]
    lin = m.max_linear_mm_s * m.scale
    ang = m.max_angular_deg_s * m.scale
    return (u[0] * lin, u[1] * lin, u[2] * lin), (u[3] * ang, u[4] * ang, u[5] * ang)


ZERO_TWIST = ((0.0, 0.0, 0.0), (0.0, 0.0, 0.0))


def _changed_bits(mask: int) -> Iterator[int]:
    bit = 0
    while mask >> bit:
        if (mask >> bit) & 1:
            yield bit
        bit += 1


class PadLogic:
    """The pad's mode (frame, groups, hold-to-run) and its step from one state to the next."""

    def __init__(self, mapping: PadMapping, source: str, frames: Sequence[str] = ("base", "tool"), *,
                 translation: bool = True, rotation: bool = True, dominant_axis: bool = False) -> None:
        self.mapping = mapping
        self.source = source
        self.frames = tuple(frames)
        self.frame_index = 0
        self.translation = translation
        self.rotation = rotation
        self.dominant_axis = dominant_axis
        self.buttons = 0
        self.running = False  # the deadman was pressed (since connect and since the last stop) and is held
        # The stop button was pressed and the deadman not pressed since: the pad keeps control with a zero
        # twist, so a lower-priority source does not take the arm the operator just stopped.
        self.stopped = False

    @property
    def frame(self) -> str:
        return self.frames[self.frame_index]

    def connect(self, state: PadState) -> None:
        """A pad (re)appeared: what it holds now are not presses, and it does not run until the deadman
        is pressed."""
        self.buttons = state.buttons
        self.running = False
        self.stopped = False  # a pad that went away was stale meanwhile: that stop is the servo's now

    def step(self, state: PadState, stamp: float) -> tuple[tuple[tuple[float, float, float],
                                                                  tuple[float, float, float]], list[ButtonEvent]]:
        """The twist for this state and the button events since the last one, oldest button first."""
        events = []
        stopped = False
        for bit in _changed_bits(state.buttons ^ self.buttons):
            pressed = state.held(bit)
            action = self.mapping.actions.get(bit)
            if bit == self.mapping.deadman:
                self.running = pressed
                self.stopped &= not pressed
            elif pressed and action is not None:
                stopped |= action == "stop"
                self._apply(action)
            # The bridge sees the shared actions (it carries out the output ones); the pad's own
            # actions are done here.
            events.append(ButtonEvent(bit, pressed, None if action in PAD_ACTIONS else action, stamp, self.source))
        self.buttons = state.buttons
        if stopped:
            self.stopped = True
        if stopped or not state.held(self.mapping.deadman):
            self.running = False
        if not self.running:
            return ZERO_TWIST, events
        twist = shape_pad(state, self.mapping, translation=self.translation, rotation=self.rotation,
                          dominant_axis=self.dominant_axis)
        return twist, events

    def _apply(self, action: str) -> None:
        if action == "toggle_frame":
            self.frame_index = (self.frame_index + 1) % len(self.frames)
        elif action == "toggle_translation":
            self.translation = not self.translation
        elif action == "toggle_rotation":
            self.rotation = not self.rotation
        elif action == "toggle_dominant":
            self.dominant_axis = not self.dominant_axis
        # "stop" is handled by the caller; output actions are the bridge's.


class FaultWatch:
    """Whether the robot's published state shows a new fault: the pad rumbles once per fault."""

    def __init__(self) -> None:
        self._faulted = False
        self._faults: int | None = None

    def observe(self, state: Mapping[str, object]) -> bool:
        faulted = state.get("state") == "fault"
        counts = state.get("fault_counts")
        total = sum(counts.values()) if isinstance(counts, Mapping) else None
        new = (faulted and not self._faulted) or (total is not None and self._faults is not None
                                                  and total > self._faults)
        self._faulted = faulted
        if total is not None:
            self._faults = total
        return new
