"""Log the telemetry to a CSV file: one row per message, joints, pose and flags.

    python examples/telemetry_csv.py --url http://127.0.0.1:8000 --token TOKEN --hz 50 --seconds 10 --out log.csv

Read only: it takes no control lease, so it runs beside whoever moves the arm.
"""

from __future__ import annotations

import argparse
import csv
import sys
import time

from servo_app.client import ServoClient, ServoError

JOINTS = [f"q{i}" for i in range(1, 7)]
POSE = ["x", "y", "z", "w", "p", "r"]


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--url", default="http://127.0.0.1:8000")
    ap.add_argument("--token", default=None, help="the service's bearer token (default: $SERVO_APP_TOKEN)")
    ap.add_argument("--hz", type=float, default=50.0, help="messages per second (1..100)")
    ap.add_argument("--seconds", type=float, default=10.0)
    ap.add_argument("--out", default="telemetry.csv")
    args = ap.parse_args()

    client = ServoClient(args.url, args.token)
    rows = 0
    try:
        with open(args.out, "w", newline="") as f:
            out = csv.writer(f)
            out.writerow(["published_unix", "state", "link", "at_rest", "settled", *JOINTS, *POSE])
            end = time.monotonic() + args.seconds
            for s in client.telemetry(hz=args.hz):
                joints = list(s.joints or ())[:6]
                pose = list(s.pose or ())[:6]
                out.writerow([s.published_unix, s.state, s.link, int(s.at_rest), int(s.settled),
                              *(joints + [""] * (6 - len(joints))), *(pose + [""] * (6 - len(pose)))])
                rows += 1
                if time.monotonic() >= end:
                    break
    except ServoError as exc:
        print(f"{type(exc).__name__}: {exc}", file=sys.stderr)
        return 1
    finally:
        client.close()
    print(f"{rows} rows to {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
