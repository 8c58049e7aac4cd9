"""The session log on a disk that fills up (``SessionLogWriter``): the reserve it keeps past its end
is still written into once the disk is full, its trouble is told at once, and a write that fails or is
cut short ends the log at its last whole record. Real disks: a tmpfs filled to its last byte (in a mount
namespace of its own, tests/small_disk.py) and a real file-size limit (RLIMIT_FSIZE) in a child."""

from __future__ import annotations

import json
import os
import resource
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from small_disk import launch, unavailable

from servo_app.session_log import RECORD_SIZE, SessionLogWriter, parse_header, read_session_log, status_record

ROOT = Path(__file__).resolve().parents[1]
needs_small_disk = pytest.mark.skipif(unavailable() is not None, reason=str(unavailable()))

# Writes records (one or two a write, as the servo processes do) until the log fails, with the disk
# filled to its last byte by another process after the first hundred; prints what the writer told.
_FILL_WHILE_WRITING = """
import json, subprocess, sys
from pathlib import Path
from servo_app.session_log import SessionLogWriter, status_record
d, reserve = Path(sys.argv[1]), int(sys.argv[2])
told, written, at_trouble, filled = [], 0, None, False
w = SessionLogWriter(d / "s.srvlog", {"model": "test"}, reserve_bytes=reserve, on_trouble=told.append)
def rec(i): return status_record(i * 0.008, i, 5, 0, tuple(float(i + k) for k in range(6)))
while not w.failed and written < 100_000:
    if written >= 100 and not filled:
        filled = True
        subprocess.run(["sh", "-c", 'cat /dev/zero > "$0" 2>/dev/null', str(d / "filler")])
    batch = [rec(written + k) for k in range(1 + written % 2)]
    w.write_records(batch)
    if w.failed:
        break
    written += len(batch)
    if told and at_trouble is None:
        at_trouble = written
w.close()
data = (d / "s.srvlog").read_bytes()
print(json.dumps({"told": told, "written": written, "records": w.records, "at_trouble": at_trouble,
                  "size": len(data), "log": data.hex()}))
"""


def _records_are_the_first(log_path: Path, n: int) -> None:
    """The log holds exactly the first ``n`` records written, whole and in order."""
    log = read_session_log(log_path)
    assert len(log.records) == n
    assert np.array_equal(log.records["seq"], np.arange(n))
    assert np.array_equal(log.records["values"][:, 1], np.arange(n, dtype=np.float32) + 1)


@needs_small_disk
def test_a_full_disk_is_told_at_once_and_the_reserve_still_takes_the_records(tmp_path: Path) -> None:
    reserve = 32 * 1024
    disk = tmp_path / "disk"
    disk.mkdir()
    p = launch(disk, 1024, [sys.executable, "-c", _FILL_WHILE_WRITING, str(disk), str(reserve)],
               env={**os.environ, "PYTHONPATH": str(ROOT)}, stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    out, err = p.communicate(timeout=60)
    assert p.returncode == 0, err
    r = json.loads(out)
    told = r["told"]
    # Told that the disk is full at the first top-up of the reserve after it filled (a quarter of the
    # reserve later at most), while the reserve (less one write) was still there to write into.
    assert len(told) == 2 and told[0].startswith("the disk is full: No space left on device"), told
    assert r["at_trouble"] is not None and 100 <= r["at_trouble"] <= 101 + reserve // 4 // RECORD_SIZE + 2
    assert r["written"] - r["at_trouble"] >= (reserve - 2 * RECORD_SIZE) // RECORD_SIZE
    # Then the reserve ran out: the write cut short or refused, and nothing after it.
    assert "cut short" in told[1] or "a write failed" in told[1], told
    assert r["records"] == r["written"]
    log_path = tmp_path / "copy.srvlog"
    log_path.write_bytes(bytes.fromhex(r["log"]))
    header_end = parse_header(log_path.read_bytes())[1]  # type: ignore[index]
    assert r["size"] == header_end + r["records"] * RECORD_SIZE  # no torn record at the end
    _records_are_the_first(log_path, r["records"])


@needs_small_disk
def test_a_log_without_room_for_its_reserve_is_not_opened(tmp_path: Path) -> None:
    disk = tmp_path / "disk"
    disk.mkdir()
    script = """
import sys
from pathlib import Path
from servo_app.session_log import SessionLogWriter
path = Path(sys.argv[1]) / "s.srvlog"
try:
    SessionLogWriter(path, {"model": "test"}, reserve_bytes=1 << 20)
except OSError as exc:
    print("refused:", exc, "| left behind:", path.exists())
"""
    p = launch(disk, 256, [sys.executable, "-c", script, str(disk)], env={**os.environ, "PYTHONPATH": str(ROOT)},
               stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    out, err = p.communicate(timeout=60)
    assert p.returncode == 0, err
    assert out.startswith("refused: [Errno 28]") and "the disk is full" in out, out
    assert out.strip().endswith("left behind: False"), out


def _write_under_a_size_limit(path: Path, room: int, batches: list[int], reserve: int) -> dict[str, object]:
    """In a forked child, open a log, then hold files to ``room`` bytes past its header (RLIMIT_FSIZE:
    writes past it fail with EFBIG, or are cut short at it) and write ``batches`` of records; what the
    writer told and counted."""
    r_fd, w_fd = os.pipe()
    pid = os.fork()
    if pid == 0:  # the child: nothing of pytest's runs here, it leaves by os._exit
        try:
            os.close(r_fd)
            told: list[str] = []
            w = SessionLogWriter(path, {"model": "test"}, reserve_bytes=reserve, on_trouble=told.append)
            resource.setrlimit(resource.RLIMIT_FSIZE, (path.stat().st_size + room, resource.RLIM_INFINITY))
            i = 0
            for n in batches:
                w.write_records([status_record(i * 0.008, i + k, 5, 0, tuple(float(i + k + j) for j in range(6)))
                                 for k in range(n)])
                i += n
            w.close()
            os.write(w_fd, json.dumps({"told": told, "records": w.records, "failed": w.failed}).encode())
        finally:
            os._exit(0)
    os.close(w_fd)
    with os.fdopen(r_fd, "rb") as f:
        data = f.read()
    os.waitpid(pid, 0)
    return json.loads(data)  # type: ignore[no-any-return]


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(room=st.integers(0, 20 * RECORD_SIZE), batches=st.lists(st.integers(1, 3), min_size=1, max_size=12),
       reserve=st.sampled_from([0, 4096]))
def test_a_failed_write_ends_the_log_at_its_last_whole_record(tmp_path: Path, room: int, batches: list[int],
                                                              reserve: int) -> None:
    path = tmp_path / f"s-{room}-{len(batches)}-{reserve}.srvlog"
    r = _write_under_a_size_limit(path, room, batches, reserve)
    header = parse_header(path.read_bytes())[1]  # type: ignore[index]
    fits, total = 0, 0
    for n in batches:  # whole writes that fit under the limit, up to the first that does not
        if total + n * RECORD_SIZE > room:
            break
        total += n * RECORD_SIZE
        fits += n
    assert r["records"] == fits
    assert path.stat().st_size == header + fits * RECORD_SIZE
    overflow = fits < sum(batches)
    assert r["failed"] is overflow
    assert len(r["told"]) == int(overflow)  # told once, however many writes came after
    if overflow:
        assert r["told"][0].startswith(f"a write failed after record {fits}: [Errno 27] File too large") or \
            r["told"][0].startswith(f"a write was cut short after record {fits}"), r["told"]
    _records_are_the_first(path, fits)
