"""Valid requests that once made the embedded controller raise an alarm, end to end: uvicorn on
loopback, the servo process streaming to the embedded simulator over real UDP. Each test has a
service of its own, ends the stream, and checks the simulator's alarm list and the session log as
`servo-app check` does."""

from __future__ import annotations

import random
import subprocess
import sys
from pathlib import Path

import pytest
from test_api_harness import Rig, running_rig

pytestmark = [pytest.mark.e2e, pytest.mark.timeout(180)]


def end_alarm_free(rig: Rig, h: dict[str, str]) -> None:
    """End the stream; no alarm on the controller and its session log passes `servo-app check`."""
    s = rig.state()
    assert s["state"] == "streaming", (s["state"], s.get("fault"), s.get("stop_reason"))
    rig.end_and_wait(h)
    assert rig.sim_alarms() == [], rig.sim_alarms()
    rig.latest_log()
    r = subprocess.run([sys.executable, "-m", "servo_app.cli", "check", str(rig.var_dir / "download.srvlog")],
                       capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stdout + r.stderr


def test_joint_targets_replacing_each_other_every_few_ms(tmp_path: Path) -> None:
    # Each new target that turns the motion stops the arm first, checking the stop's path beforehand;
    # from the state of such a stop ruckig's synchronised plan raised (RuckigError, "error in step 2")
    # and killed the servo process (MOTN-608) within a second or two of these.
    rng = random.Random(2)
    with running_rig(tmp_path) as rig:
        h = rig.streaming()
        rig.post("/api/target", h, {"joints": [0.0, 20.0, 0.0, 0.0, -60.0, 0.0]})
        rig.wait(lambda s: s["at_rest"], 10.0, "at rest")
        for _ in range(300):
            q = [rng.uniform(-60, 60), rng.uniform(0, 40), rng.uniform(-20, 20), rng.uniform(-60, 60),
                 rng.uniform(-100, -30), rng.uniform(-90, 90)]
            rig.post("/api/target", h, {"joints": q})  # paced by the round trip alone: a few ms
        rig.wait(lambda s: s["at_rest"], 20.0, "at rest")
        end_alarm_free(rig, h)
