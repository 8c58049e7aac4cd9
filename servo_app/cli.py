"""The ``servo-app`` command.

Subcommands:
  run                      the service (REST/WS API, console) against the embedded simulator or a robot
  sim fanuc|janome         a controller simulator, standalone
  check FILE [--model M]   validate a trajectory or session log as the controller would
  export FILE --mcap OUT   a session log as MCAP with ROS 2 types (Foxglove)
  monitor                  one live line per cell on the Zenoh network
  profiles                 list the robot profiles found (FANUC and Janome)
"""

from __future__ import annotations

import argparse
import importlib
import sys
from collections.abc import Callable, Sequence

from servo_app.cli_args import port_arg

Handler = Callable[[argparse.Namespace], int]


def _cmd_profiles(args: argparse.Namespace) -> int:
    from servo_app.janome.profile import available_janome_profiles, load_janome_profile
    from servo_app.robots.profile import ProfileError, available_profiles, load_profile

    print("FANUC (servo-app run --robot fanuc[:HOST[:PORT]] --model NAME)")
    for name in available_profiles():
        p = load_profile(name)
        print(f"  {name:16s} {p.display_name:34s} interval {p.interval_ms} ms  payload {p.max_payload_kg:g} kg")
    print("Janome (servo-app run --robot janome[:HOST[:PORT]] --model NAME)")
    for name in available_janome_profiles():
        try:
            j = load_janome_profile(name)
        except ProfileError as exc:  # one broken file must not hide the others
            print(f"  {name:16s} invalid: {exc}")
            continue
        strokes = "  ".join(f"{ax} {lo:g}..{hi:g}" for ax, lo, hi in zip("XYZR", j.axis_min, j.axis_max, strict=True))
        print(f"  {name:16s} {j.display_name:34s} {j.kind.name.lower():9s}  {strokes}")
    return 0


def _cmd_export(args: argparse.Namespace) -> int:
    from servo_app.mcap_export import run_export  # mcap and rosbags load in 0.2 s: only when asked

    return run_export(args)


def _cmd_monitor(args: argparse.Namespace) -> int:
    from servo_app.monitor import run_monitor  # zenoh loads only when asked

    return run_monitor(args)


# The subcommands whose parsers live in their own modules, in --help's order: (module, function adding
# the parser). Importing them all cost every command the service's imports (servo_app.run and
# servo_app.service, the differential IK with mink and scipy): `servo-app check` of a missing file took
# 4.8 s here under load, 2.3 s with its own module alone.
_SUBCOMMANDS = {
    "sim": ("servo_app.sim.cli", "add_sim_parser"),
    "run": ("servo_app.run", "add_run_parser"),
    "check": ("servo_app.check_cli", "add_check_parser"),
    "replay": ("servo_app.replay_cli", "add_replay_parser"),
}
_OWN = ("export", "monitor", "profiles")  # defined below, importing their modules only when run


def build_parser(command: str | None = None) -> argparse.ArgumentParser:
    """The whole parser, or with ``command`` (a subcommand's name) that subcommand's: of the modules in
    _SUBCOMMANDS, its own alone is imported (the cheap parsers of _OWN are always there)."""
    parser = argparse.ArgumentParser(prog="servo-app", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = parser.add_subparsers(dest="command", required=True)
    for name, (module, add_parser) in _SUBCOMMANDS.items():
        if command is None or command == name:
            getattr(importlib.import_module(module), add_parser)(sub)

    p = sub.add_parser("export", help="convert a session log (.srvlog) to MCAP with ROS 2 types (Foxglove)")
    p.add_argument("file", help="a session log written by `servo-app run` (var/sessions/*.srvlog)")
    p.add_argument("--mcap", required=True, metavar="OUT", help="the MCAP file to write")
    p.add_argument("--model", help="robot model (default: the log header's)")
    p.set_defaults(handler=_cmd_export)

    p = sub.add_parser("monitor", help="one live line per cell on the Zenoh network (servo-app run --zenoh)")
    p.add_argument("--connect", action="append", default=[], metavar="ENDPOINT",
                   help="a Zenoh router or peer, e.g. tcp/localhost:7447 (repeatable)")
    p.add_argument("--listen", action="append", default=[], metavar="ENDPOINT")
    p.add_argument("--config", default=None, help="a Zenoh JSON5 configuration")
    p.add_argument("--multicast", action="store_true", help="find peers by multicast scouting")
    p.add_argument("--http-port", type=port_arg("TCP", zero_ok=True), default=None,
                   help="also serve the lines as one web page on this port (0: any free port)")
    p.add_argument("--seconds", type=float, default=None,
                   help="stop after this long (default: until Ctrl-C; with --once, 3 s)")
    p.add_argument("--once", action="store_true",
                   help="print the table once after --seconds (default 3 s), not live, and exit")
    p.set_defaults(handler=_cmd_monitor)

    p = sub.add_parser("profiles", help="list robot profiles")
    p.set_defaults(handler=_cmd_profiles)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    # The first word that is no option names the subcommand (servo-app itself has no option but -h).
    first = next((a for a in argv if not a.startswith("-")), None)
    args = build_parser(first if first in (*_SUBCOMMANDS, *_OWN) else None).parse_args(argv)
    handler: Handler = args.handler
    return handler(args)


if __name__ == "__main__":
    sys.exit(main())
