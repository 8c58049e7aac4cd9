"""``/api/sessions``: the servo process's session logs (one binary file per stream), to list and download."""

# No `from __future__ import annotations`: FastAPI reads the dependency annotations at runtime.
from typing import Any

from fastapi import APIRouter, HTTPException
from fastapi.responses import FileResponse

from servo_app.api.deps import Service
from servo_app.api.models import Problem, SessionLogInfo

router = APIRouter(tags=["logs"])


@router.get("/api/sessions", response_model=list[SessionLogInfo])
def sessions(service: Service) -> list[dict[str, Any]]:
    """Newest first."""
    return service.session_logs()


_FILE = {"application/octet-stream": {"schema": {"type": "string", "format": "binary"}}}


@router.get("/api/sessions/{name}", response_class=FileResponse,
            responses={200: {"content": _FILE, "description": "the .srvlog file"},
                       404: {"model": Problem, "description": "no session log of that name"}})
def session_download(name: str, service: Service) -> FileResponse:
    try:
        path = service.session_log_path(name)
    except FileNotFoundError as exc:
        raise HTTPException(404, str(exc)) from None
    return FileResponse(path, media_type="application/octet-stream", filename=name)
