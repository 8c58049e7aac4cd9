"""The state vector both servo processes publish."""

from __future__ import annotations

import time

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st
from prometheus_client.parser import text_string_to_metric_families

from servo_app.api.metrics import Metrics
from servo_app.motion.settle import SettleDetector
from servo_app.service.alarms import fault_cause
from servo_app.service.views import consistent
from servo_app.state import StateVector, command_derivatives, decode_state


def test_command_derivatives_are_the_controllers_finite_differences() -> None:
    dt = 0.008
    q = [np.array([0.0, 1.0]), np.array([0.1, 1.0]), np.array([0.3, 1.0]), np.array([0.6, 1.0]),
         np.array([1.0, 1.0])]
    d = command_derivatives(q, dt)  # the last four: 0.1, 0.3, 0.6, 1.0
    np.testing.assert_allclose(d["q_cmd"], [1.0, 1.0])
    np.testing.assert_allclose(d["vel"], [0.4 / dt, 0.0])
    np.testing.assert_allclose(d["acc"], [0.1 / dt**2, 0.0])
    np.testing.assert_allclose(d["jerk"], [0.0, 0.0], atol=1e-6)
    # At the start the first command stands in for those not sent yet: one command is at rest.
    one = command_derivatives(q[:1], dt)
    assert not any(np.any(one[k]) for k in ("vel", "acc", "jerk"))


# ------------------------------------------------------------------------------- the new fields


def test_status_time_stamp_is_null_until_a_status_carries_one() -> None:
    sv = StateVector()
    s = decode_state(sv.data)
    assert s["status_time_ms"] is None and s["settled"] is False and s["status_unix"] == 0.0
    sv.set("status_time_ms", 1234)
    sv.set("settled", 1.0)
    s = decode_state(sv.data)
    assert s["status_time_ms"] == 1234 and s["settled"] is True


# -------------------------------------------------------------------------------------- settled


def test_settles_after_a_window_of_steady_feedback_not_at_the_first_steady_sample() -> None:
    d = SettleDetector(tol=0.01, window_s=0.1)
    t, x = 0.0, 0.0
    for _ in range(50):  # moving: 0.1 per 8 ms
        t, x = t + 0.008, x + 0.1
        assert not d.add(t, [x, 0.0])
    steady = [d.add(t + 0.008 * (i + 1), [x, 0.0]) for i in range(20)]
    assert steady.index(True) == 12  # the first sample 0.1 s after the last move (13 x 8 ms > 0.1 s)
    assert all(steady[12:])
    assert not d.add(t + 0.2, [x + 0.02, 0.0])  # a move beyond the tolerance unsettles at once


def test_one_sample_or_a_gap_proves_nothing() -> None:
    d = SettleDetector(tol=0.01, window_s=0.1)
    assert not d.add(0.0, [1.0])
    assert not d.add(5.0, [1.0])  # two samples, far apart: fewer than min_samples
    assert d.add(5.01, [1.0])  # three, spanning the window, all equal
    d.reset()
    assert not d.add(6.0, [1.0]) and not d.settled


@given(st.lists(st.tuples(st.floats(0.001, 0.05), st.floats(-0.05, 0.05)), min_size=1, max_size=80))
def test_settled_means_every_sample_of_the_last_window_within_the_tolerance(steps: list[tuple[float, float]]) -> None:
    tol, window = 0.01, 0.1
    d = SettleDetector(tol=tol, window_s=window)
    t, x, seen = 0.0, 0.0, []
    for dt, dx in steps:
        t, x = t + dt, x + dx
        seen.append((t, x))
        if d.add(t, [x]):
            recent = [v for ts, v in seen if ts >= t - window]
            assert max(recent) - min(recent) <= tol
            assert t - seen[0][0] >= window  # watched for a whole window


# ------------------------------------------------------------------------- a consistent state view


@pytest.mark.parametrize(("link", "state", "age", "live", "shown_state"), [
    ("streaming", "streaming", 0.01, True, "streaming"),
    ("connected", "ready", 0.01, True, "ready"),
    ("streaming", "streaming", 5.0, False, "streaming"),  # the process stalled: its last status is old
    ("fault", "fault", 0.01, False, "fault"),
    ("fault", "ready", 0.01, False, "disconnected"),  # READY beside a faulted link: not so
    ("fault", "connected", 0.01, False, "disconnected"),
    ("idle", "disconnected", 0.01, False, "disconnected"),
    ("closed", "ended", 0.01, False, "ended"),
])
def test_status_bits_are_reported_only_while_status_arrives(link: str, state: str, age: float, live: bool,
                                                             shown_state: str) -> None:
    now = 1000.0
    s = consistent({"link": link, "state": state, "status_bits": 7, "status_unix": now - age}, now)
    assert s["status_live"] is live and s["state"] == shown_state
    assert s["status_bits"] == (7 if live else None) and s["status_bits_last"] == 7
    assert s["status_age_s"] == pytest.approx(age)
    none = consistent({"link": "connected", "state": "connected", "status_bits": 0, "status_unix": 0.0}, now)
    assert none["status_live"] is False and none["status_age_s"] is None


@pytest.mark.parametrize(("link", "state", "age", "live", "shown_state"), [
    ("streaming", "streaming", 0.01, True, "streaming"),
    ("fault", "ready", 0.01, False, "disconnected"),  # what GET /api/state shows (metrics said "ready")
    ("fault", "connected", 0.01, False, "disconnected"),
    ("streaming", "streaming", 5.0, False, "streaming"),  # no status for 5 s
    ("idle", "disconnected", 0.0, False, "disconnected"),  # no stream
])
def test_metrics_show_the_state_as_the_state_endpoint_does(link: str, state: str, age: float, live: bool,
                                                           shown_state: str) -> None:
    """/metrics rendered the servo process's state uncorrected: READY beside a faulted link, where GET
    /api/state (``consistent``) says disconnected; and the last status interval stayed after status
    packets stopped. The real collector and renderer, on a published state."""
    now = time.time()
    published = {"link": link, "state": state, "status_bits": 7, "status_unix": now - age if age else 0.0,
                 "status_interval_last_ms": 8.0}
    fams = {f.name: f for f in text_string_to_metric_families(Metrics(lambda: (published, {})).render().decode())}
    states = {x.labels["state"]: x.value for x in fams["servo_state"].samples}
    assert states[shown_state] == 1.0 and sum(states.values()) == 1.0, states
    if live:
        assert fams["servo_status_interval_seconds"].samples[0].value == pytest.approx(0.008)
    else:  # absent: Prometheus marks the series stale, not a healthy-looking last interval
        assert "servo_status_interval_seconds" not in fams
    assert published["state"] == state  # the snapshot itself is not changed


@pytest.mark.parametrize(("fault", "cause"), [
    ({"code": "MOTN-603", "message": "status bit 0 fell while streaming"}, "MOTN-603"),
    ({"code": None, "message": "status bit 0 fell while streaming"}, "controller_stopped"),
    ({"code": None, "message": "SYSRDY went off while stopping"}, "sysrdy_off"),
    ({"code": None, "message": "status packets lost while streaming (no status packet for 0.104 s)"}, "status_lost"),
    ({"code": None, "message": "connection lost while streaming (reset by peer)"}, "connection_lost"),
    ({"message": "servo process ended by signal 9 (SIGKILL)"}, "servo_process"),
    ({"code": None, "message": "something new"}, "other"),
])
def test_faults_are_counted_by_a_bounded_cause(fault: dict[str, str | None], cause: str) -> None:
    assert fault_cause(fault) == cause
