"""Bearer-token authentication, the control lease, per-client rate limiting and the audit log."""

from __future__ import annotations

import json
import os
import secrets
import threading
import time
from collections import deque
from dataclasses import dataclass
from pathlib import Path
from typing import Any


def resolve_token(configured: str | None, token_file: Path) -> tuple[str, bool]:
    """The API token: configured, else $SERVO_APP_TOKEN, else the saved one, else a new one.

    Returns (token, newly_generated); a new token is saved (mode 0600) so it is printed only once.
    """
    if configured:
        return configured, False
    env = os.environ.get("SERVO_APP_TOKEN")
    if env:
        return env, False
    if token_file.is_file():
        saved = token_file.read_text().strip()
        if saved:
            return saved, False
    token = secrets.token_urlsafe(24)
    token_file.parent.mkdir(parents=True, exist_ok=True)
    fd = os.open(token_file, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
    with os.fdopen(fd, "w") as f:
        f.write(token + "\n")
    return token, True


def token_matches(expected: str, header: str | None) -> bool:
    if not header or not header.startswith("Bearer "):
        return False
    return secrets.compare_digest(header[len("Bearer "):].strip().encode(), expected.encode())


@dataclass
class Lease:
    lease_id: str
    client: str
    expires_at: float
    ttl_s: float


class LeaseManager:
    """One control lease at a time; it expires unless renewed."""

    def __init__(self, ttl_s: float = 10.0, clock: Any = time.monotonic) -> None:
        self.ttl_s = ttl_s
        self._clock = clock
        self._lease: Lease | None = None
        self._lock = threading.Lock()

    def current(self) -> Lease | None:
        with self._lock:
            if self._lease and self._clock() > self._lease.expires_at:
                self._lease = None
            return self._lease

    def acquire(self, client: str, force: bool = False, ttl_s: float | None = None) -> Lease:
        """A new lease; ``ttl_s`` may shorten the manager's TTL for this lease, never lengthen it."""
        ttl = self.ttl_s if ttl_s is None else min(float(ttl_s), self.ttl_s)
        with self._lock:
            now = self._clock()
            held = self._lease
            if held and now <= held.expires_at and not force:
                raise PermissionError(f"control is held by '{held.client}' for {held.expires_at - now:.1f} s more")
            self._lease = Lease(secrets.token_urlsafe(12), client, now + ttl, ttl)
            return self._lease

    def renew(self, lease_id: str | None) -> Lease:
        with self._lock:
            held = self._lease
            if not held or held.lease_id != lease_id or self._clock() > held.expires_at:
                raise PermissionError("this client does not hold the control lease (it may have expired)")
            held.expires_at = self._clock() + held.ttl_s
            return held

    def check(self, lease_id: str | None) -> Lease:
        lease = self.current()
        if lease is None:
            raise PermissionError("nobody holds the control lease: acquire it first (POST /api/lease)")
        if lease.lease_id != lease_id:
            raise PermissionError(f"control is held by '{lease.client}': this request has no valid X-Lease-Id")
        return lease

    def release(self, lease_id: str | None) -> None:
        with self._lock:
            if self._lease and self._lease.lease_id == lease_id:
                self._lease = None


class RateLimiter:
    """Sliding one-second window per key."""

    def __init__(self, per_second: int) -> None:
        self.per_second = per_second
        self._hits: dict[str, deque[float]] = {}
        self._lock = threading.Lock()

    def allow(self, key: str, now: float | None = None) -> bool:
        now = time.monotonic() if now is None else now
        with self._lock:
            q = self._hits.setdefault(key, deque())
            while q and now - q[0] > 1.0:
                q.popleft()
            if len(q) >= self.per_second:
                return False
            q.append(now)
            return True


class AuditLog:
    """One JSON line per motion or state-changing request, with the client."""

    def __init__(self, path: Path) -> None:
        path.parent.mkdir(parents=True, exist_ok=True)
        self.path = path
        self._lock = threading.Lock()

    def record(self, client: str, action: str, ok: bool, detail: Any = None, t: float | None = None) -> None:
        """``t``: when the request was admitted (default now), so lines order as the decisions did."""
        line = json.dumps({"t": time.time() if t is None else t, "client": client, "action": action, "ok": ok,
                           "detail": detail})
        with self._lock, open(self.path, "a") as f:
            f.write(line + "\n")
