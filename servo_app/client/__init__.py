"""A Python client for a running servo_app service (``servo-app run``): lease, session, motion, jogs,
I/O, telemetry and teach points, with typed errors. Depends on httpx and websockets only.

    from servo_app.client import ServoClient

    with ServoClient("http://127.0.0.1:8000", token="...") as arm:
        arm.start()
        arm.move_joints([0, 0, 0, 0, -90, 0])
        with arm.jog(linear=(20, 0, 0)):   # held while the block runs
            time.sleep(1.0)
        arm.teach("above_part")
"""

from servo_app.client.client import JogHold, Recording, ServoClient
from servo_app.client.errors import (
    AuthError,
    FaultError,
    LeaseError,
    RefusedError,
    ServoError,
    StoppedError,
    TimeoutError,
)
from servo_app.client.frames import offset_in_tool
from servo_app.client.state import Alarm, Fault, Point, State, Tool

__all__ = [
    "Alarm",
    "AuthError",
    "Fault",
    "FaultError",
    "JogHold",
    "LeaseError",
    "Point",
    "Recording",
    "RefusedError",
    "ServoClient",
    "ServoError",
    "State",
    "StoppedError",
    "TimeoutError",
    "Tool",
    "offset_in_tool",
]
