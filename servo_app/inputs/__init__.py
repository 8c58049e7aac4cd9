"""Input adapters behind one interface, a registry by type name, latest-value slots and the arbiter.

Nothing here imports the robot side: inputs publish stamped samples; the servo side reads them.
Device libraries (hidapi, pyserial, python-can, cantools, FastAPI) are imported only by the modules
that need them, and the registry imports those modules only when an adapter of that type is built.
"""

from servo_app.inputs.adapter import AdapterConfig, AdapterStatus, Clock, InputAdapter, SourceSpec
from servo_app.inputs.arbiter import Arbiter, Decision
from servo_app.inputs.config import InputsConfig, build_adapters, load_inputs_config, parse_inputs_config
from servo_app.inputs.errors import ConfigError, ConfigIssue
from servo_app.inputs.registry import adapter_class, adapter_types, create_adapter, register_adapter
from servo_app.inputs.samples import ButtonEvent, Measurement, PoseSample, TwistSample
from servo_app.inputs.slots import EventQueue, LatestValue, Stamped
from servo_app.inputs.validate import ValueRejected

__all__ = [
    "AdapterConfig", "AdapterStatus", "Arbiter", "ButtonEvent", "Clock", "ConfigError", "ConfigIssue", "Decision",
    "EventQueue", "InputAdapter", "InputsConfig", "LatestValue", "Measurement", "PoseSample", "SourceSpec", "Stamped",
    "TwistSample", "ValueRejected", "adapter_class", "adapter_types", "build_adapters", "create_adapter",
    "load_inputs_config", "parse_inputs_config", "register_adapter",
]
