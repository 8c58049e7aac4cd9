"""Watchdogs: hold-to-run, per-source staleness, status loss. Time is always passed in."""

from __future__ import annotations

import math

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from servo_app.safety import (
    HoldToRun,
    InputStale,
    JogExpired,
    Mode,
    SafetyState,
    StalenessWatch,
    StartRequested,
    StatusLost,
    StatusReceived,
    StatusWatch,
    StopRequested,
    transition,
)

BAD_TIMES = [math.nan, math.inf, -math.inf]
times = st.floats(min_value=0.0, max_value=1e6, allow_nan=False)
gaps = st.floats(min_value=0.0, max_value=10.0, allow_nan=False)


# --- HoldToRun -----------------------------------------------------------------------------------


def test_hold_to_run_expires_after_the_last_jog_plus_timeout():
    h = HoldToRun(0.2)
    assert not h.held and not h.expired(100.0) and not h.active(0.0)
    h = h.renew(1.0).renew(1.25)
    assert h.held and h.deadline == pytest.approx(1.45)
    assert h.active(1.44) and not h.expired(1.44)
    assert h.expired(1.46) and not h.active(1.46)
    h2, ev = h.poll(1.5)
    assert ev == JogExpired() and not h2.held
    assert h2.poll(1.6) == (h2, None)  # one held jog expires once


def test_hold_to_run_release_stops_at_once_without_an_event():
    h = HoldToRun(0.2).renew(1.0).release()
    assert not h.held and h.poll(5.0) == (h, None)


@pytest.mark.parametrize("bad", BAD_TIMES)
def test_hold_to_run_fails_safe_on_bad_clocks(bad):
    h = HoldToRun(0.2).renew(1.0)
    assert h.expired(bad) and not h.active(bad)
    assert h.renew(bad) == h  # a bogus timestamp never extends the deadline
    assert not HoldToRun(0.2).renew(bad).held  # nor starts a hold


def test_hold_to_run_ignores_out_of_order_renewals():
    h = HoldToRun(0.2).renew(2.0).renew(1.0)
    assert h.deadline == pytest.approx(2.2)


@pytest.mark.parametrize("timeout", [0.0, -1.0, math.nan, math.inf])
def test_hold_to_run_rejects_bad_timeouts(timeout):
    with pytest.raises(ValueError, match="timeout_s"):
        HoldToRun(timeout)


@settings(max_examples=200, deadline=None)
@given(st.lists(times, min_size=1, max_size=20), gaps, st.floats(min_value=1e-3, max_value=5.0))
def test_hold_to_run_property(renewals, gap, timeout):
    h = HoldToRun(timeout)
    for t in renewals:
        h = h.renew(t)
    now = max(renewals) + gap
    assert h.expired(now) == (now - max(renewals) > timeout)


# --- StalenessWatch --------------------------------------------------------------------------------


@given(st.floats(allow_nan=True, allow_infinity=True), st.floats(allow_nan=True, allow_infinity=True))
def test_a_hold_renewed_at_once_is_a_new_hold_renewed(timeout, now):
    """``HoldToRun.renewed`` (a twist's renewal, in one construction) is ``HoldToRun(timeout).renew(now)``:
    the same hold, or the same refusal of a bad timeout."""
    def outcome(make):
        try:
            return make()
        except ValueError as exc:
            return str(exc)

    assert outcome(lambda: HoldToRun.renewed(timeout, now)) == outcome(lambda: HoldToRun(timeout).renew(now))


def test_staleness_is_per_source():
    w = StalenessWatch.start({"spacemouse": 0.05, "can0": 0.5}, now=0.0)
    assert w.stale(0.05) == ()
    assert w.stale(0.06) == ("spacemouse",)
    w = w.seen("spacemouse", 0.06)
    assert w.stale(0.1) == ()
    assert w.stale(0.6) == ("spacemouse", "can0")
    assert w.events(0.6) == (InputStale("spacemouse"), InputStale("can0"))


def test_staleness_watch_is_a_value():
    w0 = StalenessWatch.start({"a": 1.0}, 0.0)
    w1 = w0.seen("a", 5.0)
    assert w0.last_seen["a"] == 0.0 and w1.last_seen["a"] == 5.0
    with pytest.raises(TypeError):
        w1.last_seen["a"] = 9.0  # type: ignore[index]


@pytest.mark.parametrize("bad", BAD_TIMES)
def test_staleness_fails_safe_on_bad_clocks(bad):
    w = StalenessWatch.start({"a": 1.0, "b": 1.0}, 0.0)
    assert w.stale(bad) == ("a", "b")
    assert w.seen("a", bad) == w


def test_staleness_rejects_unknown_sources_and_bad_setup():
    w = StalenessWatch.start({"a": 1.0}, 0.0)
    with pytest.raises(KeyError):
        w.seen("b", 1.0)
    with pytest.raises(ValueError, match="timeout"):
        StalenessWatch({"a": 0.0})
    with pytest.raises(ValueError, match="no timeout"):
        StalenessWatch({"a": 1.0}, {"b": 0.0})
    with pytest.raises(ValueError, match="start time"):
        StalenessWatch.start({"a": 1.0}, math.nan)


def test_an_unstarted_source_is_not_watched_until_seen():
    w = StalenessWatch({"a": 1.0})
    assert w.stale(100.0) == ()
    assert w.seen("a", 100.0).stale(101.5) == ("a",)


def test_stale_input_stops_a_stream():
    s = transition(transition(SafetyState(), StatusReceived(True, False, True)).state, StartRequested()).state
    w = StalenessWatch.start({"spacemouse": 0.05}, 0.0)
    (event,) = w.events(0.1)
    t = transition(s, event)
    assert t.state.mode is Mode.STOPPING and t.state.stop_reason == "input spacemouse stale"


# --- StatusWatch ------------------------------------------------------------------------------------


def test_status_lost_after_n_intervals():
    w = StatusWatch(0.008, missed=3)
    assert not w.lost(1e9) and w.poll(1e9) is None  # not watching before status output is requested
    w = w.arm(1.0)
    assert not w.lost(1.023) and w.lost(1.025)
    w = w.received(1.02)
    assert not w.lost(1.043)
    ev = w.poll(1.05)
    assert isinstance(ev, StatusLost) and "0.030 s" in ev.detail
    assert not w.disarm().lost(10.0)


@pytest.mark.parametrize("bad", BAD_TIMES)
def test_status_watch_fails_safe_on_bad_clocks(bad):
    w = StatusWatch(0.008).arm(0.0)
    assert w.lost(bad) and w.poll(bad) == StatusLost("no status packet (invalid clock)")
    assert w.received(bad) == w
    with pytest.raises(ValueError, match="arm time"):
        w.arm(bad)


@pytest.mark.parametrize(("interval", "missed"), [(0.0, 3), (math.nan, 3), (0.008, 0)])
def test_status_watch_rejects_bad_setup(interval, missed):
    with pytest.raises(ValueError):
        StatusWatch(interval, missed)


def test_status_lost_while_stopping_faults_but_only_disconnects_when_idle():
    ready = transition(SafetyState(), StatusReceived(True, False, True)).state
    streaming = transition(ready, StartRequested()).state
    stopping = transition(streaming, StopRequested()).state
    ev = StatusWatch(0.008).arm(0.0).poll(1.0)
    assert ev is not None
    assert transition(stopping, ev).state.mode is Mode.FAULT
    assert transition(ready, ev).state.mode is Mode.DISCONNECTED
