"""Per-cycle session log: every status received and every command sent, to disk.

The format is shared by both backends (the header's ``protocol`` names which one wrote the file);
``servo-app check`` reads the command records of either. What ``flags``, ``io`` and ``values`` mean
per backend:

- FANUC (J519): status = the status packet's bits, the read I/O value and the servo joints J1..J9;
  command = ``last_data | data_format << 1``, the write I/O value and the commanded values;
- Janome (point job, ``servo_app/janome/runner.py`` ``_log_exchange``): status = the robot state,
  its error code and X Y Z R; command (a target frame) = ``stop | cmd << 1``, 0 and X Y Z R.

Format (version 1), little-endian:

- ``b"SERVOLOG"`` magic, u32 header length, header as UTF-8 JSON (model, interval, j23 factor,
  start time, protocol, format version; FANUC: ``payload_kg`` the limit tables were evaluated at when
  the log opened, null for the maximum, and ``tool`` the active tool's name; logs written before
  these keys say nothing of the payload);
- then fixed 56-byte records, one per datagram or frame:

  ====== ===== ==============================================================================
  offset type  field
  ====== ===== ==============================================================================
  0      u8    kind: 0 status received, 1 command sent, 2 payload changed (a tool change at rest:
                values[0] the payload in kg, NaN for the maximum; seq the last status's), 3 a note
                (bytes 13..55 a piece of a JSON object's UTF-8 text, NUL-padded; the pieces of
                consecutive note records joined, a note ends with a newline: ``limit_tables``, the
                controller's tables as read at the stream's start; ``ended``, why the log ended: a
                FANUC start given up before its stream ran, a Janome connection's end; ``streamed``:
                commands were sent)
  1      f64   t: seconds since the session opened (monotonic clock)
  9      u32   seq: status or command sequence number
  13     u8    flags: FANUC status bits / Janome robot state (status);
                FANUC last_data | data_format << 1 / Janome stop | cmd << 1 (command)
  14     u16   io: read I/O value / Janome error code (status); write I/O value / 0 (command)
  16     f32   latency_us: status receipt to this command's send (command), 0 for status
  20     9xf32 values: servo joints J1..J9 / X Y Z R (status); commanded values (command)
  ====== ===== ==============================================================================

Every record goes to the kernel as it is written (unbuffered, after the datagram has left): a killed
process, even by SIGKILL, loses nothing it logged. ``write_records`` hands a status and the commands
that answered it to the kernel in one ``write`` (one system call per status packet instead of two).
"""

from __future__ import annotations

import contextlib
import ctypes
import errno
import json
import math
import os
import struct
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import IO, Any

import numpy as np

MAGIC = b"SERVOLOG"
FORMAT_VERSION = 1
KIND_STATUS = 0
KIND_COMMAND = 1
KIND_PAYLOAD = 2  # readers that know only kinds 0 and 1 skip it
KIND_NOTE = 3
_NOTE_HEAD = struct.Struct("<BdI")  # kind, t, seq: t stays a time for readers that skip the kind
_NOTE_TEXT = 56 - _NOTE_HEAD.size  # 43 bytes of text a record
_RECORD = struct.Struct("<BdIBHf9f")
RECORD_SIZE = _RECORD.size
RECORD_DTYPE = np.dtype(
    [("kind", "u1"), ("t", "<f8"), ("seq", "<u4"), ("flags", "u1"), ("io", "<u2"), ("latency_us", "<f4"),
     ("values", "<f4", (9,))]
)
assert RECORD_DTYPE.itemsize == RECORD_SIZE == 56


_ZEROS = (0.0,) * 9


def status_record(t: float, seq: int, bits: int, io: int, joints: tuple[float, ...] | list[float]) -> bytes:
    """One status record: the status bits (or Janome robot state), its read I/O value (error code) and
    the servo joints (X Y Z R)."""
    n = min(len(joints), 9)
    return _RECORD.pack(KIND_STATUS, t, seq, bits, io, 0.0, *joints[:n], *_ZEROS[n:])


def command_record(t: float, seq: int, last_data: int, data_format: int, io: int, latency_us: float,
                   values: tuple[float, ...] | list[float]) -> bytes:
    """One command record: ``last_data | data_format << 1``, the write I/O value, the latency from the
    status's receipt to this command's send, and the commanded values."""
    n = min(len(values), 9)
    return _RECORD.pack(KIND_COMMAND, t, seq, last_data | (data_format << 1), io, latency_us, *values[:n],
                        *_ZEROS[n:])


def payload_record(t: float, seq: int, payload_kg: float | None) -> bytes:
    """The limit tables' payload changed (kg; None: the maximum); ``seq``: the last status's."""
    return _RECORD.pack(KIND_PAYLOAD, t, seq, 0, 0, 0.0, math.nan if payload_kg is None else payload_kg,
                        *_ZEROS[1:])


def note_records(t: float, note: dict[str, Any]) -> list[bytes]:
    """A JSON note (one line) as records of kind 3."""
    text = (json.dumps(note, separators=(",", ":")) + "\n").encode()
    return [_NOTE_HEAD.pack(KIND_NOTE, t, 0) + text[i: i + _NOTE_TEXT].ljust(_NOTE_TEXT, b"\0")
            for i in range(0, len(text), _NOTE_TEXT)]


def end_note(why: str, streamed: bool) -> dict[str, Any]:
    """The note that ends a log: why its session ended (a FANUC start given up before its stream ran, a
    Janome connection closed); ``streamed``: commands (target frames) were sent."""
    return {"ended": why, "streamed": streamed}


def end_of_log(log: SessionLog) -> str | None:
    """Why the log's session ended, as its last ``ended`` note says (None: no such note)."""
    ends = [note["ended"] for _, note in log.notes() if isinstance(note.get("ended"), str)]
    return ends[-1] if ends else None


def tables_note(tables: Any) -> dict[str, Any]:
    """The note of a LimitTables (servo_app.motion.limit_tables): what ``tables_of_note`` reads back."""
    return {"limit_tables": {"vmax": tables.vmax, "check_time_s": tables.check_time_s,
                             "max_payload_kg": tables.max_payload_kg,
                             "rows": [[[list(a.no_payload), list(a.max_payload)] for a in per_type]
                                      for per_type in tables.tables]}}


class SessionLogWriter:
    """Appends records to a session log, each to the kernel as it is written.

    ``reserve_bytes`` (0: none) keeps that much disk space allocated past the end of the file
    (``fallocate`` without changing its size: a reader sees only whole records), topped up as the
    log grows. When a top-up fails (the disk is filling up) the log still has the reserve to write
    into: ``on_trouble`` is told at once, so the stream can be stopped and ended while every record
    of the stop is still logged. A write that fails or is cut short (no reserve on this file system,
    a file-size limit, an I/O error) ends the log at its last whole record: nothing is written after
    it, so the file stays readable, and ``on_trouble`` is told. It is told once per kind of trouble;
    ``trouble`` keeps the first. Why: an exception out of a write ended the servo process
    mid-stream, and the controller then stopped the arm by its own alarm."""

    def __init__(self, path: Path, header: dict[str, Any], reserve_bytes: int = 0,
                 on_trouble: Callable[[str], None] | None = None) -> None:
        """OSError if the file cannot be opened, its header written or its reserve allocated: the
        stream should not start."""
        self.path = path
        path.parent.mkdir(parents=True, exist_ok=True)
        # Unbuffered: a record in a userspace buffer dies with the process (a SIGKILLed servo process
        # lost its unflushed records, issue 13). One 56-byte write measured 1.7 us here.
        self._f: IO[bytes] = open(path, "wb", buffering=0)  # noqa: SIM115 - closed by close()
        self.records = 0
        self.trouble: str | None = None
        self.failed = False  # a write failed: nothing more is written
        self._on_trouble = on_trouble
        self._reserve = reserve_bytes
        self._reserved_to = 0
        try:
            meta = {"format_version": FORMAT_VERSION, "opened_unix": time.time(), **header}
            blob = json.dumps(meta).encode()
            head = MAGIC + struct.pack("<I", len(blob)) + blob
            if self._f.write(head) != len(head):
                raise OSError(errno.ENOSPC, "the header was cut short")
            self._end = len(head)
            # Top up when less than the reserve is left, by a quarter of it: one call every quarter.
            self._top_up_at = self._end
            if reserve_bytes > 0:
                self._top_up()
                if self.trouble is not None:
                    raise OSError(errno.ENOSPC, self.trouble)
        except OSError:
            self._f.close()
            path.unlink(missing_ok=True)
            raise

    def status(self, t: float, seq: int, bits: int, io: int, joints: tuple[float, ...]) -> None:
        self.write_records([status_record(t, seq, bits, io, joints)])

    def command(self, t: float, seq: int, last_data: int, data_format: int, io: int, latency_us: float,
                values: tuple[float, ...] | list[float]) -> None:
        self.write_records([command_record(t, seq, last_data, data_format, io, latency_us, values)])

    def write_pair(self, buf: bytearray | np.ndarray) -> None:
        """Two records packed in place (a status and its command: the FANUC servo process's
        ``_exchange_into_state``), in one write."""
        self._write(buf, 2 * RECORD_SIZE, 2)

    def write_records(self, records: list[bytes]) -> None:
        """Records made by ``status_record`` / ``command_record``, to the kernel in one write."""
        data = records[0] if len(records) == 1 else b"".join(records)
        self._write(data, len(data), len(records))

    def _write(self, data: bytes | bytearray | np.ndarray, size: int, records: int) -> None:
        if self.failed:
            return
        try:
            written = self._f.write(data)
        except OSError as exc:
            self._fail(f"a write failed after record {self.records}: {exc}")
            return
        if written != size:
            self._fail(f"a write was cut short after record {self.records} ({written} of {size} bytes: "
                       "no space was left for the rest)")
            return
        self.records += records
        self._end += size
        if self._end > self._top_up_at:
            self._top_up()

    def _top_up(self) -> None:
        """Allocate the reserve past the end again (a quarter more than needed: one call per quarter)."""
        want = self._end + self._reserve + self._reserve // 4
        err = _reserve_space(self._f.fileno(), self._reserved_to, want - self._reserved_to)
        if err == 0:
            self._reserved_to = want
            self._top_up_at = want - self._reserve
        elif err in (errno.EOPNOTSUPP, errno.ENOSYS, errno.EINVAL):  # no reserve on this file system
            self._reserve = 0
            self._top_up_at = 1 << 62
        else:
            left = max(0, self._reserved_to - self._end)
            self._tell(f"the disk is full: {os.strerror(err)} ({left} bytes reserved are left, "
                       f"{left // RECORD_SIZE} records)")
            self._top_up_at = 1 << 62  # (told once; the reserve is written into)

    def _fail(self, why: str) -> None:
        self.failed = True
        with contextlib.suppress(OSError):  # the log ends at its last whole record
            os.ftruncate(self._f.fileno(), self._end)
        self._tell(why)

    def _tell(self, why: str) -> None:
        if self.trouble is None:
            self.trouble = why
        if self._on_trouble is not None:
            self._on_trouble(why)

    def close(self) -> None:
        if not self._f.closed:
            with contextlib.suppress(OSError):  # the reserve left unused goes back to the disk
                os.ftruncate(self._f.fileno(), self._end)
            self._f.close()


_FALLOC_FL_KEEP_SIZE = 1
_libc = ctypes.CDLL(None, use_errno=True)
_fallocate = _libc.fallocate
_fallocate.argtypes = [ctypes.c_int, ctypes.c_int, ctypes.c_int64, ctypes.c_int64]
_fallocate.restype = ctypes.c_int


def _reserve_space(fd: int, offset: int, length: int) -> int:
    """Allocate ``length`` bytes of disk from ``offset`` without changing the file's size; 0 or errno."""
    if _fallocate(fd, _FALLOC_FL_KEEP_SIZE, offset, length) == 0:
        return 0
    return ctypes.get_errno()


@dataclass
class SessionLog:
    header: dict[str, Any]
    records: np.ndarray  # RECORD_DTYPE

    @property
    def commands(self) -> np.ndarray:
        return self.records[self.records["kind"] == KIND_COMMAND]

    @property
    def statuses(self) -> np.ndarray:
        return self.records[self.records["kind"] == KIND_STATUS]

    def notes(self) -> list[tuple[int, dict[str, Any]]]:
        """(commands before it, the note) for each whole note (a note cut short by a killed process,
        or damaged, is left out)."""
        kinds = self.records["kind"]
        at = np.flatnonzero(kinds == KIND_NOTE)
        if not at.size:
            return []
        before = np.cumsum(kinds == KIND_COMMAND)
        raw = self.records[at].tobytes()
        out: list[tuple[int, dict[str, Any]]] = []
        text, first = b"", None
        for k, i in enumerate(at):
            text += raw[k * RECORD_SIZE + _NOTE_HEAD.size: (k + 1) * RECORD_SIZE].rstrip(b"\0")
            first = int(before[i]) if first is None else first
            if text.endswith(b"\n"):
                with contextlib.suppress(ValueError):  # (JSONDecodeError, UnicodeDecodeError)
                    note = json.loads(text)
                    if isinstance(note, dict):
                        out.append((first, note))
                text, first = b"", None
        return out

    def payload_changes(self) -> list[tuple[int, float | None]]:
        """(commands before it, payload kg or None for the maximum) for each payload record."""
        kinds = self.records["kind"]
        at = np.flatnonzero(kinds == KIND_PAYLOAD)
        before = np.cumsum(kinds == KIND_COMMAND)
        out: list[tuple[int, float | None]] = []
        for i in at:
            kg = float(self.records["values"][i, 0])
            out.append((int(before[i]), None if math.isnan(kg) else kg))
        return out


class SessionLogError(ValueError):
    pass


def is_session_log(path: Path) -> bool:
    with open(path, "rb") as f:
        return f.read(len(MAGIC)) == MAGIC


def parse_header(data: bytes, path: object = "session log") -> tuple[dict[str, Any], int] | None:
    """The header of a log's first bytes and where its records start; None while it is not all there
    (a log being written). SessionLogError when the bytes are no session log."""
    if data[: len(MAGIC)] != MAGIC[: len(data)]:
        raise SessionLogError(f"{path}: not a servo_app session log (magic={data[:8]!r})")
    start = len(MAGIC) + 4
    if len(data) < start:
        return None
    (n,) = struct.unpack_from("<I", data, len(MAGIC))
    if len(data) < start + n:
        return None
    try:
        header = json.loads(data[start:start + n])
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:  # (bytes that are not UTF-8: the latter)
        raise SessionLogError(f"{path}: header is not valid JSON: {exc}") from exc
    if not isinstance(header, dict):  # every reader looks keys up in it
        raise SessionLogError(f"{path}: header is not a JSON object: {json.dumps(header)[:80]}")
    return header, start + n


def header_interval_ms(header: dict[str, Any], path: object = "session log") -> float | None:
    """The header's ``interval_ms`` (None if it has none); SessionLogError if it is no positive number
    (a damaged header: the readers' checkers raised on it, uncaught)."""
    ms = header.get("interval_ms")
    if ms is None:
        return None
    if isinstance(ms, bool) or not isinstance(ms, (int, float)) or not math.isfinite(ms) or ms <= 0:
        raise SessionLogError(f"{path}: header interval_ms={ms!r} is not a positive number of milliseconds "
                              "(a damaged header)")
    return float(ms)


def read_session_log(path: Path) -> SessionLog:
    """Read a log; a trailing partial record (a crash mid-write) is dropped."""
    data = Path(path).read_bytes()
    if not data:  # what a process killed between opening the log and writing its header leaves
        raise SessionLogError(f"{path}: empty (0 bytes): no header was written (the process ended as it "
                              "opened the log), so nothing was logged")
    if data[: len(MAGIC)] != MAGIC:  # a whole file: a short one is no log either
        raise SessionLogError(f"{path}: not a servo_app session log (magic={data[:8]!r})")
    parsed = parse_header(data, path)
    if parsed is None:
        raise SessionLogError(f"{path}: the header is cut short ({len(data)} bytes)")
    header, body_start = parsed
    body = data[body_start:]
    usable = len(body) - len(body) % RECORD_SIZE
    records = np.frombuffer(body[:usable], dtype=RECORD_DTYPE)
    return SessionLog(header=header, records=records)
