"""``servo-app monitor``: every cell on the Zenoh network (``servo-app run --zenoh``), one live line each.

It subscribes to ``servo_app/*/status`` (JSON, published by each cell at a few Hz and on every
change) and shows the state, the cycle latency p99, the active alarms and whether a lease is held. A
cell silent for ``STALE_S`` is shown as such (its service is gone, or the network is cut). With
``--http-port`` the same lines are served as one web page (and as JSON at ``/cells.json``).
"""

from __future__ import annotations

import argparse
import html
import json
import math
import sys
import threading
import time
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path
from typing import Any

from servo_app.stop_signals import stop_requested
from servo_app.zenoh_api import (
    JSON_ROOT,
    STATUS_SUFFIX,
    ZenohConfigError,
    ZenohSettings,
    session_config,
    zenoh_words,
)

STALE_S = 2.0  # a cell publishes its status at least every 0.2 s
# --once without --seconds: long enough to join the network and hear every cell's status several times
# over (each publishes at least every 0.2 s); it waited for Ctrl-C before, then printed.
ONCE_WINDOW_S = 3.0


class FleetMonitor:
    def __init__(self, settings: ZenohSettings) -> None:
        self.settings = settings
        self._cells: dict[str, tuple[float, dict[str, Any]]] = {}
        self._lock = threading.Lock()
        self._session: Any = None

    def start(self) -> FleetMonitor:
        import zenoh

        zenoh.init_log_from_env_or("error")
        self._session = zenoh.open(session_config(self.settings))
        self._sub = self._session.declare_subscriber(f"{JSON_ROOT}/*/{STATUS_SUFFIX}", self._on_status)
        return self

    def close(self) -> None:
        if self._session is not None:
            self._session.close()
            self._session = None

    def _on_status(self, sample: Any) -> None:
        # Anything may be published on the key: a status that is no JSON object is shown as such (one
        # publisher's bad status took the whole monitor down with a TypeError, or was dropped unseen).
        raw = sample.payload.to_bytes()
        try:
            status = json.loads(raw)
        except ValueError as exc:
            status = {"malformed": f"not JSON ({exc}): {raw[:40]!r}"}
        if not isinstance(status, dict):
            status = {"malformed": f"not a JSON object: {json.dumps(status)[:40]}"}
        cell = str(sample.key_expr).split("/")[1]
        with self._lock:
            self._cells[cell] = (time.monotonic(), status)

    def cells(self) -> dict[str, dict[str, Any]]:
        """Each cell's last status, with ``age_s`` (since it arrived) and ``stale``."""
        now = time.monotonic()
        with self._lock:
            items = list(self._cells.items())
        return {cell: {**status, "age_s": now - t, "stale": now - t > STALE_S} for cell, (t, status) in sorted(items)}

    def lines(self) -> list[str]:
        out = [f"{'CELL':16s} {'STATE':10s} {'P99':>9s}  {'LEASE':14s} ALARMS"]
        for cell, s in self.cells().items():
            if s.get("malformed"):
                out.append(f"{cell:16s} {'silent' if s['stale'] else 'malformed':10s} {'-':>9s}  {'-':14s} "
                           f"status {s['malformed']}")
                continue
            # Each field as published, or '?' when it is not what servo-app run publishes there.
            p99 = s.get("latency_p99_us")
            p99_text = "-" if not p99 else f"{p99 / 1000:.2f} ms" if _finite(p99) else "?"
            state = "silent" if s["stale"] else str(s.get("state"))
            lease = str(s.get("lease_client") or "held") if s.get("lease_held") else "-"
            alarms = s.get("alarms") or []
            alarm_text = " ".join(map(str, alarms)) if isinstance(alarms, list) else "?"
            out.append(f"{cell:16s} {state:10s} {p99_text:>9s}  {lease:14.14s} {alarm_text or '-'}")
        return out


def _finite(value: Any) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)


def _page(monitor: FleetMonitor) -> bytes:
    rows = "\n".join(f"<tr><td>{html.escape(line)}</td></tr>" for line in monitor.lines())
    return (f"<!doctype html><meta charset=utf-8><meta http-equiv=refresh content=1><title>servo_app fleet"
            f"</title><style>td{{font-family:monospace;white-space:pre}}</style><table>{rows}</table>").encode()


def serve_page(monitor: FleetMonitor, port: int) -> ThreadingHTTPServer:
    class Handler(BaseHTTPRequestHandler):
        def do_GET(self) -> None:
            if self.path == "/cells.json":
                body, kind = json.dumps(monitor.cells(), default=str).encode(), "application/json"
            else:
                body, kind = _page(monitor), "text/html; charset=utf-8"
            self.send_response(200)
            self.send_header("Content-Type", kind)
            self.send_header("Content-Length", str(len(body)))
            self.end_headers()
            self.wfile.write(body)

        def log_message(self, *args: Any) -> None:
            pass

    server = ThreadingHTTPServer(("127.0.0.1", port), Handler)
    threading.Thread(target=server.serve_forever, name="monitor http", daemon=True).start()
    return server


def run_monitor(args: argparse.Namespace) -> int:
    settings = ZenohSettings(cell="monitor", config_file=Path(args.config) if args.config else None,
                             listen=args.listen, connect=args.connect, multicast_scouting=args.multicast)
    import zenoh

    try:
        session_config(settings, {"config": "--config", "listen": "--listen", "connect": "--connect"})
        monitor = FleetMonitor(settings).start()
    except ZenohConfigError as exc:
        print(f"servo-app monitor: {exc}", file=sys.stderr)
        return 2
    except zenoh.ZError as exc:  # (an endpoint it cannot listen on, say)
        print(f"servo-app monitor: cannot open the Zenoh session: {zenoh_words(exc)}", file=sys.stderr)
        return 2
    server = serve_page(monitor, args.http_port) if args.http_port is not None else None
    if server is not None:
        print(f"servo_app monitor: http://127.0.0.1:{server.server_address[1]}/", flush=True)
    seconds = ONCE_WINDOW_S if args.seconds is None and args.once else args.seconds
    end = time.monotonic() + seconds if seconds is not None else float("inf")
    live = sys.stdout.isatty() and not args.once
    with stop_requested() as stop:
        try:
            while time.monotonic() < end and not stop.wait(min(0.5, max(0.0, end - time.monotonic()))):
                if live:  # redraw in place
                    sys.stdout.write("\x1b[H\x1b[J" + "\n".join(monitor.lines()) + "\n")
                    sys.stdout.flush()
                elif not args.once:
                    print("\n".join(monitor.lines()), flush=True)
        finally:
            try:
                if args.once:
                    print("\n".join(monitor.lines()), flush=True)
            finally:  # whatever the printing met: a session left open kept the process from exiting
                if server is not None:
                    server.shutdown()
                monitor.close()
    return 0
