"""The cell's tools in the service: which one is active, changing it, and the TCP in the state.

The definitions come from ``servo-app run --tools FILE`` (:mod:`servo_app.robots.tool`, checked whole
at start); the active tool is the servo process's (``SetTool``: its IK, pose targets, tool-frame
twists, reach check and limit tables use it) and this object's, which records it once the servo
process took it. A refused change (moving, unknown, a backend without tool offsets) changes nothing.

The state's pose (``cart_servo``) is the active TCP: the flange pose the controller reports times the
tool, so it stays the controller's own measurement (its status carries the pose of its UTOOL, which
the stream needs to be the faceplate: docs/tools.md). The controller's flange pose stays beside it as
``flange_pose``.
"""

from __future__ import annotations

import logging
import threading
from collections.abc import Callable
from pathlib import Path
from typing import Any

from servo_app import messages as msg
from servo_app.errors import CommandRejected
from servo_app.robots.tool import (
    FLANGE,
    Tool,
    ToolError,
    ToolSet,
    check_distinct,
    check_tool,
    load_tools,
    tcp_matrix,
    tcp_pose,
)
from servo_app.service.config import ServiceConfig

_log = logging.getLogger(__name__)

# Tools a client may add at run time (POST /api/tools; redefining one is not adding): each is kept
# until the service stops, so without a bound a client could grow the set, GET /api/tools and the
# console's list without end. A cell has a handful; the tools file (--tools) is the place for more.
MAX_RUNTIME_TOOLS = 64

# Modes in which a stream is alive: a tool change then waits for the controller's feedback to settle.
_STREAM_ALIVE = frozenset({"streaming", "stopping", "stopped", "ending"})


def load_tool_set(cfg: ServiceConfig, profile: Any) -> ToolSet:
    """The tools of ``cfg`` (its file, or the flange alone) for ``profile``; ToolError names what is wrong."""
    max_payload = getattr(profile, "max_payload_kg", None)  # a backend without payload tables: no bound
    if cfg.tools_file is None:
        text, source = "", "--tool"
    else:
        try:
            text = Path(cfg.tools_file).read_text(encoding="utf-8")
        except (OSError, UnicodeDecodeError) as exc:
            raise ToolError(f"{cfg.tools_file}: cannot be read: {exc}") from None
        source = str(cfg.tools_file)
    return load_tools(text, max_payload_kg=max_payload, flange_payload_kg=cfg.payload_kg, active=cfg.tool,
                      source=source)


def _expired(name: str) -> Callable[[msg.Reply], None]:
    """on_late for a tool change whose process is stopped when the wait ends: its reply is history."""

    def late(reply: msg.Reply) -> None:
        _log.info("late reply to the change to tool %r (ok=%s): its servo process was stopped", name, reply.ok)

    return late


class UnknownTool(LookupError):
    """No tool of that name (the API answers 404)."""


class ActiveTool:
    """Thread-safe: API worker threads read and change it; one change at a time."""

    def __init__(self, tools: ToolSet, max_payload_kg: float | None,
                 request: Callable[..., Any], state_vector: Callable[[], dict[str, Any]],
                 set_simulator_payload: Callable[[float | None], None] | None = None, *,
                 retire_servo: Callable[[str], None]) -> None:
        self._tools = tools
        self._at_start = frozenset(tools.tools)  # the file's and the flange: not counted in the bound
        self._active = tools.tools[tools.active]
        self._max_payload_kg = max_payload_kg
        self._request = request
        self._state_vector = state_vector
        self._set_simulator_payload = set_simulator_payload
        # Stops a servo process that did not answer a tool change in time (a fault; reset starts another).
        self._retire_servo = retire_servo
        self._lock = threading.Lock()

    @property
    def active(self) -> Tool:
        return self._active

    def all(self) -> list[Tool]:
        return list(self._tools.tools.values())

    def describe(self) -> dict[str, Any]:
        return {"active": self._active.name, "tools": [t.describe() for t in self.all()]}

    @property
    def max_payload_kg(self) -> float | None:
        """The heaviest tool that may be defined (None: no bound)."""
        return self._max_payload_kg

    # ------------------------------------------------------------------ changes
    def apply_to_new_process(self) -> None:
        """A new servo process starts with the flange and the payload of its options: give it the
        active tool's offset. A backend that refuses it (no tool offsets) raises ToolError; one that
        does not answer in time is stopped (a fault) and TimeoutError says so."""
        tool = self._active
        if tool.is_flange:
            return
        try:
            self._request(msg.SetTool(tool.name, tool.xyzwpr, tool.payload_kg), on_late=_expired(tool.name))
        except CommandRejected as exc:
            raise ToolError(f"tool {tool.name!r}: {exc}") from None
        except TimeoutError as exc:
            # It would stream the flange's TCP under the active tool's name: stopped, not kept waiting.
            why = f"the new servo process did not take the active tool {tool.name!r} in time"
            self._retire_servo(why)
            raise TimeoutError(f"{exc}; {why} and was stopped (fault): reset again (POST /api/reset) to start "
                               "another") from None

    def select(self, name: str) -> Tool:
        """Make ``name`` the active tool: refused (CommandRejected) while the arm moves, UnknownTool for
        a name not defined; nothing changes then."""
        with self._lock:
            tool = self._tools.get(name)
            if tool is None:
                raise UnknownTool(f"no tool named {name!r} (defined: {', '.join(self._tools.tools)}); "
                                  "define it in the tools file (servo-app run --tools) or POST /api/tools")
            s = self._state_vector()
            if s.get("state") in _STREAM_ALIVE and not (s.get("at_rest") and s.get("settled")):
                raise CommandRejected("tool change refused: the arm is moving (not at rest and settled); stop "
                                      "or let the motion end, wait until GET /api/state shows settled, then "
                                      "change the tool")
            old = self._active
            try:  # refused: raises, unchanged
                self._request(msg.SetTool(tool.name, tool.xyzwpr, tool.payload_kg), on_late=self._late(tool))
            except TimeoutError as exc:
                # Expired with the wait: a stalled servo process refuses it when it resumes, so the
                # service and the arm keep the old TCP (or _late learns it was taken just in time).
                raise TimeoutError(f"{exc}; the tool is not changed ({old.name!r} is active) and the servo "
                                   "process will not take this change later: once it answers again (GET "
                                   "/api/state), change the tool again") from None
            if self._set_simulator_payload is not None:
                # The embedded controller's payload follows, as a cell's PAYLOAD[] instruction would.
                try:
                    self._set_simulator_payload(tool.payload_kg)
                except BaseException as exc:  # not taken (its process ended or froze): refused, so undone
                    self._undo(tool, old, exc)
                    if isinstance(exc, TimeoutError):
                        raise TimeoutError(f"{exc}; the tool is not changed ({old.name!r} is active): once the "
                                           "controller answers again (reset: POST /api/reset), change the tool "
                                           "again") from None
                    raise
            self._active = tool
            return tool

    def _undo(self, tool: Tool, old: Tool, exc: BaseException) -> None:
        """Give the servo process ``old`` again after ``tool`` could not be completed (``exc``). With the
        deadline of a change: if it does not answer in time it holds ``tool``, which the service does
        not show, so it is stopped (a fault) rather than trusted to take ``old`` once it runs again."""
        try:
            self._request(msg.SetTool(old.name, old.xyzwpr, old.payload_kg), on_late=_expired(old.name))
        except TimeoutError as undo_exc:
            why = f"the servo process took tool {tool.name!r} and did not answer its undoing in time"
            self._retire_servo(why)
            raise TimeoutError(f"{exc}; the tool is not changed ({old.name!r} is active): {why} ({undo_exc}) and "
                               "was stopped (fault): reset (POST /api/reset) to start another with "
                               f"{old.name!r}") from None

    def _late(self, tool: Tool) -> Callable[[msg.Reply], None]:
        """The reply to a change the servo process took just before its deadline and answered after
        the wait (stalled between the two): it moves that TCP now, so the service shows it too. Called
        from the pipe's reader (not under ``_lock``, which the next change may hold waiting for it),
        in order with the other replies, so a later change's lands after it."""

        def taken(reply: msg.Reply) -> None:
            if not reply.ok:  # refused (late: the deadline), as the service reported
                return
            _log.warning("tool %r was taken by the servo process after the service stopped waiting: it is "
                         "the active tool now", tool.name)
            self._active = tool
            if self._set_simulator_payload is not None:  # not from the reader: the call may wait
                threading.Thread(target=self._late_payload, args=(tool.payload_kg,), daemon=True).start()

        return taken

    def _late_payload(self, payload_kg: float | None) -> None:
        assert self._set_simulator_payload is not None
        try:
            self._set_simulator_payload(payload_kg)
        except Exception as exc:  # the controller is gone or frozen: its own fault shows in the state
            _log.warning("the embedded controller's payload did not follow tool change: %s", exc)

    def define(self, name: str, xyzwpr: Any, payload_kg: Any) -> Tool:
        """Add a tool at run time (kept until the service stops). The active tool cannot be redefined
        (it is in use: select another first); ToolError (422) for bad values."""
        with self._lock:
            if name == self._active.name:
                raise CommandRejected(f"tool {name!r} is the active tool: select another tool first "
                                      "(PUT /api/tool), then redefine it")
            if name == FLANGE:
                raise ToolError(f"tool {FLANGE!r} is built in (zero offset, --payload-kg): name the tool otherwise")
            tool = check_tool(name, xyzwpr, payload_kg, self._max_payload_kg, where="tool")
            check_distinct(name, self._tools.tools)
            added = [n for n in self._tools.tools if n not in self._at_start]
            if name not in self._tools.tools and len(added) >= MAX_RUNTIME_TOOLS:
                raise CommandRejected(f"tool {name!r} not defined: at most {MAX_RUNTIME_TOOLS} tools can be added at "
                                      f"run time and {len(added)} are; redefine one of them (POST /api/tools "
                                      "with its name), or put the tools in the tools file (servo-app run --tools)")
            self._tools = self._tools.with_tool(tool)
            return tool

    # ------------------------------------------------------------------ the state
    def decorate(self, s: dict[str, Any]) -> dict[str, Any]:
        """The state with the active tool, its TCP as ``cart_servo`` and the flange as ``flange_pose``."""
        tool = self._active
        s["tool"] = tool.describe()
        flange = s.get("cart_servo")
        if flange is None or "flange_pose" in s:
            return s
        s["flange_pose"] = flange
        if not tool.is_flange and len(flange) >= 6:
            s["cart_servo"] = [float(v) for v in tcp_pose(flange[:6], tool.xyzwpr)]
        return s

    def decorate_robot(self, view: dict[str, Any]) -> dict[str, Any]:
        """``GET /api/robot`` with the active tool's TCP (``tcp``: its point and axes, for the console
        to draw a line from the flange and a triad), where the view gives the flange's pose."""
        tool = self._active
        flange = next((p for p in view.get("points", ()) if p.get("name") == "flange" and "xyzwpr" in p), None)
        if flange is None:
            return view
        t = tcp_matrix(flange["xyzwpr"], tool.xyzwpr)
        view["tcp"] = {"tool": tool.name, "xyz_mm": [float(v) * 1000.0 for v in t[:3, 3]],
                       "axes": [[float(v) for v in t[:3, i]] for i in range(3)]}
        return view
