"""Tools (TCP frames): definitions, validation and the pose math. Pure: no I/O beyond reading the
TOML text handed in, no threads.

A tool is FANUC UTOOL data relative to the flange (X Y Z mm, W P R deg) and the payload it puts on
the arm (kg). The flange pose times the tool is the tool centre point (TCP)::

    T_world_tcp = T_world_flange @ xyzwpr_to_matrix(tool)

A cell's tools come from a TOML file (``servo-app run --tools FILE``)::

    active = "gripper"            # optional; --tool NAME overrides; default: "flange"

    [tools.gripper]
    xyzwpr = [0, 0, 150, 0, 0, 0]
    payload_kg = 2.5

The file is checked whole before anything starts, and a bad value is named with its key. A
built-in ``flange`` tool (zero offset, the configured ``--payload-kg``) always exists, so the
service has a tool even without a file.
"""

from __future__ import annotations

import math
import re
import tomllib
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from servo_app.robots.conventions import ArrayLike, matrix_to_xyzwpr, xyzwpr_to_matrix

FLANGE = "flange"
# A tool as long as a robot's reach is surely a unit mistake (metres typed as mm are tiny, mm typed
# as 0.1 mm huge): 2 m covers every tool on the arms this service drives.
MAX_OFFSET_MM = 2000.0
TOOL_NAME_PATTERN = r"^[A-Za-z0-9][A-Za-z0-9_.-]{0,63}$"
_NAME = re.compile(TOOL_NAME_PATTERN)
ZERO = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0)


class ToolError(ValueError):
    """A tool definition that cannot be used; the message names the key and the value."""


@dataclass(frozen=True)
class Tool:
    name: str
    xyzwpr: tuple[float, float, float, float, float, float] = ZERO  # from the flange: mm, deg
    payload_kg: float | None = None  # None: the controller's assumption, the maximum payload (Appendix B)

    @property
    def is_flange(self) -> bool:
        """No offset: the TCP is the flange."""
        return all(v == 0.0 for v in self.xyzwpr)

    def describe(self) -> dict[str, Any]:
        return {"name": self.name, "xyzwpr": list(self.xyzwpr), "payload_kg": self.payload_kg}


@dataclass(frozen=True)
class ToolSet:
    """The cell's tools by name (the built-in ``flange`` first) and the one active at start."""

    tools: Mapping[str, Tool] = field(default_factory=lambda: {FLANGE: Tool(FLANGE)})
    active: str = FLANGE

    def __post_init__(self) -> None:
        if self.active not in self.tools:
            raise ToolError(f"active={self.active!r} is not a defined tool (defined: {', '.join(self.tools)})")

    def get(self, name: str) -> Tool | None:
        return self.tools.get(name)

    def with_tool(self, tool: Tool) -> ToolSet:
        """This set with ``tool`` added or replaced (the active name unchanged)."""
        return ToolSet({**self.tools, tool.name: tool}, self.active)


def check_tool(name: str, xyzwpr: Any, payload_kg: Any, max_payload_kg: float | None,
               where: str = "tools") -> Tool:
    """A :class:`Tool` from raw values, or ToolError naming ``where.name.key`` and the value."""
    key = f"{where}.{name}"
    if not isinstance(name, str) or not _NAME.match(name):
        raise ToolError(f"{where}: tool name {name!r} must be letters, digits, '_', '.', '-' (at most 64, "
                        "starting with a letter or digit)")
    if not isinstance(xyzwpr, Sequence) or isinstance(xyzwpr, str) or len(xyzwpr) != 6:
        raise ToolError(f"{key}.xyzwpr={xyzwpr!r} must be 6 numbers: X Y Z (mm) W P R (deg) from the flange")
    values: list[float] = []
    for label, v in zip("XYZWPR", xyzwpr, strict=True):
        if isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(v):
            raise ToolError(f"{key}.xyzwpr {label}={v!r} is not a finite number")
        values.append(float(v))
    dist = math.hypot(*values[:3])
    if dist > MAX_OFFSET_MM:
        raise ToolError(f"{key}.xyzwpr X Y Z = {values[:3]} is {dist:.0f} mm from the flange, over "
                        f"{MAX_OFFSET_MM:.0f} mm: units are mm (did you send 0.1 mm?)")
    for label, v in zip("WPR", values[3:], strict=True):
        if abs(v) > 360.0:
            raise ToolError(f"{key}.xyzwpr {label}={v:g} deg is outside -360..360; send an angle within it")
    payload = _checked_payload(f"{key}.payload_kg", payload_kg, max_payload_kg)
    return Tool(name, (values[0], values[1], values[2], values[3], values[4], values[5]), payload)


def check_distinct(name: str, names: Iterable[str], where: str = "tool") -> None:
    """ToolError if ``name`` differs from one of ``names`` only in case: an operator reading "Gripper"
    and "gripper" in a list cannot tell which one the arm is using."""
    twin = next((n for n in names if n != name and n.casefold() == name.casefold()), None)
    if twin == FLANGE:  # (built in: "use 'flange' to redefine it" led to a refusal)
        raise ToolError(f"{where} {name!r} differs from tool {FLANGE!r} only in case: {FLANGE!r} is built in (zero "
                        "offset, --payload-kg) and cannot be redefined: name the tool otherwise")
    if twin is not None:
        raise ToolError(f"{where} {name!r} differs from tool {twin!r} only in case: use {twin!r} to redefine it, "
                        "or a name of its own")


def _checked_payload(key: str, value: Any, max_payload_kg: float | None) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
        raise ToolError(f"{key}={value!r} must be a number of kg")
    if value <= 0.0:
        raise ToolError(f"{key}={value:g} must be above 0 kg (a tool weighs something)")
    if max_payload_kg is not None and value > max_payload_kg:
        raise ToolError(f"{key}={value:g} kg is above the robot's maximum payload of {max_payload_kg:g} kg: "
                        f"the controller's limits do not hold for it; send at most {max_payload_kg:g} kg")
    return float(value)


def flange_tool(payload_kg: float | None, max_payload_kg: float | None) -> Tool:
    """The built-in flange tool with the configured payload (None: the maximum, as the controller assumes)."""
    if payload_kg is not None:
        _checked_payload("--payload-kg", payload_kg, max_payload_kg)
    return Tool(FLANGE, ZERO, None if payload_kg is None else float(payload_kg))


def parse_tools(data: Mapping[str, Any], *, max_payload_kg: float | None, flange_payload_kg: float | None = None,
                active: str | None = None, source: str = "tools") -> ToolSet:
    """A ToolSet from a tools TOML's table; ``active`` (``--tool``) overrides the file's ``active``."""
    unknown = sorted(set(data) - {"tools", "active"})
    if unknown:
        raise ToolError(f"{source}: unknown key {unknown[0]!r} (expected 'active' and [tools.NAME] tables)")
    tables = data.get("tools", {})
    if not isinstance(tables, Mapping):
        raise ToolError(f"{source}: tools={tables!r} must be a table of [tools.NAME] tables")
    tools: dict[str, Tool] = {FLANGE: flange_tool(flange_payload_kg, max_payload_kg)}
    for name, table in tables.items():
        where = f"{source}: tools"
        if name == FLANGE:
            raise ToolError(f"{where}.{FLANGE}: the flange tool is built in (zero offset, --payload-kg); "
                            "name this tool otherwise")
        if not isinstance(table, Mapping):
            raise ToolError(f"{where}.{name}={table!r} must be a table with xyzwpr and payload_kg")
        extra = sorted(set(table) - {"xyzwpr", "payload_kg"})
        if extra:
            raise ToolError(f"{where}.{name}: unknown key {extra[0]!r} (expected xyzwpr, payload_kg)")
        for key in ("xyzwpr", "payload_kg"):
            if key not in table:
                raise ToolError(f"{where}.{name}.{key} is missing")
        tools[name] = check_tool(name, table["xyzwpr"], table["payload_kg"], max_payload_kg, where)
        check_distinct(name, tools, f"{where}.{name}: tool")
    chosen = active if active is not None else data.get("active", FLANGE)
    if not isinstance(chosen, str) or chosen not in tools:
        key = "--tool" if active is not None else f"{source}: active"
        raise ToolError(f"{key}={chosen!r} is not a defined tool (defined: {', '.join(tools)})")
    return ToolSet(tools, chosen)


def load_tools(text: str, *, max_payload_kg: float | None, flange_payload_kg: float | None = None,
               active: str | None = None, source: str = "tools") -> ToolSet:
    """``parse_tools`` of a TOML text (``source`` names the file in messages)."""
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise ToolError(f"{source}: not valid TOML: {exc}") from None
    return parse_tools(data, max_payload_kg=max_payload_kg, flange_payload_kg=flange_payload_kg, active=active,
                       source=source)


# ------------------------------------------------------------------------------------- pose math
def tcp_matrix(flange_xyzwpr: ArrayLike, tool_xyzwpr: ArrayLike) -> np.ndarray:
    """The TCP's 4x4 pose (world, metres) for a flange pose and a tool (both FANUC units)."""
    return xyzwpr_to_matrix(flange_xyzwpr) @ xyzwpr_to_matrix(tool_xyzwpr)


def tcp_pose(flange_xyzwpr: ArrayLike, tool_xyzwpr: ArrayLike) -> np.ndarray:
    """The TCP's X Y Z W P R (world) for a flange pose and a tool (both FANUC units)."""
    return matrix_to_xyzwpr(tcp_matrix(flange_xyzwpr, tool_xyzwpr))


def flange_pose(tcp_xyzwpr: ArrayLike, tool_xyzwpr: ArrayLike) -> np.ndarray:
    """The flange's X Y Z W P R for a TCP pose: the inverse of :func:`tcp_pose`."""
    return matrix_to_xyzwpr(xyzwpr_to_matrix(tcp_xyzwpr) @ np.linalg.inv(xyzwpr_to_matrix(tool_xyzwpr)))
