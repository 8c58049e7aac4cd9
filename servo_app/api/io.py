"""``/api/io``: read and write controller I/O through the command packets (only while streaming).
Reading needs the token, writing the token and the control lease. The answer names what was read or
written: ``{"ok": true, "type": "DO", "index": 1, "mask": 1, "value": 1}``."""

# No `from __future__ import annotations`: FastAPI reads the dependency annotations at runtime.
from typing import Annotated

from fastapi import APIRouter, Query
from pydantic import BaseModel, Field

from servo_app.api.deps import Authed, Calls, Controlling, Service
from servo_app.api.models import REFUSALS, IoWrite

router = APIRouter(tags=["io"], responses=REFUSALS)


class IoWritten(BaseModel):
    """An I/O write carried out: sent with the next command packet."""

    ok: bool = Field(True, description="always true: a refusal is an HTTP error with a `detail` message")
    type: str = Field(description="the I/O type, canonical (DO, F, M, ...)")
    index: int = Field(description="the first of the 16 points the write covers")
    mask: int = Field(description="the points written (bit 0: the point at `index`)")
    value: int = Field(description="the value written to the masked points")


class IoRead(BaseModel):
    """An I/O read: the 16 points from ``index``, as a later status packet echoed them."""

    ok: bool = Field(True, description="always true: a refusal is an HTTP error with a `detail` message")
    type: str = Field(description="the I/O type, canonical (DI, DO, F, M, ...)")
    index: int
    mask: int = Field(description="the points read (bit 0: the point at `index`); the others read 0")
    value: int = Field(description="the points read (bit 0: the point at `index`)")
    detail: int = Field(description="the same as `value` (the earlier answer's field)")


@router.get("/api/io", summary="Read 16 I/O points")
def io_read(type: str, index: int, client: Authed, service: Service, calls: Calls,
            mask: Annotated[int, Query(ge=0, le=0xFFFF, description="the points to read")] = 0xFFFF) -> IoRead:
    """Read 16 points from ``index`` through the command packets (only while streaming; the types and
    indexes allowed are in GET /api/limits, ``io_allow``). Token only."""
    ack = calls.call(client, "io.read", lambda: service.io_read(type, index, mask),
                     {"type": type, "index": index, "mask": mask})
    value = int(ack.detail)
    return IoRead(type=type.upper(), index=index, mask=mask, value=value, detail=value)


@router.post("/api/io", summary="Write I/O points")
def io_write(body: IoWrite, client: Controlling, service: Service, calls: Calls) -> IoWritten:
    """Write the masked points of the 16 from ``index`` with the next command packet (only while
    streaming; the types and indexes allowed are in GET /api/limits, ``io_allow``). Token and lease."""
    ack = calls.call(client, "io.write", lambda: service.io_write(body.type, body.index, body.mask, body.value),
                     body.model_dump())
    return IoWritten(type=str(ack.detail), index=body.index, mask=body.mask, value=body.value)
