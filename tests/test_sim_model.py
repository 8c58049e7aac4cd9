"""FanucControllerModel, driven cycle by cycle without sockets: protocol, alarms of 61.9, I/O, servo."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest
import ruckig

from servo_app.fanuc.packets import (
    Command,
    IoType,
    LimitTableRequest,
    Status,
    StatusBit,
    StatusStart,
    StatusStop,
    decode_from_robot,
)
from servo_app.motion.limit_tables import default_tables
from servo_app.robots.kinematics import ArmKinematics
from servo_app.robots.profile import load_profile
from servo_app.sim.fanuc_model import ControllerConfig, FanucControllerModel, ProgramState, SimControlError

PROFILE = load_profile("lrmate200id")
CLIENT = ("127.0.0.1", 50000)
WAIT, RECV, SYSRDY, MOVING = (int(b) for b in StatusBit)


class Rig:
    """A model plus a clock: one ``tick()`` per 8 ms (or the configured interval)."""

    def __init__(self, config: ControllerConfig | None = None, **kw) -> None:
        self.lines: list[str] = []
        self.m = FanucControllerModel(PROFILE, config, log=self.lines.append, **kw)
        self.t = 0.0
        self.status: Status | None = None

    def send(self, pkt) -> list[bytes]:
        return self.m.on_datagram(pkt.encode() if hasattr(pkt, "encode") else pkt, self.t, CLIENT)

    def tick(self, n: int = 1) -> Status | None:
        for _ in range(n):
            self.t += self.m.interval_s
            raw = self.m.tick(self.t)
            self.status = None if raw is None else decode_from_robot(raw)
        return self.status

    def ready(self) -> Status:
        """Status output on and the program waiting at IBGN start."""
        self.send(StatusStart())
        st = self.tick()
        assert st is not None and st.status & WAIT
        return st

    def cmd(self, q, seq: int | None = None, **kw) -> Command:
        assert self.status is not None
        return Command(seq=self.status.seq if seq is None else seq, values=tuple(float(v) for v in q), **kw)

    def stream(self, rows, last: bool = True, **kw) -> None:
        """One command per status packet, answering the status just received (the manual's guide)."""
        seq = self.status.seq if self.status is not None else 0
        for i, q in enumerate(rows):
            self.send(Command(seq=seq, values=tuple(float(v) for v in q),
                              last_data=int(last and i == len(rows) - 1), **kw))
            seq = (seq + 1) & 0xFFFFFFFF
            self.tick()

    def codes(self) -> list[str]:
        return [e.code for e in self.m.events]


def smooth_move(q0, q1, vel_frac=0.5, acc_frac=0.5, jerk_frac=0.5, dt=0.008, profile=PROFILE,
                limits=None):
    """A ruckig (time-optimal, jerk-limited) move sampled at dt, in FANUC joints (deg). ``limits``
    (vel, acc, jerk) default to the ones that hold at any flange speed up to Vmax."""
    t = default_tables(profile)
    vel, acc, jrk = limits if limits is not None else t.for_cap(t.vmax)
    otg = ruckig.Ruckig(6, dt)
    inp, out = ruckig.InputParameter(6), ruckig.OutputParameter(6)
    inp.current_position, inp.target_position = list(q0), list(q1)
    inp.current_velocity = inp.current_acceleration = [0.0] * 6
    inp.target_velocity = inp.target_acceleration = [0.0] * 6
    inp.max_velocity = list(vel * vel_frac)
    inp.max_acceleration = list(acc * acc_frac)
    inp.max_jerk = list(jrk * jerk_frac)
    rows = [list(q0)]
    while otg.update(inp, out) == ruckig.Result.Working:
        rows.append(list(out.new_position))
        out.pass_to_input(inp)
    rows.append(list(q1))
    return np.array(rows)


# ---- status output ---------------------------------------------------------------------------------

def test_no_status_before_start_then_every_tick_seq_from_1_and_restart_resets() -> None:
    r = Rig()
    assert r.tick() is None
    r.send(StatusStart())
    seqs = [r.tick().seq for _ in range(3)]
    assert seqs == [1, 2, 3]
    r.send(StatusStart())
    assert r.tick().seq == 1


def test_stop_packet_stops_status_output_at_once_without_alarm_when_not_streaming() -> None:
    r = Rig()
    r.ready()
    r.send(StatusStop())
    assert r.tick() is None and r.tick() is None
    assert r.m.events == []


def test_status_seq_wraps_and_the_stream_follows_it() -> None:
    r = Rig()
    r.send(StatusStart())
    r.m.set_next_status_seq(0xFFFFFFFE)
    st = r.tick()
    assert st.seq == 0xFFFFFFFE
    r.stream(np.zeros((4, 6)))
    assert r.m.alarms() == []
    assert r.m.processed_commands == 4
    assert r.status.seq == 2  # FFFFFFFE, FFFFFFFF, 0, 1, 2


def test_timestamp_has_2ms_resolution_and_wraps() -> None:
    r = Rig(ControllerConfig(interval_ms=4, timestamp_offset_ms=0xFFFFFFFF - 9))
    r.send(StatusStart())
    stamps = [r.tick().timestamp_ms for _ in range(6)]
    assert all(s % 2 == 0 for s in stamps)
    assert stamps[0] > 0xFFFFFF00 and stamps[-1] < 100  # wrapped to small values


def test_status_bits_through_a_stream_and_the_cartesian_pose_of_the_servo_joints() -> None:
    r = Rig()
    st = r.ready()
    assert st.status == WAIT | SYSRDY
    assert st.cartesian[:3] == pytest.approx((465.0, 0.0, 365.0), abs=1e-3)  # LR Mate at all-zero joints
    rows = smooth_move(np.zeros(6), [10, 5, -5, 10, 10, 10])
    r.send(r.cmd(rows[0]))
    r.tick()
    assert r.status.status & RECV and r.status.status & WAIT
    r.stream(rows[1:40], last=False)
    assert r.status.status & MOVING
    r.stream(rows[40:])
    st = r.tick()
    assert not st.status & (WAIT | RECV)
    assert r.m.alarms() == []
    r.tick(60)  # settle; the looping program is back at IBGN start
    st = r.status
    assert st.status == WAIT | SYSRDY
    assert st.joints[:6] == pytest.approx([10, 5, -5, 10, 10, 10], abs=1e-3)
    fk = ArmKinematics(PROFILE).flange_xyz_mm_fanuc_deg(np.array(st.joints[:6]))
    assert st.cartesian[:3] == pytest.approx(tuple(fk), abs=0.05)
    assert any(abs(c) > 0.1 for c in st.currents[:6]) and all(c == 0 for c in st.currents[6:])


# ---- program control, MOTN-606 -----------------------------------------------------------------------------

def test_606_starting_outside_auto_or_100_percent() -> None:
    r = Rig(ControllerConfig(auto_start=False))
    r.send(StatusStart())
    assert not r.tick().status & WAIT
    r.m.set_mode("T1")
    assert r.m.start_program() is False
    assert r.codes() == ["MOTN-606"] and r.lines == ["MOTN-606 ST:Need to AUTO and 100% ovrd"]
    assert not r.tick().status & SYSRDY
    r.m.reset()
    r.m.set_mode("AUTO")
    r.m.set_override(50)
    assert r.m.start_program() is False
    r.m.reset()
    r.m.set_override(100)
    assert r.m.start_program() is True
    assert r.tick().status == WAIT | SYSRDY


def test_606_changing_the_override_while_running() -> None:
    r = Rig()
    r.ready()
    r.m.set_override(90)
    assert r.codes() == ["MOTN-606"]
    st = r.tick()
    assert st.status & (WAIT | SYSRDY) == 0
    assert r.m.program is ProgramState.ABORTED


# ---- sequence numbers, MOTN-600 --------------------------------------------------------------------------------

def test_first_command_accepts_the_last_and_the_previous_status_seq() -> None:
    for back in (0, 1):
        r = Rig()
        r.ready()
        r.tick()
        r.send(r.cmd(np.zeros(6), seq=r.status.seq - back))
        r.tick()
        assert r.m.alarms() == [] and r.status.status & RECV


def test_600_first_command_with_an_old_seq() -> None:
    r = Rig()
    r.ready()
    r.tick(2)
    r.send(r.cmd(np.zeros(6), seq=r.status.seq - 2))
    assert [e.code for e in r.m.alarms()] == ["MOTN-600"]
    assert r.lines[0] == f"MOTN-600 ST:Sequence No error. PC {r.status.seq - 2}, Rob {r.status.seq}"


def test_a_strict_controller_takes_the_first_command_only_for_the_latest_status() -> None:
    """Issue 15's controller: a first command that answers the status before the latest (it came one
    interval late) posts MOTN-600 "PC 20, Rob 21"; the latest one is taken."""
    late, timely = Rig(ControllerConfig(strict_first_seq=True)), Rig(ControllerConfig(strict_first_seq=True))
    for r in (late, timely):
        r.ready()
        r.tick()
    late.send(late.cmd(np.zeros(6), seq=late.status.seq - 1))
    assert late.codes() == ["MOTN-600"]
    assert late.lines[0] == f"MOTN-600 ST:Sequence No error. PC {late.status.seq - 1}, Rob {late.status.seq}"
    timely.send(timely.cmd(np.zeros(6)))
    timely.tick()
    assert timely.codes() == [] and timely.status.status & RECV


def test_600_skipped_seq_is_found_when_processed() -> None:
    r = Rig()
    st = r.ready()
    r.send(r.cmd(np.zeros(6)))
    r.tick()
    r.send(r.cmd(np.zeros(6), seq=st.seq + 2))
    assert r.m.alarms() == []  # only buffered so far
    r.tick()
    assert r.lines == [f"MOTN-600 ST:Sequence No error. PC {st.seq + 2}, Rob {st.seq + 1}"]


def test_600_same_seq_twice_faq() -> None:
    r = Rig()
    st = r.ready()
    r.send(r.cmd(np.zeros(6)))
    r.send(r.cmd(np.zeros(6), seq=st.seq))
    r.tick()
    assert r.m.alarms() == []
    r.tick()
    assert [e.code for e in r.m.alarms()] == ["MOTN-600"]


# ---- buffering: 603, 604, START_MOVE -------------------------------------------------------------------------------

def test_603_when_the_next_command_is_missing_after_motion_started() -> None:
    r = Rig()
    r.ready()
    r.send(r.cmd(np.zeros(6)))
    r.tick()
    assert r.m.alarms() == []
    r.tick()
    assert r.lines == ["MOTN-603 ST:Receiving interval over"]
    assert r.status.status & (WAIT | RECV | SYSRDY) == 0


def test_604_more_commands_than_pkt_stack_minus_one() -> None:
    r = Rig(ControllerConfig(pkt_stack=4, start_move=3))
    st = r.ready()
    for i in range(3):
        r.send(r.cmd(np.zeros(6), seq=st.seq + i))
    assert r.m.alarms() == []
    r.send(r.cmd(np.zeros(6), seq=st.seq + 3))
    assert r.lines == ["MOTN-604 ST:Too many packet received"]


def test_start_move_waits_for_the_buffer_and_buffered_commands_ride_out_a_gap() -> None:
    r = Rig(ControllerConfig(start_move=3))
    st = r.ready()
    r.send(r.cmd(np.zeros(6)))
    r.tick(3)  # one buffered: motion has not started, so no MOTN-603 either
    assert r.m.processed_commands == 0 and r.m.alarms() == []
    r.send(r.cmd(np.zeros(6), seq=st.seq + 1))
    r.send(r.cmd(np.zeros(6), seq=st.seq + 2))
    r.tick(3)  # three processed from the buffer, no new command needed meanwhile
    assert r.m.processed_commands == 3 and r.m.alarms() == []
    r.tick()
    assert r.codes() == ["MOTN-603"]


# ---- packet content: 602, 605, 607, 619 ----------------------------------------------------------------------------

def test_602_unknown_data_format() -> None:
    r = Rig()
    r.ready()
    r.send(r.cmd(np.zeros(6), data_format=2))
    r.tick()
    assert r.lines == ["MOTN-602 ST:Data type error"]


def test_605_nan_names_the_axis_and_seq() -> None:
    r = Rig()
    st = r.ready()
    r.send(r.cmd([0, 0, 0, math.inf, 0, 0]))
    r.tick()
    assert r.lines == [f"MOTN-605 ST:Command is NaN or infinity.(A:4,Sq.{st.seq})"]
    ev = r.m.alarms()[0]
    assert (ev.axis, ev.seq) == (4, st.seq)


def test_607_wrong_protocol_version_on_any_packet() -> None:
    r = Rig()
    r.send(StatusStart(version=2))
    assert r.lines == ["MOTN-607 ST:Protocol version mismatch PC 2, Rob 1"]
    assert r.tick() is None  # the start packet was not taken


def test_619_cartesian_format_on_a_model_without_cartesian_support() -> None:
    r = Rig(ControllerConfig(cartesian_supported=False))
    r.ready()
    r.send(r.cmd([465, 0, 365, 180, -90, 0], data_format=0))
    r.tick()
    assert r.lines == ["MOTN-619 ST:Cartesian type is not supported"]


def test_608_stop_packet_while_commands_are_processed() -> None:
    r = Rig()
    r.ready()
    r.send(r.cmd(np.zeros(6)))
    r.tick()
    r.send(StatusStop())
    assert r.lines == ["MOTN-608 ST:TCP/IP error. See Cause & Remedy."]
    assert r.tick() is None


def test_bad_datagrams_are_counted_not_fatal() -> None:
    r = Rig()
    r.send(b"\x00\x00\x00\x01garbage")
    r.send(b"")
    assert r.m.bad_packets == 2 and r.m.events == []


# ---- limits: 609, 610, 611, 612, 613, 614, 617, joint range ------------------------------------------------------

def stream_rows(rows: np.ndarray, config: ControllerConfig | None = None, **kw) -> Rig:
    r = Rig(config, **kw)
    r.ready()
    r.stream(rows)
    return r


STAGE1 = tuple(default_tables(PROFILE).at_speed(k, 0.0) for k in range(3))  # J6 never moves the flange


def test_609_velocity() -> None:
    # J6 accelerated smoothly (acc/jerk at half their limits) to 5 % above its velocity limit.
    rows = smooth_move([0, 0, 0, 0, 0, -340], [0, 0, 0, 0, 0, 340], 1.05, 0.5, 0.5, limits=STAGE1)
    r = stream_rows(rows, initial_joints=rows[0])
    (ev,) = r.m.alarms()
    assert (ev.code, ev.axis) == ("MOTN-609", 6)
    assert r.lines[-1] == f"MOTN-609 ST:Exceeded Jnt Velocity Limit.(A:6,Sq.{ev.seq})"


def _from_jerk(j: float, a_stop: float, axis: int = 5, dt: float = 0.008) -> np.ndarray:
    """Rows whose finite-difference jerk is ``j`` until the acceleration passes ``a_stop``."""
    rows, q, v, a = [np.zeros(6)], 0.0, 0.0, 0.0
    while a <= a_stop:
        a += j * dt
        v += a * dt
        q += v * dt
        r = np.zeros(6)
        r[axis] = q
        rows.append(r)
    return np.array(rows)


def test_610_acceleration_j6_at_low_flange_speed() -> None:
    # J6 turns the flange about its own centre: flange speed 0, the stage-1 limit applies at once.
    acc1 = default_tables(PROFILE).at_speed(1, 0.0)[5]
    jrk1 = default_tables(PROFILE).at_speed(2, 0.0)[5]
    rows = _from_jerk(0.7 * jrk1, 1.02 * acc1)
    r = stream_rows(rows)
    (ev,) = r.m.alarms()
    assert (ev.code, ev.axis) == ("MOTN-610", 6)
    assert r.lines[-1].startswith("MOTN-610 ST:Exceeded Jnt Acc/Dec Limit.(A:6,Sq.")
    assert "MOTN-613" in r.codes()  # passed 80 % on the way


def test_611_jerk() -> None:
    jrk1 = default_tables(PROFILE).at_speed(2, 0.0)[5]
    dv = 1.2 * jrk1 * 0.008**2  # a velocity step: jerk 1.2x, acceleration far below its limit
    rows = np.zeros((6, 6))
    rows[2:, 5] = dv * 0.008 * np.arange(1, 5)
    r = stream_rows(rows)
    (ev,) = r.m.alarms()
    assert (ev.code, ev.axis) == ("MOTN-611", 6)


@pytest.mark.parametrize(("code", "fracs"), [("MOTN-612", (0.85, 0.5, 0.5)), ("MOTN-613", (0.9, 0.85, 0.7)),
                                             ("MOTN-614", (0.5, 0.5, 0.85))])
def test_612_613_614_warnings_do_not_stop(code: str, fracs: tuple[float, float, float]) -> None:
    rows = smooth_move([0, 0, 0, 0, 0, -340], [0, 0, 0, 0, 0, 340], *fracs, limits=STAGE1)
    r = stream_rows(rows, initial_joints=rows[0])
    assert r.m.alarms() == []
    assert code in r.codes()
    assert next(ln for ln in r.lines if ln.startswith(code)).startswith(f"{code} ST:Close to Jnt")
    assert r.m.processed_commands == len(rows)


def test_617_first_command_far_from_the_command_position() -> None:
    r = Rig(initial_joints=[0, 0, 0, 0, -30, 0])
    r.ready()
    r.send(r.cmd(np.zeros(6)))
    r.tick()
    assert r.lines == [f"MOTN-617 ST:Discontinous command.(Sq.{r.status.seq - 1})"]


def test_joint_range_alarm_mot017_and_alarm_freezes_the_arm() -> None:
    r = Rig(initial_joints=[169.0, 0, 0, 0, 0, 0])
    r.ready()
    rows = smooth_move([169.0, 0, 0, 0, 0, 0], [172.0, 0, 0, 0, 0, 0], 0.2, 0.2, 0.2)
    r.stream(rows)
    (ev,) = r.m.alarms()
    assert ev.code == "MOTN-017" and ev.axis == 1
    frozen = r.tick().joints
    assert r.tick(5).joints == frozen
    assert r.status.status & (WAIT | RECV | SYSRDY | MOVING) == 0
    assert r.m.command_position[0] <= 170.0
    # Commands after the alarm are ignored and counted.
    ignored = r.m.ignored_commands
    r.send(r.cmd(np.zeros(6)))
    assert r.m.ignored_commands == ignored + 1


def test_reset_after_alarm_brings_the_looping_program_back() -> None:
    r = Rig()
    r.ready()
    r.send(r.cmd(np.zeros(6), data_format=5))
    r.tick()
    with pytest.raises(SimControlError):
        r.m.jog_to(np.ones(6))
    r.m.reset()
    r.tick(40)  # restart delay 0.2 s
    assert r.status.status == WAIT | SYSRDY


# ---- last data, ignored commands -------------------------------------------------------------------------------------

def test_last_data_ends_control_and_later_commands_are_ignored() -> None:
    r = Rig(ControllerConfig(restart_delay_s=1.0))
    st = r.ready()
    r.send(r.cmd(np.zeros(6)))
    r.send(r.cmd(np.zeros(6), seq=st.seq + 1, last_data=1))
    r.tick()
    assert r.status.status & WAIT  # the last-data command is still in the buffer
    r.tick()
    assert r.status.status & (WAIT | RECV) == 0
    assert r.m.program is ProgramState.ENDED
    r.send(r.cmd(np.zeros(6), seq=st.seq + 2))
    assert r.m.ignored_commands == 1 and r.m.alarms() == []
    r.tick(130)
    assert r.status.status & WAIT  # back at IBGN start


def test_two_streams_back_to_back_through_the_program_loop() -> None:
    r = Rig()
    r.ready()
    r.stream(smooth_move(np.zeros(6), [5, 0, 0, 0, 0, 0]))
    r.tick(40)
    assert r.status.status & WAIT
    r.stream(smooth_move([5, 0, 0, 0, 0, 0], np.zeros(6)))
    assert r.m.alarms() == []


# ---- I/O, PRIO-023 ----------------------------------------------------------------------------------

def test_io_write_then_read_back_masked_and_zero_without_commands() -> None:
    r = Rig()
    st = r.ready()
    assert (st.read_io_type, st.read_io_value) == (0, 0)
    r.m.io.set(IoType.DI, 3, True)
    st = r.tick()
    assert st.read_io_value == 0  # no command packet: 0
    base = r.status.seq
    r.send(r.cmd(np.zeros(6), write_io_type=IoType.DO, write_io_index=1, write_io_mask=0xFF,
                 write_io_value=0xA5, read_io_type=IoType.DO, read_io_index=1, read_io_mask=0x0F))
    r.tick()
    st = r.status
    assert (st.read_io_type, st.read_io_index, st.read_io_mask, st.read_io_value) == (IoType.DO, 1, 0x0F, 0x05)
    r.send(r.cmd(np.zeros(6), seq=base + 1, read_io_type=IoType.DI, read_io_index=2, read_io_mask=0xFFFF,
                 last_data=1))
    r.tick()
    assert r.m.io.get(IoType.DO, 1) and not r.m.io.get(IoType.DO, 2) and r.m.io.get(IoType.DO, 8)
    assert r.m.alarms() == []


@pytest.mark.parametrize(("field", "io_type", "index"), [
    ("read", IoType.DI, 505),  # 505..520 goes past DI 512
    ("read", IoType.SO, 1),  # SO is not assigned
    ("write", IoType.UO, 10),  # 10..25 goes past UO 24
    ("write", IoType.WSO, 1),
    ("read", IoType.F, 0),  # no point 0
])
def test_prio023_unassigned_io(field: str, io_type: int, index: int) -> None:
    r = Rig()
    r.ready()
    kw = ({"read_io_type": io_type, "read_io_index": index, "read_io_mask": 1} if field == "read"
          else {"write_io_type": io_type, "write_io_index": index, "write_io_mask": 1, "write_io_value": 1})
    r.send(r.cmd(np.zeros(6), **kw))
    r.tick()
    assert r.lines == ["PRIO-023 There is no I/O for this type"]


# ---- limit tables --------------------------------------------------------------------------------------------------

def test_limit_table_responses_are_the_enforced_tables() -> None:
    r = Rig()
    tables = r.m.tables
    for axis in range(1, 10):
        for kind in range(3):
            (raw,) = r.send(LimitTableRequest(axis=axis, limit_type=kind))
            resp = decode_from_robot(raw)
            assert (resp.axis, resp.limit_type) == (axis, kind)
            assert resp.vmax_mm_s == round(tables.vmax) and resp.check_time_s == 5
            if axis <= 6:
                t = tables.tables[kind][axis - 1]
                assert resp.no_payload == pytest.approx(t.no_payload, rel=1e-6)
                assert resp.max_payload == pytest.approx(t.max_payload, rel=1e-6)
            else:
                assert set(resp.no_payload) == {0.0} and set(resp.max_payload) == {0.0}
    # What the checker enforces at stage 1 (no payload set = max payload) is what was sent.
    assert r.m.checker.vel_lim == pytest.approx([tables.tables[0][i].max_payload[0] for i in range(6)])
    assert r.m.checker.acc1 == pytest.approx([tables.tables[1][i].max_payload[0] for i in range(6)])
    assert r.send(LimitTableRequest(axis=10, limit_type=0)) == []
    assert r.send(LimitTableRequest(axis=1, limit_type=3)) == []
    assert r.m.bad_requests == 2


def test_injected_tables_are_both_answered_and_enforced() -> None:
    base = default_tables(PROFILE)
    slow = replace(base, tables=(tuple(replace(t, no_payload=(10.0,) * 20, max_payload=(10.0,) * 20)
                                       for t in base.tables[0]), base.tables[1], base.tables[2]))
    r = Rig(tables=slow)
    resp = decode_from_robot(r.send(LimitTableRequest(axis=2, limit_type=0))[0])
    assert set(resp.max_payload) == {10.0}
    r.ready()
    r.stream(smooth_move(np.zeros(6), [0, 5, 0, 0, 0, 0]))  # fine for the defaults, not for 10 deg/s
    assert r.m.alarms()[0].code == "MOTN-609"


# ---- servo, jog --------------------------------------------------------------------------------------------------

@pytest.mark.parametrize("interval_ms", [8, 4])
def test_servo_lags_the_command_about_as_the_faq_says(interval_ms: int) -> None:
    """FAQ: ~50 ms at 8 ms including communication, about half at 4 ms. Measured on a ramp."""
    r = Rig(ControllerConfig(interval_ms=interval_ms, servo_delay_cycles=2, servo_tau_cycles=3))
    dt = interval_ms / 1000.0
    r.ready()
    v = 20.0  # deg/s on J1, cruising
    limits = (np.full(6, v), np.full(6, 500.0), np.full(6, 5000.0))
    rows = smooth_move(np.zeros(6), [20, 0, 0, 0, 0, 0], dt=dt, limits=limits, vel_frac=1, acc_frac=1,
                       jerk_frac=1)
    r.stream(rows[: len(rows) // 2], last=False)  # stop mid-cruise
    assert r.m.alarms() == []
    lag_s = (r.m.command_position[0] - r.status.joints[0]) / v
    expected = 5 * dt  # 2 cycles of delay + 3 cycles of time constant
    assert lag_s == pytest.approx(expected, rel=0.1)
    assert lag_s + dt == pytest.approx({8: 0.048, 4: 0.024}[interval_ms], rel=0.1)


def test_jog_moves_the_command_position_smoothly_and_is_refused_while_streaming() -> None:
    r = Rig()
    r.ready()
    duration = r.m.jog_to([10, -5, 5, 0, 20, 0])
    assert duration > 0.1
    st = r.tick()
    assert st.status & MOVING
    r.tick(int(duration / 0.008) + 60)
    assert r.status.joints[:6] == pytest.approx([10, -5, 5, 0, 20, 0], abs=1e-3)
    assert not r.status.status & MOVING
    # A stream starts from the jogged position without MOTN-617.
    r.send(r.cmd([10, -5, 5, 0, 20, 0]))
    r.tick()
    with pytest.raises(SimControlError):
        r.m.jog_to(np.zeros(6))
    assert r.m.alarms() == []


def test_set_joints_initial_position() -> None:
    r = Rig(initial_joints=[1, 2, 3, 4, 5, 6])
    r.m.set_joints([0, 10, 0, 0, 0, 0])
    r.send(StatusStart())
    assert r.tick().joints[:6] == pytest.approx([0, 10, 0, 0, 0, 0])


def test_the_simulator_checks_appendix_b_with_the_arm_kinematics() -> None:
    """A J1 move swings the flange: the checker opens a window above Vmax/20 and tracks Vpeak."""
    r = Rig()
    r.ready()
    rows = smooth_move(np.zeros(6), [30, 0, 0, 0, 0, 0], 0.5, 0.5, 0.5)
    r.stream(rows[: len(rows) // 2], last=False)
    c = r.m.checker
    assert c.window_open and c.vpeak > c.s_low
    radius_mm = 465.0  # flange distance from the J1 axis at this posture
    assert c.flange_speed == pytest.approx(np.radians(abs(c.velocity[0])) * radius_mm, rel=1e-3)
    r.stream(rows[len(rows) // 2:])
    assert r.m.alarms() == [] and not c.window_open  # closed by the last data
