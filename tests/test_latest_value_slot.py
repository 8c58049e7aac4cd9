"""The shared-memory slot's reader against a writer caught in the middle of a write (its counter odd),
as a writer preempted mid-write on a busy machine leaves it: a reader with patience waits for the
finished write and returns it whole; one without gives up at once; none returns half a write."""

from __future__ import annotations

import threading
import time

import numpy as np
import pytest

from servo_app.ipc import LatestValueSlot


@pytest.fixture
def slots():
    writer = LatestValueSlot(4)
    reader = LatestValueSlot(4, name=writer.name, create=False)  # the other process's view of it
    yield writer, reader
    reader.close()
    writer.close()


def test_a_reader_with_patience_waits_out_a_write_left_half_done(slots) -> None:
    writer, reader = slots
    writer.write(np.array([1.0, 2.0, 3.0, 4.0]))
    writer._seq[0] += 1  # a write begun: the counter odd, then half the values in
    writer._data[:2] = 9.0
    with pytest.raises(TimeoutError):
        reader.read(retries=100)  # the servo cycle's read: never waits
    t = time.monotonic()
    with pytest.raises(TimeoutError):
        reader.read(retries=10, patience_s=0.05)
    assert time.monotonic() - t >= 0.05
    got: list[tuple[int, np.ndarray]] = []
    waiting = threading.Thread(target=lambda: got.append(reader.read(retries=10, patience_s=10.0)))
    waiting.start()
    waiting.join(0.05)
    assert waiting.is_alive() and not got  # still waiting for the write to finish
    writer._data[2:] = 9.0  # the write finishes
    writer._seq[0] += 1
    writer._written = int(writer._seq[0])
    waiting.join(10.0)
    version, values = got[0]
    assert version == 2 and values.tolist() == [9.0] * 4


def test_closing_twice_is_harmless_and_the_creator_unlinks_once() -> None:
    """A dead servo process's handle is shut down by the reset that replaces it and again at the
    service's close: the second close must do nothing (it raised AttributeError, a 500)."""
    writer = LatestValueSlot(4)
    reader = LatestValueSlot(4, name=writer.name, create=False)
    reader.close()
    reader.close()
    writer.close()
    writer.close()
    with pytest.raises(FileNotFoundError):  # unlinked by the creator's first close
        LatestValueSlot(4, name=writer.name, create=False)
