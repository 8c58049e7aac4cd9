"""``servo-app check``: CSV of joints or X Y Z W P R, first violation, usage table, exit codes."""

from __future__ import annotations

import argparse
import importlib.util
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from test_sim_model import PROFILE, STAGE1, smooth_move

from servo_app.check_cli import TrajectoryError, add_check_parser, load_trajectory
from servo_app.robots.conventions import matrix_to_xyzwpr
from servo_app.robots.kinematics import ArmKinematics


def run_cli(capsys: pytest.CaptureFixture[str], *argv: str) -> tuple[int, str, str]:
    parser = argparse.ArgumentParser()
    add_check_parser(parser.add_subparsers())
    args = parser.parse_args(["check", *argv])
    code = args.handler(args)
    out = capsys.readouterr()
    return code, out.out, out.err


def write_csv(path: Path, rows: np.ndarray, header: str | None = "j1,j2,j3,j4,j5,j6", sep: str = ",") -> Path:
    lines = [header] if header else []
    lines += [sep.join(f"{v:.9f}" for v in r) for r in rows]
    path.write_text("\n".join(lines) + "\n")
    return path


SMOOTH = smooth_move(np.zeros(6), [20, -10, 15, 30, -20, 45], 0.5, 0.5, 0.5)


def test_smooth_joint_trajectory_passes_with_a_usage_table(tmp_path: Path, capsys) -> None:
    code, out, _ = run_cli(capsys, str(write_csv(tmp_path / "ok.csv", SMOOTH)), "--model", "lrmate200id")
    assert code == 0
    assert "OK: no violation" in out
    table = [ln for ln in out.splitlines() if ln.startswith("J")]
    assert len(table) == 6
    pct = np.array([[float(x) for x in ln.split()[1:]] for ln in table])
    assert 0 < pct.max() < 100


def test_jerk_violation_reports_code_axis_row_value_limit_and_exit_1(tmp_path: Path, capsys) -> None:
    rows = SMOOTH.copy()
    rows[50:, 2] += 0.05  # a 0.05 deg step on J3 at row 51
    code, out, _ = run_cli(capsys, str(write_csv(tmp_path / "bad.csv", rows)), "--model", "lrmate200id")
    assert code == 1
    first = out.split("FIRST VIOLATION: ", 1)[1]
    assert first.startswith("MOTN-611 ST:Exceeded Jnt Jerk Limit.(A:3,Sq.51)")
    assert "axis J3, row 51 (line 52): jerk" in first and "limit" in first


def test_whitespace_separated_without_header_with_comments(tmp_path: Path, capsys) -> None:
    p = tmp_path / "traj.txt"
    write_csv(p, SMOOTH, header=None, sep=" ")
    p.write_text("# recorded joints\n" + p.read_text())
    code, out, _ = run_cli(capsys, str(p), "--model", "lrmate200id", "--interval-ms", "8")
    assert code == 0 and f"{len(SMOOTH)} rows (joints)" in out


def test_xyzwpr_rows_are_converted_through_ik(tmp_path: Path, capsys) -> None:
    if importlib.util.find_spec("servo_app.robots.ik") is None:
        pytest.skip("no IK yet")
    arm = ArmKinematics(PROFILE)
    start = np.array([0.0, 10.0, -10.0, 0.0, -40.0, 0.0])
    joints = smooth_move(start, start + np.array([20, -10, 15, 30, -20, 45]), 0.4, 0.4, 0.4)
    cart = np.array([matrix_to_xyzwpr(arm.fk_fanuc_deg(q)) for q in joints])
    p = write_csv(tmp_path / "cart.csv", cart, header="x,y,z,w,p,r")
    code, out, _ = run_cli(capsys, str(p), "--model", "lrmate200id")
    assert code == 0, out
    assert "(xyzwpr)" in out
    # Without a header the format must be given.
    p2 = write_csv(tmp_path / "cart2.csv", cart, header=None)
    code, out, _ = run_cli(capsys, str(p2), "--model", "lrmate200id", "--format", "xyzwpr")
    assert code == 0 and "(xyzwpr)" in out


def test_unreachable_cartesian_row_is_a_violation(tmp_path: Path, capsys) -> None:
    if importlib.util.find_spec("servo_app.robots.ik") is None:
        pytest.skip("no IK yet")
    rows = np.array([[465.0, 0, 365, 180, -90, 0]] * 3 + [[5000.0, 0, 365, 180, -90, 0]])
    code, out, _ = run_cli(capsys, str(write_csv(tmp_path / "far.csv", rows, header="x,y,z,w,p,r")),
                           "--model", "lrmate200id")
    assert code == 1 and "MOTN-018" in out and "row 4" in out


@pytest.mark.parametrize(("content", "needle"), [
    ("j1,j2,j3,j4,j5,j6\n0,0,0,0,0,0\n0,0,x,0,0,0\n", ":3: not a number"),
    ("0,0,0,0,0\n", "5 values, need at least 6"),
    ("0,0,0,0,0,0\n0,0,0,0,0,0,0\n", "the rows above have 6"),
    ("# nothing\n", "no data rows"),
])
def test_bad_input_exits_2(tmp_path: Path, capsys, content: str, needle: str) -> None:
    p = tmp_path / "bad.csv"
    p.write_text(content)
    code, _, err = run_cli(capsys, str(p), "--model", "lrmate200id")
    assert code == 2 and needle in err


def test_missing_file_unknown_type_and_unknown_model_exit_2(tmp_path: Path, capsys) -> None:
    assert run_cli(capsys, str(tmp_path / "nope.csv"), "--model", "lrmate200id")[0] == 2
    odd = tmp_path / "log.bin"
    odd.write_bytes(b"\x00")
    code, _, err = run_cli(capsys, str(odd), "--model", "lrmate200id")
    assert code == 2 and "unknown file type" in err
    ok = write_csv(tmp_path / "ok.csv", SMOOTH[:5])
    code, _, err = run_cli(capsys, str(ok), "--model", "no_such_robot")
    assert code == 2 and "unknown" in err


def test_a_missing_log_without_model_says_no_such_file(tmp_path: Path, capsys) -> None:
    """Without --model (a session log names its own), a path that is not there is "no such file", not
    a CSV without a model."""
    missing = tmp_path / "session-gone.srvlog"
    code, _, err = run_cli(capsys, str(missing))
    assert code == 2 and err.strip() == f"servo-app check: {missing}: no such file", err


@pytest.mark.parametrize("interval", [-8, 0, "fast"])
def test_a_damaged_header_interval_exits_2_and_interval_ms_overrides_it(tmp_path: Path, capsys,
                                                                         interval: object) -> None:
    """A header whose interval_ms is no positive number: check and export exit 2 naming the field (a
    traceback, or for 0 the profile's interval taken silently), and check runs with --interval-ms."""
    from servo_app.session_log import SessionLogWriter

    path = tmp_path / "damaged.srvlog"
    w = SessionLogWriter(path, {"model": "lrmate200id", "interval_ms": interval, "protocol": "fanuc-j519-v1"})
    for i in range(5):
        w.command(i * 0.008, i + 1, int(i == 4), 1, 0, 0.0, [0.0] * 6)
    w.close()
    code, out, err = run_cli(capsys, str(path))
    assert code == 2 and out == "", out
    assert f"header interval_ms={interval!r} is not a positive number" in err and "--interval-ms" in err, err
    code, out, _ = run_cli(capsys, str(path), "--interval-ms", "8")
    assert code == 0 and "at 8 ms" in out
    done = subprocess.run([sys.executable, "-m", "servo_app.cli", "export", str(path), "--mcap",
                           str(tmp_path / "d.mcap")], capture_output=True, text=True, timeout=120)
    assert done.returncode == 2 and "Traceback" not in done.stderr, done.stderr
    assert f"{path}: header interval_ms={interval!r}" in done.stderr, done.stderr


def test_nan_row_is_reported_like_the_controller(tmp_path: Path, capsys) -> None:
    rows = SMOOTH[:10].copy()
    rows[5, 4] = np.nan
    code, out, _ = run_cli(capsys, str(write_csv(tmp_path / "nan.csv", rows)), "--model", "lrmate200id")
    assert code == 1 and "MOTN-605 ST:Command is NaN or infinity.(A:5,Sq.6)" in out


def test_warning_only_exits_0_and_payload_changes_the_limits(tmp_path: Path, capsys) -> None:
    j6 = smooth_move([0, 0, 0, 0, 0, -340], [0, 0, 0, 0, 0, 340], 0.9, 0.85, 0.7, limits=STAGE1)
    p = write_csv(tmp_path / "warn.csv", j6)
    code, out, _ = run_cli(capsys, str(p), "--model", "lrmate200id")
    assert code == 0 and "MOTN-613" in out and "OK: no violation" in out
    acc_pct = float(next(ln for ln in out.splitlines() if ln.startswith("J6")).split()[2])
    assert acc_pct == pytest.approx(85.0, abs=0.5)
    # At no payload the stage-1 acceleration limit is 1.6 / 1.3 times higher (profile table shape).
    code, out, _ = run_cli(capsys, str(p), "--model", "lrmate200id", "--payload", "0")
    acc_pct0 = float(next(ln for ln in out.splitlines() if ln.startswith("J6")).split()[2])
    assert code == 0 and acc_pct0 == pytest.approx(85.0 * 1.3 / 1.6, abs=0.5)


@pytest.mark.parametrize("payload", ["-3", "70", "nan", "inf"])
def test_a_payload_outside_the_robots_range_exits_2_naming_it(tmp_path: Path, capsys, payload: str) -> None:
    """--payload outside 0..the maximum was taken (the tables clamped it, NaN made every acceleration a
    MOTN-610): refused, naming the value, the range and what to give."""
    p = write_csv(tmp_path / "ok.csv", SMOOTH)
    code, out, err = run_cli(capsys, str(p), "--model", "lrmate200id", "--payload", payload)
    assert code == 2 and out == "", out
    assert f"--payload {float(payload):g} must be between 0 and the robot's maximum payload, 7 kg" in err, err


def test_load_trajectory_is_the_dispatch_hook(tmp_path: Path) -> None:
    t = load_trajectory(write_csv(tmp_path / "a.csv", SMOOTH[:3]))
    assert t.fmt == "joints" and t.values.shape == (3, 6) and t.lines == [2, 3, 4]
    with pytest.raises(TrajectoryError):
        load_trajectory(tmp_path / "a.csv", fmt="quaternions")


def write_log(path: Path, streams: list[tuple[int, np.ndarray]]) -> Path:
    from servo_app.session_log import SessionLogWriter

    w = SessionLogWriter(path, {"model": "lrmate200id", "interval_ms": 8.0})
    t = 0.0
    for seq0, rows in streams:
        for i, q in enumerate(rows):
            w.status(t, seq0 + i, 0x07, 0, tuple(q))
            w.command(t, seq0 + i, int(i == len(rows) - 1), 1, 0, 100.0, tuple(q))
            t += 0.008
    w.close()
    return path


def test_session_log_is_checked_per_stream_with_wire_sequence_numbers(tmp_path: Path, capsys) -> None:
    back = smooth_move(SMOOTH[-1], np.zeros(6), 0.5, 0.5, 0.5)
    ok = write_log(tmp_path / "ok.srvlog", [(1000, SMOOTH), (5000, back)])
    code, out, _ = run_cli(capsys, str(ok), "--model", "lrmate200id")
    assert code == 0, out
    assert f"{len(SMOOTH) + len(back)} rows (joints)" in out
    bad_rows = back.copy()
    bad_rows[30:, 1] += 0.05
    bad = write_log(tmp_path / "bad.log", [(1000, SMOOTH), (5000, bad_rows)])  # any suffix: the magic decides
    code, out, _ = run_cli(capsys, str(bad), "--model", "lrmate200id")
    assert code == 1
    assert "MOTN-611 ST:Exceeded Jnt Jerk Limit.(A:2,Sq.5030)" in out
    assert f"command {len(SMOOTH) + 31} of the log (Sq.5030)" in out


# ----------------------------------------------- the model from the log's header; Janome logs (issue 14)


def servo_app_cli(*argv: str) -> subprocess.CompletedProcess[str]:
    """The real command, in a process of its own."""
    return subprocess.run([sys.executable, "-m", "servo_app.cli", *argv], capture_output=True, text=True,
                          timeout=120)


def test_session_log_needs_no_model_its_header_names_it(tmp_path: Path) -> None:
    ok = write_log(tmp_path / "ok.srvlog", [(1000, SMOOTH)])
    r = servo_app_cli("check", str(ok))
    assert r.returncode == 0, r.stderr
    assert f"{len(SMOOTH)} rows (joints)" in r.stdout and "OK: no violation" in r.stdout
    bad_rows = SMOOTH.copy()
    bad_rows[50:, 2] += 0.05
    r = servo_app_cli("check", str(write_log(tmp_path / "bad.srvlog", [(1000, bad_rows)])))
    assert r.returncode == 1 and "MOTN-611" in r.stdout


def test_csv_without_model_says_how_to_give_one(tmp_path: Path) -> None:
    r = servo_app_cli("check", str(write_csv(tmp_path / "a.csv", SMOOTH[:5])))
    assert r.returncode == 2 and "--model" in r.stderr and "servo-app profiles" in r.stderr


def write_janome_log(path: Path, targets: list[tuple[float, float, float, float]], model: str = "jr3000",
                     start: tuple[float, float, float, float] = (150.0, 160.0, 50.0, 0.0)) -> Path:
    """A log as the Janome servo process writes it: status = state, error, X Y Z R; target = stop | cmd << 1."""
    from servo_app.janome.protocol import Cmd, RobotState
    from servo_app.session_log import SessionLogWriter

    w = SessionLogWriter(path, {"model": model, "protocol": "janome-pointjob-v1", "axes": ["X", "Y", "Z", "R"],
                                "fixed_interval": False})
    t = 0.0
    w.status(t, 1, RobotState.READY, 0, start)
    for i, xyzr in enumerate(targets):
        t += 0.05
        w.command(t, i + 2, 0, Cmd.LINE, 0, 100.0, xyzr)
        w.status(t + 0.04, i + 2, RobotState.READY, 0, xyzr)
    w.close()
    return path


def test_janome_log_is_checked_against_its_strokes_and_step(tmp_path: Path) -> None:
    good = [(150.0 + 4 * i, 160.0, 50.0, 0.5 * i) for i in range(1, 20)]
    r = servo_app_cli("check", str(write_janome_log(tmp_path / "janome-ok.srvlog", good)))
    assert r.returncode == 0, (r.stdout, r.stderr)
    assert "jr3000" in r.stdout and "OK: no violation" in r.stdout and "19 moves" in r.stdout
    # A target beyond the JR3000's X stroke (0..300 mm): the robot would answer OUT_OF_RANGE.
    out_of_stroke = [(290.0, 160.0, 50.0, 0.0), (298.0, 160.0, 50.0, 0.0), (305.0, 160.0, 50.0, 0.0)]
    r = servo_app_cli("check", str(write_janome_log(tmp_path / "janome-far.srvlog", out_of_stroke,
                                                    start=(285.0, 160.0, 50.0, 0.0))))
    assert r.returncode == 1, (r.stdout, r.stderr)
    first = r.stdout.split("FIRST VIOLATION: ", 1)[1]
    assert first.startswith("OUT_OF_RANGE") and "X=305.000 mm is outside the stroke [0, 300]" in first
    assert "target 3 of the log (seq 4)" in first
    # A step longer than the link's max_step_mm (10 mm for the JR3000): a stop could travel that far.
    r = servo_app_cli("check", str(write_janome_log(tmp_path / "janome-jump.srvlog", [(180.0, 160.0, 50.0, 0.0)])))
    assert r.returncode == 1 and "30.000 mm step, longer than max_step_mm 10" in r.stdout


def test_profiles_lists_the_janome_models_too() -> None:
    r = servo_app_cli("profiles")
    assert r.returncode == 0, r.stderr
    for name in ("lrmate200id", "jr3000", "jc3", "js3"):
        assert re.search(rf"^\s*{name}\s", r.stdout, re.M), (name, r.stdout)
    assert "scara" in r.stdout


def test_a_log_with_no_command_passes_and_says_why(tmp_path: Path) -> None:
    """A start that never streamed leaves a log of status packets and no command (both backends):
    nothing the controller could refuse, so it passes (exit 0, where it was an error, exit 2)."""
    from servo_app.session_log import SessionLogWriter

    fanuc = SessionLogWriter(tmp_path / "fanuc.srvlog", {"model": "lrmate200id", "interval_ms": 8.0})
    for i in range(3):
        fanuc.status(0.008 * i, 100 + i, 0x03, 0, tuple(SMOOTH[0]))  # SYSRDY off: the start waited
    fanuc.close()
    r = servo_app_cli("check", str(tmp_path / "fanuc.srvlog"))
    assert r.returncode == 0, (r.stdout, r.stderr)
    assert "no commands were sent in this session (3 status packets logged" in r.stdout
    assert "OK: no violation" in r.stdout
    janome = write_janome_log(tmp_path / "janome.srvlog", [])
    r = servo_app_cli("check", str(janome))
    assert r.returncode == 0, (r.stdout, r.stderr)
    assert "no target frames were sent in this session (1 status packet logged" in r.stdout



@pytest.mark.parametrize("options", [["--payload", "3"], ["--interval-ms", "4"], ["--format", "joints"],
                                     ["--warn-lim", "90"], ["--payload", "3", "--interval-ms", "4"]])
def test_a_janome_log_refuses_the_fanuc_tables_options(tmp_path: Path, options: list[str]) -> None:
    """--payload, --interval-ms, --format and --warn-lim shape FANUC's limit-table check; a Janome
    log's check uses none of them. They were taken in silence (exit 0, as if checked at that
    payload); now refused, exit 2, naming each and what to do."""
    log = write_janome_log(tmp_path / "janome-ok.srvlog", [(150.0 + 4 * i, 160.0, 50.0, 0.0) for i in range(1, 5)])
    r = servo_app_cli("check", str(log), *options)
    assert r.returncode == 2, (r.stdout, r.stderr)
    named = [o for o in options if o.startswith("--")]
    assert f"{log}: a Janome log: {', '.join(named)} " in r.stderr, r.stderr
    assert f"run the check without {' and '.join(named)}" in r.stderr, r.stderr
    assert r.stdout == ""
    assert servo_app_cli("check", str(log), "--model", "jr3000").returncode == 0  # (--model still applies)


def _scaled_tables(factor: float) -> object:
    """The profile's tables with every acceleration and jerk stage times ``factor``: a controller whose
    own tables differ from the profile's."""
    from dataclasses import replace

    from servo_app.motion.limit_tables import AxisTable, default_tables

    def axis(t: AxisTable) -> AxisTable:
        return AxisTable(tuple(v * factor for v in t.no_payload), tuple(v * factor for v in t.max_payload))

    tables = default_tables(PROFILE)
    vel, acc, jerk = tables.tables
    return replace(tables, tables=(vel, tuple(axis(t) for t in acc), tuple(axis(t) for t in jerk)))


def write_two_stream_log(path: Path, first: tuple[object, np.ndarray], second: tuple[object, np.ndarray]) -> Path:
    """A FANUC log of two streams, each opened by the controller's tables note (as the servo process
    writes it when it reads them at a start), its sequence numbers from 1 (the controller restarts them)."""
    from servo_app.session_log import SessionLogWriter, note_records, tables_note

    w = SessionLogWriter(path, {"model": PROFILE.name, "interval_ms": 8.0, "protocol": "fanuc-j519-v1",
                                "payload_kg": None})
    t = 0.0
    for tables, rows in (first, second):
        if tables is not None:  # (None: a stream without the controller's tables)
            w.write_records(note_records(t, tables_note(tables)))
        for i, q in enumerate(rows):
            w.command(t, i + 1, int(i == len(rows) - 1), 1, 0, 0.0, tuple(q))
            t += 0.008
        t += 1.0
    w.close()
    return path


def test_each_stream_of_a_log_is_judged_at_the_tables_its_start_recorded(tmp_path: Path) -> None:
    """One log, two streams, the controller publishing other tables at the second start: each stream is
    judged at its own. Only the first note's tables were used for the whole log: a brisk second stream
    under the profile's tables passed (exit 0), and one under looser tables after a first under the
    profile's was a false MOTN-611."""
    loose, strict = _scaled_tables(1.4), _scaled_tables(1.0)
    goal = [30.0, -20.0, 20.0, 40.0, -30.0, 60.0]
    brisk = np.array(smooth_move(np.zeros(6), goal, 0.9, 0.95, 0.95, limits=loose.for_cap(loose.vmax)))
    gentle = np.array(smooth_move(np.zeros(6), goal, 0.3, 0.3, 0.3))
    n = len(brisk)
    # Loose, then the profile's: the second stream's brisk move is over the controller's limits.
    r = servo_app_cli("check", str(write_two_stream_log(tmp_path / "loose-then-strict.srvlog",
                                                        (loose, brisk), (strict, brisk[::-1]))))
    assert r.returncode == 1, (r.stdout, r.stderr)
    first = r.stdout.split("FIRST VIOLATION: ", 1)[1]
    assert first.startswith("MOTN-611"), first
    assert f"the controller's tables, as streamed (published at commands 1 and {n + 1})" in r.stdout, r.stdout
    # The profile's, then loose: the brisk second stream is within the tables it streamed at.
    r = servo_app_cli("check", str(write_two_stream_log(tmp_path / "strict-then-loose.srvlog",
                                                        (strict, gentle), (loose, brisk[::-1]))))
    assert r.returncode == 0, (r.stdout, r.stderr)
    assert "OK: no violation" in r.stdout
    # A first stream without the controller's tables (the profile's), then one with them.
    r = servo_app_cli("check", str(write_two_stream_log(tmp_path / "none-then-loose.srvlog",
                                                        (None, gentle), (loose, brisk[::-1]))))
    assert r.returncode == 0, (r.stdout, r.stderr)
    assert (f"the profile's tables to command {len(gentle)}, then the controller's tables, as streamed "
            f"(published at command {len(gentle) + 1})") in r.stdout, r.stdout


def test_a_violation_in_a_later_stream_names_its_own_command_of_the_log(tmp_path: Path) -> None:
    """The controller restarts its sequence numbers at each stream: a violation at Sq.5 of a log's
    second stream was reported as "command 5 of the log", a command of the first stream, which
    passed; it names the second stream's command now, and its detection row there."""
    goal = [30.0, -20.0, 20.0, 40.0, -30.0, 60.0]
    gentle = np.array(smooth_move(np.zeros(6), goal, 0.3, 0.3, 0.3))
    loose = _scaled_tables(1.4)
    brisk = np.array(smooth_move(np.zeros(6), goal, 0.9, 0.95, 0.95, limits=loose.for_cap(loose.vmax)))
    r = servo_app_cli("check", str(write_two_stream_log(tmp_path / "gentle-then-brisk.srvlog",
                                                        (None, gentle), (None, brisk[::-1]))))
    assert r.returncode == 1, (r.stdout, r.stderr)
    first = r.stdout.split("FIRST VIOLATION: ", 1)[1].splitlines()
    seq = int(re.search(r"Sq\.(\d+)\)", first[0]).group(1))
    assert f"command {len(gentle) + seq} of the log (Sq.{seq})" in first[1], first
    detected = re.search(r"detected at row (\d+)", first[1])
    assert detected is None or int(detected.group(1)) > len(gentle), first
