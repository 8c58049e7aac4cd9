"""``servo-app run``: the service (REST/WS API and console) against the embedded simulator or a robot."""

from __future__ import annotations

import argparse
import gc
import math
import signal
import sys
from pathlib import Path
from typing import Any

from servo_app.api.auth import resolve_token
from servo_app.cli_args import port_arg
from servo_app.fanuc.session import MAX_PKT_STACK
from servo_app.inputs.errors import ConfigError
from servo_app.realtime import make_realtime
from servo_app.robots.profile import ProfileError
from servo_app.robots.tool import ToolError
from servo_app.service import ServiceConfig, ServoService
from servo_app.service.config import servo_stall_error

MAX_LEAD = MAX_PKT_STACK - 2  # the session's own bound (SessionConfig)


def _lead(text: str) -> int:
    """``--lead``: checked here, not by the servo process once started (a traceback naming POST /api/reset)."""
    try:
        lead = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number of commands") from None
    if not 0 <= lead <= MAX_LEAD:
        raise argparse.ArgumentTypeError(f"{lead} is outside 0..{MAX_LEAD} (the controller buffers $PKT_STACK - 1 "
                                         f"commands, $PKT_STACK at most {MAX_PKT_STACK})")
    return lead


def _stall_s(text: str) -> float:
    """``--servo-stall-s``: checked here, not once the service runs (ServiceConfig checks it too)."""
    try:
        value = float(text)
    except ValueError:
        value = math.nan
    if (why := servo_stall_error(value)) is not None:
        raise argparse.ArgumentTypeError(f"{text!r}: {why}")
    return value


def add_run_parser(sub: Any) -> None:
    p = sub.add_parser("run", help="run the service (default: against the embedded FANUC simulator)")
    p.add_argument("--robot", default=None,
                   help="fanuc:HOST[:PORT] of an external controller; default: the embedded simulator")
    p.add_argument("--model", default=None, help="robot profile (see `servo-app profiles`); default: the backend's")
    p.add_argument("--host", default="127.0.0.1", help="HTTP interface to listen on")
    p.add_argument("--http-port", type=port_arg("TCP"), default=8000)
    p.add_argument("--interval-ms", type=int, choices=(4, 8), default=None,
                   help="communication interval; default: the profile's")
    p.add_argument("--lead", type=_lead, default=ServiceConfig.lead,
                   help="extra commands kept in the controller's buffer (61.4); the default 2 rides out two "
                        "lost status packets in a row, 0 alarms (MOTN-603) at the first one")
    p.add_argument("--servo-stall-s", type=_stall_s, default=ServiceConfig.servo_stall_s, metavar="SECONDS",
                   help="a servo process that runs no cycle for this long is stalled: the service names the fault "
                        "and ends it, a reset starts another (docs/faults.md)")
    p.add_argument("--token", default=None, help="API token (else $SERVO_APP_TOKEN, else var/token)")
    p.add_argument("--var-dir", type=Path, default=Path("var"), help="session logs, audit log, token")
    p.add_argument("--payload-kg", type=float, default=None, help="payload for the limit tables")
    p.add_argument("--cors-origin", action="append", default=[], help="allow this origin (CORS closed by default)")
    p.add_argument("--inputs", type=Path, default=None, metavar="FILE",
                   help="inputs TOML: adapters, feeds and [[applications]] (examples in configs/inputs/)")
    p.add_argument("--tools", type=Path, default=None, metavar="FILE",
                   help="tools TOML: [tools.NAME] xyzwpr = [X, Y, Z, W, P, R] (mm, deg from the flange), payload_kg "
                        "(docs/tools.md; example in configs/tools/)")
    p.add_argument("--tool", default=None, metavar="NAME",
                   help="the active tool at start (default: the file's 'active', else the flange)")
    p.add_argument("--mcap", action="store_true",
                   help="also write each session log as MCAP (ROS 2 types, for Foxglove) beside it, live")
    p.add_argument("--zenoh", nargs="?", const="", default=None, metavar="CONFIG",
                   help="also serve the cell on Zenoh: ROS 2 topics as rmw_zenoh names them, plus JSON status "
                        "(docs/zenoh.md); CONFIG: a Zenoh JSON5 configuration (default: peer mode, no multicast)")
    p.add_argument("--cell", default=None, help="the cell's name on Zenoh (default: the host name)")
    p.add_argument("--zenoh-listen", action="append", default=[], metavar="ENDPOINT",
                   help="a Zenoh endpoint to listen on, e.g. tcp/0.0.0.0:7447 (repeatable)")
    p.add_argument("--zenoh-connect", action="append", default=[], metavar="ENDPOINT",
                   help="a Zenoh router or peer to connect to, e.g. tcp/localhost:7447 (repeatable)")
    p.add_argument("--zenoh-mode", choices=("peer", "client"), default="peer")
    p.add_argument("--ros-domain", type=int, default=0, help="ROS_DOMAIN_ID of the ROS 2 key expressions")
    p.add_argument("--zenoh-json", action="store_true",
                   help="also the JSON keys servo_app/CELL/json/... for tools that are not ROS")
    p.add_argument("--api-priority", type=int, default=5,
                   help="SCHED_FIFO priority of the HTTP/WebSocket event loop, below the servo process (20) and the "
                        "embedded simulator (10), so feed samples are handled as they arrive; 0: normal priority")
    p.set_defaults(handler=run)


def run(args: argparse.Namespace) -> int:
    import uvicorn

    from servo_app.api.app import create_app

    try:  # first: the audit log, the token and the session logs go there (a file there was a traceback)
        args.var_dir.mkdir(parents=True, exist_ok=True)
        token, new = resolve_token(args.token, args.var_dir / "token")
    except OSError as exc:  # (a file where the directory should be, no permission, a full disk)
        print(f"servo-app run: --var-dir={str(args.var_dir)!r} cannot be used: {exc}; name a directory this user "
              "can write", file=sys.stderr)
        return 2
    if new:
        print(f"API token (saved in {args.var_dir / 'token'}, shown once): {token}", flush=True)
    # From here until uvicorn installs its own handlers, SIGINT and SIGTERM are recorded, not raised: a
    # KeyboardInterrupt in the middle of start-up left the servo process and its shared memory behind,
    # and a signal absorbed with no effect was lost (the service kept running). The server, once made,
    # exits as soon as it has started. uvicorn re-raises the signal that stopped it, after its shutdown,
    # into these handlers, so the `finally` below still ends the stream before we exit.
    received: list[int] = []
    servers: list[Any] = []

    def on_signal(signum: int, frame: object) -> None:
        received.append(signum)
        for s in servers:
            s.should_exit = True

    if args.zenoh is not None and (why := zenoh_setting_error(args)) is not None:
        print(f"servo_app: {why}", flush=True)
        return 2
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, on_signal)
    try:
        service = ServoService(ServiceConfig(robot=args.robot, model=args.model, interval_ms=args.interval_ms,
                                             lead=args.lead, var_dir=args.var_dir, payload_kg=args.payload_kg,
                                             inputs_config=args.inputs, mcap_live=args.mcap, tools_file=args.tools,
                                             tool=args.tool, servo_stall_s=args.servo_stall_s))
    except (ValueError, ProfileError) as exc:  # --robot, --model: nothing is started yet
        if isinstance(exc, ToolError):
            print(f"servo_app: invalid tools configuration: {exc}", flush=True)
        else:
            print(f"servo-app run: {exc}", file=sys.stderr)
        return 2
    try:
        service.open()
    except ConfigError as exc:  # nothing is started yet: the inputs file is read first
        print(f"servo_app: invalid inputs configuration:\n{exc}", flush=True)
        return 2
    except ToolError as exc:  # the tools file is read before anything starts (open closes what it started)
        print(f"servo_app: invalid tools configuration: {exc}", flush=True)
        return 2
    report_input_failures(service)
    target = "embedded simulator" if service.sim else args.robot
    assert service.robot_address is not None
    print(f"servo_app: {service.profile.display_name} via {target} at "
          f"{service.robot_address[0]}:{service.robot_address[1]}; console http://{args.host}:{args.http_port}",
          flush=True)
    try:
        app = create_app(service, token, cors_origins=args.cors_origin or None)
    except BaseException:  # the stream, the servo process and the simulator end with us, not after
        service.close()
        raise
    try:
        zenoh_iface = start_zenoh(app.state.api, args) if args.zenoh is not None else None
    except Exception as exc:  # zenoh.ZError: an endpoint it cannot listen on, say (the settings were checked)
        from servo_app.zenoh_api import zenoh_words

        service.close()
        print(f"servo_app: cannot open the Zenoh session: {zenoh_words(exc)}", flush=True)
        return 2
    except BaseException:
        service.close()
        raise
    config = uvicorn.Config(app, host=args.host, port=args.http_port, log_level="warning")
    server = uvicorn.Server(config)
    servers.append(server)
    server.should_exit = bool(received)
    # Start-up objects (FastAPI, pydantic, numpy, mujoco: ~100,000) never become garbage: keep them
    # out of the collector's scans. A full collection over them held the GIL for ~60 ms here,
    # stalling every input adapter's thread.
    gc.collect()
    gc.freeze()
    # This thread runs the event loop; threads it starts later (a worker pool) begin at normal priority.
    print(f"servo_app: API event loop {make_realtime(args.api_priority)}", flush=True)
    try:
        server.run()  # returns on SIGINT/SIGTERM
    finally:
        if zenoh_iface is not None:  # no more commands in before the stream ends
            zenoh_iface.close()
        # The servo process decelerates, sends last data and stops the status output before it exits.
        summary = service.close(group_signal_wait_s=0.3 if signal.SIGINT in received else 0.0)
        print(f"servo_app: stopped; stream {summary.get('state')}, link {summary.get('link')}, "
              f"servo process exit code {summary.get('servo_exit_code')}, "
              f"controller alarms {summary.get('alarms', [])}", flush=True)
    return 0 if summary.get("servo_exit_code") == 0 else 1


def zenoh_settings(args: argparse.Namespace) -> Any:
    from servo_app.zenoh_api import ZenohSettings, cell_name

    return ZenohSettings(cell=cell_name(args.cell), domain=args.ros_domain,
                         config_file=Path(args.zenoh) if args.zenoh else None, mode=args.zenoh_mode,
                         listen=args.zenoh_listen, connect=args.zenoh_connect, json=args.zenoh_json)


def zenoh_setting_error(args: argparse.Namespace) -> str | None:
    """Why the Zenoh options cannot be used (naming the option and value), or None: checked before
    anything starts (a bad endpoint was a traceback once the servo process and simulator were up)."""
    from servo_app.zenoh_api import ZenohConfigError, session_config

    try:
        session_config(zenoh_settings(args), {"config": "--zenoh", "listen": "--zenoh-listen",
                                              "connect": "--zenoh-connect"})
    except ZenohConfigError as exc:
        return str(exc)
    return None


def start_zenoh(api: Any, args: argparse.Namespace) -> Any:
    """The Zenoh interface in this (the API) process; never in the servo process."""
    from servo_app.zenoh_api import ZenohInterface

    settings = zenoh_settings(args)
    iface = ZenohInterface(api, settings).start()
    print(f"servo_app: Zenoh cell {settings.cell!r} (ROS domain {settings.domain}): topics /{settings.cell}/..., "
          f"status {iface.json_key('status')}", flush=True)
    return iface


def report_input_failures(service: ServoService, timeout_s: float = 3.0) -> None:
    """On stderr, each input device that could not be opened: which, why and the fix (the console and
    GET /api/inputs show the same). Waits until every adapter has tried once, ``timeout_s`` at most."""
    if service.inputs is None:
        return
    for adapter, failure in service.inputs.wait_first_open(timeout_s):
        print(f"servo_app: input {adapter.name!r} ({adapter.config.type}) cannot be opened: {failure.message} "
              f"[{failure.error}]", file=sys.stderr, flush=True)
