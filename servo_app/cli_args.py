"""Argument types shared by the ``servo-app`` commands (argparse names the option with the message)."""

from __future__ import annotations

import argparse
from collections.abc import Callable


def port_arg(kind: str, zero_ok: bool = False) -> Callable[[str], int]:
    """An argparse ``type`` for a ``kind`` ("TCP", "UDP") port 0..65535; ``zero_ok`` says in the
    messages that 0 takes any free port. (70000 had a bind fail later: uvicorn's unreported, the
    service running on serving nothing; the simulator's as a traceback.)"""
    hint = " (0: any free port)" if zero_ok else ""

    def parse(text: str) -> int:
        try:
            port = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{text!r} is not a number: a {kind} port 0..65535{hint}") from None
        if not 0 <= port <= 65535:
            raise argparse.ArgumentTypeError(f"{port} is outside 0..65535{hint}")
        return port

    return parse
