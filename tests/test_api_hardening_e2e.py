"""The API's hardening (issue 14): strict request types, control of the lease, the jog rate limit as
a token bucket, resource limits (body size, telemetry rate, odd names) and the audit of refusals.

The limiter, the lease manager and the audit log are checked alone on injected clocks; everything
else end to end, against one running service (uvicorn on loopback, the servo process streaming to
the embedded simulator over real UDP), as tests/test_api_e2e.py does. Bursts and floods come from a
process of their own: from this one the client shares the GIL with the server's thread and would
itself set the rate.
"""

from __future__ import annotations

import itertools
import json
import statistics
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import httpx
import pytest
import websockets.sync.client
from hypothesis import given, settings
from hypothesis import strategies as st
from test_api_harness import AUTH, Rig, running_rig
from waiting import wait_until
from websockets.exceptions import ConnectionClosed

from servo_app import messages as msg
from servo_app.api.auth import AuditLog, LeaseManager, RateLimiter
from servo_app.api.body_limit import MAX_BODY_BYTES
from servo_app.errors import InvalidRequest

JSON = {"Content-Type": "application/json"}


# ---------------------------------------------------------------------------------- pure parts


def test_jog_limiter_is_a_token_bucket_that_spreads_a_fast_client_evenly() -> None:
    """A client at 500 requests/s gets the rate, one request each 1/rate s: no gap a hold-to-run
    (200 ms) could expire in. (A sliding window let 100 through in 0.2 s and then none for 0.8 s.)"""
    limiter = RateLimiter(100)
    t, admitted = 1000.0, []
    for i in range(1000):  # 2 s at 500/s
        now = t + i * 0.002
        if limiter.allow("127.0.0.1", now):
            admitted.append(now)
    gaps = [b - a for a, b in itertools.pairwise(admitted)]
    assert max(gaps) <= 0.01 + 0.002 + 1e-9, max(gaps)  # the rate's period, at most one request late
    assert 200 <= len(admitted) <= 200 + limiter.burst + 1, len(admitted)
    # Keys are apart; an idle client saves up at most the burst.
    assert limiter.allow("10.0.0.2", t)
    quiet = t + 2.0 + 60.0
    assert sum(limiter.allow("127.0.0.1", quiet) for _ in range(1000)) == limiter.burst
    # Many clients that came and went are forgotten once their buckets are full again; a busy one is not.
    for i in range(5000):
        limiter.allow(f"10.1.{i // 256}.{i % 256}", quiet + 1.0)
    assert len(limiter._buckets) > 4096
    for _ in range(limiter.burst):  # the first of these forgets the 5000, full again by now
        limiter.allow("busy", quiet + 1.999)
    assert limiter.allow("10.9.9.9", quiet + 2.0) and set(limiter._buckets) == {"busy", "10.9.9.9"}


@settings(max_examples=200, deadline=None)
@given(st.lists(st.floats(0.0, 0.05), min_size=1, max_size=400), st.integers(1, 200))
def test_jog_limiter_never_admits_more_than_the_rate_and_the_burst(gaps: list[float], rate: int) -> None:
    """Whatever the arrivals: in any span of t seconds at most burst + rate * t requests get through,
    and a request is refused only when the bucket is empty (a client at or under the rate is never
    refused once its burst is spent evenly)."""
    limiter = RateLimiter(rate)
    t, admitted = 0.0, []
    for g in gaps:
        t += g
        if limiter.allow("k", t):
            admitted.append(t)
    for i, start in enumerate(admitted):
        for j in range(i, len(admitted)):
            assert j - i + 1 <= limiter.burst + rate * (admitted[j] - start) + 1e-6
    calm = RateLimiter(rate)
    assert all(calm.allow("k", i / rate) for i in range(3 * rate))  # exactly at the rate: never refused


def test_lease_manager_hands_a_displaced_or_expired_lease_to_exactly_one_stopper() -> None:
    now = [0.0]
    leases = LeaseManager(ttl_s=1.0, clock=lambda: now[0])
    a, displaced = leases.take("alice")
    assert displaced is None
    with pytest.raises(PermissionError, match=r"force=true"):
        leases.take("bob")
    with pytest.raises(PermissionError, match=r"renew"):
        leases.take("alice")  # the same name with another id (a console reloaded): how to go on
    b, displaced = leases.take("bob", force=True)
    assert displaced is a and leases.pop_expired() is None  # the take-over stops it, not the watch
    with pytest.raises(PermissionError, match=r"'bob'.*nothing released"):
        leases.release(a.lease_id)
    assert leases.current() is b
    now[0] = 2.0  # bob's lease runs out: the watch gets it, once
    assert leases.pop_expired() is b and leases.pop_expired() is None
    now[0] = 4.0
    leases.take("carol", ttl_s=0.5)
    now[0] = 5.0  # carol's ran out, and dave takes control before the watch looked: dave's request stops it
    d, displaced = leases.take("dave")
    assert displaced is not None and displaced.client == "carol" and leases.pop_expired() is None
    assert leases.release(d.lease_id) is d and leases.release("anything") is None


def test_a_hand_over_waits_for_the_old_leases_actions_only_and_refuses_them_from_its_change() -> None:
    """A take-over changes the lease at once (a check after it refuses the old id, naming the new
    holder) and its block (the stop) starts once the old lease's actions admitted before it have
    ended; an expiry's hand-over does not wait for the live lease's actions."""
    leases = LeaseManager(ttl_s=60.0)
    a, _ = leases.take("alice")
    resume = leases.admit(a.lease_id)  # alice's resume: checked, not carried out yet
    stopping = threading.Event()
    granted: list[Any] = []

    def take_over() -> None:
        with leases.handing_over(lambda: leases.take("bob", force=True)) as (b, displaced):
            assert displaced is a
            granted.append(b)
            stopping.set()  # where the take-over's stop runs

    bob = threading.Thread(target=take_over)
    bob.start()
    wait_until(lambda: (held := leases.current()) is not None and held.client == "bob", 5.0)
    with pytest.raises(PermissionError, match=r"held by 'bob'"):
        leases.admit(a.lease_id)  # alice's next request, during the hand-over
    assert not stopping.is_set()  # waits for alice's resume
    leases.done(resume)
    bob.join(5.0)
    assert stopping.is_set() and not bob.is_alive()

    def expire() -> None:
        with leases.handing_over(leases.pop_expired) as lost:
            assert lost is None

    with leases.acting(granted[0].lease_id):  # bob acts; an expiry's hand-over (nothing expired) goes on
        expiry = threading.Thread(target=expire)
        expiry.start()
        expiry.join(5.0)
        assert not expiry.is_alive()


def test_audit_log_rotates_by_size(tmp_path: Path) -> None:
    path = tmp_path / "audit.log"
    log = AuditLog(path, max_bytes=2000, backups=2)
    for i in range(100):
        log.record("127.0.0.1:1", "jog", i % 2 == 0, {"i": i})
    files = [path, path.with_name("audit.log.1"), path.with_name("audit.log.2")]
    assert all(f.is_file() and 0 < f.stat().st_size <= 2000 for f in files)
    assert not path.with_name("audit.log.3").exists()
    newest = [json.loads(x)["detail"]["i"] for f in reversed(files) for x in f.read_text().splitlines()]
    assert newest == list(range(100 - len(newest), 100))  # the newest lines, in order, none lost in between
    # A new log on the same file goes on from its size.
    AuditLog(path, max_bytes=2000, backups=2).record("c", "x", True)
    assert path.stat().st_size <= 2000


# ------------------------------------------------------------------------------- end to end


@pytest.fixture(scope="module")
def rig(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Rig]:
    with running_rig(tmp_path_factory.mktemp("hardening")) as r:
        yield r
        assert r.sim_alarms() == [], r.sim_alarms()


def audit_lines(rig: Rig) -> list[dict[str, Any]]:
    return [json.loads(x) for x in (rig.var_dir / "audit.log").read_text().splitlines()]


def lease_lost_stops(s: dict[str, Any]) -> int:
    return sum(n for why, n in s["stops_by_reason"].items() if why.startswith("control lease lost"))


@pytest.mark.e2e
@pytest.mark.timeout(120)
def test_request_types_are_strict_and_a_refusal_changes_nothing(rig: Rig) -> None:
    h = rig.streaming("strict")
    stops = dict(rig.state()["stops_by_reason"])
    refused = [
        ("/api/session/stop", {"fast": "1"}, "fast"),  # once made a fast stop
        ("/api/session/stop", {"fast": 1}, "fast"),
        ("/api/jog", {"joints": [0, 0, 0, 0, 0, "1"]}, "joints"),
        ("/api/jog", {"joints": [0, 0, 0, 0, 0, True]}, "joints"),
        ("/api/jog", {"joints": [0, 0, 0, 0, 0, 1], "hold_ms": "200"}, "hold_ms"),
        ("/api/jog", {"linear": ["1", 0, 0]}, "linear"),
        ("/api/target", {"joints": [0, 0, 0, 0, 0, 0], "speed_scale": "0.5"}, "speed_scale"),
        ("/api/io", {"type": "DO", "index": True, "value": 1}, "index"),
        ("/api/io", {"type": "DO", "index": 1, "value": "1"}, "value"),
        ("/api/lease", {"client": "x", "force": "true"}, "force"),
        ("/api/lease", {"client": "x", "ttl_s": "5"}, "ttl_s"),
        ("/api/lease", {"client": "x", "ttl_s": 1e-6, "force": True}, "ttl_s"),  # took the lease, gone at once
        ("/api/lease", {"client": 5}, "client"),
        # The trajectory upload parses its own body (up to 2 MiB, in a worker thread): as strict.
        ("/api/trajectory", {"joints": [["5", 0, 0, 0, -90, 0]]}, "joints"),  # once replayed to J1 = 5
        ("/api/trajectory", {"joints": [[True, 0, 0, 0, -90, 0]]}, "joints"),
        ("/api/trajectory", {"joints": [[0, 0, 0, 0, -90, 0]], "times": [True]}, "times"),
        ("/api/trajectory", {"joints": [[0, 0, 0, 0, -90, 0]], "speed_scale": "0.5"}, "speed_scale"),
    ]
    for path, body, field in refused:
        r = rig.http.post(path, json=body, headers=h)
        assert r.status_code == 422, (path, body, r.status_code, r.text)
        assert any(field in e["loc"] for e in r.json()["detail"]), (path, r.json())
    s = rig.state()
    assert s["state"] == "streaming" and s["stops_by_reason"] == stops, s["stops_by_reason"]
    assert rig.http.get("/api/lease").json()["client"] == "strict"
    # The errors for NaN and unknown keys stay as clear as before; an integer is a number.
    r = rig.http.post("/api/jog", content=b'{"joints": [NaN, 0, 0, 0, 0, 0]}', headers={**h, **JSON})
    assert r.status_code == 422 and "joints[0]=nan" in r.text
    r = rig.http.post("/api/jog", json={"joints": [0] * 6, "hold": 1}, headers=h)
    assert r.status_code == 422 and r.json()["detail"][0]["type"] == "extra_forbidden"
    # A target's errors are its own model's alone: a bad pose is not also a joint target missing "joints".
    for body, field, value in (({"xyzwpr": [400.0, 0.0, 300.0, 180.0, 0.0, 0.0], "angular_speed": 500}, "angular_speed",
                                500), ({"joints": [0, 0, 0, 0, -90, 0], "speed_scale": 2}, "speed_scale", 2)):
        r = rig.http.post("/api/target", json=body, headers=h)
        errors = r.json()["detail"]
        assert r.status_code == 422 and [(e["loc"][-1], e["input"]) for e in errors] == [(field, value)], r.text
    assert rig.http.post("/api/jog", json={"joints": [0, 0, 0, 0, 0, 1], "hold_ms": 100}, headers=h).status_code == 200
    # The schema refusals of motion routes are in the audit log (as 409s and 429s are).
    mine = [x for x in audit_lines(rig) if x["action"] == "POST /api/session/stop" and not x["ok"]]
    assert mine and mine[-1]["detail"]["status"] == 422 and mine[-1]["detail"]["errors"][0]["loc"][-1] == "fast"


@pytest.mark.e2e
@pytest.mark.timeout(120)
def test_a_speed_too_small_to_end_a_move_is_refused_and_the_servo_process_lives_on(rig: Rig) -> None:
    """A pose target at 5e-324 mm/s (a subnormal: above 0) was accepted, reached the shaper as a
    speed of 0, raised inside the cycle and ended the servo process. Every way in now refuses a
    speed below the floor by its own values (422 naming the field), the servo process too, and a
    move at the floor itself is taken."""
    h = rig.streaming("slow")
    pid, starts = rig.service.stream.pid, rig.state()["servo_starts"]  # type: ignore[union-attr]
    pose = [round(v, 3) for v in rig.state()["cart_servo"]]
    q = [round(v, 3) for v in rig.state()["q_cmd"]]
    refused = [
        ("/api/target", {"xyzwpr": pose, "linear_speed": 5e-324, "angular_speed": 30}, "linear_speed"),
        ("/api/target", {"xyzwpr": pose, "linear_speed": 100, "angular_speed": 5e-324}, "angular_speed"),
        ("/api/target", {"xyzwpr": pose, "linear_speed": 0.09}, "linear_speed"),
        ("/api/target", {"joints": q, "speed_scale": 5e-324}, "speed_scale"),
        ("/api/target", {"joints": q, "speed_scale": 1e-12}, "speed_scale"),
        ("/api/trajectory", {"joints": [q], "speed_scale": 5e-324}, "speed_scale"),
    ]
    for path, body, field in refused:
        r = rig.http.post(path, json=body, headers=h)
        assert r.status_code == 422, (path, body, r.status_code, r.text)
        assert any(field in e["loc"] for e in r.json()["detail"]), (path, r.json())
    # The servo process checks them itself (another client of its pipe: Zenoh, a plug-in).
    for req in (msg.PoseTarget(xyzwpr=tuple(pose), linear_speed=5e-324),
                msg.JointTarget(joints=tuple(q), speed_scale=5e-324)):
        with pytest.raises(InvalidRequest, match="speed"):
            rig.service.request(req)
    s = rig.state()
    assert s["state"] == "streaming" and s["fault"] is None and s["servo_starts"] == starts, s
    assert rig.service.stream.pid == pid  # type: ignore[union-attr]
    # At the floor: taken, and it moves.
    q_to = [q[0] + 0.05, *q[1:]]
    rig.post("/api/target", h, json={"joints": q_to, "speed_scale": 0.001})
    rig.wait(lambda s: s["q_cmd"][0] > q[0] + 0.001, timeout=10, what="J1 moving at the floor speed")
    rig.post("/api/session/stop", h)
    rig.wait_state("stopped")
    rig.post("/api/session/resume", h)
    rig.wait_state("streaming")


@pytest.mark.e2e
@pytest.mark.timeout(120)
def test_ending_the_session_needs_the_lease_and_stopping_does_not(rig: Rig) -> None:
    h = rig.streaming("owner")
    for headers in (AUTH, {**AUTH, "X-Lease-Id": "forged"}):
        r = rig.http.post("/api/session/end", headers=headers)
        assert r.status_code == 409, r.text
        assert "'owner'" in r.json()["detail"] and "POST /api/lease" in r.json()["detail"]
    assert rig.state()["state"] == "streaming"
    rig.post("/api/session/stop", AUTH)  # any signed-in client may stop the arm
    rig.wait_state("stopped")
    rig.post("/api/session/resume", h)
    rig.wait_state("streaming")


@pytest.mark.e2e
@pytest.mark.timeout(120)
def test_releasing_someone_elses_lease_is_refused(rig: Rig) -> None:
    a = rig.lease("alice")
    for headers in ({**AUTH, "X-Lease-Id": "forged"}, AUTH):
        r = rig.http.request("DELETE", "/api/lease", headers=headers)
        assert r.status_code == 409, r.text
        assert "'alice'" in r.json()["detail"] and "force=true" in r.json()["detail"]
    assert rig.http.get("/api/lease").json()["client"] == "alice"
    assert rig.http.post("/api/lease/renew", headers=a).status_code == 200
    # Refusals of a lease say what to do next, to the holder's own name too.
    r = rig.http.post("/api/lease", json={"client": "alice"}, headers=AUTH)
    assert r.status_code == 409 and "renew" in r.json()["detail"] and "force=true" in r.json()["detail"]
    r = rig.http.post("/api/lease", json={"client": "bob"}, headers=AUTH)
    assert r.status_code == 409 and "force=true" in r.json()["detail"]
    r = rig.http.post("/api/session/resume", headers={**AUTH, "X-Lease-Id": "forged"})
    assert r.status_code == 409 and "force=true" in r.json()["detail"]
    assert rig.http.request("DELETE", "/api/lease", headers=a).status_code == 200
    assert rig.http.get("/api/lease").json()["held"] is False


@pytest.mark.e2e
@pytest.mark.timeout(120)
def test_a_take_over_stops_the_old_motion_before_the_new_holders_first_jog(rig: Rig) -> None:
    a = rig.streaming("alice")
    s = rig.state()
    goal = list(s["q_cmd"])
    goal[0] += -30.0 if goal[0] > 0 else 30.0
    rig.post("/api/target", a, {"joints": goal, "speed_scale": 0.1})
    s = rig.wait(lambda s: abs(s["vel"][0]) > 1.0, 5.0, "alice's target moving")
    lost = lease_lost_stops(s)
    b = rig.lease("bob", force=True)
    # Bob's first jog, sent the moment he has control, is not taken into alice's motion: it has
    # been stopped already (a watch polling every 50 ms used to stop it after the jog, and bob's too).
    r = rig.http.post("/api/jog", json={"joints": [0, 0, 0, 0, 0, 5.0]}, headers=b)
    assert r.status_code == 409, f"bob's first jog was accepted into alice's motion: {r.text}"
    s = rig.state()
    assert s["state"] in ("stopping", "stopped") and s["stop_reason"] == "control lease lost (alice)", s
    assert lease_lost_stops(s) == lost + 1
    s = rig.wait_state("stopped")
    assert abs(s["q_cmd"][0] - goal[0]) > 1.0  # alice's target was cut short
    rig.post("/api/session/resume", b)  # bob goes on (the interrupted target continues)
    s = rig.wait(lambda s: s["at_rest"] and abs(s["q_cmd"][0] - goal[0]) < 1e-3, 30.0, "the target reached")
    assert s["state"] == "streaming" and lease_lost_stops(s) == lost + 1  # no second, late stop


@pytest.mark.e2e
@pytest.mark.timeout(120)
@pytest.mark.parametrize("late", ["resume", "target"])
def test_the_old_holders_motion_let_through_just_before_a_take_over_does_not_outlast_it(tmp_path: Path,
                                                                                         late: str) -> None:
    """Alice's resume (her stop having cut a target short) or target (her jog's hold having run out, which
    a target resumes by itself) passed its lease check, then bob took control over before it reached the
    servo process: the take-over's stop found the arm stopped and had nothing to stop, and alice's request
    then moved the arm under bob's lease, bob never having asked. Now a take-over waits for the old
    holder's requests let through before it, so its stop comes after them; one of alice's checked during
    the hand-over is refused, naming bob. The interleaving is driven on a real service: alice's request to
    the servo process is held at a gate until bob's take-over has finished (the old order) or waits for
    it (the new)."""
    with running_rig(tmp_path) as rig:
        a = rig.streaming("alice")
        goal = list(rig.state()["q_cmd"])
        goal[0] += -30.0 if goal[0] > 0 else 30.0
        target = {"joints": goal, "speed_scale": 0.1}
        if late == "resume":
            rig.post("/api/target", a, target)
            rig.wait(lambda s: abs(s["vel"][0]) > 1.0, 5.0, "alice's target moving")
            rig.post("/api/session/stop", a)
            why, path, body, gated = "stop requested", "/api/session/resume", None, msg.Resume
        else:
            rig.post("/api/jog", a, {"joints": [5.0, 0, 0, 0, 0, 0], "hold_ms": 100})
            why, path, body, gated = "hold-to-run expired", "/api/target", target, msg.JointTarget
        s = rig.wait(lambda s: s["state"] == "stopped" and s["at_rest"], 5.0, "alice's arm stopped")
        assert s["stop_reason"] == why, s
        lost = lease_lost_stops(s)
        real = rig.service.request
        at_gate, go = threading.Event(), threading.Event()

        def gate(message: msg.Request, *args: Any, **kw: Any) -> Any:
            if isinstance(message, gated):  # alice's request, between its lease check and the servo process
                at_gate.set()
                assert go.wait(15.0), "the gate was never opened"
            return real(message, *args, **kw)

        answers: dict[str, httpx.Response] = {}

        def post(who: str, url: str, headers: dict[str, str], json: Any) -> None:
            with httpx.Client(base_url=rig.base_url, timeout=20.0) as c:
                answers[who] = c.post(url, json=json, headers=headers)

        rig.service.request = gate  # type: ignore[method-assign]
        alice = threading.Thread(target=post, args=("alice", path, a, body))
        bob = threading.Thread(target=post, args=("bob", "/api/lease", AUTH, {"client": "bob", "force": True}))
        try:
            alice.start()
            assert at_gate.wait(10.0), "alice's request never reached the servo process"
            bob.start()
            # Bob's take-over ran, or waits for alice's request (its thread in LeaseManager.handing_over).
            wait_until(lambda: not bob.is_alive() or _waits_in("handing_over"), 10.0)
            again = rig.http.post(path, json=body, headers=a)  # alice again: checked after the take-over
            assert again.status_code == 409 and "held by 'bob'" in again.text, again.text
            go.set()
            alice.join(20.0)
            bob.join(20.0)
        finally:
            go.set()
            rig.service.request = real  # type: ignore[method-assign]
        assert answers["bob"].status_code == 200, answers["bob"].text
        assert answers["alice"].status_code in (200, 409), answers["alice"].text
        assert rig.http.get("/api/lease").json()["client"] == "bob"
        # Whatever alice was told, the take-over's stop came last: the arm is stopped for the lost lease
        # (before: streaming, moving to alice's goal under bob's lease).
        s = rig.state()
        assert s["state"] in ("stopping", "stopped") and s["stop_reason"] == "control lease lost (alice)", \
            (s["state"], s["stop_reason"])
        assert lease_lost_stops(s) == lost + 1
        s = rig.wait(lambda s: s["state"] == "stopped" and s["at_rest"], 5.0, "stopped at rest")
        assert abs(s["q_cmd"][0] - goal[0]) > 1.0  # alice's goal not reached
        assert rig.sim_alarms() == [], rig.sim_alarms()


def _waits_in(function: str) -> bool:
    """Some thread's stack holds ``function``'s frame."""
    for frame in sys._current_frames().values():
        f: Any = frame
        while f is not None:
            if f.f_code.co_name == function:
                return True
            f = f.f_back
    return False


BURST = """
import asyncio, json, sys, time
from urllib.parse import urlsplit
import httpx
base, headers, seconds, rate = sys.argv[1], json.loads(sys.argv[2]), float(sys.argv[3]), float(sys.argv[4])
url = urlsplit(base)
body = json.dumps({"joints": [0, 0, 0, 0, 0, 5.0], "hold_ms": 400}).encode()
# Requests written by hand on a few kept-alive connections: an HTTP client library spends more
# CPU per request than this machine's share gives a process at 500 requests/s.
head = "".join(f"{k}: {v}\\r\\n" for k, v in {**headers, "Host": url.netloc, "Content-Type": "application/json",
                                              "Content-Length": str(len(body))}.items())
REQUEST = f"POST /api/jog HTTP/1.1\\r\\n{head}\\r\\n".encode() + body
WORKERS = 8

async def worker(k, t0, codes):
    reader, writer = await asyncio.open_connection(url.hostname, url.port)
    i = k
    while i / rate < seconds:  # request i leaves at t0 + i / rate
        await asyncio.sleep(max(0.0, t0 + i / rate - time.monotonic()))
        writer.write(REQUEST)
        status = int((await reader.readline()).split()[1])
        length = 0
        while (line := await reader.readline()) not in (b"\\r\\n", b""):
            name, _, value = line.decode().partition(":")
            if name.lower() == "content-length":
                length = int(value)
        await reader.readexactly(length)
        codes.append(status)
        i += WORKERS
    writer.close()

async def main():
    codes, states = [], []
    done = asyncio.Event()
    async with httpx.AsyncClient(base_url=base, timeout=10.0) as watcher:
        async def watch():  # the state through the burst, on a connection of its own
            while not done.is_set():
                s = (await watcher.get("/api/state")).json()
                states.append([s["state"], s["stops_by_reason"].get("hold-to-run expired", 0)])
                await asyncio.sleep(0.05)

        w = asyncio.create_task(watch())
        t0 = time.monotonic()
        await asyncio.gather(*(worker(k, t0, codes) for k in range(WORKERS)))
        elapsed = time.monotonic() - t0
        s = (await watcher.get("/api/state")).json()  # within the last jog's hold
        done.set()
        await w
    states.append([s["state"], s["stops_by_reason"].get("hold-to-run expired", 0)])
    print(json.dumps({"codes": codes, "elapsed": elapsed, "states": states}))

asyncio.run(main())
"""


@pytest.mark.e2e
@pytest.mark.timeout(120)
def test_holding_a_jog_at_500_requests_per_s_never_stops_the_arm(rig: Rig) -> None:
    h = rig.streaming("holder")
    before = rig.state()["stops_by_reason"].get("hold-to-run expired", 0)
    run = subprocess.run([sys.executable, "-c", BURST, rig.base_url, json.dumps(h), "2.0", "500"],
                         capture_output=True, text=True, timeout=90)
    assert run.returncode == 0, run.stderr
    out = json.loads(run.stdout)
    codes = out["codes"]
    ok, limited = codes.count(200), codes.count(429)
    print(f"{len(codes)} jogs in {out['elapsed']:.2f} s: {ok} ok, {limited} limited; states {out['states'][:3]}...")
    assert ok + limited == len(codes), set(codes)
    assert ok > 0 and limited > 0
    assert ok <= 100 * (out["elapsed"] + 1)  # the rate, and a burst of at most a second's worth
    # The arm streamed the whole time: no hold-to-run stop between the accepted jogs.
    assert {st for st, _ in out["states"]} == {"streaming"}, out["states"]
    assert all(n == before for _, n in out["states"]), (before, out["states"])
    rig.wait(lambda s: s["state"] == "stopped" and s["at_rest"], 5.0, "the hold-to-run stop after the last jog")


FLOOD = """
import json, sys, time
import httpx
base, seconds, size = sys.argv[1], float(sys.argv[2]), int(sys.argv[3])
body = b"[" + b"0," * (size // 2) + b"0]"
codes = []
t0 = time.monotonic()
with httpx.Client(base_url=base, timeout=10.0) as c:
    while time.monotonic() - t0 < seconds:
        try:
            codes.append(c.post("/api/jog", content=body, headers={"Content-Type": "application/json"}).status_code)
        except httpx.TransportError:  # the server closes rather than read 10 MB: the write fails
            codes.append(0)
print(json.dumps(codes))
"""


@pytest.mark.e2e
@pytest.mark.timeout(120)
def test_big_bodies_are_refused_before_authentication_and_parsing(rig: Rig) -> None:
    h = rig.streaming("bodies")
    big = b'{"joints": [' + b"0," * 100_000 + b"0]}"  # 200 KB: the 2-million-element array's little sibling
    assert len(big) > MAX_BODY_BYTES
    for headers in (h, {}, {"Authorization": "Bearer wrong"}):
        t0 = time.perf_counter()
        r = rig.http.post("/api/jog", content=big, headers={**headers, **JSON})
        took = time.perf_counter() - t0
        assert r.status_code == 413, (headers, r.status_code, r.text[:200])
        assert str(MAX_BODY_BYTES) in r.json()["detail"] and took < 0.5, took
    # Without a Content-Length (chunked), counted as it arrives.
    chunks = iter([big[i:i + 8192] for i in range(0, len(big), 8192)])
    r = rig.http.post("/api/jog", content=chunks, headers={**h, **JSON})
    assert r.status_code == 413 and r.request.headers.get("transfer-encoding") == "chunked", r.text[:200]
    assert rig.state()["state"] == "streaming"
    # The refusals on motion routes are in the audit log.
    refused = [x for x in audit_lines(rig) if x["action"] == "POST /api/jog" and not x["ok"]
               and isinstance(x["detail"], dict) and x["detail"].get("status") == 413]
    assert len(refused) >= 4
    # 10 MB bodies without a token from another process: /api/health stays fast meanwhile.
    flood = subprocess.Popen([sys.executable, "-c", FLOOD, rig.base_url, "3.0", str(10_000_000)],
                             stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        latencies = []
        while flood.poll() is None:
            t0 = time.perf_counter()
            assert rig.http.get("/api/health").status_code == 200
            latencies.append(time.perf_counter() - t0)
            time.sleep(0.02)
        out, err = flood.communicate(timeout=30)
    finally:
        flood.kill()
    assert flood.returncode == 0, err
    codes = json.loads(out)
    print(f"{len(codes)} 10 MB bodies ({codes.count(413)} answered 413); /api/health: median "
          f"{statistics.median(latencies) * 1e3:.1f} ms, max {max(latencies) * 1e3:.1f} ms over {len(latencies)}")
    assert len(codes) >= 5 and set(codes) <= {413, 0}
    assert max(latencies) < 0.3, max(latencies)


@pytest.mark.e2e
@pytest.mark.timeout(60)
def test_odd_session_log_names_are_not_found(rig: Rig) -> None:
    for name in ("%00.srvlog", "a%00b.srvlog", "x" * 300 + ".srvlog", "..%2F..%2Fetc%2Fpasswd"):
        r = rig.http.get(f"/api/sessions/{name}")
        assert r.status_code == 404, (name, r.status_code, r.text)
        if "%2F" not in name:  # (a "/" in the name: no such route at all)
            assert "GET /api/sessions" in r.json()["detail"], r.text


@pytest.mark.e2e
@pytest.mark.parametrize("path", ["/api/jog", "/api/target", "/api/session/stop", "/api/lease", "/api/io"])
def test_a_body_that_is_not_text_is_422_naming_it(rig: Rig, path: str) -> None:
    h = rig.lease("bytes")
    r = rig.http.post(path, content=b'{"joints": [1, \xff\xfe]}', headers={**h, "Content-Type": "application/json"})
    assert r.status_code == 422, r.text  # FastAPI's own answer: 400 "There was an error parsing the body"
    assert "not UTF-8" in r.json()["detail"][0]["msg"], r.text


@pytest.mark.e2e
@pytest.mark.parametrize("path", ["/api/jog", "/api/target", "/api/trajectory", "/api/lease", "/api/io"])
@pytest.mark.parametrize("body", [b'{"joints": ' + b"[" * 5000 + b"]" * 5000 + b"}", b"[" * 60_000],
                         ids=["nested-5000", "open-60000"])
def test_a_body_nested_too_deep_to_parse_is_422_naming_it_and_changes_nothing(rig: Rig, path: str,
                                                                              body: bytes) -> None:
    """JSON's parser recurses: thousands of brackets raised RecursionError, which the trajectory upload
    answered with a 500 and every other route with a bare 400 "There was an error parsing the body"."""
    h = rig.lease("deep")
    before = rig.wait(lambda s: s["at_rest"], what="at rest (an earlier test's jog, or the take-over's stop)")
    r = rig.http.post(path, content=body, headers={**h, **JSON})
    assert r.status_code == 422, r.text[:300]
    assert r.json()["detail"][0]["msg"].startswith("the body nests lists or objects"), r.text[:300]
    after = rig.state()
    assert (after["state"], after["q_cmd"], after["stops_by_reason"]) == (
        before["state"], before["q_cmd"], before["stops_by_reason"])
    assert rig.http.get("/api/lease").json()["client"] == "deep"


NO_BODY_ROUTES = [("POST", "/api/session/start"), ("POST", "/api/session/resume"), ("POST", "/api/session/end"),
                  ("POST", "/api/reset"), ("POST", "/api/lease/renew"), ("DELETE", "/api/lease"),
                  ("POST", "/api/points/nobody"), ("DELETE", "/api/points/nobody")]


@pytest.mark.e2e
@pytest.mark.timeout(90)
def test_a_route_that_takes_no_body_refuses_one_and_changes_nothing(rig: Rig) -> None:
    """``POST /api/session/end`` with ``{"fast": NaN}`` ended the stream, ``/api/session/start`` with a
    broken body started one: a body there is a mistake (meant for another route, or malformed), refused
    before anything happens. No body, ``{}`` and ``null`` are still none."""
    h = rig.streaming("nobody")
    before = rig.wait(lambda s: s["at_rest"], what="at rest")
    points = rig.http.get("/api/points").json()
    for method, path in NO_BODY_ROUTES:
        for body in (b'{"fast": NaN}', b'{"linear": [1, 0, 0', b"fast=true"):
            r = rig.http.request(method, path, content=body, headers={**h, **JSON})
            assert r.status_code == 422, (method, path, body, r.status_code, r.text)
            assert f"{method} {path} takes no body" in r.json()["detail"][0]["msg"], r.text
    after = rig.state()
    assert (after["state"], after["q_cmd"], after["stops_by_reason"]) == (
        before["state"], before["q_cmd"], before["stops_by_reason"])
    assert rig.http.get("/api/lease").json()["client"] == "nobody"
    assert rig.http.get("/api/points").json() == points
    for body in (b"", b"{}", b"null"):  # none, as clients send it
        r = rig.http.post("/api/lease/renew", content=body, headers={**h, **JSON})
        assert r.status_code == 200, (body, r.text)
    rig.post("/api/session/end", h, json={})
    rig.wait_state("ended")


@pytest.mark.e2e
@pytest.mark.timeout(60)
def test_an_io_read_mask_out_of_range_is_422_whatever_the_state(rig: Rig) -> None:
    """The mask is the request's own value: checked first, not after "only while streaming" (409)."""
    h = rig.lease("io")
    if rig.state()["state"] != "ended" and rig.state()["link"] == "streaming":
        rig.post("/api/session/end", h)
        rig.wait_state("ended")
    for mask in (70000, -1):
        r = rig.http.get("/api/io", params={"type": "DO", "index": 1, "mask": mask}, headers=AUTH)
        assert r.status_code == 422 and r.json()["detail"][0]["loc"] == ["query", "mask"], r.text
    r = rig.http.get("/api/io", params={"type": "DO", "index": 1, "mask": 1}, headers=AUTH)
    assert r.status_code == 409 and "only while streaming" in r.text, r.text  # a good mask: the state's turn


@pytest.mark.e2e
@pytest.mark.timeout(60)
def test_a_refusal_echoes_a_huge_input_cut_short_and_a_bad_csv_says_what_to_send(rig: Rig) -> None:
    """The trajectory upload takes 2 MiB: a 1.5 MB junk field came back whole in its 422."""
    h = rig.lease("echo")
    r = rig.http.post("/api/trajectory", json={"joints": [[0, 0, 0, 0, -90, 0]], "junk": "x" * 1_500_000}, headers=h)
    assert r.status_code == 422 and len(r.content) < 2000, (r.status_code, len(r.content))
    error = r.json()["detail"][0]
    assert error["loc"] == ["body", "junk"] and error["input"].endswith("(1500002 characters in all)"), error
    csv = {**h, "Content-Type": "text/csv"}
    r = rig.http.post("/api/trajectory", content=b"a,b,c\n", headers=csv)
    assert r.status_code == 422 and r.json()["detail"].startswith("csv: no data rows; send rows of 6 numbers"), r.text
    r = rig.http.post("/api/trajectory", content=b"0,0,0,0,-90,0\n1,2,x,4,5,6\n", headers=csv)
    assert r.status_code == 422 and r.json()["detail"] == "csv line 2: not a number in '1,2,x,4,5,6'", r.text


@pytest.mark.e2e
@pytest.mark.timeout(90)
def test_the_log_of_a_running_stream_downloads_whole_as_far_as_written(rig: Rig) -> None:
    """A session log grows while it is sent (a record every few ms): each download is the file as it
    was when asked, with a Content-Length that matches (a file response read on to the end)."""
    h = rig.streaming("downloader")
    name = rig.http.get("/api/sessions").json()[0]["name"]
    rig.wait(lambda s: rig.http.get("/api/sessions").json()[0]["bytes"] > 150_000, 60.0, "a log over 150 kB")
    sizes = []
    for _ in range(20):
        r = rig.http.get(f"/api/sessions/{name}")  # raises on a broken response
        assert r.status_code == 200 and len(r.content) == int(r.headers["content-length"]), r.headers
        sizes.append(len(r.content))
    assert sizes == sorted(sizes) and sizes[-1] > sizes[0], sizes  # it grew meanwhile, and each was whole
    rig.post("/api/session/stop", h)


@pytest.mark.e2e
@pytest.mark.timeout(60)
@pytest.mark.parametrize("hz", ["nan", "inf", "-inf", "0", "-5", "0.5", "1000", "1e308"])
def test_telemetry_refuses_a_rate_outside_1_to_100(rig: Rig, hz: str) -> None:
    with websockets.sync.client.connect(f"{rig.ws_url}/ws/telemetry?hz={hz}") as ws, \
            pytest.raises(ConnectionClosed) as closed:
        ws.recv(timeout=5)
    assert closed.value.rcvd is not None and closed.value.rcvd.code == 1008
    assert closed.value.rcvd.reason.startswith("hz=") and "1..100" in closed.value.rcvd.reason


@pytest.mark.e2e
@pytest.mark.timeout(60)
@pytest.mark.parametrize("query", ["hz=abc", "hz=", "hz=50&hz=abc", "hz=" + "a" * 300, "hz=" + "%E2%82%AC" * 60])
def test_telemetry_refuses_a_rate_that_is_no_number_with_a_reason(rig: Rig, query: str) -> None:
    """It was a bare HTTP 403 before the handshake (FastAPI's own refusal), with no reason to read. A
    long value made the reason longer than a close frame carries (123 bytes): the close failed, and
    the socket ended with no code and no reason."""
    with websockets.sync.client.connect(f"{rig.ws_url}/ws/telemetry?{query}") as ws, \
            pytest.raises(ConnectionClosed) as closed:
        ws.recv(timeout=5)
    assert closed.value.rcvd is not None and closed.value.rcvd.code == 1008
    assert "is not a number of messages per second" in closed.value.rcvd.reason, closed.value.rcvd.reason
    assert closed.value.rcvd.reason.endswith("connect with e.g. ?hz=50"), closed.value.rcvd.reason


@pytest.mark.e2e
@pytest.mark.timeout(60)
def test_telemetry_at_an_allowed_rate_still_flows(rig: Rig) -> None:
    with websockets.sync.client.connect(f"{rig.ws_url}/ws/telemetry?hz=100") as ws:
        assert "state" in json.loads(ws.recv(timeout=5))
        assert "state" in json.loads(ws.recv(timeout=5))


# ------------------------------------------------------------------------------ offline docs


@pytest.mark.e2e
@pytest.mark.slow
@pytest.mark.timeout(180)
def test_docs_render_offline_in_chromium(rig: Rig) -> None:
    """Swagger UI lists the operations with every request that leaves the machine blocked (its files,
    favicon included, come from the service)."""
    sync_api = pytest.importorskip("playwright.sync_api", reason="playwright is not installed (pip install -e .[test])")
    from test_web_console import CHROMIUM, CHROMIUM_ARGS, _chromium_or_reason

    reason = _chromium_or_reason()
    if reason:
        pytest.skip(reason)
    blocked: list[str] = []

    def only_loopback(route: Any) -> None:
        url = route.request.url
        if url.startswith((f"{rig.base_url}/", "data:", "blob:")):
            route.continue_()
        else:
            blocked.append(url)
            route.abort()

    with sync_api.sync_playwright() as pw:
        browser = pw.chromium.launch(executable_path=str(CHROMIUM), headless=True, args=CHROMIUM_ARGS)
        try:
            page = browser.new_page()
            page.route("**/*", only_loopback)
            page.goto(f"{rig.base_url}/docs")
            page.wait_for_selector(".opblock", timeout=30_000)
            summaries = page.locator(".opblock-summary-path").all_inner_texts()
            assert "/api/session/end" in summaries and "/api/lease" in summaries and len(summaries) >= 15
            assert page.locator(".opblock-summary-description", has_text="End the stream").count() == 1
        finally:
            browser.close()
    assert blocked == [], blocked
    assert rig.http.get("/docs-assets/favicon.png").status_code == 200
