"""Errors shared by every floor: a request the servo process refuses (the API answers 409)."""

from __future__ import annotations


class CommandRejected(ValueError):
    """A motion command that cannot be executed; the message names the field and the value."""
