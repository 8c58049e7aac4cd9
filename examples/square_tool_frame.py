"""Draw a square in the tool frame: four pose moves along the tool's own X and Y axes, back to the start.

    python examples/square_tool_frame.py --url http://127.0.0.1:8000 --token TOKEN --side 50

The corners are offsets from the current pose in the tool's axes (whatever way the tool points, the
square lies in its XY plane); the orientation stays as it is. At the end it prints how far each
corner the arm settled at is from the corner asked for, as the controller reports the TCP.
"""

from __future__ import annotations

import argparse
import math
import sys

from servo_app.client import ServoClient, ServoError, offset_in_tool


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--url", default="http://127.0.0.1:8000")
    ap.add_argument("--token", default=None, help="the service's bearer token (default: $SERVO_APP_TOKEN)")
    ap.add_argument("--side", type=float, default=50.0, help="side of the square, mm")
    ap.add_argument("--speed", type=float, default=100.0, help="linear speed, mm/s")
    args = ap.parse_args()

    try:
        with ServoClient(args.url, args.token, name="square_tool_frame") as arm:
            arm.ensure_streaming()
            start = arm.wait_settled().pose
            assert start is not None
            s = args.side
            worst = 0.0
            for dx, dy in ((s, 0.0), (s, s), (0.0, s), (0.0, 0.0)):
                corner = offset_in_tool(start, dx, dy)
                arm.move_pose(corner, linear_speed=args.speed)
                reached = arm.wait_settled().pose
                assert reached is not None
                error = math.dist(reached[:3], corner[:3])
                worst = max(worst, error)
                print(f"corner tool ({dx:+.0f}, {dy:+.0f}) mm: world {tuple(round(v, 1) for v in corner[:3])}, "
                      f"off by {error:.2f} mm")
            alarms = [a.code for a in arm.state().alarms]
            print(f"square of {s:g} mm done: worst corner {worst:.2f} mm, alarms {alarms}")
            return 0 if not alarms else 1
    except ServoError as exc:
        print(f"{type(exc).__name__}: {exc}", file=sys.stderr)
        return 1


if __name__ == "__main__":
    sys.exit(main())
