"""Configuration errors that say where: file, dotted key, offending value, and why."""

from __future__ import annotations

from dataclasses import dataclass

from pydantic import ValidationError

from servo_app.input_slot import MAX_HOLD_S

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


# A source's timeout must end before the servo's longest hold does (with the bridge's grace to spare),
# or the servo stops by itself first: "hold-to-run expired" after 2 s of motion on a dead sensor's last
# command, not "input <source> stale" after the timeout. 200 meant as milliseconds did just that.
MAX_STALE_AFTER_S = MAX_HOLD_S - 0.1


def check_stale_after(value: float | None) -> None:
    """KeyedError for a timeout the servo's own hold would cut short."""
    if value is not None and value > MAX_STALE_AFTER_S:
        raise KeyedError("stale_after_s", value, f"at most {MAX_STALE_AFTER_S:g} (seconds, not milliseconds): the "
                         f"servo holds an input command at most {MAX_HOLD_S:g} s, so with a longer timeout a source "
                         "that went quiet stopped the arm late, 'hold-to-run expired', not named")
