"""Controller simulators that speak the real wire protocols.

FANUC Stream Motion (J519): :class:`FanucControllerModel` (pure, cycle by cycle) and
:class:`FanucSimulator` (the same on a UDP socket with its own tick thread). Janome: not yet.
"""

from servo_app.sim.fanuc_model import ControllerConfig, FanucControllerModel, ProgramState, SimControlError
from servo_app.sim.fanuc_server import FanucSimulator, FaultConfig

__all__ = [
    "ControllerConfig",
    "FanucControllerModel",
    "FanucSimulator",
    "FaultConfig",
    "ProgramState",
    "SimControlError",
]
