"""``/ws/telemetry``: the state (:class:`~servo_app.api.models.StateView`, as ``GET /api/state``
answers it) pushed at ``?hz=`` (1..100, default 50).

A rate that is not a number, or outside 1..100 (NaN, infinity, 0, negative, huge), is refused: the
socket is accepted and closed at once with code 1008 and a reason naming the value, so a client sees
why. (``hz=nan`` used to make the period NaN, and the loop sent as fast as it could to anyone who
asked.)
"""

# No `from __future__ import annotations`: FastAPI reads the annotations at runtime.
import asyncio
import math

from fastapi import APIRouter, WebSocket, WebSocketDisconnect, status

from servo_app.api.deps import api_of
from servo_app.api.models import StateView
from servo_app.api.state import state_snapshot
from servo_app.errors import close_reason

router = APIRouter()

HZ_MIN, HZ_MAX = 1.0, 100.0


def telemetry_rate_error(hz: float) -> str | None:
    """Why ``hz`` is no telemetry rate, or None."""
    if not math.isfinite(hz) or not HZ_MIN <= hz <= HZ_MAX:
        return f"hz={hz} is outside {HZ_MIN:g}..{HZ_MAX:g} messages per second: connect with e.g. ?hz=50"
    return None


@router.websocket("/ws/telemetry")
async def telemetry(ws: WebSocket, hz: str = "50") -> None:
    """The state at ``hz`` messages a second (1..100). ``hz`` is parsed here, not by FastAPI: its
    refusal of a non-number (``hz=abc``) was a bare HTTP 403 before the handshake, with no reason."""
    api = api_of(ws)
    await ws.accept()
    try:
        rate = float(hz)
    except ValueError:
        # The value cut short, so the reason still says what to do within a close frame's 123 bytes
        shown = repr(hz)
        if len(shown.encode()) > 32:
            shown = f"{shown.encode()[:28].decode(errors='ignore')}... ({len(hz)} characters)"
        error: str | None = f"hz={shown} is not a number of messages per second: connect with e.g. ?hz=50"
    else:
        error = telemetry_rate_error(rate)
    if error is not None:
        await ws.close(code=status.WS_1008_POLICY_VIOLATION, reason=close_reason(error))
        return
    period = 1.0 / rate
    loop = asyncio.get_running_loop()
    due = loop.time()
    try:
        while True:
            s = await asyncio.to_thread(state_snapshot, api)
            await ws.send_text(StateView.model_validate(s).model_dump_json(exclude_unset=True))
            # Absolute deadlines, so the time spent reading and sending does not lower the rate;
            # after a stall, carry on from now rather than sending a burst.
            due = max(due + period, loop.time() - period)
            await asyncio.sleep(max(0.0, due - loop.time()))
    except (WebSocketDisconnect, RuntimeError, OSError):  # the client went away
        return
