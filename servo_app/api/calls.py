"""The one place that turns a service call into an HTTP answer, and writes its audit line.

Refusals: :class:`~servo_app.service.InvalidRequest` -> 422 (the request itself is bad: found here or
by the servo process, which checks a request whole before anything changes), :class:`CommandRejected`
-> 409 (refused by the state; the text ends with the next step), ``TimeoutError`` -> 503 (no answer).
InvalidRequest is a CommandRejected too, so it is caught first. Every
request to the servo process is a typed message (:mod:`servo_app.messages`) passed to
:meth:`ServiceCalls.forward`.
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Callable
from typing import Any

from fastapi import HTTPException

from servo_app import messages as msg
from servo_app.api.auth import AuditLog
from servo_app.api.models import Ack
from servo_app.errors import CommandRejected
from servo_app.service import InvalidRequest, ServoService


class ServiceCalls:
    def __init__(self, service: ServoService, audit: AuditLog) -> None:
        self.service = service
        self.audit = audit

    def forward(self, client: str, action: str, message: msg.Request, *, at: float | None = None) -> Ack:
        """Send ``message`` to the servo process; the audit line records its fields."""
        detail = {f.name: getattr(message, f.name) for f in dataclasses.fields(message)}
        return self.call(client, action, lambda: self.service.request(message), detail, at)

    def call(self, client: str, action: str, fn: Callable[[], Any], detail: Any = None,
             at: float | None = None) -> Ack:
        """Run a service call; refusals become 422 (invalid here), 409 (refused by the state) or 503.
        ``at``: when the request was admitted, for the audit line (default: now)."""
        at = time.time() if at is None else at
        try:
            result = fn()
        except InvalidRequest as exc:
            self.audit.record(client, action, False, str(exc), at)
            raise HTTPException(422, str(exc)) from None
        except CommandRejected as exc:
            self.audit.record(client, action, False, str(exc), at)
            raise HTTPException(409, str(exc)) from None
        except TimeoutError as exc:
            self.audit.record(client, action, False, str(exc), at)
            raise HTTPException(503, str(exc)) from None
        self.audit.record(client, action, True, detail or None, at)
        return Ack(detail=result)
