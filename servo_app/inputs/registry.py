"""Adapters registered by type name and built from configuration, like python-can's interfaces.

Built-in types are registered as "module:Class" strings and imported only when used, so a service
without CAN never imports python-can, and the HID adapter imports hidapi only when it opens.
"""

from __future__ import annotations

import importlib
import time
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from pydantic import ValidationError

from servo_app.inputs.adapter import AdapterConfig, Clock, InputAdapter
from servo_app.inputs.errors import ConfigError, ConfigIssue, issues_from_validation

_REGISTRY: dict[str, type[InputAdapter] | str] = {
    "spacemouse": "servo_app.inputs.spacemouse.hid_adapter:SpaceMouseHidAdapter",
    "spacenav": "servo_app.inputs.spacemouse.spacenav_adapter:SpaceNavAdapter",
    "serial_line": "servo_app.inputs.serial_sensor.adapter:SerialLineAdapter",
    "serial_binary": "servo_app.inputs.serial_sensor.adapter:SerialBinaryAdapter",
    "can": "servo_app.inputs.can_sensor.adapter:CanSensorAdapter",
    "gamepad": "servo_app.inputs.gamepad.adapter:GamepadAdapter",
}


def register_adapter(type_name: str, cls: type[InputAdapter] | str) -> None:
    """Register an adapter class (or a lazy "module:Class" reference) under a type name."""
    if isinstance(cls, type) and not issubclass(cls, InputAdapter):
        raise TypeError(f"{cls!r} is not an InputAdapter")
    _REGISTRY[type_name] = cls


def adapter_types() -> list[str]:
    return sorted(_REGISTRY)


def adapter_class(type_name: str) -> type[InputAdapter]:
    entry = _REGISTRY[type_name]
    if isinstance(entry, str):
        module, _, attr = entry.partition(":")
        entry = getattr(importlib.import_module(module), attr)
        _REGISTRY[type_name] = entry
    return entry


def validate_adapter_config(data: Mapping[str, Any], *, file: str = "<config>", prefix: str = "",
                            base_dir: Path | None = None) -> AdapterConfig:
    """Validate one adapter table; errors name the file, the dotted key and the offending value."""
    type_name = data.get("type")
    if type_name not in _REGISTRY:
        raise ConfigError([ConfigIssue(file, f"{prefix}type", type_name,
                                       f"unknown adapter type; known: {', '.join(adapter_types())}")])
    cls = adapter_class(type_name)
    try:
        return cls.config_model.model_validate(dict(data), context={"base_dir": base_dir})
    except ValidationError as exc:
        raise ConfigError(issues_from_validation(exc, file, prefix)) from None


def create_adapter(config: Mapping[str, Any] | AdapterConfig, *, clock: Clock = time.monotonic,
                   file: str = "<config>", base_dir: Path | None = None) -> InputAdapter:
    """Build an adapter from a dict with at least `name` and `type` (or an already validated config)."""
    if not isinstance(config, AdapterConfig):
        prefix = f"adapters.{config.get('name', '?')}."
        config = validate_adapter_config(config, file=file, prefix=prefix, base_dir=base_dir)
    return adapter_class(config.type)(config, clock=clock)
