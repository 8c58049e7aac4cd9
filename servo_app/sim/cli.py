"""``servo-app sim fanuc|janome``: run a controller simulator standalone until Ctrl-C or SIGTERM."""

from __future__ import annotations

import argparse
import math
import signal
import sys
from typing import Any

from servo_app.cli_args import port_arg
from servo_app.fanuc.packets import ROBOT_PORT
from servo_app.stop_signals import signal_event, stop_requested


def _joints(text: str) -> list[float]:
    """``--joints``: J1..J6 in FANUC deg, comma-separated; all six, finite (three or eleven given were
    taken as they came: the missing ones 0, the extra ones dropped)."""
    parts = text.split(",")
    try:
        values = [float(v) for v in parts]
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r}: expected 6 numbers J1..J6 (FANUC deg), comma-separated, "
                                         "e.g. 0,0,0,0,-90,0") from None
    if len(values) != 6:
        raise argparse.ArgumentTypeError(f"{text!r} has {len(values)} values: give all 6, J1..J6 (FANUC deg), "
                                         "e.g. 0,0,0,0,-90,0")
    bad = next((i for i, v in enumerate(values) if not math.isfinite(v)), None)
    if bad is not None:
        raise argparse.ArgumentTypeError(f"J{bad + 1}={parts[bad].strip()} is not a finite number")
    return values


def add_sim_parser(sub: Any) -> argparse.ArgumentParser:
    """Register ``sim`` on the ``servo-app`` subparsers."""
    p = sub.add_parser("sim", help="run a controller simulator (FANUC J519 over UDP)")
    kinds = p.add_subparsers(dest="sim_kind", required=True)

    f = kinds.add_parser("fanuc", help="FANUC Stream Motion (J519) controller simulator")
    f.add_argument("--host", default="127.0.0.1", help="address to bind (default 127.0.0.1)")
    f.add_argument("--port", type=port_arg("UDP", zero_ok=True), default=ROBOT_PORT,
                   help=f"UDP port (default {ROBOT_PORT}; 0: any)")
    f.add_argument("--model", default="lrmate200id", help="robot profile name or TOML path")
    f.add_argument("--interval-ms", type=int, choices=(4, 8), default=None,
                   help="communication interval (default: the profile's)")
    f.add_argument("--pkt-stack", type=int, default=10, help="$PKT_STACK, 2..10 (default 10)")
    f.add_argument("--start-move", type=int, default=1, help="$START_MOVE (default 1)")
    f.add_argument("--payload", type=float, default=None, help="payload kg (default: maximum payload)")
    f.add_argument("--joints", type=_joints, default=None, help="initial joints J1..J6, FANUC deg, comma-separated")
    f.add_argument("--no-cartesian", action="store_true",
                   help="model a robot without Cartesian format (MOTN-619 for data format 0)")
    f.add_argument("--strict-first-seq", action="store_true",
                   help="take a stream's first command only as the answer to the latest status (MOTN-600 "
                        "otherwise), as a strict controller does; default: the latest or the one before")
    f.add_argument("--jitter-ms", type=float, default=0.0, help="tick jitter +- ms (1 at 8 ms: 6-10 ms)")
    f.add_argument("--drop", type=float, default=0.0, help="status packet drop probability")
    f.add_argument("--seed", type=int, default=0, help="fault injection RNG seed")
    f.set_defaults(handler=_run_fanuc)

    from servo_app.sim.janome_sim import add_janome_sim_parser

    add_janome_sim_parser(kinds)
    return p


def _run_fanuc(args: argparse.Namespace) -> int:
    from servo_app.robots.profile import ProfileError, load_profile
    from servo_app.sim.fanuc_model import ControllerConfig
    from servo_app.sim.fanuc_server import FanucSimulator, FaultConfig

    try:
        profile = load_profile(args.model)
        if args.payload is not None and not 0.0 < args.payload <= profile.max_payload_kg:
            # (the controller's limit tables are made for 0..the maximum: none hold beyond)
            raise ValueError(f"--payload={args.payload:g} kg is outside the {profile.display_name}'s payloads: "
                             f"above 0 and at most {profile.max_payload_kg:g} kg")
        config = ControllerConfig(pkt_stack=args.pkt_stack, start_move=args.start_move,
                                  payload_kg=args.payload, cartesian_supported=not args.no_cartesian,
                                  strict_first_seq=args.strict_first_seq)
        faults = FaultConfig(drop_prob=args.drop, jitter_s=args.jitter_ms / 1000.0, seed=args.seed)
        sim = FanucSimulator(args.host, args.port, profile, args.interval_ms, config=config,
                             faults=faults, initial_joints=args.joints)
    except (ValueError, ProfileError) as exc:
        print(f"servo-app sim fanuc: {exc}", file=sys.stderr)
        return 2
    with stop_requested() as stop:
        try:
            sim.start()
        except OSError as exc:
            print(f"servo-app sim fanuc: cannot bind {args.host}:{args.port}: {exc}", file=sys.stderr)
            return 2
        try:
            # SIGUSR1 is the teach pendant's RESET (a real controller's alarm is reset there, never over
            # the network); handled before the address is printed: a SIGUSR1 once it is must not kill it.
            with signal_event(signal.SIGUSR1) as reset:
                host, port = sim.address
                c = sim.controller
                print(f"FANUC J519 simulator ({c.profile.display_name}, {c.interval_ms} ms) listening on "
                      f"udp://{host}:{port}", flush=True)
                print("IBGN start program running and looping; SIGUSR1 resets an alarm (the teach pendant's "
                      "RESET); Ctrl-C to stop", flush=True)
                while not stop.wait(0.05):
                    if reset.is_set():
                        reset.clear()
                        sim.reset()
                        print("RESET (SIGUSR1): alarm cleared", flush=True)
        finally:
            sim.stop()
            s = sim.interval_stats()
            print(f"intervals: {s.count} measured, mean {s.mean_ms:.3f} ms, min {s.min_ms:.3f}, max {s.max_ms:.3f}, "
                  f"p99 {s.p99_ms:.3f}, overruns {s.overruns}", flush=True)
    return 0
