"""The one interface every input adapter implements, and the thread that runs it.

An adapter owns one device (or socket, or bus). Its thread opens the device, then polls it in short
bounded waits so `stop()` is honoured promptly, and publishes stamped samples into `output` (a
latest-value slot) and button events into `events`. Whatever goes wrong is caught and counted:
an I/O error closes the device and retries with exponential backoff (the source goes stale
meanwhile, because nothing is published); any other exception is logged with its traceback and the
adapter keeps polling.
"""

from __future__ import annotations

import logging
import math
import threading
import time
from abc import ABC, abstractmethod
from collections import Counter
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any, ClassVar

from pydantic import BaseModel, ConfigDict, Field, PositiveFloat, field_validator, model_validator

from servo_app.inputs.device_failure import DeviceFailure, generic_failure
from servo_app.inputs.errors import check_stale_after
from servo_app.inputs.problems import Problem, ProblemLog
from servo_app.inputs.samples import ButtonEvent, check_jog_stale, check_twist_frames
from servo_app.inputs.slots import EventQueue, LatestValue
from servo_app.inputs.validate import ValueRejected
from servo_app.realtime import make_realtime

Clock = Callable[[], float]
RobotState = Callable[[], Mapping[str, Any]]  # the servo process's published state (a shared-memory copy)


class AdapterConfig(BaseModel):
    """Settings common to all adapters; each adapter type extends this with its own."""

    # No inf or nan in any setting: TOML spells both, and stale_after_s = inf would mean a device
    # unplugged mid-jog never goes stale (the arm runs on until the servo's own hold cap runs out).
    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)

    name: str = Field(min_length=1)
    type: str
    priority: int = 0
    stale_after_s: PositiveFloat = 0.1
    # Multiplier on published values: one number, or one per field name (measurements).
    scale: float | dict[str, float] = 1.0
    # Measurement adapters: |value| <= deadband publishes 0. SpaceMouse: fraction of full scale.
    deadband: float = Field(0.0, ge=0.0)
    yield_when_idle: bool = False
    poll_timeout_s: PositiveFloat = 0.05
    reconnect_min_s: PositiveFloat = 0.2
    reconnect_max_s: PositiveFloat = 5.0
    # SCHED_FIFO priority of the adapter's thread (0: normal scheduling). Above ordinary work, so a
    # frame is read as it arrives; below the servo process (20) and the embedded simulator (10).
    realtime_priority: int = Field(5, ge=0, le=99)

    @model_validator(mode="after")
    def _timeout_cap(self) -> AdapterConfig:
        # As for feeds and applications: past the servo's longest hold, a device gone quiet mid-jog
        # left the arm moving on its last command until 'hold-to-run expired', the source not named.
        check_stale_after(self.stale_after_s)
        return self


class JogDeviceConfig(AdapterConfig):
    """What the hand-held jog devices (SpaceMouse, gamepad) check alike; each declares its own `frames`
    (hence check_fields=False), so the field order of each config stays its own."""

    device: ClassVar[str]  # as messages name it: "the gamepad takes one overall scale factor"

    @field_validator("frames", check_fields=False)
    @classmethod
    def _frames(cls, v: list[str]) -> list[str]:
        # Checked here: a frame the servo lacks loaded silently, and after toggle_frame reached it
        # every sample was refused and the arm stopped answering.
        return check_twist_frames(v)

    @field_validator("stale_after_s")
    @classmethod
    def _stale(cls, v: float) -> float:
        # Each poll also waits at most a quarter of it: a tiny one spun the adapter's thread too.
        return check_jog_stale(v)

    @field_validator("scale", mode="before")
    @classmethod
    def _scalar_scale(cls, v: object) -> object:
        # One factor for the whole device: AdapterConfig's per-field scales are for measurements.
        if isinstance(v, dict):
            raise ValueError(f"the {cls.device} takes one overall scale factor")
        return v


@dataclass(frozen=True)
class SourceSpec:
    """What the arbiter needs to know about a command source."""

    name: str
    priority: int
    stale_after_s: float
    slot: LatestValue[Any]
    yield_when_idle: bool = False


@dataclass(frozen=True)
class AdapterStatus:
    name: str
    type: str
    running: bool
    connected: bool
    stale: bool
    age_s: float
    samples: int
    connects: int
    problems: Counter[str]  # missing kinds read as 0
    last_problem: Problem | None
    recent_problems: tuple[Problem, ...]  # newest last, with the offending bytes in hex
    failure: DeviceFailure | None = None  # the device cannot be opened now: which, why, what to do


class InputAdapter(ABC):
    config_model: ClassVar[type[AdapterConfig]] = AdapterConfig
    # Exceptions that mean "the device is gone": close and reconnect rather than keep polling.
    io_errors: ClassVar[tuple[type[BaseException], ...]] = (OSError,)

    def __init__(self, config: AdapterConfig, *, clock: Clock = time.monotonic) -> None:
        self.config = config
        self.clock = clock
        self.output: LatestValue[Any] = LatestValue(config.name)
        self.events: EventQueue[ButtonEvent] = EventQueue()
        self.log = logging.getLogger(f"servo_app.inputs.{config.type}.{config.name}")
        self.problems = ProblemLog(self.log, clock)
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._connected = False
        self._connects = 0
        self.failure: DeviceFailure | None = None  # why the last open failed; None once open
        self.first_attempt = threading.Event()  # set after the first open, failed or not
        self.scheduling = "not started"  # what the thread got: SCHED_FIFO or normal priority
        # Set by the inputs bridge when the service starts, for devices that signal the robot's state
        # back to the operator (a gamepad rumbles on a fault).
        self.robot_state: RobotState | None = None

    # -- identity -------------------------------------------------------------------------------
    @property
    def name(self) -> str:
        return self.config.name

    @property
    def priority(self) -> int:
        return self.config.priority

    @property
    def stale_after_s(self) -> float:
        return self.config.stale_after_s

    @property
    def connected(self) -> bool:
        return self._connected

    def source_spec(self) -> SourceSpec:
        return SourceSpec(self.name, self.priority, self.stale_after_s, self.output, self.config.yield_when_idle)

    # -- what each adapter implements -----------------------------------------------------------
    @abstractmethod
    def _open(self) -> None:
        """Open the device; raise (any exception) if it is not there."""

    @abstractmethod
    def _poll(self) -> None:
        """Wait at most `config.poll_timeout_s` for input, decode it and publish."""

    @abstractmethod
    def _close(self) -> None:
        """Release the device (it may already be gone)."""

    def explain_open_failure(self, exc: BaseException) -> DeviceFailure:
        """What `_open` raising ``exc`` means: the device, the reason, the fix. Adapters name their device."""
        return generic_failure(self.name, self.config.type, exc)

    # -- lifecycle ------------------------------------------------------------------------------
    def start(self) -> None:
        if self._thread is not None and self._thread.is_alive():
            return
        self._stop.clear()
        self.first_attempt.clear()
        self._thread = threading.Thread(target=self._run, name=f"input-{self.name}", daemon=True)
        self._thread.start()

    def stop(self, timeout: float = 5.0) -> None:
        self._stop.set()
        t = self._thread
        if t is not None and t is not threading.current_thread():
            t.join(timeout)
        self._thread = None

    @property
    def running(self) -> bool:
        return self._thread is not None and self._thread.is_alive()

    def __enter__(self) -> InputAdapter:
        self.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()

    def _run(self) -> None:
        try:
            self._run_until_stopped()
        finally:
            self.problems.flush()  # counts still held back by the log's rate limit

    def _run_until_stopped(self) -> None:
        self.scheduling = make_realtime(self.config.realtime_priority)
        backoff = self.config.reconnect_min_s
        while not self._stop.is_set():
            try:
                self._open()
            except Exception as exc:  # a missing device is normal while unplugged
                try:
                    self.failure = self.explain_open_failure(exc)
                except Exception:  # an explanation must never stop the retries
                    self.failure = generic_failure(self.name, self.config.type, exc)
                self.problems.record("open_failed", f"{self.failure.message} ({self.failure.error})",
                                     level=logging.INFO)
                self.first_attempt.set()
                self._safe_close()
                self._stop.wait(backoff)
                backoff = min(backoff * 2.0, self.config.reconnect_max_s)
                continue
            self.failure = None
            self.first_attempt.set()
            self._connected = True
            self._connects += 1
            backoff = self.config.reconnect_min_s
            try:
                self._poll_until_failure()
            finally:
                self._connected = False
                self._safe_close()
            if not self._stop.is_set():
                self._stop.wait(backoff)

    def _poll_until_failure(self) -> None:
        while not self._stop.is_set():
            self.problems.report_due()  # a held-back count whose kind did not recur
            try:
                self._poll()
            except self.io_errors as exc:
                self.problems.record("disconnected", f"{type(exc).__name__}: {exc}")
                return
            except Exception as exc:
                self.problems.record("error", f"{type(exc).__name__}: {exc}", level=logging.ERROR, exc_info=True)
                self._stop.wait(self.config.poll_timeout_s)  # a repeating bug must not spin a core

    def _safe_close(self) -> None:
        try:
            self._close()
        except Exception as exc:
            self.problems.record("close_failed", f"{type(exc).__name__}: {exc}", level=logging.INFO)

    # -- helpers for subclasses -----------------------------------------------------------------
    def _publish(self, sample: Any) -> None:
        self.output.publish(sample)

    def _emit(self, event: ButtonEvent) -> None:
        self.events.put(event)  # looked up each time: the bridge replaces the queue before start

    def _condition(self, field: str, value: float) -> float:
        """Apply the common deadband (hard zero, for measurements) and scale; ValueRejected if the scaled
        value overflows (a huge reading would otherwise fail the sample, and its neighbours, unnamed)."""
        scale = self.config.scale
        factor = scale.get(field, 1.0) if isinstance(scale, dict) else scale
        if self.config.deadband and abs(value) <= self.config.deadband:
            value = 0.0
        out = value * factor
        if not math.isfinite(out):
            raise ValueRejected(field, value, f"not finite once scaled by {factor}")
        return out

    def status(self, now: float | None = None) -> AdapterStatus:
        now = self.clock() if now is None else now
        age = self.output.age(now)
        counts, recent = self.problems.snapshot()
        return AdapterStatus(
            name=self.name, type=self.config.type, running=self.running, connected=self._connected,
            stale=age > self.stale_after_s, age_s=age, samples=self.output.seq, connects=self._connects,
            problems=counts, last_problem=recent[-1] if recent else None,
            recent_problems=tuple(recent), failure=self.failure,
        )


__all__ = ["AdapterConfig", "AdapterStatus", "Clock", "InputAdapter", "JogDeviceConfig", "RobotState", "SourceSpec"]
