"""The embedded simulator's control pipe (servo_app.sim.process): each reply goes to the call that
asked for it, a late one is discarded, and the simulator drops a request whose caller gave up.

Both ends run here over a real multiprocessing pipe: the parent's ``ControlPipe`` against a scripted
simulator end, and the simulator's ``serve_calls`` against a fake simulator. (A real simulator
process stopped with SIGSTOP: tests/test_fault_matrix_e2e.py::test_embedded_controller_frozen_*.)
"""

from __future__ import annotations

import multiprocessing as mp
import threading
import time
from collections.abc import Iterator
from dataclasses import dataclass
from multiprocessing.connection import Connection
from typing import Any

import pytest

from servo_app.sim.process import ControlPipe, serve_calls


@pytest.fixture
def pipe() -> Iterator[tuple[ControlPipe, Connection]]:
    ours, theirs = mp.get_context("spawn").Pipe()
    control = ControlPipe(ours, "simulator")
    yield control, theirs
    theirs.close()
    control.close()


def test_a_late_reply_is_discarded_never_returned_to_the_next_call(pipe: tuple[ControlPipe, Connection]) -> None:
    control, sim = pipe
    with pytest.raises(TimeoutError, match=r"did not answer events within 0\.2 s"):
        control.call("events", timeout=0.2)  # nobody answers in time (a stopped process)
    first = sim.recv()
    assert first["call"] == "events" and first["deadline"] < time.monotonic()
    sim.send({"id": first["id"], "ok": True, "result": None})  # the answer comes late (reset's is None)

    answered = threading.Event()

    def answer_next() -> None:
        req = sim.recv()
        assert req["call"] == "events"
        sim.send({"id": req["id"], "ok": True, "result": [{"code": "MOTN-608"}]})
        answered.set()

    t = threading.Thread(target=answer_next)
    t.start()
    assert control.call("events", timeout=5.0) == [{"code": "MOTN-608"}]
    t.join(5)
    assert answered.is_set() and control.late_replies == 1


def test_concurrent_calls_each_get_their_own_reply(pipe: tuple[ControlPipe, Connection]) -> None:
    """Answered in the reverse order of asking: still each to its caller."""
    control, sim = pipe
    results: dict[str, Any] = {}

    def ask(name: str) -> None:
        results[name] = control.call(name, timeout=5.0)

    callers = [threading.Thread(target=ask, args=(name,)) for name in ("reset", "events", "set_override")]
    for c in callers:
        c.start()
    requests = [sim.recv() for _ in callers]
    assert len({r["id"] for r in requests}) == 3
    for r in reversed(requests):
        sim.send({"id": r["id"], "ok": True, "result": f"answer to {r['call']}"})
    for c in callers:
        c.join(5)
    assert results == {name: f"answer to {name}" for name in ("reset", "events", "set_override")}
    assert control.late_replies == 0


def test_a_refusal_raises_and_a_gone_simulator_fails_at_once(pipe: tuple[ControlPipe, Connection]) -> None:
    control, sim = pipe

    def refuse_then_go() -> None:
        req = sim.recv()
        sim.send({"id": req["id"], "ok": False, "error": "ValueError: no such mode"})
        sim.recv()
        sim.close()  # the simulator process ends with a call outstanding

    t = threading.Thread(target=refuse_then_go)
    t.start()
    with pytest.raises(RuntimeError, match="no such mode"):
        control.call("set_mode", "X", timeout=5.0)
    t0 = time.monotonic()
    with pytest.raises(TimeoutError, match="ended before answering reset"):
        control.call("reset", timeout=30.0)
    assert time.monotonic() - t0 < 5.0  # not the whole timeout
    t.join(5)
    with pytest.raises(TimeoutError, match="has ended"):
        control.call("events", timeout=1.0)


# ------------------------------------------------------------------------ the simulator's end


@dataclass
class _Alarm:
    code: str
    message: str = ""
    time_s: float = 0.0
    axis: int | None = None
    seq: int | None = None
    controller_time_ms: int | None = None


class FakeSimulator:
    def __init__(self) -> None:
        self.lock = threading.Lock()
        self.resets = 0

    def events(self) -> list[_Alarm]:
        return [_Alarm("MOTN-603")]

    def reset(self) -> None:
        self.resets += 1


def test_the_simulator_drops_a_request_whose_caller_gave_up() -> None:
    """A reset that reaches the simulator after its deadline (it was stopped meanwhile) is not
    carried out late and gets no reply; the next request is answered under its own id."""
    parent, child = mp.get_context("spawn").Pipe()
    sim = FakeSimulator()
    server = threading.Thread(target=serve_calls, args=(sim, child), daemon=True)
    server.start()
    now = time.monotonic()
    parent.send({"id": 1, "call": "reset", "args": (), "deadline": now - 0.1})
    parent.send({"id": 2, "call": "events", "args": (), "deadline": now + 5.0})
    assert parent.poll(5.0)
    reply = parent.recv()
    assert reply["id"] == 2 and reply["ok"] and [e["code"] for e in reply["result"]] == ["MOTN-603"]
    assert sim.resets == 0
    parent.send({"id": 3, "call": "reset", "args": (), "deadline": time.monotonic() + 5.0})
    assert parent.poll(5.0) and parent.recv() == {"id": 3, "ok": True, "result": None}
    assert sim.resets == 1
    parent.send({"id": 4, "call": "quit", "deadline": time.monotonic() + 5.0})
    assert parent.poll(5.0) and parent.recv() == {"id": 4, "ok": True}
    server.join(5)
    assert not server.is_alive()
    assert not parent.poll(0)  # nothing ever came for the dropped request
