"""``servo-app check`` and ``export`` of a long session log show their progress on stderr: rewritten in
place on a terminal (a real pseudo-terminal here), a line now and then once a job has run a few seconds
elsewhere, nothing for a short job; the report on stdout is unchanged (real commands, real files)."""

from __future__ import annotations

import os
import pty
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from servo_app.session_log import SessionLogWriter

ROOT = Path(__file__).resolve().parents[1]
ENV = {**os.environ, "PYTHONPATH": str(ROOT)}

pytestmark = pytest.mark.timeout(180)


def write_long_log(path: Path, commands: int) -> Path:
    """A FANUC joint log of a slow sway, ``commands`` of it (one stream)."""
    t = np.arange(commands) * 0.008
    q = np.zeros((commands, 6))
    q[:, 0] = 10.0 * (1.0 - np.cos(2 * np.pi * t / 8.0))  # (from rest)
    q[:, 4] = -60.0
    w = SessionLogWriter(path, {"model": "lrmate200id", "interval_ms": 8.0, "protocol": "fanuc-j519-v1",
                                "payload_kg": 3.0})
    for i in range(commands):
        w.command(float(t[i]), i + 1, int(i == commands - 1), 1, 0, 0.0, tuple(q[i]))
    w.close()
    return path


def run_on_a_terminal(*argv: str) -> tuple[int, str, str]:
    """``servo-app *argv`` with its stderr on a pseudo-terminal; (exit code, stdout, what the terminal got)."""
    master, slave = pty.openpty()
    try:
        p = subprocess.Popen([sys.executable, "-m", "servo_app.cli", *argv], stdout=subprocess.PIPE,
                             stderr=slave, text=True, env=ENV)
        os.close(slave)
        slave = -1
        chunks: list[bytes] = []
        while True:  # (read as it comes: a full terminal buffer would block the command)
            try:
                data = os.read(master, 4096)
            except OSError:  # EIO: the command and its terminal end are gone
                break
            if not data:
                break
            chunks.append(data)
        out, _ = p.communicate(timeout=120)
        return p.returncode, out, b"".join(chunks).decode()
    finally:
        os.close(master)
        if slave >= 0:
            os.close(slave)


@pytest.fixture(scope="module")
def long_log(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return write_long_log(tmp_path_factory.mktemp("long") / "long.srvlog", 40_000)


def test_check_of_a_long_log_shows_its_progress_on_a_terminal(long_log: Path) -> None:
    code, out, term = run_on_a_terminal("check", str(long_log))
    assert code == 0, (out, term)
    assert out.startswith(f"{long_log}: 40000 rows (joints)") and "OK: no violation" in out, out
    assert "\rservo-app check: " in term and "of 40,000 commands" in term and "s left" in term, repr(term)
    assert term.endswith("\r\x1b[K"), repr(term[-80:])  # the line erased once done


def test_export_of_a_long_log_prints_progress_lines_to_a_pipe_after_a_few_seconds(long_log: Path,
                                                                                  tmp_path: Path) -> None:
    r = subprocess.run([sys.executable, "-m", "servo_app.cli", "export", str(long_log), "--mcap",
                        str(tmp_path / "long.mcap")], capture_output=True, text=True, env=ENV, timeout=150)
    assert r.returncode == 0, r.stderr
    lines = r.stderr.splitlines()
    assert lines and all(line.startswith("servo-app export: ") and "of 40,000 records" in line for line in lines), \
        r.stderr
    assert "\r" not in r.stderr and "\x1b" not in r.stderr
    assert r.stdout.startswith(f"{tmp_path / 'long.mcap'}: ")


def test_a_short_check_prints_no_progress(tmp_path: Path) -> None:
    log = write_long_log(tmp_path / "short.srvlog", 500)
    code, out, term = run_on_a_terminal("check", str(log))
    assert code == 0 and "OK: no violation" in out, (out, term)
    assert "servo-app check:" not in term, repr(term)
    r = subprocess.run([sys.executable, "-m", "servo_app.cli", "check", str(log)], capture_output=True, text=True,
                       env=ENV, timeout=60)
    assert r.returncode == 0 and r.stderr == "", r.stderr


@pytest.mark.parametrize("existing", [False, True])
def test_ctrl_c_stops_an_export_in_one_line_leaving_no_partial_file(long_log: Path, tmp_path: Path,
                                                                    existing: bool) -> None:
    """Ctrl-C during `servo-app export` printed a KeyboardInterrupt traceback from wherever the loop was.
    Now it stops at its next check with one line and exit 130; its partial file is removed, and an
    MCAP already at the output path is left as it was (the export replaces it only when whole)."""
    out = tmp_path / "long.mcap"
    if existing:
        out.write_bytes(b"an earlier export")
    p = subprocess.Popen([sys.executable, "-m", "servo_app.cli", "export", str(long_log), "--mcap", str(out)],
                         stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=ENV)
    partial = tmp_path / "long.mcap.partial"
    try:
        deadline = time.monotonic() + 60.0
        while not (partial.exists() and partial.stat().st_size > 0):  # under way, mid-file
            assert p.poll() is None and time.monotonic() < deadline, "the export did not get under way"
            time.sleep(0.01)
        p.send_signal(signal.SIGINT)
        stdout, stderr = p.communicate(timeout=30)
    finally:
        if p.poll() is None:
            p.kill()
            p.communicate(timeout=10)
    assert p.returncode == 130, (p.returncode, stderr)
    assert "Traceback" not in stderr and "KeyboardInterrupt" not in stderr, stderr
    lines = [line for line in stderr.splitlines() if " records" not in line]  # (not a progress line)
    assert len(lines) == 1 and lines[0].startswith("servo-app export: interrupted at record "), stderr
    assert lines[0].endswith(f"of 40,000; nothing was written to {out}"), stderr
    assert stdout == "" and not partial.exists(), stdout
    assert (out.read_bytes() == b"an earlier export") if existing else not out.exists()


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM])
def test_ctrl_c_stops_a_check_in_one_line(long_log: Path, sig: signal.Signals) -> None:
    """Ctrl-C during `servo-app check` printed a KeyboardInterrupt traceback from wherever the checker
    was (SIGTERM ended it without a word). Now it stops at its next check of the request with one
    line naming where it was, no report on stdout, and exit 130."""
    master, slave = pty.openpty()
    p = subprocess.Popen([sys.executable, "-m", "servo_app.cli", "check", str(long_log)], stdout=subprocess.PIPE,
                         stderr=slave, text=True, env=ENV)
    os.close(slave)
    term = b""
    try:
        while b"of 40,000 commands" not in term:  # the progress line: the checker is under way
            data = os.read(master, 4096)  # (EIO / b"": the command ended before; the assert below says)
            assert data, term
            term += data
        p.send_signal(sig)
        while True:
            try:
                data = os.read(master, 4096)
            except OSError:  # EIO: the command and its terminal end are gone
                break
            if not data:
                break
            term += data
        stdout, _ = p.communicate(timeout=30)
    finally:
        os.close(master)
        if p.poll() is None:
            p.kill()
            p.communicate(timeout=10)
    text = term.decode()
    assert p.returncode == 130, (p.returncode, text[-2000:])
    assert "Traceback" not in text and "KeyboardInterrupt" not in text, text[-2000:]
    lines = [line for line in text.replace("\r\x1b[K", "\n").replace("\r", "\n").splitlines()
             if line.strip() and " commands, " not in line]  # (not a progress line)
    assert len(lines) == 1 and lines[0].startswith(f"servo-app check: {long_log}: interrupted at command "), lines
    assert lines[0].endswith("of 40,000: no verdict (run the check again to its end)"), lines
    assert stdout == "", stdout
