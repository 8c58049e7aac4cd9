"""``servo-app sim``: fanuc runs standalone until Ctrl-C; janome needs the server to connect to."""

from __future__ import annotations

import argparse
import signal
import socket
import subprocess
from pathlib import Path

import pytest
from test_api_harness import STOP_WAYS, servo_app_argv

from servo_app.fanuc.packets import Status, StatusStart, decode_from_robot
from servo_app.sim.cli import add_sim_parser

ROOT = Path(__file__).resolve().parents[1]


def parse(*argv: str) -> argparse.Namespace:
    parser = argparse.ArgumentParser()
    add_sim_parser(parser.add_subparsers())
    return parser.parse_args(["sim", *argv])


def test_janome_needs_the_server_to_connect_to(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit):
        parse("janome")  # the robot is the TCP client: --connect HOST:PORT is required
    assert "--connect" in capsys.readouterr().err


def test_bad_settings_exit_2(capsys: pytest.CaptureFixture[str]) -> None:
    args = parse("fanuc", "--port", "0", "--pkt-stack", "11")
    assert args.handler(args) == 2
    assert "pkt_stack=11" in capsys.readouterr().err


@pytest.mark.parametrize(("argv", "words"), [
    (["--port", "70000"], ["--port", "70000", "0..65535"]),  # was a traceback (OverflowError), exit 1
    (["--port", "udp"], ["--port", "'udp'", "0..65535"]),
    (["--joints", "10,20,30"], ["--joints", "3 values", "all 6"]),  # was taken: J4..J6 at 0
    (["--joints", "0,0,0,0,0,0,0,0,0,0,0"], ["--joints", "11 values"]),  # was taken: five dropped
    (["--joints", "0,x,0,0,-90,0"], ["--joints", "'0,x,0,0,-90,0'", "6 numbers"]),
    (["--joints", "0,0,inf,0,-90,0"], ["--joints", "J3=inf", "finite"]),
    (["--payload", "1000"], ["--payload=1000", "at most 7 kg"]),  # was taken: limits judged at 1000 kg
    (["--payload", "-3"], ["--payload=-3", "above 0"]),
])
def test_bad_options_exit_2_naming_the_option_and_value(argv: list[str], words: list[str]) -> None:
    r = subprocess.run(servo_app_argv("ctrl-c", "sim", "fanuc", *argv), cwd=ROOT, capture_output=True, text=True,
                       timeout=30)
    assert r.returncode == 2, (r.returncode, r.stdout, r.stderr)
    assert "Traceback" not in r.stderr and "listening" not in r.stdout, r.stderr
    for w in words:
        assert w in r.stderr, (w, r.stderr)


def stopped(proc: subprocess.Popen[str], sig: int) -> str:
    """Send ``sig``; the process must end by itself with 0. Its whole output."""
    proc.send_signal(sig)
    try:
        proc.wait(timeout=10)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.wait(5)
        pytest.fail(f"still running 10 s after {signal.Signals(sig).name}")
    out, err = proc.stdout.read(), proc.stderr.read()  # type: ignore[union-attr]
    proc.stdout.close()  # type: ignore[union-attr]
    proc.stderr.close()  # type: ignore[union-attr]
    assert proc.returncode == 0, err
    return out


def fanuc_sim(how: str, *args: str) -> tuple[subprocess.Popen[str], int]:
    """``servo-app sim fanuc --port 0 ARGS`` started (``how``: as test_api_harness.servo_app_argv) and the
    UDP port it printed."""
    proc = subprocess.Popen(servo_app_argv(how, "sim", "fanuc", "--port", "0", *args),
                            cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    first = proc.stdout.readline()  # type: ignore[union-attr]
    if "listening on udp://127.0.0.1:" not in first:
        proc.kill()
        _, err = proc.communicate(timeout=10)
        raise AssertionError(f"no address printed: {first!r}; {err}")
    return proc, int(first.rsplit(":", 1)[1])


@pytest.mark.e2e
@pytest.mark.parametrize(("how", "sig"), STOP_WAYS, ids=[how for how, _ in STOP_WAYS])
def test_fanuc_standalone_serves_status_until_stopped(how: str, sig: int) -> None:
    proc, port = fanuc_sim(how, "--interval-ms", "4")
    try:
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
            s.settimeout(5.0)
            s.sendto(StatusStart().encode(), ("127.0.0.1", port))
            statuses = [decode_from_robot(s.recvfrom(2048)[0]) for _ in range(5)]
        assert [st.seq for st in statuses] == [1, 2, 3, 4, 5]
        assert all(isinstance(st, Status) and st.status & 0x05 == 0x05 for st in statuses)
    finally:
        out = stopped(proc, sig)  # the buffered reader: readline() above used it
    assert "Ctrl-C to stop" in out and "intervals:" in out


@pytest.mark.e2e
def test_fanuc_standalone_resets_its_alarm_on_sigusr1() -> None:
    """SIGUSR1 is the teach pendant's RESET (no reset comes over the network): an alarm (here MOTN-607,
    a version-2 packet) clears, SYSRDY comes back in the status still flowing, and the simulator runs on."""
    proc, port = fanuc_sim("ctrl-c")
    try:
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
            s.settimeout(5.0)

            def sysrdy() -> bool:
                st = decode_from_robot(s.recvfrom(2048)[0])
                assert isinstance(st, Status)
                return bool(st.status & 0x04)

            s.sendto(StatusStart().encode(), ("127.0.0.1", port))
            assert sysrdy()
            s.sendto(StatusStart(version=2).encode(), ("127.0.0.1", port))  # MOTN-607: SYSRDY off
            assert any(not sysrdy() for _ in range(50))
            proc.send_signal(signal.SIGUSR1)
            assert any(sysrdy() for _ in range(200)), "SYSRDY did not come back after SIGUSR1"
    finally:
        out = stopped(proc, signal.SIGINT)
    assert "RESET (SIGUSR1): alarm cleared" in out


@pytest.mark.e2e
@pytest.mark.parametrize(("how", "sig"), STOP_WAYS, ids=[how for how, _ in STOP_WAYS])
def test_janome_standalone_runs_until_stopped(how: str, sig: int) -> None:
    """Connected to a server that sends nothing: the point job waits (a minute before its receive timeout),
    and the signal ends it with its summary."""
    with socket.create_server(("127.0.0.1", 0)) as server:
        server.settimeout(30.0)
        port = server.getsockname()[1]
        proc = subprocess.Popen(servo_app_argv(how, "sim", "janome", "--connect", f"127.0.0.1:{port}",
                                               "--timeout-ms", "60000"),
                                cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        try:
            conn, _ = server.accept()
            with conn:
                conn.settimeout(10.0)
                assert conn.recv(4096), "the robot's hello"
                out = stopped(proc, sig)
        finally:
            if proc.poll() is None:
                proc.kill()
                proc.wait(5)
    assert "Ctrl-C to stop" in out and "moves: 0;" in out, out
