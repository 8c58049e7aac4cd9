"""The command-line tools that run until stopped (``servo-app sim``, ``monitor``, ``replay``), and the
long ones (``check``, ``export``), stop on SIGINT (Ctrl-C) and on SIGTERM, both handled explicitly.
(``servo-app run`` has handlers of its own around uvicorn's; the servo process its own.)

Python raises KeyboardInterrupt on SIGINT only when the process did not inherit it ignored, and a
script's background job does inherit it ignored (POSIX shells without job control): such a tool
ignored Ctrl-C and ``kill -INT`` alike (seen: a test's SIGINT left a simulator running). SIGTERM
(``kill``, systemd, ``docker stop``) ended it at once, without its closing work.
"""

from __future__ import annotations

import contextlib
import signal
import threading
from collections.abc import Iterator
from types import FrameType

STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM)


@contextlib.contextmanager
def signal_event(*signals: signal.Signals) -> Iterator[threading.Event]:
    """An event set by any of ``signals`` while the block runs (main thread only); the previous
    handlers come back after it."""
    requested = threading.Event()

    def on_signal(signum: int, frame: FrameType | None) -> None:
        requested.set()

    previous = {s: signal.signal(s, on_signal) for s in signals}
    try:
        yield requested
    finally:
        for s, handler in previous.items():
            signal.signal(s, handler)


def stop_requested() -> contextlib.AbstractContextManager[threading.Event]:
    """An event set by SIGINT or SIGTERM while the block runs (main thread only)."""
    return signal_event(*STOP_SIGNALS)
