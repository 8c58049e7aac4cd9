"""Session log notes (kind 3: a JSON object split over records) and payload records (kind 2): what is
written reads back, beside the statuses and commands, and a note cut short by a killed process is
left out (real files, the servo process's writer)."""

from __future__ import annotations

import tempfile
from pathlib import Path

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from servo_app.motion.limit_tables import default_tables
from servo_app.robots.profile import load_profile
from servo_app.session_log import (
    RECORD_SIZE,
    SessionLogWriter,
    command_record,
    note_records,
    payload_record,
    read_session_log,
    tables_note,
)

_JSON = st.recursive(st.none() | st.booleans() | st.integers(-2**53, 2**53) | st.text(max_size=30)
                     | st.floats(allow_nan=False, allow_infinity=False),
                     lambda inner: st.lists(inner, max_size=5)
                     | st.dictionaries(st.text(max_size=8), inner, max_size=5),
                     max_leaves=40)


@settings(max_examples=150, deadline=None)
@given(notes=st.lists(st.dictionaries(st.text(max_size=10), _JSON, max_size=6), max_size=4),
       commands=st.integers(0, 5), payload=st.none() | st.floats(0.0, 7.0))
def test_notes_and_payloads_read_back_between_the_commands(notes: list[dict], commands: int,
                                                           payload: float | None) -> None:
    with tempfile.TemporaryDirectory() as d:
        path = Path(d) / "n.srvlog"
        w = SessionLogWriter(path, {"model": "lrmate200id"})
        for i in range(commands):
            w.write_records([command_record(i * 0.008, i + 1, 0, 1, 0, 0.0, [float(i)] * 6)])
        for note in notes:
            w.write_records(note_records(1.0, note))
        w.write_records([payload_record(1.0, 7, payload)])
        w.write_records([command_record(2.0, 99, 1, 1, 0, 0.0, [9.0] * 6)])
        w.close()
        log = read_session_log(path)
    assert log.notes() == [(commands, n) for n in notes]
    # (a payload is a float32 value: 1e-7 of its kg)
    assert log.payload_changes() == [(commands, None if payload is None else float(np.float32(payload)))]
    assert log.commands["seq"].tolist() == [*range(1, commands + 1), 99]
    assert np.all(np.isfinite(log.records["t"]))  # a reader that skips the kinds still reads a time


def test_a_note_cut_short_is_left_out_and_the_tables_round_trip(tmp_path: Path) -> None:
    tables = default_tables(load_profile("lrmate200id"))
    path = tmp_path / "cut.srvlog"
    w = SessionLogWriter(path, {"model": "lrmate200id"})
    w.write_records(note_records(0.0, tables_note(tables)))
    w.write_records(note_records(0.1, {"other": "x" * 200}))
    w.close()
    whole = read_session_log(path).notes()
    assert [sorted(n) for _, n in whole] == [["limit_tables"], ["other"]]
    assert whole[0][1]["limit_tables"]["rows"][1][0] == [list(tables.tables[1][0].no_payload),
                                                          list(tables.tables[1][0].max_payload)]
    data = path.read_bytes()
    path.write_bytes(data[: len(data) - 2 * RECORD_SIZE - 10])  # killed two records and a bit before the end
    assert [sorted(n) for _, n in read_session_log(path).notes()] == [["limit_tables"]]
