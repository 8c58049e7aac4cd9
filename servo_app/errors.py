"""Errors shared by every floor: why a request was refused, by kind.

- :class:`CommandRejected`: the current state does not allow it (the API answers 409, and the text
  ends with the next step: start a session, resume, reset the fault, ...);
- :class:`InvalidRequest`: the request itself is bad: a count, a range, an implausible value (the API
  answers 422). It is a CommandRejected too, so a caller that only asks "was it refused?" keeps
  working; the API tells them apart by catching InvalidRequest first.

Either way the message names the field and the value, and nothing changed. :func:`json_safe` makes a
refusal's details, which echo the input, encodable; :func:`validation_errors` also keeps the echo short.
"""

from __future__ import annotations

import json
import math
from typing import Any


class CommandRejected(ValueError):
    """A motion command that cannot be executed in the current state; the message says what to do next."""


class InvalidRequest(CommandRejected):
    """A request refused for its own values before anything changed (the API answers 422)."""


def json_safe(value: object) -> object:
    """``value`` in a form JSON can carry: non-finite numbers become their names ("nan", "inf"),
    exceptions (pydantic's ``ctx``) their messages, mapping keys strings, and any other object JSON has
    no type for its text. A validation error echoes the bad input: NaN there made the refusal itself
    fail to encode (a 500)."""
    if isinstance(value, float):
        return value if math.isfinite(value) else str(value)
    if value is None or isinstance(value, str | int):  # (bool is an int)
        return value
    if isinstance(value, dict):
        return {str(k): json_safe(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [json_safe(v) for v in value]
    return str(value)


ECHO_CHARS = 500  # of a refusal's echo of the bad input, as JSON text


def echoed(value: object) -> object:
    """A refusal's echo of the bad input: as :func:`json_safe` makes it, or, when its JSON text is
    longer than ECHO_CHARS, the start of that text and its length (a 1.9 MB junk field came back
    whole in its 422)."""
    safe = json_safe(value)
    text = json.dumps(safe)
    if len(text) <= ECHO_CHARS:
        return safe
    return f"{text[:ECHO_CHARS]}... ({len(text)} characters in all)"


CLOSE_REASON_BYTES = 123  # RFC 6455: a close frame's payload is at most 125 bytes, 2 of them the code


def close_reason(text: str) -> str:
    """``text`` as a WebSocket close frame can carry it: at most 123 UTF-8 bytes, cut short with "...".
    A longer reason (one echoing a long query value or path) made the close itself fail: the server
    logged a ProtocolError and the socket ended with no code and no reason."""
    data = text.encode()
    if len(data) <= CLOSE_REASON_BYTES:
        return text
    return data[: CLOSE_REASON_BYTES - 3].decode(errors="ignore") + "..."


def validation_errors(errors: list[Any]) -> list[Any]:
    """A validation error list (pydantic's, FastAPI's) as a refusal carries it: JSON-safe, each input
    echoed within ECHO_CHARS."""
    return [json_safe({**e, "input": echoed(e["input"])} if isinstance(e, dict) and "input" in e else e)
            for e in errors]
