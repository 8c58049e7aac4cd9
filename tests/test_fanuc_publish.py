"""The FANUC servo process's per-cycle publish writes what the plain helpers compute, without allocating."""

from __future__ import annotations

import numpy as np

from servo_app.fanuc.runner import _CommandHistory, _Latency
from servo_app.state import FIELDS, STATE_SIZE, command_derivatives


def test_the_preallocated_history_writes_exactly_the_controllers_finite_differences() -> None:
    rng = np.random.default_rng(3)
    dt = 0.004
    hist, plain = _CommandHistory(6, dt), []
    d = np.zeros(STATE_SIZE)
    for k in range(8):  # from the first command (it stands in for those not sent yet) to a full window
        q = tuple(float(v) for v in rng.uniform(-90, 90, 6))
        hist.add(q)
        plain.append(np.array(q))
        hist.write(d)
        for key, want in command_derivatives(plain, dt).items():
            assert np.array_equal(d[FIELDS[key]], want), (k, key)
    hist.clear()
    hist.add((1.0,) * 6)
    hist.write(d)
    assert not d[FIELDS["vel"]].any() and not d[FIELDS["jerk"]].any()  # a new stream starts at rest


def test_the_latency_count_goes_on_past_the_window() -> None:
    lat = _Latency()
    for _ in range(5000):
        lat.add(100.0, 2000.0)
    assert len(lat.samples) == 4096 and lat.count == 5000  # the refresh cadence counts commands, not samples
