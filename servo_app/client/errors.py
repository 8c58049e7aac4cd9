"""The client's exceptions: each carries the server's own message (which ends with the next step)."""

from __future__ import annotations

import builtins
from typing import Any


class ServoError(Exception):
    """Anything the service refused or that went wrong talking to it. ``message`` is the server's text."""

    def __init__(self, message: str, *, status: int | None = None) -> None:
        super().__init__(message)
        self.message = message
        self.status = status


class AuthError(ServoError):
    """401: the bearer token is missing or wrong."""


class LeaseError(ServoError):
    """The control lease: held by another client, expired, or lost while this client held it."""


class RefusedError(ServoError):
    """The service refused the request: 422 (the request itself is bad), 404 (nothing of that name),
    409 (not in this state), 429 (too many jogs).

    ``field``: for a 422 schema error, where in the request (``body.joints``); ``next_step``: the
    part of the server's sentence that says what to do (after its last ``;``), if it has one."""

    def __init__(self, message: str, *, status: int | None = None, field: str | None = None,
                 errors: list[dict[str, Any]] | None = None) -> None:
        super().__init__(message, status=status)
        self.field = field
        self.errors = errors or []
        head, sep, tail = message.rpartition(";")
        self.next_step: str | None = tail.strip() if sep and head else None


class FaultError(ServoError):
    """The service is in the fault state: ``code`` (the controller's alarm, e.g. MOTN-603; None for a
    fault the service detected itself), ``cause`` and ``remedy`` (the manual's, or the service's)."""

    def __init__(self, message: str, *, code: str | None = None, cause: str | None = None,
                 remedy: str | None = None, status: int | None = None) -> None:
        text = message if code is None else f"{code}: {message}"
        if remedy:
            text += f" (remedy: {remedy})"
        super().__init__(text, status=status)
        self.code = code
        self.cause = cause
        self.remedy = remedy


class StoppedError(ServoError):
    """A motion the client was waiting for ended short: the arm was stopped (``reason``) before it
    arrived, by another client, an input, the lease watch or a safety stop."""

    def __init__(self, message: str, *, reason: str | None = None) -> None:
        super().__init__(message)
        self.reason = reason


class TimeoutError(ServoError, builtins.TimeoutError):  # still a builtin TimeoutError
    """Nothing happened in time: a wait ran out, the service did not answer (503), or a request timed out."""
