"""Gamepad: the pure mapping (hypothesis properties: hold-to-run, deadband, expo, bounds, button edges),
the configuration's checks, and the adapter's thread reading SDL's virtual joystick, a real SDL device
in the game controller layout (plugged, unplugged, plugged again, rumbled)."""

from __future__ import annotations

import math
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from waiting import assert_refreshed_within, wait_for, wait_until

from servo_app.inputs import (
    Arbiter,
    ButtonEvent,
    ConfigError,
    ConfigIssue,
    Decision,
    LatestValue,
    SourceSpec,
    TwistSample,
    create_adapter,
    load_inputs_config,
    parse_inputs_config,
)
from servo_app.inputs.actions import LOCAL_ACTIONS
from servo_app.inputs.bridge import InputsBridge
from servo_app.inputs.gamepad.adapter import DEFAULT_AXES, GamepadAdapter, GamepadConfig, gamepad_failure
from servo_app.inputs.gamepad.mapping import (
    AXIS_NAMES,
    BUTTON_NAMES,
    COMPONENTS,
    TRIGGERS,
    FaultWatch,
    PadLogic,
    PadMapping,
    PadState,
    normalize_axes,
    parse_source,
    shape_pad,
)
from servo_app.inputs.gamepad.sdl import NoPad, SdlControllers, VirtualPad

LB, A, B, X, Y = (BUTTON_NAMES.index(n) for n in ("leftshoulder", "a", "b", "x", "y"))


def mapping(**kw: Any) -> PadMapping:
    buttons = kw.pop("buttons", {"a": "toggle_output:DO[1]", "b": "stop", "x": "toggle_frame", "y": "toggle_rotation"})
    return PadMapping.from_names(kw.pop("axes", DEFAULT_AXES), kw.pop("deadman", "leftshoulder"), buttons, **kw)


def state(buttons: int = 0, **axes: float) -> PadState:
    return PadState(tuple(axes.get(n, 0.0) for n in AXIS_NAMES), buttons)


def held(*buttons: int) -> int:
    return sum(1 << b for b in set(buttons))


def running_logic(m: PadMapping | None = None) -> PadLogic:
    """Connected with nothing held, then the deadman pressed."""
    logic = PadLogic(m or mapping(), "pad")
    logic.connect(state())
    logic.step(state(held(LB)), 0.0)
    return logic


sticks = st.floats(-1.0, 1.0, allow_nan=False)
triggers = st.floats(0.0, 1.0, allow_nan=False)
pad_states = st.builds(lambda a, t, b: PadState((*a, *t), b), st.tuples(sticks, sticks, sticks, sticks),
                       st.tuples(triggers, triggers), st.integers(0, (1 << len(BUTTON_NAMES)) - 1))


# ------------------------------------------------------------------------------------- the mapping


@given(pad_states)
def test_no_motion_unless_the_deadman_is_held(s: PadState) -> None:
    logic = running_logic()
    released = PadState(s.axes, s.buttons & ~held(LB))
    (lin, ang), _ = logic.step(released, 1.0)
    assert lin == (0.0, 0.0, 0.0) and ang == (0.0, 0.0, 0.0) and not logic.running


@given(pad_states)
def test_a_deadman_held_when_the_pad_appears_does_not_run_until_pressed_again(s: PadState) -> None:
    logic = PadLogic(mapping(), "pad")
    first = PadState(s.axes, s.buttons | held(LB))
    logic.connect(first)
    assert logic.step(first, 0.0)[0] == ((0.0,) * 3, (0.0,) * 3)
    logic.step(PadState(s.axes, 0), 0.1)  # released ...
    (lin, ang), _ = logic.step(PadState(s.axes, held(LB)), 0.2)  # ... and pressed: now it runs
    assert logic.running and (lin, ang) == shape_pad(PadState(s.axes, held(LB)), logic.mapping)


@settings(max_examples=300)
@given(pad_states, st.floats(0.0, 0.9), st.floats(0.0, 1.0), st.floats(0.1, 3.0))
def test_twist_is_bounded_by_the_speeds_and_mirrors_with_the_sticks(s: PadState, deadband: float, expo: float,
                                                                    scale: float) -> None:
    axes = {"x": "-lefty", "y": "-leftx", "z": "-righty", "rz": "-rightx"}  # sticks only: mirroring flips them
    m = mapping(axes=axes, deadband=deadband, expo=expo, max_linear_mm_s=80.0, max_angular_deg_s=20.0, scale=scale)
    lin, ang = shape_pad(s, m)
    assert all(abs(v) <= 80.0 * scale * (1 + 1e-12) for v in lin)
    assert all(abs(v) <= 20.0 * scale * (1 + 1e-12) for v in ang)
    mirrored = PadState(tuple(-v for v in s.axes[:4]) + s.axes[4:], s.buttons)
    mlin, mang = shape_pad(mirrored, m)
    assert mlin == tuple(-v for v in lin) and mang == tuple(-v for v in ang)


@given(st.floats(-1.0, 1.0), st.floats(0.0, 0.9), st.floats(0.0, 1.0))
def test_deadband_then_expo_on_one_stick(u: float, deadband: float, expo: float) -> None:
    m = mapping(axes={"x": "-lefty"}, deadband=deadband, expo=expo, max_linear_mm_s=100.0)
    x = shape_pad(state(lefty=-u), m)[0][0]
    if abs(u) <= deadband:
        assert x == 0.0  # a stick resting off centre commands nothing
    else:
        v = (abs(u) - deadband) / (1 - deadband)
        assert x == pytest.approx(math.copysign(100.0 * ((1 - expo) * v + expo * v ** 3), u), abs=1e-9)
        assert math.copysign(1.0, x) == math.copysign(1.0, u) or x == 0.0
    assert shape_pad(state(lefty=-1.0), m)[0][0] == pytest.approx(100.0)  # full deflection: full speed


@given(st.floats(0.0, 1.0), st.floats(0.0, 1.0))
def test_two_triggers_make_one_axis_and_buttons_read_one(right: float, left: float) -> None:
    m = mapping(deadband=0.0, expo=0.0, max_angular_deg_s=30.0)
    (_, (rx, ry, _)) = shape_pad(state(held(BUTTON_NAMES.index("dpdown")), righttrigger=right, lefttrigger=left), m)
    assert rx == pytest.approx(30.0 * (right - left)) and ry == -30.0


@given(st.lists(st.integers(0, (1 << len(BUTTON_NAMES)) - 1), min_size=1, max_size=12))
def test_every_button_edge_is_one_event_in_button_order(masks: list[int]) -> None:
    logic = PadLogic(mapping(buttons={}), "pad")
    logic.connect(state())
    prev = 0
    for t, mask in enumerate(masks):
        _, events = logic.step(state(mask), float(t))
        changed = [b for b in range(len(BUTTON_NAMES)) if (mask ^ prev) >> b & 1]
        assert [(e.button, e.pressed, e.stamp, e.source) for e in events] == \
            [(b, bool(mask >> b & 1), float(t), "pad") for b in changed]
        prev = mask


def test_button_actions_frame_groups_and_stop() -> None:
    logic = running_logic(mapping(deadband=0.0, expo=0.0))
    full = {"lefty": -1.0, "rightx": -1.0}  # +X and +RZ
    (lin, ang), _ = logic.step(state(held(LB), **full), 1.0)
    assert lin == (100.0, 0.0, 0.0) and ang == (0.0, 0.0, 30.0) and logic.frame == "base"
    _, events = logic.step(state(held(LB, X, Y), **full), 1.1)  # toggle_frame, toggle_rotation
    assert events == [ButtonEvent(X, True, "toggle_frame", 1.1, "pad"), ButtonEvent(Y, True, "toggle_rotation",
                                                                                   1.1, "pad")]
    (lin, ang), _ = logic.step(state(held(LB), **full), 1.2)
    assert logic.frame == "tool" and lin == (100.0, 0.0, 0.0) and ang == (0.0, 0.0, 0.0)
    _, events = logic.step(state(held(LB, A), **full), 1.3)  # an output: for the bridge, nothing here
    assert events == [ButtonEvent(A, True, "toggle_output:DO[1]", 1.3, "pad")]
    twist, events = logic.step(state(held(LB, B), **full), 1.4)  # stop: the pad's own, not the bridge's
    assert twist == ((0.0,) * 3, (0.0,) * 3)
    assert events == [ButtonEvent(A, False, "toggle_output:DO[1]", 1.4, "pad"), ButtonEvent(B, True, None, 1.4, "pad")]
    assert logic.step(state(held(LB), **full), 1.5)[0] == ((0.0,) * 3, (0.0,) * 3)  # stays stopped
    logic.step(state(**full), 1.6)
    assert logic.step(state(held(LB), **full), 1.7)[0][0] == (100.0, 0.0, 0.0)  # the deadman pressed anew
    # Stop and the deadman in the same reading: stop wins.
    logic.step(state(**full), 1.8)
    assert logic.step(state(held(LB, B), **full), 1.9)[0] == ((0.0,) * 3, (0.0,) * 3)


def test_every_shared_local_action_is_carried_out() -> None:
    logic = running_logic(mapping(buttons={"x": "toggle_frame", "y": "toggle_rotation", "a": "toggle_translation",
                                           "b": "toggle_dominant"}))
    before = (logic.frame, logic.rotation, logic.translation, logic.dominant_axis)
    logic.step(state(held(LB, X, Y, A, B)), 1.0)
    assert len(LOCAL_ACTIONS) == 4
    assert (logic.frame, logic.rotation, logic.translation, logic.dominant_axis) == \
        ("tool", not before[1], not before[2], not before[3])


@given(st.lists(st.integers(-32768, 32767), min_size=6, max_size=6))
def test_normalized_axes_stay_within_full_deflection(raw: list[int]) -> None:
    axes = normalize_axes(raw)
    assert all(-1.0 <= v <= 1.0 for v in axes) and normalize_axes([32767])[0] == 1.0 == -normalize_axes([-32768])[0]


@pytest.mark.parametrize(("text", "error"), [
    ("leftz", "neither an axis"), ("-", "not an axis source"), ("a-b-c", "not an axis source"),
    ("lefty*2", "not an axis source"),
])
def test_bad_axis_sources_name_the_value(text: str, error: str) -> None:
    with pytest.raises(ValueError, match=error):
        parse_source(text)


def test_fault_watch_fires_once_per_new_fault() -> None:
    w = FaultWatch()
    assert not w.observe({"state": "streaming", "fault_counts": {}})
    assert w.observe({"state": "fault", "fault_counts": {"alarm": 1}})
    assert not w.observe({"state": "fault", "fault_counts": {"alarm": 1}})
    assert not w.observe({"state": "disconnected", "fault_counts": {"alarm": 1}})  # reset
    assert w.observe({"state": "disconnected", "fault_counts": {"alarm": 1, "link": 1}})  # over before it was seen
    assert not w.observe({"state": "streaming"})


# ------------------------------------------------------------------------------------ configuration


def test_configuration_errors_name_the_key_and_value() -> None:
    bad = {"adapters": {"pad": {"type": "gamepad", "deadman": "lb", "axes": {"x": "leftz", "w": "lefty"},
                                "buttons": {"a": "explode", "q": "stop"}, "scale": {"x": 2.0}}}}
    with pytest.raises(ConfigError) as ei:
        parse_inputs_config(bad, file="pad.toml")
    text = str(ei.value)
    for needle in ("adapters.pad.deadman", "'lb' is not a button", "adapters.pad.axes", "leftz", "adapters.pad.buttons",
                   "explode", "one overall scale"):
        assert needle in text, needle

    def clash(table: dict[str, Any]) -> ConfigIssue:
        with pytest.raises(ConfigError) as ei:
            parse_inputs_config({"adapters": {"pad": {"type": "gamepad", **table}}}, file="pad.toml")
        (issue,) = ei.value.issues
        return issue

    # A button with two uses names the key and the button (it named the whole table, and no button).
    issue = clash({"deadman": "a", "buttons": {"a": "stop"}})
    assert (issue.key, issue.value) == ("adapters.pad.buttons.a", "stop") and "'a' is the deadman" in issue.reason
    issue = clash({"buttons": {"dpup": "stop"}})
    assert (issue.key, issue.value) == ("adapters.pad.buttons.dpup", "stop")
    assert "'dpup' drives axis ry ('dpup-dpdown')" in issue.reason and "set axes.ry" in issue.reason
    issue = clash({"deadman": "dpdown"})
    assert (issue.key, issue.value) == ("adapters.pad.axes.ry", "dpup-dpdown") and "'dpdown' is the deadman" in \
        issue.reason


def test_the_example_configuration_loads() -> None:
    cfg = load_inputs_config(Path(__file__).parent.parent / "configs" / "inputs" / "gamepad.toml")
    (pad,) = cfg.adapters
    assert isinstance(pad, GamepadConfig) and pad.deadman == "leftshoulder" and pad.buttons["b"] == "stop"
    assert pad.axes == DEFAULT_AXES and pad.mapping().actions[A] == "toggle_output:DO[1]"


def test_failures_name_the_pad_the_reason_and_the_fix() -> None:
    f = gamepad_failure("pad", None, NoPad("no game controller", []))
    assert f.device == "game controller (SDL)" and "no game controller is plugged in" in f.reason
    assert "input group" in f.fix
    f = gamepad_failure("pad", None, NoPad("no game controller", [(0, "Weird Stick", False)]))
    assert "no controller mapping for Weird Stick" in f.reason and "SDL_GAMECONTROLLERCONFIG" in f.fix
    f = gamepad_failure("pad", "xbox", NoPad("no game controller named like 'xbox'", [(0, "PS5 Controller", True)]))
    assert f.device == "game controller (SDL) named like 'xbox'" and "PS5 Controller" in f.reason
    assert "[adapters.pad]" in f.fix
    assert "servo_app[gamepad]" in gamepad_failure("pad", None, RuntimeError("needs pysdl2 ...")).fix


# ----------------------------------------------------------------------------- SDL's virtual joystick


@pytest.fixture
def pad() -> Iterator[VirtualPad]:
    p = VirtualPad()
    try:
        yield p
    finally:
        p.close()


def adapter(**kw: Any) -> GamepadAdapter:
    cfg = {"name": "pad", "type": "gamepad", "realtime_priority": 0, "reconnect_min_s": 0.05, "reconnect_max_s": 0.1,
           "deadband": 0.0, "expo": 0.0, "buttons": {"x": "toggle_frame", "a": "toggle_output:DO[1]"}, **kw}
    a = create_adapter(cfg)
    assert isinstance(a, GamepadAdapter)
    return a


def test_sdl_names_axes_and_buttons_as_the_mapping_does(pad: VirtualPad) -> None:
    sdl = pad.sdl
    assert tuple(sdl.SDL_GameControllerGetStringForAxis(i).decode() for i in range(len(AXIS_NAMES))) == AXIS_NAMES
    assert tuple(sdl.SDL_GameControllerGetStringForButton(i).decode() for i in range(len(BUTTON_NAMES))) == \
        BUTTON_NAMES
    assert len(AXIS_NAMES) == sdl.SDL_CONTROLLER_AXIS_MAX and len(BUTTON_NAMES) == sdl.SDL_CONTROLLER_BUTTON_MAX
    assert {sdl.SDL_CONTROLLER_AXIS_TRIGGERLEFT, sdl.SDL_CONTROLLER_AXIS_TRIGGERRIGHT} == TRIGGERS
    assert set(COMPONENTS) == set(DEFAULT_AXES)
    assert sdl.SDL_WasInit(sdl.SDL_INIT_VIDEO) == 0  # headless: no video subsystem, no window


def test_the_adapter_reads_the_virtual_pad_hold_to_run(pad: VirtualPad) -> None:
    a = adapter()
    with a:
        wait_for(a.output, lambda s: s.is_zero())  # connected, at rest: a live zero
        assert a.connected and a.pad_name == "servo_app virtual pad"
        pad.axis("lefty", -1.0)  # full forward, deadman not held: nothing
        pad.axis("righttrigger", 0.5)
        wait_until(lambda: a.logic.buttons == 0 and a.output.read().value.is_zero() and a.output.seq >= 3)
        pad.button("leftshoulder", True)
        s = wait_for(a.output, lambda s: s.linear[0] > 0)
        assert isinstance(s, TwistSample) and s.linear == (100.0, 0.0, 0.0) and s.frame == "base" and s.source == "pad"
        assert s.angular == pytest.approx((15.0, 0.0, 0.0), abs=0.01)  # half the right trigger: half the roll speed
        pad.button("x", True)  # toggle_frame
        wait_for(a.output, lambda s: s.frame == "tool" and s.linear[0] == 100.0)
        ev = a.events.drain()
        assert [(e.button, e.pressed, e.action) for e in ev] == [(LB, True, None), (X, True, "toggle_frame")]
        pad.button("leftshoulder", False)  # released: zero at once, the stick still forward
        wait_for(a.output, lambda s: s.is_zero())
        held_steady = a.output.read()
        wait_for(a.output, lambda s: s.is_zero() and a.output.read().stamp > held_steady.stamp)  # refreshed


def test_the_stop_button_keeps_the_arm_from_a_lower_priority_source(pad: VirtualPad) -> None:
    """The pad yields while idle (configured so), and its stop gave a zero twist like a released deadman:
    a lower-priority source that was live took the arm the operator had just stopped. Now the pad keeps
    control with its zero twist until the deadman is pressed anew; a plain release still yields."""
    a = adapter(priority=20, buttons={"b": "stop"})
    auto: LatestValue[TwistSample] = LatestValue("auto")
    arbiter = Arbiter([a.source_spec(), SourceSpec("auto", 0, 5.0, auto)])

    def select() -> Decision:
        auto.publish(TwistSample((0.0, 50.0, 0.0), (0.0, 0.0, 0.0), "base", time.monotonic(), "auto"))
        return arbiter.select()

    with a:
        wait_for(a.output, lambda s: s.is_zero())
        pad.axis("lefty", -1.0)
        pad.button("leftshoulder", True)
        wait_for(a.output, lambda s: s.linear[0] > 0)
        assert select().active == "pad"
        pad.button("b", True)  # stop, the deadman still held
        wait_for(a.output, lambda s: s.is_zero())
        d = select()
        assert d.active == "pad" and d.sample.is_zero(), d  # the arm stays stopped
        pad.button("b", False)
        pad.button("leftshoulder", False)
        wait_until(lambda: not a.logic.buttons)
        d = select()
        assert d.active == "pad" and d.sample.is_zero(), d  # released too: still the pad's stop
        pad.button("leftshoulder", True)  # pressed anew: the pad runs again
        wait_for(a.output, lambda s: s.linear[0] > 0 and not s.stop)
        pad.button("leftshoulder", False)  # a plain release yields, as configured
        wait_for(a.output, lambda s: s.is_zero() and not s.stop)
        assert select().active == "auto"


TELEOP_PAD = """
[adapters.pad]
type = "gamepad"
realtime_priority = 0
deadband = 0.0
expo = 0.0

[adapters.pad.buttons]
b = "stop"

[feeds.auto]
kind = "twist"
stale_after_s = 1.5

[[applications]]
name = "teleop"
type = "teleop"
sources = { twist = "pad" }
priority = 20
"""


def test_the_stop_button_holds_through_a_teleop_application(pad: VirtualPad, tmp_path: Path) -> None:
    """The same stop with the pad driving a teleop application (yield_when_idle, its default): the
    application rebuilt the twist without the stop mark, so the live lower-priority feed took the arm
    the operator had just stopped. Bridge, pad adapter and application run as in the service."""
    path = tmp_path / "inputs.toml"
    path.write_text(TELEOP_PAD)
    bridge = InputsBridge.from_file(path)
    teleop = bridge.application("teleop")
    reader = bridge.adapters[0]
    assert isinstance(reader, GamepadAdapter)

    def active() -> str | None:
        bridge.feeds.submit("auto", {"kind": "twist", "linear": [0.0, 50.0, 0.0], "frame": "base"})
        bridge.step(time.monotonic())
        return bridge.arbiter.active

    bridge.start(request=lambda _msg: None)
    try:
        bridge.enable(True)
        wait_for(teleop.output, lambda s: s.is_zero())
        pad.axis("lefty", -1.0)
        pad.button("leftshoulder", True)
        wait_for(teleop.output, lambda s: s.linear[0] > 0)
        assert active() == "teleop"
        pad.button("b", True)  # stop, the deadman still held
        wait_for(teleop.output, lambda s: s.is_zero())
        assert active() == "teleop"  # the arm stays stopped: the feed does not take it
        last = bridge.last_command
        assert last is not None and not any(last.values), last
        pad.button("b", False)
        pad.button("leftshoulder", False)
        pad.axis("lefty", 0.0)
        wait_until(lambda: not reader.logic.buttons)  # the adapter has read the release
        assert active() == "teleop"  # released too: still the pad's stop
        pad.button("leftshoulder", True)  # pressed anew, then a plain release: yields, as configured
        wait_for(teleop.output, lambda s: s.is_zero() and not s.stop)
        pad.button("leftshoulder", False)
        wait_until(lambda: active() == "auto")
    finally:
        bridge.close()


def test_unplugged_mid_jog_goes_quiet_reports_and_reconnects_not_running(pad: VirtualPad) -> None:
    a = adapter(stale_after_s=0.2)
    with a:
        wait_for(a.output, lambda s: s.is_zero())
        pad.button("leftshoulder", True)
        pad.axis("leftx", -1.0)  # +Y
        wait_for(a.output, lambda s: s.linear[1] == 100.0)
        pad.detach()
        wait_until(lambda: a.failure is not None)
        seq = a.output.seq
        st_ = a.status()
        assert not st_.connected and st_.problems["disconnected"] == 1
        assert "was unplugged" in st_.recent_problems[0].message
        assert "no game controller is plugged in" in a.failure.reason  # type: ignore[union-attr]
        wait_until(lambda: a.status().problems["open_failed"] >= 2 and a.status().stale)
        assert a.output.seq == seq  # nothing published while it is gone
        again = VirtualPad()
        try:
            again.button("leftshoulder", True)  # plugged in with the deadman held and the stick deflected
            again.axis("leftx", -1.0)
            wait_until(lambda: a.connected and a.output.seq > seq)
            assert a.failure is None and a.status().connects == 2
            wait_until(lambda: a.output.seq > seq + 2)
            assert a.output.read().value.is_zero()  # not running: the deadman was not pressed since
            again.button("leftshoulder", False)
            wait_until(lambda: not a.logic.buttons)  # the release was read (a person's takes longer than a poll)
            again.button("leftshoulder", True)
            wait_for(a.output, lambda s: s.linear[1] == 100.0)
        finally:
            again.close()


def test_a_pad_at_rest_stays_live_whatever_the_poll_timeout(pad: VirtualPad) -> None:
    """The pad is refreshed at most once per poll: poll_timeout_s at or above stale_after_s let the
    resting pad go stale between polls (the arm stopped for a lost input nobody had touched)."""
    with adapter(stale_after_s=0.2, poll_timeout_s=1.0) as a:
        wait_for(a.output, lambda s: s.is_zero())
        assert_refreshed_within(a.output, 0.2)


def test_a_new_robot_fault_rumbles_the_pad_once(pad: VirtualPad) -> None:
    robot = {"state": "streaming", "fault_counts": {}}
    a = adapter()
    a.robot_state = lambda: dict(robot)
    with a:
        wait_for(a.output, lambda s: s.is_zero())
        wait_until(lambda: a._robot_checked_at > -math.inf)
        robot.update(state="fault", fault_counts={"stream lost": 1})
        wait_until(lambda: a.rumbles == 1)
        assert pad.rumbles == [(0xFFFF, 0xFFFF)]
        checked = a._robot_checked_at
        wait_until(lambda: a._robot_checked_at > checked + 0.15)  # looked at again: the same fault, no rumble
        assert a.rumbles == 1 and len(pad.rumbles) == 1


def test_a_pad_without_motors_is_not_rumbled() -> None:
    bare = VirtualPad("bare pad", rumble=False)
    try:
        a = adapter(rumble_strength=0.5)
        a.robot_state = lambda: {"state": "fault"}
        with a:
            wait_until(lambda: a._robot_checked_at > -math.inf)
            assert a.rumbles == 0 and bare.rumbles == []
    finally:
        bare.close()


def test_match_picks_a_pad_by_name_and_names_the_others_when_none_matches(pad: VirtualPad) -> None:
    a = adapter(match="xbox")
    with a:
        assert a.first_attempt.wait(10)
        assert a.failure is not None and "servo_app virtual pad" in a.failure.reason and not a.connected
    with adapter(match="VIRTUAL") as b:
        wait_for(b.output, lambda s: s.is_zero())
        assert b.pad_name == "servo_app virtual pad"


def test_two_gamepad_inputs_read_two_pads_and_a_third_says_which_input_holds_them(pad: VirtualPad) -> None:
    """Both inputs used to open the first pad: the second pad moved nothing and the first drove two sources."""
    second = VirtualPad("servo_app second pad")
    try:
        with adapter() as a, adapter(name="pad2") as b:
            wait_for(a.output, lambda s: s.is_zero())
            wait_for(b.output, lambda s: s.is_zero())
            assert {a.pad_name, b.pad_name} == {"servo_app virtual pad", "servo_app second pad"}
            mine = pad if b.pad_name == "servo_app virtual pad" else second
            mine.button("leftshoulder", True)
            mine.axis("leftx", -1.0)
            wait_for(b.output, lambda s: s.linear[1] == 100.0)  # the pad b reads drives b only
            assert a.output.read().value.is_zero() and not a.logic.buttons
            with adapter(name="pad3") as c:
                assert c.first_attempt.wait(10) and not c.connected
                assert c.failure is not None and "already read by another input" in c.failure.reason
                assert "by input 'pad'" in c.failure.reason and "by input 'pad2'" in c.failure.reason
                assert "[adapters.pad3]" in c.failure.fix
                a.stop()  # its pad is free again: the third input takes it
                wait_until(lambda: c.connected and c.failure is None)
    finally:
        second.close()


def test_sdl_is_given_back_when_the_adapter_stops() -> None:
    a = adapter()
    a.start()
    assert a.first_attempt.wait(10) and a.failure is not None  # no pad: SDL was started to look
    a.stop()
    probe = SdlControllers()
    try:
        assert probe.joysticks() == []
    finally:
        probe.close()
    assert probe.sdl.SDL_WasInit(probe.sdl.SDL_INIT_GAMECONTROLLER) == 0  # every reference given back
