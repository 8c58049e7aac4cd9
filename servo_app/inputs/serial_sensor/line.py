"""Line-oriented ASCII sensors, e.g. a distance sensor printing `D=123.45\r\n`.

Each field has a regular expression searched in every line; its first group (or the group named
`value`) is the number. A line where no field matches, or a number that does not parse, is
malformed. A line that never ends is cut at `max_line` bytes so garbage cannot grow the buffer, and
a line longer than that is refused whole (garbage ending in `D=5` is not a reading of 5).
"""

from __future__ import annotations

import re
from collections.abc import Mapping

from servo_app.inputs.serial_sensor.parsing import Bad, Decoded, ParseResult


class LineParser:
    def __init__(self, patterns: Mapping[str, str | re.Pattern[str]], *, terminator: bytes = b"\n",
                 encoding: str = "ascii", max_line: int = 256) -> None:
        if not terminator:
            raise ValueError("terminator must not be empty")
        self.patterns = {k: re.compile(p) if isinstance(p, str) else p for k, p in patterns.items()}
        for name, p in self.patterns.items():
            if p.groups < 1:
                raise ValueError(f"pattern for field {name!r} needs a group around the number")
        self.terminator = terminator
        self.encoding = encoding
        self.max_line = max_line
        self._buf = bytearray()

    def feed(self, data: bytes) -> list[ParseResult]:
        self._buf.extend(data)
        out: list[ParseResult] = []
        while True:
            i = self._buf.find(self.terminator)
            if i < 0:
                if len(self._buf) > self.max_line:
                    out.append(Bad("overflow", f"no line end within {self.max_line} bytes", bytes(self._buf)))
                    self._buf.clear()
                return out
            raw = bytes(self._buf[:i])
            del self._buf[:i + len(self.terminator)]
            line = raw.strip(b"\r\n")
            if len(line) > self.max_line:
                out.append(Bad("overflow", f"a line of {len(line)} bytes, longer than max_line {self.max_line}", line))
            elif line:
                out.append(self._parse(line))

    def _parse(self, line: bytes) -> ParseResult:
        try:
            text = line.decode(self.encoding)
        except UnicodeDecodeError as exc:
            return Bad("malformed", f"not {self.encoding} text: {exc.reason}", line)
        values: dict[str, float] = {}
        for name, pattern in self.patterns.items():
            m = pattern.search(text)
            if m is None:
                continue
            token = m.group("value") if "value" in pattern.groupindex else m.group(1)
            try:
                values[name] = float(token)
            except (TypeError, ValueError):
                return Bad("malformed", f"field {name!r} value {token!r} is not a number", line)
        if not values:
            return Bad("malformed", "no field matched the line", line)
        return Decoded(values, line)
