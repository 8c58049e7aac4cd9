"""A warning on its own (no change of the safety state) reaches the service's safety view: the supervisor
marks it, and the servo process's publish sends the view for it, coalesced (a warning every cycle must not
cost a view every cycle). End to end: tests/test_alarms_state_e2e.py (FANUC) and
tests/test_janome_api_e2e.py (Janome)."""

from __future__ import annotations

import multiprocessing as mp
import time
from collections.abc import Callable

from test_servo_cycle_property import Cell

from servo_app import messages as msg
from servo_app.ipc import LatestValueSlot
from servo_app.process_handle import WARNINGS_PUBLISH_S, ServoProcessHost
from servo_app.state import STATE_SIZE, StateVector

WARNING = msg.ControllerAlarm(code="MOTN-612", message="MOTN-612 ST:Close to Jnt Velocity Limit.(A:1,Sq.25)")


def test_a_controller_warning_changes_no_state_and_is_marked_for_the_view() -> None:
    cell = Cell()
    cell.start()
    sup = cell.sup
    sup.changed = False
    before = sup.state
    cell.request(WARNING)
    assert sup.state == before and not sup.changed  # a warning is no safety transition
    assert sup.warned and [w["code"] for w in sup.describe()["warnings"]] == ["MOTN-612"]
    cell.request(msg.ControllerAlarm(code="MOTN-609", message="MOTN-609 ST:Exceeded Jnt Velocity Limit"))
    assert sup.changed and sup.state.mode.value == "fault"  # an alarm is one


class Host(ServoProcessHost):
    def _publish_backend(self, sv: StateVector) -> None:
        pass


def safety_views(parent: mp.connection.Connection) -> list[dict]:
    views = []
    while parent.poll(0):
        ev = parent.recv()
        if isinstance(ev, msg.SafetyChanged):
            views.append(ev.view)
    return views


def publish_until(host: Host, parent: mp.connection.Connection, pred: Callable[[dict], bool]) -> list[dict]:
    """The views the publish sends, pass after pass, until one answers ``pred``."""
    views: list[dict] = []
    deadline = time.monotonic() + 5.0
    while not views or not pred(views[-1]):
        assert time.monotonic() < deadline, views[-1:]
        host._publish()
        views += safety_views(parent)
    return views


def test_the_publish_sends_the_view_for_new_warnings_at_most_every_warnings_publish_s() -> None:
    cell = Cell()
    cell.start()
    slot = LatestValueSlot(STATE_SIZE)
    parent, child = mp.Pipe()
    try:
        host = Host(child, slot.name)
        host.sup = cell.sup
        host._publish()  # the start's view
        assert len(safety_views(parent)) == 1
        for _ in range(200):  # no warning, no state change: no view, however many passes
            host._publish()
        assert safety_views(parent) == []
        cell.request(WARNING)
        views = publish_until(host, parent, lambda v: v["warnings"][-1]["code"] == "MOTN-612")
        assert len(views) == 1, views  # the view (WARNINGS_PUBLISH_S after the last one at most)
        # A warning every pass (every cycle) for a while: a view at most every WARNINGS_PUBLISH_S.
        t0, n = time.monotonic(), 0
        while time.monotonic() - t0 < 6 * WARNINGS_PUBLISH_S:
            n += 1
            cell.sup._warn("link", f"warning {n}", cell.t)
            host._publish()
        views = safety_views(parent)
        assert n > 50 and 1 <= len(views) <= 7, (n, len(views))
        # The last one of the burst goes out too, once its time comes.
        publish_until(host, parent, lambda v: v["warnings"][-1]["message"] == f"warning {n}")
        host._publish()
        assert safety_views(parent) == []
    finally:
        parent.close()
        child.close()
        slot.close()
