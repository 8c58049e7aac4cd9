"""Every example in examples/ run as its own process (``python examples/X.py --url ... --token ...``)
against a running service, as a user would run it; each must finish cleanly with zero alarms."""

from __future__ import annotations

import csv
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import pytest
from test_api_harness import TOKEN, Rig, running_rig

pytestmark = [pytest.mark.e2e, pytest.mark.timeout(180)]

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"


@pytest.fixture(scope="module")
def rig(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Rig]:
    with running_rig(tmp_path_factory.mktemp("examples")) as r:
        yield r


def run_example(rig: Rig, name: str, *args: str) -> str:
    proc = subprocess.run([sys.executable, str(EXAMPLES / name), "--url", rig.base_url, "--token", TOKEN, *args],
                          capture_output=True, text=True, timeout=150)
    assert proc.returncode == 0, f"{name} exited {proc.returncode}:\n{proc.stdout}\n{proc.stderr}"
    return proc.stdout


def test_every_example_is_tested() -> None:
    assert {p.name for p in EXAMPLES.glob("*.py")} == {"pick_and_place.py", "square_tool_frame.py",
                                                        "telemetry_csv.py"}


def test_pick_and_place_between_taught_points_toggles_the_gripper(rig: Rig) -> None:
    out = run_example(rig, "pick_and_place.py", "--cycles", "2", "--gripper", "DO:7", "--teach-demo")
    assert out.count("taught ") == 2
    lines = [ln for ln in out.splitlines() if ln.startswith("cycle ")]
    assert lines == ["cycle 1: at pick, DO:7 on, reads True", "cycle 1: at place, DO:7 off, reads False",
                     "cycle 2: at pick, DO:7 on, reads True", "cycle 2: at place, DO:7 off, reads False"], out
    assert "done: 2 cycles, alarms []" in out
    assert {p["name"] for p in rig.http.get("/api/points").json()} >= {"pick", "place"}
    # Run again: the points are taught now, nothing is taught twice.
    assert "taught " not in run_example(rig, "pick_and_place.py", "--cycles", "1", "--teach-demo")
    assert rig.sim_alarms() == [] and rig.http.get("/api/lease").json()["held"] is False


def test_pick_and_place_without_points_says_to_teach_them(tmp_path: Path) -> None:
    with running_rig(tmp_path) as fresh:
        proc = subprocess.run([sys.executable, str(EXAMPLES / "pick_and_place.py"), "--url", fresh.base_url,
                               "--token", TOKEN], capture_output=True, text=True, timeout=120)
        assert proc.returncode == 2 and "teach ['pick', 'place'] first" in proc.stderr, proc.stderr


def test_the_square_is_drawn_in_the_tool_frame(rig: Rig) -> None:
    out = run_example(rig, "square_tool_frame.py", "--side", "40")
    corners = [ln for ln in out.splitlines() if ln.startswith("corner ")]
    assert len(corners) == 4 and all(float(ln.rsplit("off by ", 1)[1].split()[0]) < 1.0 for ln in corners), out
    assert "alarms []" in out and rig.sim_alarms() == []


def test_telemetry_is_logged_to_csv(rig: Rig, tmp_path: Path) -> None:
    path = tmp_path / "telemetry.csv"
    out = run_example(rig, "telemetry_csv.py", "--hz", "50", "--seconds", "1", "--out", str(path))
    with path.open() as f:
        rows = list(csv.DictReader(f))
    assert out.strip() == f"{len(rows)} rows to {path}"
    assert 20 <= len(rows) <= 80, len(rows)  # about 50 in a second
    times = [float(r["published_unix"]) for r in rows]
    assert times == sorted(times) and times[-1] - times[0] > 0.5
    assert all(r["state"] and r["q5"] and r["x"] for r in rows)
