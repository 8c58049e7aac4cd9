"""``/api/sessions``: the servo process's session logs (one binary file per stream), to list and download."""

# No `from __future__ import annotations`: FastAPI reads the dependency annotations at runtime.
from typing import Any

from fastapi import APIRouter, HTTPException
from fastapi.responses import FileResponse

from servo_app.api.deps import Service
from servo_app.api.models import Problem, SessionLogInfo

router = APIRouter(tags=["logs"])


@router.get("/api/sessions", response_model=list[SessionLogInfo], summary="List the session logs")
def sessions(service: Service) -> list[dict[str, Any]]:
    """The session logs in the service's var directory, newest first (open: no token)."""
    return service.session_logs()


_FILE = {"application/octet-stream": {"schema": {"type": "string", "format": "binary"}}}


@router.get("/api/sessions/{name}", response_class=FileResponse, summary="Download a session log",
            responses={200: {"content": _FILE, "description": "the .srvlog file"},
                       404: {"model": Problem, "description": "no session log of that name"}})
def session_download(name: str, service: Service) -> FileResponse:
    """One ``.srvlog`` file by the name ``GET /api/sessions`` lists (``servo-app check`` reads it)."""
    # A name the file system cannot take (a NUL byte: ValueError; too long: OSError) names no log.
    try:
        if "\x00" in name:
            raise FileNotFoundError(f"no session log {name!r}")
        path = service.session_log_path(name)
    except (FileNotFoundError, ValueError, OSError) as exc:
        raise HTTPException(404, f"{exc}: list them with GET /api/sessions") from None
    return FileResponse(path, media_type="application/octet-stream", filename=name)
