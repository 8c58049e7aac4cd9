"""The FANUC servo process's per-cycle publish writes what the plain helpers compute, without allocating."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from servo_app.fanuc.runner import _CommandHistory, _Latency, _TimeWindow
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


@settings(max_examples=300, deadline=None)
@given(st.lists(st.floats(0.0, 1e5, allow_nan=False) | st.sampled_from([0.0, 1.0, 250.0]), min_size=1,
                max_size=600),
       st.integers(0, 5000))
def test_the_compiled_percentiles_are_numpys(samples: list[float], earlier: int) -> None:
    """The latency window's p50/p99 and a time window's median/max, compiled, against numpy's own (ties,
    odd and even counts, a ring that has wrapped after ``earlier`` older samples)."""
    lat = _Latency()
    older = [float(k % 977) for k in range(earlier)]
    for v in older + samples:
        lat.add(v, 1e9)
    want = np.percentile(np.array((older + samples)[-_Latency.SIZE:]), [50, 99])
    assert lat.percentiles() == (float(want[0]), float(want[1]))
    window = _TimeWindow(size=256, every=len(samples))
    for v in samples:
        window.add(v)
    kept = np.array(samples[-256:])
    assert (window.p50_us, window.max_us) == (float(np.median(kept)), float(kept.max()))


def test_a_nan_sample_makes_the_percentiles_nan_as_numpys_do() -> None:
    lat = _Latency()
    for v in (1.0, float("nan"), 3.0):
        lat.add(v, 1e9)
    assert all(np.isnan(lat.percentiles())) and np.isnan(np.percentile([1.0, np.nan, 3.0], 50))


@settings(max_examples=100, deadline=None)
@given(st.lists(st.floats(0.0, 1e4, allow_nan=False) | st.sampled_from([0.0, 100.0, 8000.0, 8000.5]),
                min_size=1, max_size=80),
       st.integers(0, 40))
def test_the_command_kernel_writes_what_the_plain_figures_are(latencies: list[float], seed: int) -> None:
    """_command_into_state (one compiled call per command sent) against the plain reading of the figures:
    bisect for the histogram bucket (le semantics), a running sum, np.percentile every 16th command, max,
    late count, and command_derivatives of the history."""
    import bisect

    from servo_app.fanuc.runner import _BUCKETS, _CMD_AT, _P50_P99, _command_into_state
    from servo_app.state import LATENCY_BUCKETS_US

    dt, late_us = 0.008, 4000.0
    rng = np.random.default_rng(seed)
    d = np.zeros(STATE_SIZE)
    lat, hist = _Latency(), _CommandHistory(6, dt)
    hist_sum, hist_counts, commands, plain = 0.0, [0] * (len(LATENCY_BUCKETS_US) + 1), [], []
    p50 = p99 = 0.0
    for k, us in enumerate(latencies, start=1):
        q = rng.uniform(-90, 90, 6).tolist()
        hist.values[:] = q
        _command_into_state(d, _CMD_AT, _BUCKETS, _P50_P99, lat.ring, lat.stats, lat.scratch, lat.out, hist.q,
                            hist.at, hist.values, us, late_us, dt)
        hist_counts[bisect.bisect_left(LATENCY_BUCKETS_US, us)] += 1
        hist_sum += us
        plain.append(us)
        commands.append(np.array(q))
        if k % 16 == 0:
            p50, p99 = (float(v) for v in np.percentile(np.array(plain), [50, 99]))
        assert d[FIELDS["latency_hist"]].tolist() == hist_counts
        assert d[FIELDS["latency_sum_us"].start] == hist_sum
        assert (d[FIELDS["latency_p50_us"].start], d[FIELDS["latency_p99_us"].start]) == (p50, p99)
        assert d[FIELDS["latency_last_us"].start] == us
        assert d[FIELDS["latency_max_us"].start] == max(plain)
        assert d[FIELDS["late_commands"].start] == sum(v > late_us for v in plain)
        for key, want in command_derivatives(commands, dt).items():
            assert np.array_equal(d[FIELDS[key]], want), (k, key)
    assert lat.count == len(latencies) and lat.max_us == max(latencies)


f32s = st.floats(-1e5, 1e5, width=32, allow_nan=False)
u16 = st.integers(0, 0xFFFF)
exchanges = st.lists(
    st.tuples(st.integers(1, 50), st.integers(0, 255), st.integers(0, 255), u16, u16, u16, st.integers(0, 2**32 - 1),
              st.lists(f32s, min_size=9, max_size=9), st.lists(f32s, min_size=9, max_size=9),
              st.integers(0, 1), st.integers(0, 1), u16, st.lists(f32s, min_size=6, max_size=9),
              st.floats(1e-4, 0.02), st.floats(0.0, 3e-3), st.booleans(), st.booleans(),
              st.tuples(*[st.integers(0, 2**40)] * 5)),
    min_size=1, max_size=40)


@settings(max_examples=60, deadline=None)
@given(exchanges)
def test_the_exchange_kernel_writes_and_logs_what_the_python_path_does(tmp_path_factory, steps) -> None:
    """A new status packet and the one command that answered it, the servo process's usual exchange: the
    compiled path (``_log_exchange``, straight from the datagrams' bytes) against the Python one
    (``_log_datagram``: decoded fields, status_record + command_record, _publish_status, _command_sent),
    status after status: the same log bytes, the same state vector (but the wall-clock time of the status,
    read by each), the same settle verdicts, latency window and command history."""
    from multiprocessing import Pipe

    from servo_app.fanuc.packets import Status, decode_from_robot, pack_command
    from servo_app.fanuc.runner import StreamConfig, _ServoProcess
    from servo_app.fanuc.session import SentCommand
    from servo_app.ipc import LatestValueSlot
    from servo_app.session_log import RECORD_SIZE, SessionLogWriter, read_session_log

    tmp = tmp_path_factory.mktemp("exchange")
    slot = LatestValueSlot(STATE_SIZE)
    ends = Pipe()
    procs = [_ServoProcess(StreamConfig(port=9, settle_window_s=0.02), ends[0], slot.name) for _ in range(2)]
    unix = FIELDS["status_unix"].start
    try:
        for p, name in zip(procs, ("compiled", "python"), strict=True):
            p.log = SessionLogWriter(tmp / f"{name}.srvlog", {})
            p.t0 = 900.0  # (each set its own clock's origin when made)
        t, seq, cmd_seq = 1000.0, 7, 3
        for (gap, bits, io_type, io_index, io_mask, io_value, stamp, cart, joints, last, fmt, wio, values, dt,
             lag, early, as_array, link) in steps:
            seq += gap
            cmd_seq += 1
            t += dt
            data = Status(seq=seq, status=bits, read_io_type=io_type, read_io_index=io_index, read_io_mask=io_mask,
                          read_io_value=io_value, timestamp_ms=stamp, cartesian=tuple(cart), joints=tuple(joints),
                          currents=(0.0,) * 9).encode()
            command = pack_command(cmd_seq, tuple(values), fmt, last, (0, 0, 0), (2, 1, 0xFFFF, wio))
            t_first, t_sent = (t + lag, t + 2 * lag) if early else (0.0, t + lag)
            for k, p in enumerate(procs):
                p._t_recv = t  # (as _io_step sets it on the datagram's arrival)
                s = p.session
                s.last_status = decode_from_robot(data)  # a new object each: as each process decodes its own
                s.sent = [SentCommand(cmd_seq, tuple(values), fmt, last, (0, 0, 0), (2, 1, 0xFFFF, wio), command,
                                      early, np.array(values) if as_array else None)]
                for name, v in zip(("commands_sent", "status_received", "status_lost", "status_duplicated",
                                    "malformed"), link, strict=True):
                    setattr(s.stats, name, v)
                if k == 0:
                    p._after_datagram(data, t, t_sent, t_first)  # the usual exchange: the compiled path
                else:
                    p._log_datagram(t, t_sent, t_first)
                assert s.sent == []
            a, b = (p.state.data for p in procs)
            assert abs(a[unix] - b[unix]) < 5.0
            a[unix] = b[unix]
            assert np.array_equal(a, b)
            assert procs[0].settle.settled == procs[1].settle.settled
            for x, y in ((procs[0].latency.ring, procs[1].latency.ring), (procs[0].hist.q, procs[1].hist.q)):
                assert np.array_equal(x, y)
        logs = [read_session_log(p.log.path).records.tobytes() for p in procs]  # type: ignore[union-attr]
        assert logs[0] == logs[1] and len(logs[0]) == 2 * len(steps) * RECORD_SIZE  # (headers: each its time)
    finally:
        for p in procs:
            p._close_log()
            p.sock.close()
            p.cycle.late_command = None
        slot.close()
        for c in ends:
            c.close()
