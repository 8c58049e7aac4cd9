"""Configuration errors that say where: file, dotted key, offending value, and why."""

from __future__ import annotations

from dataclasses import dataclass

from pydantic import ValidationError

_MISSING = "<missing>"


@dataclass(frozen=True)
class ConfigIssue:
    file: str
    key: str
    value: object
    reason: str

    def __str__(self) -> str:
        return f"{self.file}: {self.key} = {self.value!r}: {self.reason}"


class KeyedError(ValueError):
    """Raised from a model-level check to point at one key (pydantic would blame the whole table)."""

    def __init__(self, key: str, value: object, message: str) -> None:
        super().__init__(message)
        self.key = key
        self.value = value


class ConfigError(ValueError):
    def __init__(self, issues: list[ConfigIssue]) -> None:
        self.issues = issues
        super().__init__("\n".join(str(i) for i in issues))


def issues_from_validation(exc: ValidationError, file: str, prefix: str = "") -> list[ConfigIssue]:
    issues = []
    for err in exc.errors():
        # Drop pydantic's union/function markers so the key reads as the user wrote it.
        loc = [str(p) for p in err["loc"] if not str(p).startswith(("function-", "union["))]
        cause = (err.get("ctx") or {}).get("error")
        if isinstance(cause, KeyedError):
            loc.append(cause.key)
            key = prefix + ".".join(loc)
            issues.append(ConfigIssue(file, key, cause.value, str(cause)))
            continue
        key = prefix + ".".join(loc) if loc else prefix.rstrip(".")
        value = _MISSING if err["type"] == "missing" else err.get("input")
        issues.append(ConfigIssue(file, key, value, err["msg"]))
    return issues
