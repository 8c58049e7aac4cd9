"""The service behind the API, split by job: ``core`` (the lifecycle and requests), ``alarms``
(controller alarms forwarded to the servo process), ``io`` (I/O through the stream) and ``views``
(what the API shows). Everything vendor-specific comes from the robot backend
(:mod:`servo_app.backends`)."""

from servo_app.backends import InvalidRequest
from servo_app.service.config import ServiceConfig
from servo_app.service.core import ServoService

__all__ = ["InvalidRequest", "ServiceConfig", "ServoService"]
