"""SpaceMouse through the spacenavd daemon (when the daemon owns the device).

The daemon only sends on change, so between events the last state holds: a zero state is refreshed
as "at rest" while the connection is up; a deflected state is held for `hold_s` after its last
event (the kernel may drop repeated identical values while the cap is held steady) and then goes
stale. The default hold of 0 s keeps the safe behaviour: no news while deflected means stop.
"""

from __future__ import annotations

import time
from typing import Literal

from pydantic import Field

from servo_app.inputs.adapter import Clock, InputAdapter
from servo_app.inputs.device_failure import DeviceFailure, spacenav_failure
from servo_app.inputs.spacemouse.core import SpaceMouseConfig, SpaceMouseCore
from servo_app.inputs.spacemouse.spacenav import (
    DEFAULT_SOCKET,
    ButtonChange,
    MalformedEvent,
    MotionEvent,
    SpnavClient,
    decode_event,
)


class SpaceNavConfig(SpaceMouseConfig):
    type: Literal["spacenav"] = "spacenav"
    socket: str = DEFAULT_SOCKET
    hold_s: float = Field(0.0, ge=0.0)
    # spacenavd's own convention (its default axis map): X right, Y up, Z away from the user, the same
    # for rotations. The robot's, as the HID adapter gives it: X right, Y away, Z up. So Y and Z trade
    # places, and pushing the cap away moves the arm away (read as they came, it moved up, and lifting
    # the cap moved it away).
    axis_map: list[int] = Field(default_factory=lambda: [0, 2, 1, 3, 5, 4], min_length=6, max_length=6)
    axis_signs: list[int] = Field(default_factory=lambda: [1, 1, 1, 1, 1, 1], min_length=6, max_length=6)


class SpaceNavAdapter(InputAdapter):
    config_model = SpaceNavConfig
    config: SpaceNavConfig

    def __init__(self, config: SpaceNavConfig, *, clock: Clock = time.monotonic) -> None:
        super().__init__(config, clock=clock)
        self.client = SpnavClient(config.socket)
        self.core = SpaceMouseCore(config, self._publish, self._emit)
        self._last_motion = -float("inf")

    def _open(self) -> None:
        self.client.connect(timeout_s=max(self.config.poll_timeout_s, 0.5))
        self.core.reset()

    def _close(self) -> None:
        self.client.close()

    def explain_open_failure(self, exc: BaseException) -> DeviceFailure:
        return spacenav_failure(self.name, self.config.socket, exc)

    def _poll(self) -> None:
        self.process(self.client.receive(self.core.rest_wait_s), self.clock())

    def process(self, events: list[bytes], now: float) -> None:
        moved = False
        for raw in events:
            try:
                ev = decode_event(raw)
            except MalformedEvent as exc:
                self.problems.record("malformed", str(exc), exc.data)
                continue
            if isinstance(ev, MotionEvent):
                self.core.set_axes(ev.translation, ev.rotation)
                moved = True
            elif isinstance(ev, ButtonChange):
                self.core.button(ev.button, ev.pressed, now)
        if moved:
            self._last_motion = now
        if moved or self.core.at_rest or now - self._last_motion <= self.config.hold_s:
            self.core.publish(now)
