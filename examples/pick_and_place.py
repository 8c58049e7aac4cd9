"""Pick and place between two taught points, closing and opening a gripper on a digital output.

    python examples/pick_and_place.py --url http://127.0.0.1:8000 --token TOKEN --cycles 2 --gripper DO:1

The points are "pick" and "place" (teach them with the console's Points card, or with
``arm.teach("pick")``); with ``--teach-demo`` any that is missing is taught here first, a few
centimetres either side of where the arm stands, so the example runs on a fresh simulator.
Each cycle: above the pick point, down (a joint move to the point as taught), gripper on, up, above
the place point, down, gripper off, up.
"""

from __future__ import annotations

import argparse
import sys

from servo_app.client import Point, ServoClient, ServoError


def above(point: Point, height_mm: float) -> tuple[float, ...]:
    x, y, z, w, p, r = point.pose
    return (x, y, z + height_mm, w, p, r)


def teach_demo_points(arm: ServoClient, names: list[str]) -> None:
    """Teach the missing points beside the current pose: pick 60 mm to one side, place to the other."""
    home = arm.wait_settled().pose
    assert home is not None
    for name, dy in (("pick", -60.0), ("place", 60.0)):
        if name in names:
            continue
        x, y, z, w, p, r = home
        arm.move_pose((x, y + dy, z - 30.0, w, p, r), linear_speed=150.0)
        print(f"taught {name}: {arm.teach(name).pose}")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--url", default="http://127.0.0.1:8000")
    ap.add_argument("--token", default=None, help="the service's bearer token (default: $SERVO_APP_TOKEN)")
    ap.add_argument("--cycles", type=int, default=2)
    ap.add_argument("--gripper", default="DO:1", help="the gripper's output, TYPE:INDEX")
    ap.add_argument("--approach-mm", type=float, default=40.0, help="height above the points to approach from")
    ap.add_argument("--speed", type=float, default=150.0, help="linear speed of the approach moves, mm/s")
    ap.add_argument("--teach-demo", action="store_true", help="teach missing points beside the current pose")
    args = ap.parse_args()
    io_type, io_index = args.gripper.split(":")

    try:
        with ServoClient(args.url, args.token, name="pick_and_place") as arm:
            arm.ensure_streaming()
            names = [p.name for p in arm.points()]
            if args.teach_demo:
                teach_demo_points(arm, names)
            points = {p.name: p for p in arm.points()}
            missing = {"pick", "place"} - set(points)
            if missing:
                print(f"teach {sorted(missing)} first (or run with --teach-demo)", file=sys.stderr)
                return 2
            gripper = (io_type, int(io_index))
            for cycle in range(1, args.cycles + 1):
                for name, grip in (("pick", True), ("place", False)):
                    arm.move_pose(above(points[name], args.approach_mm), linear_speed=args.speed)
                    arm.move_to(name)
                    arm.wait_settled()
                    arm.io_write(*gripper, grip)
                    print(f"cycle {cycle}: at {name}, {args.gripper} {'on' if grip else 'off'}, "
                          f"reads {arm.io_read(*gripper)}")
                    arm.move_pose(above(points[name], args.approach_mm), linear_speed=args.speed)
            alarms = [a.code for a in arm.state().alarms]
            print(f"done: {args.cycles} cycles, alarms {alarms}")
            return 0 if not alarms else 1
    except ServoError as exc:
        print(f"{type(exc).__name__}: {exc}", file=sys.stderr)
        return 1


if __name__ == "__main__":
    sys.exit(main())
