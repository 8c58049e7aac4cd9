"""The inputs section of the service configuration, read from TOML.

    [adapters.<name>]          # one table per adapter; `type` picks the class from the registry
    type = "spacemouse"
    priority = 20

    [feeds.<name>]             # HTTP/WebSocket feed sources (no thread: the API publishes them)
    kind = "pose"

Every problem is reported with the file, the dotted key and the value, all at once.
"""

from __future__ import annotations

import time
import tomllib
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from pydantic import ValidationError

from servo_app.inputs.adapter import AdapterConfig, Clock, InputAdapter
from servo_app.inputs.errors import ConfigError, ConfigIssue, issues_from_validation
from servo_app.inputs.feed.models import FeedSourceConfig
from servo_app.inputs.registry import create_adapter, validate_adapter_config

# [[applications]] is read by servo_app.inputs.apps.config (load_service_inputs), which needs the sources first.
_TOP_LEVEL = {"adapters", "feeds", "applications"}


@dataclass
class InputsConfig:
    path: Path | None
    adapters: list[AdapterConfig] = field(default_factory=list)
    feeds: dict[str, FeedSourceConfig] = field(default_factory=dict)


def read_toml(path: Path) -> dict[str, Any]:
    """A configuration file's tables; an unreadable or malformed file is a ConfigError naming it."""
    file = str(path)
    try:
        return tomllib.loads(path.read_text(encoding="utf-8"))
    except OSError as exc:
        raise ConfigError([ConfigIssue(file, "", None, f"cannot read: {exc.strerror or exc}")]) from None
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError([ConfigIssue(file, "", None, f"not valid TOML: {exc}")]) from None


def load_inputs_config(path: str | Path) -> InputsConfig:
    path = Path(path)
    return parse_inputs_config(read_toml(path), file=str(path), base_dir=path.parent, path=path)


def parse_inputs_config(data: Mapping[str, Any], *, file: str = "<config>", base_dir: Path | None = None,
                        path: Path | None = None) -> InputsConfig:
    issues: list[ConfigIssue] = []
    cfg = InputsConfig(path)
    for key in data:
        if key not in _TOP_LEVEL:
            issues.append(ConfigIssue(file, key, data[key], f"unknown section; expected one of {sorted(_TOP_LEVEL)}"))

    for name, table in _tables(data, "adapters", file, issues):
        if "name" in table and table["name"] != name:
            issues.append(ConfigIssue(file, f"adapters.{name}.name", table["name"], "must match the table name"))
            continue
        try:
            cfg.adapters.append(validate_adapter_config({**table, "name": name}, file=file,
                                                        prefix=f"adapters.{name}.", base_dir=base_dir))
        except ConfigError as exc:
            issues.extend(exc.issues)

    adapter_names = set(_raw_names(data, "adapters"))
    for name, table in _tables(data, "feeds", file, issues):
        if name in adapter_names:
            # One name, one source: the feed's slot replaced the adapter's, and the device was ignored.
            issues.append(ConfigIssue(file, f"feeds.{name}", table, f"already names an adapter ([adapters.{name}]); "
                                      "give the feed or the adapter another name"))
            continue
        try:
            cfg.feeds[name] = FeedSourceConfig.model_validate(table)
        except ValidationError as exc:
            issues.extend(issues_from_validation(exc, file, f"feeds.{name}."))

    if issues:
        raise ConfigError(issues)
    return cfg


def _raw_names(data: Mapping[str, Any], section: str) -> list[str]:
    raw = data.get(section, {})
    return list(raw) if isinstance(raw, dict) else []


def _tables(data: Mapping[str, Any], section: str, file: str,
            issues: list[ConfigIssue]) -> list[tuple[str, dict[str, Any]]]:
    raw = data.get(section, {})
    if not isinstance(raw, dict):
        issues.append(ConfigIssue(file, section, raw, "must be a table of named tables"))
        return []
    out = []
    for name, table in raw.items():
        if not isinstance(table, dict):
            issues.append(ConfigIssue(file, f"{section}.{name}", table, "must be a table"))
        else:
            out.append((name, table))
    return out


def build_adapters(cfg: InputsConfig, *, clock: Clock = time.monotonic) -> list[InputAdapter]:
    """Instantiate the configured adapters (not started)."""
    return [create_adapter(a, clock=clock) for a in cfg.adapters]
