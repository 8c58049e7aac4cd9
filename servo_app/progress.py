"""Progress of a long command-line job (``servo-app check`` and ``export`` of a large log) on stderr.

A 200,000-command log takes ~20 s to check and over a minute to export; with nothing on the screen
it looks hung. On a terminal: one line rewritten in place, from the first second on; elsewhere (a
pipe, a CI log): a line every 10 s once the job has run 3 s. A short job prints nothing either way,
and stdout (the report) is never touched.
"""

from __future__ import annotations

import sys
import time
from collections.abc import Callable
from typing import TextIO


class Progress:
    def __init__(self, what: str, total: int, unit: str, stream: TextIO | None = None,
                 clock: Callable[[], float] = time.monotonic) -> None:
        self.what, self.total, self.unit = what, max(1, total), unit
        self.stream = stream if stream is not None else sys.stderr
        self.clock = clock
        try:
            self.tty = self.stream.isatty()
        except (AttributeError, ValueError):  # (a closed or odd stream: lines, as to a file)
            self.tty = False
        self.t0 = clock()
        # On a terminal: from 1 s, every 0.5 s; elsewhere from 3 s, every 10 s (a log stays short).
        self._next = self.t0 + (1.0 if self.tty else 3.0)
        self._every = 0.5 if self.tty else 10.0
        self._shown = False

    def update(self, done: int) -> None:
        """``done`` of ``total`` so far; cheap when nothing is due (one clock read)."""
        now = self.clock()
        if now < self._next:
            return
        self._next = now + self._every
        elapsed = now - self.t0
        share = min(1.0, done / self.total)
        left = f", about {elapsed * (1.0 - share) / share:.0f} s left" if share > 0.0 else ""
        line = f"{self.what}: {100.0 * share:3.0f} % ({done:,} of {self.total:,} {self.unit}, {elapsed:.0f} s{left})"
        try:
            if self.tty:
                self.stream.write(f"\r{line}\x1b[K")
            else:
                self.stream.write(line + "\n")
            self.stream.flush()
        except (OSError, ValueError):  # stderr gone (a closed pipe): the job goes on without it
            return
        self._shown = True

    def close(self) -> None:
        """Done: on a terminal the progress line is erased (the report follows on stdout)."""
        if self._shown and self.tty:
            try:
                self.stream.write("\r\x1b[K")
                self.stream.flush()
            except (OSError, ValueError):
                pass
