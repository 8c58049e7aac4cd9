"""``servo-app run``: the service (REST/WS API and console) against the embedded simulator or a robot."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

from servo_app.api.auth import resolve_token
from servo_app.service import ServiceConfig, ServoService


def add_run_parser(sub: Any) -> None:
    p = sub.add_parser("run", help="run the service (default: against the embedded FANUC simulator)")
    p.add_argument("--robot", default=None,
                   help="fanuc:HOST[:PORT] of an external controller; default: the embedded simulator")
    p.add_argument("--model", default="lrmate200id", help="robot profile (see `servo-app profiles`)")
    p.add_argument("--host", default="127.0.0.1", help="HTTP interface to listen on")
    p.add_argument("--http-port", type=int, default=8000)
    p.add_argument("--interval-ms", type=int, choices=(4, 8), default=None,
                   help="communication interval; default: the profile's")
    p.add_argument("--lead", type=int, default=0, help="extra commands kept in the controller's buffer (61.4)")
    p.add_argument("--token", default=None, help="API token (else $SERVO_APP_TOKEN, else var/token)")
    p.add_argument("--var-dir", type=Path, default=Path("var"), help="session logs, audit log, token")
    p.add_argument("--payload-kg", type=float, default=None, help="payload for the limit tables")
    p.add_argument("--cors-origin", action="append", default=[], help="allow this origin (CORS closed by default)")
    p.set_defaults(handler=run)


def run(args: argparse.Namespace) -> int:
    import uvicorn

    from servo_app.api.app import create_app

    token, new = resolve_token(args.token, args.var_dir / "token")
    if new:
        print(f"API token (saved in {args.var_dir / 'token'}, shown once): {token}", flush=True)
    service = ServoService(ServiceConfig(robot=args.robot, model=args.model, interval_ms=args.interval_ms,
                                         lead=args.lead, var_dir=args.var_dir, payload_kg=args.payload_kg))
    service.open()
    target = "embedded simulator" if service.sim else args.robot
    print(f"servo_app: {service.profile.display_name} via {target} at "
          f"{service.robot_address[0]}:{service.robot_address[1]}; console http://{args.host}:{args.http_port}",
          flush=True)
    app = create_app(service, token, cors_origins=args.cors_origin or None)
    config = uvicorn.Config(app, host=args.host, port=args.http_port, log_level="warning")
    server = uvicorn.Server(config)
    try:
        server.run()  # returns on SIGINT/SIGTERM
    finally:
        # The servo process got the same signal from the terminal, or gets it now: it decelerates,
        # sends last data and stops the status output before it exits.
        service.close()
    return 0


