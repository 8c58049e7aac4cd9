"""What a device's button may be mapped to (pure: names in, actions out).

Local actions change how the device itself reads: its frame, translation or rotation on or off, the
dominant-axis lock. An output action acts on the robot's I/O through the service: on each press,
``toggle_output:DO[1]`` flips digital output 1 (a gripper, a light). Outputs are written through
the stream's command packets, so they act only while the arm streams with input control enabled.
"""

from __future__ import annotations

import re
from dataclasses import dataclass

LOCAL_ACTIONS = ("toggle_frame", "toggle_translation", "toggle_rotation", "toggle_dominant")
OUTPUT_TYPES = ("DO", "RO", "F", "M")  # the writable point types of the J519 I/O fields
_OUTPUT = re.compile(r"toggle_output:([A-Z]+)\[(\d+)\]")


@dataclass(frozen=True)
class OutputToggle:
    io_type: str
    point: int  # 1-based, as on the teach pendant

    def __str__(self) -> str:
        return f"toggle_output:{self.io_type}[{self.point}]"


Action = str | OutputToggle  # a local action's name, or an output action


def parse_action(text: str) -> Action:
    """The action a configured name stands for; ValueError naming the value otherwise."""
    if text in LOCAL_ACTIONS:
        return text
    m = _OUTPUT.fullmatch(text)
    if m is None:
        raise ValueError(f"{text!r} is not a button action: one of {', '.join(LOCAL_ACTIONS)}, "
                         f"or toggle_output:TYPE[n] with TYPE in {', '.join(OUTPUT_TYPES)}")
    io_type, point = m.group(1), int(m.group(2))
    if io_type not in OUTPUT_TYPES:
        raise ValueError(f"{text!r}: {io_type} is not an output type ({', '.join(OUTPUT_TYPES)})")
    if point < 1:
        raise ValueError(f"{text!r}: points are numbered from 1")
    return OutputToggle(io_type, point)
