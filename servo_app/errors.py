"""Errors shared by every floor: why a request was refused, by kind.

- :class:`CommandRejected`: the current state does not allow it (the API answers 409, and the text
  ends with the next step: start a session, resume, reset the fault, ...);
- :class:`InvalidRequest`: the request itself is bad: a count, a range, an implausible value (the API
  answers 422). It is a CommandRejected too, so a caller that only asks "was it refused?" keeps
  working; the API tells them apart by catching InvalidRequest first.

Either way the message names the field and the value, and nothing changed.
"""

from __future__ import annotations


class CommandRejected(ValueError):
    """A motion command that cannot be executed in the current state; the message says what to do next."""


class InvalidRequest(CommandRejected):
    """A request refused for its own values before anything changed (the API answers 422)."""
