"""``/api/io``: read and write controller I/O through the command packets (only while streaming).
Reading needs the token, writing the token and the control lease."""

# No `from __future__ import annotations`: FastAPI reads the dependency annotations at runtime.
from fastapi import APIRouter

from servo_app.api.deps import Authed, Calls, Controlling, Service
from servo_app.api.models import REFUSALS, Ack, IoValue, IoWrite

router = APIRouter(tags=["io"], responses=REFUSALS)


@router.get("/api/io")
def io_read(type: str, index: int, client: Authed, service: Service, calls: Calls, mask: int = 0xFFFF) -> IoValue:
    """Read 16 points from ``index`` through the command packets (only while streaming)."""
    ack = calls.call(client, "io.read", lambda: service.io_read(type, index, mask),
                     {"type": type, "index": index, "mask": mask})
    return IoValue(detail=ack.detail)


@router.post("/api/io")
def io_write(body: IoWrite, client: Controlling, service: Service, calls: Calls) -> Ack:
    """Write the masked points of the 16 from ``index`` with the next command packet."""
    return calls.call(client, "io.write", lambda: service.io_write(body.type, body.index, body.mask, body.value),
                      body.model_dump())
