"""Latest-value slots in shared memory between the servo process and the rest of the service.

A slot is a float64 array behind a sequence counter (a seqlock): the single writer makes the counter
odd, writes, makes it even; a reader copies and retries while the counter was odd or changed. Nothing
blocks the writer, so the servo cycle never waits on a reader.
"""

from __future__ import annotations

import time
from multiprocessing import shared_memory

import numpy as np


class LatestValueSlot:
    def __init__(self, size: int, name: str | None = None, create: bool = True) -> None:
        nbytes = 8 * (size + 1)
        self._shm = shared_memory.SharedMemory(name=name, create=create, size=nbytes if create else 0)
        self._owner = create
        self._closed = False
        buf = np.ndarray((size + 1,), dtype=np.float64, buffer=self._shm.buf)
        self._seq = buf[:1].view(np.uint64)
        self._data = buf[1:]
        if create:
            buf[:] = 0.0
        self.size = size
        # The counter as this side last wrote it: the only writer need not read it back from the shared
        # page on every write (once per servo cycle).
        self._written = int(self._seq[0])

    @property
    def name(self) -> str:
        return self._shm.name

    def write(self, values: np.ndarray) -> None:
        s = self._written
        self._seq[0] = s + 1
        if values.size == self.size:  # (the whole vector, as the servo process writes it: no view made)
            self._data[...] = values
        else:
            self._data[: values.size] = values
        self._seq[0] = self._written = s + 2

    @property
    def version(self) -> int:
        """The version of the values last written, read without copying them (version 0: never
        written). While a write is in progress it is still the one before."""
        return int(self._seq[0]) >> 1

    def read(self, retries: int = 1000, patience_s: float = 0.0) -> tuple[int, np.ndarray]:
        """(version, copy of the values); version 0 means never written. ``retries`` tries at once, then,
        with ``patience_s``, more tries ~0.1 ms apart until that long has passed; TimeoutError after.

        Why the patience: a write takes ~1 us, but a writer preempted in the middle of it (a busy
        machine) leaves the counter odd for a scheduler tick or more, and 1000 tries at once took
        ~0.1 ms: the service's /api/state then read no state at all (a CI run saw it). A reader that
        may wait (the service's) waits it out; the servo cycle's own reads never wait."""
        for _ in range(retries):
            got = self._try_read()
            if got is not None:
                return got
        deadline = time.monotonic() + patience_s
        while time.monotonic() < deadline:
            time.sleep(1e-4)  # (the writer may need this CPU to finish)
            got = self._try_read()
            if got is not None:
                return got
        raise TimeoutError("slot kept changing while being read")

    def _try_read(self) -> tuple[int, np.ndarray] | None:
        """One try: (version, copy of the values), or None when a write was under way or landed meanwhile."""
        s1 = int(self._seq[0])
        if s1 % 2:
            return None
        out = self._data.copy()
        return (s1 // 2, out) if int(self._seq[0]) == s1 else None

    def close(self) -> None:
        """Unmap (and, as the creator, unlink) the slot; again: nothing (a dead process's handle is shut
        down once by the reset that replaces it and again at the service's close)."""
        if self._closed:
            return
        self._closed = True
        # Views into the buffer must go before the mapping can close.
        del self._seq, self._data
        self._shm.close()
        if self._owner:
            self._shm.unlink()
