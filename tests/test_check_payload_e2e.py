"""``servo-app check`` judges a session log against the limit tables the live service streamed with:
the payload of the tool that was active (a real run: the service, the servo process and the embedded
FANUC simulator on loopback, with a tools file)."""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory
from test_api_harness import Rig, running_rig
from test_checker_cli import run_cli

from servo_app import messages as msg
from servo_app.errors import CommandRejected
from servo_app.mcap_export import export_mcap
from servo_app.motion.limit_tables import AxisTable, LimitTables, default_tables
from servo_app.robots.profile import load_profile
from servo_app.session_log import SessionLogWriter, read_session_log

pytestmark = pytest.mark.e2e
WARNINGS = {"MOTN-612", "MOTN-613", "MOTN-614"}  # close to a limit: posted, the stream goes on

TOOLS = """
active = "light"

[tools.light]
xyzwpr = [0, 0, 100, 0, 0, 0]
payload_kg = 1.0

[tools.heavy]
xyzwpr = [0, 0, 100, 0, 0, 0]
payload_kg = 7.0
"""


@pytest.fixture
def rig(tmp_path: Path) -> Iterator[Rig]:
    (tmp_path / "tools.toml").write_text(TOOLS)
    # A low flange speed cap: the shaper then uses the tables' low-speed stages, where the light tool's
    # limits are above the maximum payload's.
    with running_rig(tmp_path, tools_file=tmp_path / "tools.toml", flange_speed_cap=250.0) as r:
        yield r


def brisk_moves(rig: Rig, h: dict[str, str]) -> None:
    """Joint targets out and back at full speed: the shaper uses the light tool's limits (above the
    maximum payload's)."""
    home = rig.state()["q_cmd"][:6]
    for joints in ([40.0, -20.0, 20.0, 30.0, -30.0, 60.0], home):
        rig.post("/api/target", h, json={"joints": joints, "speed_scale": 1.0})
        rig.wait(lambda s, q=joints: s["at_rest"] and np.abs(np.subtract(s["q_cmd"][:6], q)).max() < 0.01,
                 15.0, f"at rest at {joints}")


def ended_log(rig: Rig, h: dict[str, str]) -> Path:
    rig.end_and_wait(h)
    rig.latest_log()
    return rig.var_dir / "download.srvlog"


def test_a_light_tools_log_is_checked_at_its_payload(rig: Rig, capsys: pytest.CaptureFixture[str]) -> None:
    h = rig.streaming("payload")
    brisk_moves(rig, h)
    # The controller (at 1 kg) took every command (warnings near its limits aside).
    assert [c for c in rig.sim_alarms() if c not in WARNINGS] == []
    path = ended_log(rig, h)
    code, out, err = run_cli(capsys, str(path))
    assert code == 0, out + err  # (judged at the maximum payload: a false MOTN-611)
    assert read_session_log(path).header["payload_kg"] == 1.0
    assert "OK: no violation" in out
    assert "limit tables at payload 1 kg as streamed, tool 'light'" in out  # which tables, and why
    # Against the maximum payload's tables the same commands are too brisk: the payload mattered.
    code, out, err = run_cli(capsys, str(path), "--payload", "7")
    assert code == 1 and ("MOTN-610" in out or "MOTN-611" in out), out
    assert "streamed at payload 1 kg; checking at --payload 7 kg" in err


def test_the_mcap_export_of_a_light_tools_log_has_no_false_alarm(rig: Rig, tmp_path: Path) -> None:
    """`servo-app export` judges with the same checker: at the payload the log records, its
    /diagnostics and /limit_usage are what the controller saw (no alarm), the heavy tool's tables
    aside."""
    h = rig.lease("payload")
    rig.http.put("/api/tool", json={"name": "heavy"}, headers=h).raise_for_status()
    h = rig.streaming("payload")
    rig.wait_at_rest_settled(10.0)
    rig.http.put("/api/tool", json={"name": "light"}, headers=h).raise_for_status()  # a payload record
    brisk_moves(rig, h)
    assert [c for c in rig.sim_alarms() if c not in WARNINGS] == []
    src = ended_log(rig, h)
    out = tmp_path / "light.mcap"
    assert export_mcap(src, out).alarms == []
    by_topic: dict[str, list[Any]] = {}
    with open(out, "rb") as f:
        for _, channel, _, decoded in make_reader(f, decoder_factories=[DecoderFactory()]).iter_decoded_messages():
            by_topic.setdefault(channel.topic, []).append(decoded)
    peak = max(max(m.jerk_pct) for m in by_topic["/limit_usage"])
    assert 50.0 < peak <= 100.0, peak  # (in % of the light tool's limits: above 100 at 7 kg's)


def test_a_tool_change_mid_log_changes_the_tables_from_there(rig: Rig, capsys: pytest.CaptureFixture[str]) -> None:
    """Heavy first (the header's payload), then the light tool at rest within the same stream: the
    light tool's brisk moves are judged at 1 kg, as the controller judged them."""
    h = rig.lease("payload")
    rig.http.put("/api/tool", json={"name": "heavy"}, headers=h).raise_for_status()
    h = rig.streaming("payload")
    rig.wait_at_rest_settled(10.0)
    rig.http.put("/api/tool", json={"name": "light"}, headers=h).raise_for_status()
    brisk_moves(rig, h)
    assert [c for c in rig.sim_alarms() if c not in WARNINGS] == []
    path = ended_log(rig, h)
    log = read_session_log(path)
    assert log.header["payload_kg"] == 7.0 and log.header["tool"] == "heavy"
    assert [kg for _, kg in log.payload_changes()] == [1.0]
    code, out, err = run_cli(capsys, str(path))
    assert code == 0, out + err
    assert "changed by tool changes to payload 1 kg from command" in out


def test_a_log_without_the_payload_is_judged_at_the_maximum_with_a_note(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """A log written before the payload was recorded: the maximum payload, and a note saying how to
    give the tool's."""
    path = tmp_path / "old.srvlog"
    w = SessionLogWriter(path, {"model": "lrmate200id", "interval_ms": 8.0, "protocol": "fanuc-j519-v1"})
    for i in range(5):
        w.command(i * 0.008, i + 1, int(i == 4), 1, 0, 0.0, [0.0] * 6)
    w.close()
    code, out, err = run_cli(capsys, str(path))
    assert code == 0
    assert "the maximum payload, 7 kg (the log does not record its payload)" in out
    assert "does not record the payload" in err and "--payload KG" in err


def _scaled(tables: LimitTables, factor: float) -> LimitTables:
    """Every acceleration and jerk stage times ``factor``: a controller whose own tables differ from the
    profile's."""
    def axis(t: AxisTable) -> AxisTable:
        return AxisTable(tuple(v * factor for v in t.no_payload), tuple(v * factor for v in t.max_payload))

    vel, acc, jerk = tables.tables
    return replace(tables, tables=(vel, tuple(axis(t) for t in acc), tuple(axis(t) for t in jerk)))


def test_a_log_is_checked_against_the_controllers_own_tables(tmp_path: Path,
                                                             capsys: pytest.CaptureFixture[str]) -> None:
    """A controller that publishes tables 1.4 times the profile's: the stream moves at them, the log
    records them, and check and export judge against them (against the profile's: false MOTN-610/611)."""
    loose = _scaled(default_tables(load_profile("lrmate200id")), 1.4)
    with running_rig(tmp_path, sim_options={"tables": loose}) as rig:
        h = rig.streaming("tables")
        assert rig.state()["tables_from_controller"]
        brisk_moves(rig, h)
        assert [c for c in rig.sim_alarms() if c not in WARNINGS] == []
        path = ended_log(rig, h)
    code, out, err = run_cli(capsys, str(path))
    assert code == 0, out + err
    assert "the controller's tables, as streamed" in out
    assert export_mcap(path, tmp_path / "loose.mcap").alarms == []


def test_a_refused_tool_change_leaves_the_logged_tool_as_it_was(rig: Rig) -> None:
    """A tool change the servo process refuses (the arm moves: PUT /api/tool refuses it before, so it is
    sent to the process directly, as a change racing a motion reaches it), then a request that is
    taken: the next log's header still names the tool that is active."""
    h = rig.streaming("payload")
    rig.post("/api/target", h, {"joints": [40.0, -20.0, 20.0, 30.0, -30.0, 60.0], "speed_scale": 0.2})
    rig.wait(lambda s: not s["at_rest"], 5.0, "moving")
    with pytest.raises(CommandRejected, match="tool change refused"):
        rig.service.request(msg.SetTool("heavy", (0.0, 0.0, 100.0, 0.0, 0.0, 0.0), 7.0))
    rig.post("/api/session/stop", h)  # a request that is taken
    rig.wait(lambda s: s["state"] == "stopped" and s["at_rest"], 15.0, "stopped")
    ended_log(rig, h)
    h = rig.streaming("payload")
    path = ended_log(rig, h)
    header = read_session_log(path).header
    assert (header["tool"], header["payload_kg"]) == ("light", 1.0), header
