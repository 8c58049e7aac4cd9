"""The OpenAPI document with what this service's robot takes: the request models (api.models) are the
same for every backend, but the axis count, the joint ranges, the I/O types and indexes and the maximum
payload are the configured robot's. Its checks refuse the rest (422, naming the field and value); without these
constraints in the document a client or fuzzer generated from it sends 5 joints to a 6-axis arm, I/O
type "SO" or a 90 kg tool, all of which the document allowed.

Documentation only: validation stays where it is, with its messages.
"""

from __future__ import annotations

from typing import Any

from servo_app.backends import RobotBackend


def document_robot(doc: dict[str, Any], backend: RobotBackend, max_payload_kg: float | None) -> dict[str, Any]:
    """``doc`` (FastAPI's OpenAPI document) with the robot's constraints, changed in place."""
    schemas = doc["components"]["schemas"]
    axes = len(backend.axes())
    for model in ("JointJog", "JointTarget"):
        joints = schemas[model]["properties"]["joints"]
        joints.update(minItems=axes, maxItems=axes)
        joints["description"] += f"; this robot has {axes}"
    bounds = backend.target_bounds()
    if bounds is not None:
        axes_in_range = [{"type": "number", "minimum": lo, "maximum": hi} for lo, hi in bounds]
        schemas["JointTarget"]["properties"]["joints"]["prefixItems"] = axes_in_range
        replay = doc["paths"].get("/api/trajectory", {}).get("post")
        if replay is not None and len(bounds) == 6:  # (FANUC's alone: six values a waypoint)
            rows = replay["requestBody"]["content"]["application/json"]["schema"]["properties"]["joints"]
            rows["anyOf"][0]["items"]["prefixItems"] = axes_in_range
    if max_payload_kg is not None:
        schemas["DefineTool"]["properties"]["payload_kg"]["maximum"] = max_payload_kg
    indexes = backend.io_indexes()
    if indexes:
        _document_io(doc, indexes)
    return doc


def _document_io(doc: dict[str, Any], indexes: dict[str, tuple[int, int]]) -> None:
    """The allowed types (in any case, as check_io takes them: a pattern) and the index range: in the
    body per type, in the read's query (one range for all) the widest."""
    types = sorted(indexes)
    pattern = "^(?:" + "|".join(_any_case(t) for t in types) + ")$"
    spans = ", ".join(f"{t} {lo}..{hi}" for t, (lo, hi) in sorted(indexes.items()))
    lo, hi = min(r[0] for r in indexes.values()), max(r[1] for r in indexes.values())
    write = doc["components"]["schemas"]["IoWrite"]
    kinds = f"the I/O types this service allows, in any case: {', '.join(types)}"
    write["properties"]["type"].update(pattern=pattern, description=kinds)
    write["properties"]["index"].update(minimum=lo, maximum=hi, description=(
        f"the first of the 16 points accessed; by type: {spans}"))
    write["allOf"] = [{"if": {"properties": {"type": {"pattern": "^" + _any_case(t) + "$"}}, "required": ["type"]},
                       "then": {"properties": {"index": {"minimum": a, "maximum": b}}}}
                      for t, (a, b) in sorted(indexes.items()) if (a, b) != (lo, hi)]
    if not write["allOf"]:
        del write["allOf"]
    for param in doc["paths"]["/api/io"]["get"]["parameters"]:
        if param["name"] == "type":
            param["schema"]["pattern"] = pattern
            param["description"] = kinds
        elif param["name"] == "index":
            param["schema"].update(minimum=lo, maximum=hi)
            param["description"] = f"the first of the 16 points read; by type: {spans}"


def _any_case(name: str) -> str:
    # JSON Schema's patterns (ECMA 262) have no case-insensitive flag.
    return "".join(f"[{c.upper()}{c.lower()}]" if c.isalpha() else c for c in name)
