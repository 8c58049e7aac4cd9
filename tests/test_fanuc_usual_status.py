"""The usual status's flat path (``StreamSupervisor.on_datagram`` into ``StreamSession.on_usual_status``)
against the general one: two cells, the same but for the flat path declined in one, are given the same
random operator stream (test_servo_cycle_property's) and the same disturbed datagrams (duplicated,
stale, truncated, status bits changed). At every step both must send the same bytes and stand in the
same state: the supervisor's view, the link's counters, the commands just made."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st
from test_servo_cycle_property import HOLD_RENEW_CYCLES, KIN, Cell, PoseOffset, random_events

from servo_app.fanuc.packets import SEQ_OFFSET, STATUS_BITS_OFFSET, StatusBit
from servo_app.fanuc.session import StreamSession
from servo_app.messages import Jog, PoseTarget, Request, Reset, Resume, Twist
from servo_app.robots.conventions import matrix_to_xyzwpr

CYCLES = 700


def disturbed(raw: bytes, stale: bytes | None, rng: np.random.Generator) -> list[bytes]:
    """What reaches the supervisor for the controller's status ``raw``: mostly itself, sometimes twice,
    after a truncated datagram, followed by an older status, or with bit 1 or 3 changed (the bits that
    leave a stream running but move the safety state off its fixed point). Never lost: unanswered, the
    controller would stop the stream (a gap's statuses are declined by sequence: tested below)."""
    r = rng.random()
    if r < 0.03:
        return [raw, raw]
    if r < 0.04:
        return [raw[:40], raw]
    if r < 0.06 and stale is not None:
        return [raw, stale]
    if r < 0.08:
        flipped = bytearray(raw)
        flipped[STATUS_BITS_OFFSET] ^= int(rng.choice([StatusBit.COMMAND_RECEIVED, StatusBit.MOVING]))
        return [bytes(flipped)]
    return [raw]


def view(cell: Cell) -> tuple[object, ...]:
    s = cell.sup.session
    return (cell.sup.describe(), s.stats, s.phase, s.last_status, s._next_cmd_seq, s._sent_since_start,
            [(c.seq, c.data, list(c.values), c.early) for c in s.sent])


def run_twins(seed: int) -> int:
    """Both cells through one random stream; the flat path's hits in the first."""
    flat, general = Cell(), Cell()
    general.sup.session.on_usual_status = lambda data, now: None  # type: ignore[method-assign]  # declines all
    hits = 0
    usual = flat.sup.session.on_usual_status

    def counted(data: bytes, now: float) -> list[bytes] | None:
        nonlocal hits
        out = usual(data, now)
        hits += out is not None
        return out

    flat.sup.session.on_usual_status = counted  # type: ignore[method-assign]
    cells = (flat, general)
    for cell in cells:
        cell.start()
    assert view(flat) == view(general)
    rng = np.random.default_rng(seed)
    queue = random_events(seed)
    next_at, held, stale = 0, None, None

    def request(req: Request) -> None:
        accepted = [cell.request(req) for cell in cells]
        assert accepted[0] == accepted[1], req

    for k in range(CYCLES):
        if held is not None and k < next_at and k % HOLD_RENEW_CYCLES == 0:
            request(held)
        if queue and k >= next_at:
            gap, ev = queue.pop(0)
            next_at = k + gap
            held = ev if isinstance(ev, (Twist, Jog)) else None
            if flat.sup.state.stop_fast and flat.sup.state.mode.value == "stopped":
                request(Reset())
                request(Resume())
            if isinstance(ev, PoseOffset):
                here = matrix_to_xyzwpr(KIN.fk_fanuc_deg(np.array(flat.sent[-1])))
                goal = here + np.array(ev.offset) * [1, 1, 1, 0.1, 0.1, 0.1]
                request(PoseTarget(xyzwpr=tuple(float(x) for x in goal), linear_speed=ev.linear_speed,
                                   angular_speed=ev.angular_speed))
            else:
                request(ev)
        raws = []
        for cell in cells:
            cell.t += cell.dt
            raws.append(cell.ctrl.tick(cell.t))
        assert raws[0] == raws[1], k
        if raws[0] is None:
            outs = [cell.sup.on_idle(cell.t) for cell in cells]
            assert outs[0] == outs[1], k
            for cell, out in zip(cells, outs, strict=True):
                cell.deliver(out)
            continue
        for datagram in disturbed(raws[0], stale, rng):
            outs = [cell.sup.on_datagram(datagram, cell.t) for cell in cells]
            assert outs[0] == outs[1], (k, datagram[:16])
            assert view(flat) == view(general), k
            for cell, out in zip(cells, outs, strict=True):
                cell.sent += [np.array(c.command.values[:6]) for c in cell.sup.session.sent]
                cell.deliver(out)
        stale = raws[0]
    assert flat.ctrl.alarms() == general.ctrl.alarms()
    return hits


@settings(max_examples=8, deadline=None, derandomize=True)
@given(st.integers(0, 2**31 - 1))
def test_the_flat_path_sends_and_records_what_the_general_path_does(seed: int) -> None:
    run_twins(seed)


def test_the_flat_path_takes_most_statuses_of_a_stream_and_declines_the_rest() -> None:
    # (so that the equivalence above is between two paths: the flat one is really taken, and not always)
    hits = run_twins(7)
    assert CYCLES // 3 < hits < CYCLES, hits


def last_raw(cell: Cell) -> bytes:
    """The session's last status packet, as the controller sent it (a duplicate)."""
    st = cell.sup.session.last_status
    assert st is not None
    return st.encode()


def test_the_flat_path_declines_without_changing_anything() -> None:
    cell = Cell()
    cell.start()
    session: StreamSession = cell.sup.session
    for _ in range(5):
        cell.cycle()
    before = view(cell)
    raw = cell.ctrl.tick(cell.t + cell.dt)
    assert raw is not None
    seq = int.from_bytes(raw[SEQ_OFFSET: SEQ_OFFSET + 4], "big")
    gap = raw[:SEQ_OFFSET] + (seq + 1).to_bytes(4, "big") + raw[SEQ_OFFSET + 4:]  # the one after it: this one lost
    no_sysrdy = bytearray(raw)
    no_sysrdy[STATUS_BITS_OFFSET] &= ~StatusBit.SYSRDY
    for declined in (raw[:40], bytes(no_sysrdy), gap, last_raw(cell)):
        assert session.on_usual_status(declined, cell.t) is None
        assert view(cell) == before
    assert session.on_usual_status(raw, cell.t) is not None  # (the same status, undisturbed: taken)
