"""The ``servo-app`` command.

Subcommands:
  run                      the service (REST/WS API, console) against the embedded simulator or a robot
  sim fanuc|janome         a controller simulator, standalone
  check FILE --model M     validate a trajectory or session log as the controller would
  profiles                 list the robot profiles found
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Callable, Sequence

Handler = Callable[[argparse.Namespace], int]


def _cmd_profiles(args: argparse.Namespace) -> int:
    from servo_app.robots.profile import available_profiles, load_profile

    for name in available_profiles():
        p = load_profile(name)
        print(f"{name:16s} {p.display_name:20s} interval {p.interval_ms} ms  payload {p.max_payload_kg:g} kg")
    return 0


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="servo-app", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = parser.add_subparsers(dest="command", required=True)

    from servo_app.sim.cli import add_sim_parser

    add_sim_parser(sub)

    from servo_app.run import add_run_parser

    add_run_parser(sub)

    from servo_app.check_cli import add_check_parser

    add_check_parser(sub)

    p = sub.add_parser("profiles", help="list robot profiles")
    p.set_defaults(handler=_cmd_profiles)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    handler: Handler = args.handler
    return handler(args)


if __name__ == "__main__":
    sys.exit(main())
