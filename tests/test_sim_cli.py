"""``servo-app sim``: fanuc runs standalone until Ctrl-C; janome needs the server to connect to."""

from __future__ import annotations

import argparse
import select
import signal
import socket
import subprocess
import sys
from pathlib import Path

import pytest

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


@pytest.mark.e2e
def test_fanuc_standalone_serves_status_until_ctrl_c() -> None:
    code = ("import argparse, faulthandler, signal, sys\n"
            "faulthandler.register(signal.SIGUSR1, all_threads=True)  # the test's view of a hang\n"
            "from servo_app.sim.cli import add_sim_parser\n"
            "p = argparse.ArgumentParser(); add_sim_parser(p.add_subparsers())\n"
            "a = p.parse_args(sys.argv[1:]); sys.exit(a.handler(a))\n")
    proc = subprocess.Popen([sys.executable, "-c", code, "sim", "fanuc", "--port", "0", "--interval-ms", "4"],
                            cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        first = proc.stdout.readline()
        assert "listening on udp://127.0.0.1:" in first, proc.stderr.read() if proc.poll() is not None else first
        port = int(first.rsplit(":", 1)[1])
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
            s.settimeout(5.0)
            s.sendto(StatusStart().encode(), ("127.0.0.1", port))
            statuses = [decode_from_robot(s.recvfrom(2048)[0]) for _ in range(5)]
        assert [st.seq for st in statuses] == [1, 2, 3, 4, 5]
        assert all(isinstance(st, Status) and st.status & 0x05 == 0x05 for st in statuses)
    finally:
        proc.send_signal(signal.SIGINT)
        try:
            proc.wait(timeout=10)
        except subprocess.TimeoutExpired:  # (once in a full run): fail with every thread's stack
            proc.send_signal(signal.SIGUSR1)
            select.select([proc.stderr], [], [], 5.0)
            proc.kill()
            proc.wait(5)
            pytest.fail(f"no exit 10 s after SIGINT; stderr, with its threads' stacks:\n{proc.stderr.read()}")
    out, err = proc.stdout.read(), proc.stderr.read()  # the buffered readers: readline() above used them
    proc.stdout.close()
    proc.stderr.close()
    assert proc.returncode == 0, err
    assert "Ctrl-C to stop" in out and "intervals:" in out
