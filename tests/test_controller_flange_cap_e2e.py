"""The flange-speed cap the controller publishes (its limit tables' Vmax, $MAX_SPD) holds when it is
tighter than the configured one, end to end (service, servo process, the embedded controller on
loopback publishing Vmax 300 mm/s where the profile says 4000).

Before: the servo cycle took the configured cap over the controller's (a twist of 280 mm/s, over
the controller's 300 mm/s share of 240 at a configured 1000 mm/s, was taken), and the twist feeds
refused by the configured cap or the profile's $MAX_SPD, never the controller's (a feed sample of
280 mm/s was 'accepted' and then refused by the servo, or taken).
"""

from __future__ import annotations

import time
from dataclasses import replace
from pathlib import Path

import pytest
from test_api_harness import AUTH, running_rig

from servo_app.motion.limit_tables import default_tables
from servo_app.robots.profile import load_profile

pytestmark = [pytest.mark.e2e, pytest.mark.timeout(120)]

MODEL = "lrmate200id"
CONTROLLER_VMAX = 300.0  # the controller's $MAX_SPD, mm/s
SHARE = 0.8 * CONTROLLER_VMAX  # what the servo takes of it (ServoSettings.flange_speed_margin): 240 mm/s


@pytest.mark.parametrize("configured", [None, 1000.0])
def test_a_twist_over_the_controllers_published_cap_is_refused(tmp_path: Path, configured: float | None) -> None:
    tables = replace(default_tables(load_profile(MODEL)), vmax=CONTROLLER_VMAX)
    inputs = tmp_path / "inputs.toml"
    inputs.write_text('[feeds.jog]\nkind = "twist"\nstale_after_s = 0.25\n')
    with running_rig(tmp_path / "var", model=MODEL, inputs_config=inputs, flange_speed_cap=configured,
                     sim_options={"tables": tables}) as rig:
        h = rig.lease()
        s = rig.start_streaming(h)
        assert s["tables_from_controller"], s["tables_from_controller"]
        # The servo: a Cartesian jog under the configured cap's share but over the controller's.
        r = rig.post("/api/jog", h, {"linear": [0.0, 280.0, 0.0], "angular": [0.0, 0.0, 0.0], "frame": "base"},
                     expect=422)
        assert f"above the flange-speed cap {SHARE:.0f} mm/s" in r.json()["detail"], r.text
        rig.post("/api/jog", h, {"linear": [0.0, 200.0, 0.0], "angular": [0.0, 0.0, 0.0], "frame": "base",
                                 "hold_ms": 100})
        # The feed, at its door: 280 mm/s refused naming the controller's share; 200 mm/s taken.
        rig.post("/api/inputs/enable", h, {"enable": True})
        feed = {"kind": "twist", "linear": [0.0, 280.0, 0.0], "frame": "base"}
        r = rig.http.post("/api/feed/jog", json={**feed, "stamp": time.time()}, headers=AUTH)
        assert r.status_code == 422, r.text
        detail = str(r.json()["detail"])
        assert "'linear'" in detail and f"flange-speed cap in force, {SHARE:.0f} mm/s" in detail, detail
        r = rig.http.post("/api/feed/jog", json={**feed, "linear": [0.0, 200.0, 0.0], "stamp": time.time()},
                          headers=AUTH)
        assert r.status_code == 200 and r.json()["accepted"], r.text
        rig.wait(lambda s: s["state"] == "stopped", 5.0, "the feed's jog stale: stopped")
        # No alarm (the controller's warnings, MOTN-614 "close to the jerk limit", stop nothing).
        assert [a["code"] for a in rig.state()["alarms"] if not a["warning"]] == [], rig.state()["alarms"]


PROFILE_VMAX = 4000.0  # lrmate200id's profile $MAX_SPD


@pytest.mark.parametrize(("configured", "before", "after", "source"), [
    (None, PROFILE_VMAX, CONTROLLER_VMAX, "the controller's $MAX_SPD"),
    (1000.0, 1000.0, CONTROLLER_VMAX, "holds the configured flange_speed_cap of 1000 mm/s to it"),
    (200.0, 200.0, 200.0, "the configured flange_speed_cap (below the controller's $MAX_SPD"),
])
def test_limits_and_robot_show_the_flange_cap_in_force(tmp_path: Path, configured: float | None, before: float,
                                                        after: float, source: str) -> None:
    """GET /api/limits and /api/robot give the flange-speed cap the service holds the arm to and
    where it comes from: before a start the configured cap within the profile's $MAX_SPD, after it
    the tighter of the configured cap and the controller's $MAX_SPD; a twist over its share is
    refused naming the same number. Before: both showed the profile's 4000 mm/s whatever held."""
    tables = replace(default_tables(load_profile(MODEL)), vmax=CONTROLLER_VMAX)
    with running_rig(tmp_path / "var", model=MODEL, flange_speed_cap=configured,
                     sim_options={"tables": tables}) as rig:
        shown = {path: rig.http.get(path).json() for path in ("/api/limits", "/api/robot")}
        h = rig.lease()
        rig.start_streaming(h)
        deadline = time.monotonic() + 5.0  # the tables' event reaches the service just after the start
        while rig.http.get("/api/limits").json().get("max_flange_speed_mm_s") != after and time.monotonic() < deadline:
            time.sleep(0.01)
        for path, got in shown.items():
            assert (got.get("max_flange_speed_mm_s"), rig.http.get(path).json().get("max_flange_speed_mm_s")) \
                == (before, after), path
        for path, got in shown.items():
            assert "profile's $MAX_SPD" in got.get("max_flange_speed_source", ""), (path, got)
            now = rig.http.get(path).json()
            assert source in now["max_flange_speed_source"], (path, now["max_flange_speed_source"])
        share = 0.8 * after  # ServoSettings.flange_speed_margin
        r = rig.post("/api/jog", h, {"linear": [0.0, share + 10.0, 0.0], "angular": [0.0, 0.0, 0.0],
                                     "frame": "base"}, expect=422)
        assert f"above the flange-speed cap {share:.0f} mm/s" in r.json()["detail"], r.text
