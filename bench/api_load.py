"""Does API load reach the servo cycle? Status-to-command latency with and without it.

The service (servo process and simulator each in a process of their own) and the API (uvicorn on
loopback) run here, as in `servo-app run`. Two streams of ``--seconds`` each, with the same motion
(joint jogs renewed at 50 Hz, direction flipping every 2 s), so the servo process does the same work:

1. no API load: the jogs go straight into the service (the servo pipe), the API sits idle;
2. API load: the jogs come over HTTP (hold-to-run renewals at 50 Hz) and two WebSocket telemetry
   clients read the state at 30 Hz each, all from a client process of their own.

Latency comes from each stream's session log (``latency_us`` of every command). Prints a table and
writes its section of bench/RESULTS.md with the command line.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import uvicorn

from servo_app.api.app import create_app
from servo_app.messages import End, Jog, Start
from servo_app.service import ServiceConfig, ServoService

sys.path.insert(0, str(Path(__file__).parent))
from results import command_line, write_section
from stream_latency import HEADER, closed_log, latency_row, wait_for

TOKEN = "bench-api-load"
JOG_HZ = 50.0

# The API clients, in a process of their own: a jog client at 50 Hz and two telemetry readers.
CLIENTS = """
import json, sys, threading, time
import httpx, websockets.sync.client
port, token, seconds, hz = int(sys.argv[1]), sys.argv[2], float(sys.argv[3]), float(sys.argv[4])
auth = {"Authorization": "Bearer " + token}
stop, counts = threading.Event(), [0, 0]
def telemetry(i):
    with websockets.sync.client.connect(f"ws://127.0.0.1:{port}/ws/telemetry?hz=30") as ws:
        while not stop.is_set():
            json.loads(ws.recv(timeout=5))
            counts[i] += 1
readers = [threading.Thread(target=telemetry, args=(i,)) for i in range(2)]
for t in readers:
    t.start()
n = refused = 0
t0 = time.monotonic()
with httpx.Client(base_url=f"http://127.0.0.1:{port}", timeout=10.0) as c:
    r = c.post("/api/lease", json={"client": "bench", "force": True}, headers=auth)
    h = {**auth, "X-Lease-Id": r.json()["lease_id"]}
    while (elapsed := time.monotonic() - t0) < seconds:
        if n % 100 == 99:
            c.post("/api/lease/renew", headers=h)
        sign = 1.0 if int(elapsed / 2) % 2 == 0 else -1.0
        r = c.post("/api/jog", json={"joints": [20.0 * sign, 0, 0, 0, 0, 15.0 * sign], "hold_ms": 200}, headers=h)
        n += 1
        refused += r.status_code != 200
        time.sleep(max(0.0, t0 + n / hz - time.monotonic()))
took = time.monotonic() - t0
stop.set()
for t in readers:
    t.join(5)
print(json.dumps({"jog_hz": n / took, "refused": refused, "telemetry_hz": [k / took for k in counts]}))
"""


def jog_direct(service: ServoService, seconds: float) -> str:
    t0, n = time.monotonic(), 0
    while (elapsed := time.monotonic() - t0) < seconds:
        sign = 1.0 if int(elapsed / 2) % 2 == 0 else -1.0
        service.request(Jog(joints=(20.0 * sign, 0, 0, 0, 0, 15.0 * sign), hold_s=0.2))
        n += 1
        time.sleep(max(0.0, t0 + n / JOG_HZ - time.monotonic()))
    return f"no API load: jogs at {n / (time.monotonic() - t0):.0f} Hz into the service directly"


def jog_over_api(port: int, seconds: float) -> str:
    run = subprocess.run([sys.executable, "-c", CLIENTS, str(port), TOKEN, str(seconds), str(JOG_HZ)],
                         capture_output=True, text=True, timeout=seconds + 60)
    if run.returncode != 0:
        raise RuntimeError(run.stderr)
    r = json.loads(run.stdout)
    t1, t2 = r["telemetry_hz"]
    return (f"API load: HTTP jogs at {r['jog_hz']:.0f} Hz ({r['refused']} refused), WS telemetry "
            f"{t1:.0f} Hz + {t2:.0f} Hz")


def jog_with_zenoh(app: object, service: ServoService, seconds: float) -> str:
    """The direct jogs while the Zenoh interface publishes at 50 Hz to a subscriber in this process
    (the cell's API process work: state reads, CDR, Zenoh I/O)."""
    import socket

    from servo_app.ros.messages import JOINT_STATE
    from servo_app.zenoh_api import ZenohInterface, ZenohSettings, ros_key

    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        endpoint = f"tcp/127.0.0.1:{sock.getsockname()[1]}"
    iface = ZenohInterface(app.state.api, ZenohSettings(cell="bench", listen=[endpoint])).start()  # type: ignore[attr-defined]
    received = [0]
    sub = iface.session.declare_subscriber(ros_key(0, "/bench/joint_states", JOINT_STATE),  # type: ignore[union-attr]
                                           lambda _: received.__setitem__(0, received[0] + 1))
    try:
        jog_direct(service, seconds)
    finally:
        sub.undeclare()
        iface.close()
    return f"direct jogs, Zenoh publishing ({received[0] / seconds:.0f} joint states/s received)"


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--seconds", type=float, default=60.0, help="streaming time per case (default 60)")
    p.add_argument("--interval-ms", type=int, choices=(4, 8), default=4)
    p.add_argument("--lead", type=int, default=ServiceConfig.lead)
    p.add_argument("--zenoh", action="store_true",
                   help="a third row: direct jogs while the Zenoh interface publishes (needs eclipse-zenoh)")
    p.add_argument("--no-write", action="store_true", help="print only; leave bench/RESULTS.md as it is")
    args = p.parse_args(argv)

    rows: list[str] = []
    with tempfile.TemporaryDirectory() as tmp:
        service = ServoService(ServiceConfig(var_dir=Path(tmp), interval_ms=args.interval_ms, lead=args.lead))
        service.open()
        app = create_app(service, TOKEN)
        server = uvicorn.Server(uvicorn.Config(app, host="127.0.0.1", port=0,
                                               log_level="warning", ws="websockets-sansio"))
        thread = threading.Thread(target=server.run, daemon=True)
        thread.start()
        try:
            while not server.started:
                time.sleep(0.01)
            port = int(server.servers[0].sockets[0].getsockname()[1])
            # zenoh before api: the api row's lease would expire during it and stop the arm
            for case in ("direct", *(("zenoh",) if args.zenoh else ()), "api"):
                service.request(Start())
                wait_for(service, lambda s: s["state"] == "streaming", 15.0)
                if case == "zenoh":
                    what = jog_with_zenoh(app, service, args.seconds)
                else:
                    what = (jog_direct(service, args.seconds) if case == "direct"
                            else jog_over_api(port, args.seconds))
                wait_for(service, lambda s: s["state"] == "stopped", 10.0)  # the last hold ran out
                service.request(End())
                wait_for(service, lambda s: s["state"] in ("ended", "fault"), 30.0)
                rows.append(latency_row(what, closed_log(service), args.lead))
            alarms = [e["code"] for e in service.sim_call("events")]
        finally:
            server.should_exit = True
            thread.join(10)
            service.close()

    print(HEADER)
    print("\n".join(rows))
    print(f"simulator alarms: {alarms or 'none'}")
    text = (
        f"Service and API as in `servo-app run` (servo process and simulator each in their own process), "
        f"{args.interval_ms} ms, lead {args.lead}; the same joint jogs at {JOG_HZ:g} Hz in both rows, the API "
        f"clients in a process of their own. Latency = status receipt to command send, from each stream's "
        f"session log.\n\n{HEADER}\n|---|---|---|---|---|---|---|---|---|---|\n" + "\n".join(rows)
        + f"\n\nSimulator alarms: {', '.join(alarms) or 'none'}."
    )
    if not args.no_write:
        cmd = command_line(__file__, argv)
        print("wrote", write_section("api_load", cmd, text))
    return 0 if not alarms else 1


if __name__ == "__main__":
    sys.exit(main())
