"""MCAP written live beside each session log (``servo-app run --mcap``).

The servo process writes only its ``.srvlog`` (one unbuffered 56-byte write per datagram): the cycle
never waits on a serializer. This follower runs in the API process, in a thread of its own, reads
the records the servo process has written so far every ``poll_s`` and appends their messages (the
same conversion as ``servo-app export``) to ``NAME.mcap``. Small chunks: a process killed mid-session
leaves an MCAP readable up to its last chunk, and the ``.srvlog`` complete.

A writer that stops (its disk full, a write error) says so through ``on_error`` (the service lists it
as a warning and in GET /api/state): the ``.srvlog`` stays complete and ``servo-app export`` converts
it, but only if the operator learns that the ``.mcap`` is cut short.
"""

from __future__ import annotations

import logging
import threading
from collections.abc import Callable
from pathlib import Path
from typing import Any, BinaryIO

import numpy as np

from servo_app.mcap_export import ExportError, LogConverter, McapSink
from servo_app.session_log import RECORD_DTYPE, RECORD_SIZE, SessionLogError, parse_header

log = logging.getLogger(__name__)


class LiveMcapRecorder:
    def __init__(self, srvlog: Path, poll_s: float = 0.2, chunk_size: int = 64 * 1024,
                 on_error: Callable[[LiveMcapRecorder], None] | None = None,
                 on_finished: Callable[[LiveMcapRecorder], None] | None = None) -> None:
        self.srvlog = Path(srvlog)
        self.path = self.srvlog.with_suffix(".mcap")
        self.poll_s = poll_s
        self.chunk_size = chunk_size
        self.error: str | None = None  # why the writer stopped (the OS's or the converter's words)
        self.on_error = on_error  # called once, on the writer's thread, when it stops short
        self.on_finished = on_finished  # called once, on the writer's thread, when the file is whole
        self.records = 0
        self._closed = threading.Event()
        self._discarded = False
        self._thread = threading.Thread(target=self._run, name=f"mcap {self.srvlog.name}", daemon=True)

    def start(self) -> LiveMcapRecorder:
        self._thread.start()
        return self

    def close(self) -> None:
        """The session log is complete: write what is left and finish the file (without waiting)."""
        self._closed.set()

    def discard(self) -> None:
        """The session log held nothing and was deleted: so is the MCAP, and neither error nor finish
        is told (without waiting)."""
        self._discarded = True
        self._closed.set()

    def join(self, timeout: float | None = None) -> None:
        self._thread.join(timeout)

    @property
    def done(self) -> bool:
        return not self._thread.is_alive()

    def _run(self) -> None:
        try:
            with self._open_srvlog() as src:
                header, offset = self._header(src)
                if header is None:
                    return
                converter = LogConverter(header)
                with open(self.path, "wb") as out:
                    sink = McapSink(out, header, chunk_size=self.chunk_size)
                    while True:
                        closed = self._closed.is_set()  # read before the data: the last records are in
                        offset = self._drain(src, offset, converter, sink)
                        if closed:
                            break
                        self._closed.wait(self.poll_s)
                    sink.finish()
        except (OSError, ExportError, SessionLogError) as exc:
            if self._discarded:  # (the log deleted before it was opened here)
                self.path.unlink(missing_ok=True)
                return
            self.error = exc.strerror if isinstance(exc, OSError) and exc.strerror else str(exc)
            log.warning("live MCAP stopped: %s: %s (%s)", self.path, self.error, self.remedy)
            if self.on_error is not None:
                self.on_error(self)
        else:
            if self._discarded:
                self.path.unlink(missing_ok=True)
            elif self.on_finished is not None:
                self.on_finished(self)

    def _open_srvlog(self) -> BinaryIO:
        try:
            return open(self.srvlog, "rb")
        except FileNotFoundError:
            # Deleted as it closed (it held nothing: discard), which its LogClosed tells, maybe after
            # this thread began: no error until the close says it was not that.
            self._closed.wait()
            raise

    @property
    def remedy(self) -> str:
        """What to do once the writer has stopped: the session log is whole, convert it afterwards."""
        return (f"the session log {self.srvlog} is complete: `servo-app export {self.srvlog} --mcap {self.path}` "
                "converts it (free disk space first if the disk is full)")

    def _header(self, src: BinaryIO) -> tuple[dict[str, Any] | None, int]:
        """Wait for the header (written before the first record), then parse it."""
        while True:
            closed = self._closed.is_set()
            src.seek(0)
            parsed = parse_header(src.read(), self.srvlog)
            if parsed is not None:
                return parsed
            if closed:
                return None, 0
            self._closed.wait(self.poll_s)

    def _drain(self, src: BinaryIO, offset: int, converter: LogConverter, sink: McapSink) -> int:
        src.seek(offset)
        data = src.read()
        usable = len(data) - len(data) % RECORD_SIZE
        for rec in np.frombuffer(data[:usable], dtype=RECORD_DTYPE):
            sink.write(converter.feed(rec))
            self.records += 1
        return offset + usable
