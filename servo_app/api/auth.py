"""Bearer-token authentication, the control lease, per-client rate limiting and the audit log."""

from __future__ import annotations

import contextlib
import errno
import json
import logging
import os
import secrets
import threading
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any, TypeVar

_log = logging.getLogger(__name__)
T = TypeVar("T")


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


TAKE_OVER = "take control: POST /api/lease with force=true"


@dataclass
class Lease:
    lease_id: str
    client: str
    expires_at: float
    ttl_s: float


class LeaseManager:
    """One control lease at a time; it expires unless renewed.

    A lease that ends without its holder releasing it (it expired, or another client took over) is
    kept as *lost* until someone stops the motion it may have left running: a take-over hands it to
    the new holder's request (:meth:`take`), which stops the arm before answering; an expiry nobody
    followed up is collected by the API's watch (:meth:`pop_expired`). One of the two, never both.
    """

    def __init__(self, ttl_s: float = 10.0, clock: Any = time.monotonic) -> None:
        self.ttl_s = ttl_s
        self._clock = clock
        self._lease: Lease | None = None
        self._expired: Lease | None = None  # expired, its motion not stopped yet
        self._lock = threading.Lock()
        # Actions in flight per lease id (from their check to their end) and one hand-over at a time: a
        # take-over, release or expiry stop waits for the old lease's actions, so an action whose check
        # passed just before it (a resume, a target) cannot land after its stop, under the new holder.
        # A Condition and counts, not a lock held while acting: an action's start and end may run on
        # different threads (a FastAPI dependency's), and a jog must never wait for another jog.
        self._acts = threading.Condition(threading.Lock())
        self._in_flight: dict[str, int] = {}
        self._handover = threading.Lock()

    def admit(self, lease_id: str | None) -> Lease:
        """Check ``lease_id`` (PermissionError as :meth:`check`) and count an action under it in flight
        until :meth:`done`: a hand-over waits for it. Never blocks beyond a short lock (the event loop
        calls it): during a hand-over the old lease id is refused already."""
        with self._acts:
            lease = self.check(lease_id)
            self._in_flight[lease.lease_id] = self._in_flight.get(lease.lease_id, 0) + 1
        return lease

    def done(self, lease: Lease) -> None:
        """The action :meth:`admit` let through under ``lease`` has ended (done or refused)."""
        with self._acts:
            left = self._in_flight[lease.lease_id] - 1
            if left:
                self._in_flight[lease.lease_id] = left
            else:
                del self._in_flight[lease.lease_id]
                self._acts.notify_all()

    @contextlib.contextmanager
    def acting(self, lease_id: str | None) -> Iterator[Lease]:
        """:meth:`admit` and :meth:`done` around the block: a hand-over's stop comes after it."""
        lease = self.admit(lease_id)
        try:
            yield lease
        finally:
            self.done(lease)

    @contextlib.contextmanager
    def handing_over(self, change: Callable[[], T]) -> Iterator[T]:
        """A take-over, release or expiry (``change``: :meth:`take`, :meth:`release`, :meth:`pop_expired`)
        and, in the block, the stop that follows it; one at a time. ``change`` is atomic with the
        actions' check (from then on the old lease id is refused: 409 naming the new holder), then the
        block waits for the old lease's actions let through before it, so its stop comes after them;
        the new lease's actions are not waited for (its id is handed out after the block). A
        PermissionError from ``change`` (nothing changed) propagates and waits for nothing."""
        with self._handover:
            with self._acts:
                result = change()
                current = self.current()
                keep = current.lease_id if current else None
                self._acts.wait_for(lambda: all(lid == keep for lid in self._in_flight))
            yield result

    def _expire(self) -> None:  # under the lock
        if self._lease and self._clock() > self._lease.expires_at:
            self._expired, self._lease = self._lease, None

    def current(self) -> Lease | None:
        with self._lock:
            self._expire()
            return self._lease

    def expired_unstopped(self) -> bool:
        """Whether a lease ran out whose motion nobody has stopped yet (:meth:`pop_expired` takes it)."""
        with self._lock:
            self._expire()
            return self._expired is not None

    def pop_expired(self) -> Lease | None:
        """A lease that ran out since the last call, if nobody has taken control since."""
        with self._lock:
            self._expire()
            lost, self._expired = self._expired, None
            return lost

    def take(self, client: str, force: bool = False, ttl_s: float | None = None) -> tuple[Lease, Lease | None]:
        """A new lease and the one it displaced (a live one taken over with ``force``, or one that
        expired with its motion not stopped yet): the caller stops that motion before answering.
        ``ttl_s`` may shorten the manager's TTL for this lease, never lengthen it."""
        ttl = self.ttl_s if ttl_s is None else min(float(ttl_s), self.ttl_s)
        with self._lock:
            self._expire()
            now = self._clock()
            held = self._lease
            if held and not force:
                left = f"{held.expires_at - now:.1f} s"
                if held.client == client:
                    raise PermissionError(
                        f"control is held by '{held.client}' (this name, another lease id) for {left} more: "
                        f"renew it with its lease id as X-Lease-Id (POST /api/lease/renew), release it "
                        f"(DELETE /api/lease), or {TAKE_OVER}")
                raise PermissionError(f"control is held by '{held.client}' for {left} more: wait until it is "
                                      f"released or expires, or {TAKE_OVER}")
            displaced = held or self._expired
            self._expired = None
            self._lease = Lease(secrets.token_urlsafe(12), client, now + ttl, ttl)
            return self._lease, displaced

    def acquire(self, client: str, force: bool = False, ttl_s: float | None = None) -> Lease:
        return self.take(client, force, ttl_s)[0]

    def renew(self, lease_id: str | None) -> Lease:
        with self._lock:
            self._expire()
            held = self._lease
            if not held or held.lease_id != lease_id:
                who = f"'{held.client}' holds it" if held else "nobody holds it"
                raise PermissionError(f"this client does not hold the control lease (it may have expired; {who}): "
                                      "acquire it: POST /api/lease")
            held.expires_at = self._clock() + held.ttl_s
            return held

    def check(self, lease_id: str | None) -> Lease:
        lease = self.current()
        if lease is None:
            raise PermissionError("nobody holds the control lease: acquire it first (POST /api/lease)")
        if lease.lease_id != lease_id:
            what = "has no X-Lease-Id" if not lease_id else "has an X-Lease-Id that is not the current lease's"
            raise PermissionError(f"control is held by '{lease.client}': this request {what}; send the lease id "
                                  f"from POST /api/lease as X-Lease-Id, or {TAKE_OVER}")
        return lease

    def release(self, lease_id: str | None) -> Lease | None:
        """Release the lease ``lease_id`` names; None if nobody holds one. A lease id that is not the
        holder's is refused (PermissionError): releasing must not take control away from another."""
        with self._lock:
            self._expire()
            held = self._lease
            if held is None:
                return None
            if held.lease_id != lease_id:
                what = "no X-Lease-Id" if not lease_id else "an X-Lease-Id that is not the current lease's"
                raise PermissionError(f"control is held by '{held.client}' and this request has {what}: nothing "
                                      f"released; send the holder's lease id, or {TAKE_OVER}")
            self._lease = None
            return held


class RateLimiter:
    """A token bucket per key: ``per_second`` tokens a second, up to ``burst`` saved up.

    A client that sends faster than the rate gets every request that fits, evenly spread (one each
    1/per_second s), so a held jog button renews its hold-to-run continuously; a sliding window let
    the first ``per_second`` through at once and then refused everything for the rest of the second,
    longer than the hold-to-run, so the arm stopped and started again.
    """

    def __init__(self, per_second: int, burst: int | None = None) -> None:
        self.per_second = per_second
        self.burst = max(1, per_second // 4) if burst is None else burst
        self._buckets: dict[str, tuple[float, float]] = {}  # key -> (tokens, when counted)
        self._lock = threading.Lock()

    def allow(self, key: str, now: float | None = None) -> bool:
        now = time.monotonic() if now is None else now
        with self._lock:
            if len(self._buckets) > 4096:  # many clients come and go: forget those whose bucket is full again
                self._buckets = {k: (n, w) for k, (n, w) in self._buckets.items()
                                 if n + (now - w) * self.per_second < self.burst}
            tokens, then = self._buckets.get(key, (float(self.burst), now))
            tokens = min(float(self.burst), tokens + max(0.0, now - then) * self.per_second)
            if tokens < 1.0 - 1e-9:  # (a client exactly at the rate must not lose a request to rounding)
                self._buckets[key] = (tokens, now)
                return False
            self._buckets[key] = (max(0.0, tokens - 1.0), now)
            return True


class AuditLog:
    """One JSON line per motion or state-changing request (refusals included), with the client.

    Rotates by size: past ``max_bytes`` the file becomes ``audit.log.1`` (the older ones shift up to
    ``.{backups}``, the oldest is dropped), so a flood of refused requests cannot fill the disk.
    """

    def __init__(self, path: Path, max_bytes: int = 5 * 1024 * 1024, backups: int = 3) -> None:
        path.parent.mkdir(parents=True, exist_ok=True)
        self.path = path
        self.max_bytes = max_bytes
        self.backups = backups
        self._lock = threading.Lock()
        self._size = path.stat().st_size if path.exists() else 0
        self.dropped = 0  # lines not written since the last that was (a full disk), with why
        self.last_error = ""

    def _rotate(self) -> None:  # under the lock
        for i in range(self.backups, 0, -1):
            older = self.path.with_name(f"{self.path.name}.{i}")
            newer = self.path.with_name(f"{self.path.name}.{i - 1}") if i > 1 else self.path
            if newer.exists():
                os.replace(newer, older)
        if self.backups == 0:
            self.path.unlink(missing_ok=True)
        self._size = 0

    def record(self, client: str, action: str, ok: bool, detail: Any = None, t: float | None = None) -> None:
        """``t``: when the request was admitted (default now), so lines order as the decisions did."""
        line = json.dumps({"t": time.time() if t is None else t, "client": client, "action": action, "ok": ok,
                           "detail": detail}, default=str) + "\n"
        data = line.encode()
        with self._lock:
            if self.dropped:  # the count of lines a full disk cost, first, once they can be written again
                lost = json.dumps({"t": time.time(), "client": "", "action": "audit.dropped", "ok": False,
                                   "detail": f"{self.dropped} lines not written: {self.last_error}"})
                data = lost.encode() + b"\n" + data
            try:
                if self._size and self._size + len(data) > self.max_bytes:
                    self._rotate()
                with open(self.path, "ab", buffering=0) as f:
                    if f.write(data) != len(data):  # cut short: no torn line is left behind
                        f.truncate(self._size)
                        raise OSError(errno.ENOSPC, "no space left for the whole line")
            except OSError as exc:
                # The request it records has been decided (a stop must answer on a full disk too): the
                # line is counted as lost, and the loss written once the disk takes lines again.
                if not self.dropped:
                    _log.warning("audit log %s: %s (lines are counted, not written, until it works again)",
                                 self.path, exc)
                self.dropped += 1
                self.last_error = str(exc)
                self._size = self.path.stat().st_size if self.path.exists() else 0
                return
            self._size += len(data)
            self.dropped = 0
