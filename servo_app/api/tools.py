"""``/api/tools`` and ``/api/tool``: the cell's tools (TCP frames) and the active one.

Listing is open. Changing the active tool needs the token and the control lease, and the arm at
rest: with a stream alive, the commanded motion at rest and the controller's feedback settled (409
otherwise, saying what to wait for); 404 for a name nobody defined. A refused change changes nothing.
Defining a tool at run time (``POST /api/tools``) keeps it until the service stops (the tools file
is the permanent place: ``servo-app run --tools``).
"""

# No `from __future__ import annotations`: FastAPI reads the dependency annotations at runtime.
from typing import Any

from fastapi import APIRouter, HTTPException

from servo_app.api.deps import Calls, Controlling, Service
from servo_app.api.models import REFUSALS, DefineTool, Problem, SelectTool, ToolsView, ToolView
from servo_app.errors import InvalidRequest
from servo_app.robots.tool import ToolError
from servo_app.service.tools import UnknownTool

router = APIRouter(tags=["tools"])

_UNKNOWN = {404: {"model": Problem, "description": "no tool of that name: the text lists the defined ones"}}


@router.get("/api/tools", summary="The cell's tools and the active one", response_model=ToolsView)
def tools_list(service: Service) -> dict[str, Any]:
    """Every tool (the built-in ``flange`` first): its TCP from the flange and its payload, and the
    name of the active tool (open: no token)."""
    return service.tools.describe()


@router.put("/api/tool", summary="Change the active tool (at rest)", responses={**REFUSALS, **_UNKNOWN})
def tool_select(body: SelectTool, client: Controlling, service: Service, calls: Calls) -> ToolView:
    """Make ``name`` the TCP of jogs, pose targets and the displayed pose, and its payload the limit
    tables'. Allowed without a stream, or with the arm at rest and settled; 409 while it moves, 404
    for an unknown name; a refusal changes nothing. Token and lease."""

    def select() -> dict[str, Any]:
        try:
            return service.set_tool(body.name).describe()
        except UnknownTool as exc:
            raise HTTPException(404, str(exc.args[0])) from None

    try:
        ack = calls.call(client, "tool.select", select, {"name": body.name})
    except HTTPException as exc:
        if exc.status_code == 404:
            calls.audit.record(client, "tool.select", False, exc.detail)
        raise
    return ToolView.model_validate(ack.detail)


@router.post("/api/tools", summary="Define a tool for this run", responses=REFUSALS)
def tool_define(body: DefineTool, client: Controlling, service: Service, calls: Calls) -> ToolView:
    """Add (or replace) a tool until the service stops: its TCP from the flange and its payload, checked
    as the tools file's are (422 naming the value). The active tool cannot be redefined (409), nor
    more than 64 added (409: MAX_RUNTIME_TOOLS). Token and lease."""

    def define() -> dict[str, Any]:
        try:
            return service.tools.define(body.name, body.xyzwpr, body.payload_kg).describe()
        except ToolError as exc:
            raise InvalidRequest(str(exc)) from None

    ack = calls.call(client, "tools.define", define, body.model_dump())
    return ToolView.model_validate(ack.detail)
