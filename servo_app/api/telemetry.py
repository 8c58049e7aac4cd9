"""``/ws/telemetry``: the state (:class:`~servo_app.api.models.StateView`, as ``GET /api/state``
answers it) pushed at ``?hz=`` (1..100, default 50)."""

# No `from __future__ import annotations`: FastAPI reads the annotations at runtime.
import asyncio

from fastapi import APIRouter, WebSocket, WebSocketDisconnect

from servo_app.api.deps import api_of
from servo_app.api.models import StateView
from servo_app.api.state import state_snapshot

router = APIRouter()


@router.websocket("/ws/telemetry")
async def telemetry(ws: WebSocket, hz: float = 50.0) -> None:
    api = api_of(ws)
    await ws.accept()
    period = 1.0 / min(max(hz, 1.0), 100.0)
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
