"""Robot backends: one interface, a registry by name (python-can's ``BusABC`` and ``BACKENDS``).

A backend is everything vendor-specific the service, the API and the console need: its wire
session and servo process, its profiles, its embedded simulator, its axes and units, its I/O rules,
its alarm catalogue and its limits. The service asks the backend; nothing above this module tests
for a vendor's name. ``docs/backends.md`` says what a new one implements.

``--robot NAME[:TARGET]`` picks one: ``fanuc:HOST[:PORT]``, ``janome:HOST[:PORT]``, or the name alone
for the backend's embedded simulator. Backends register by name, lazily imported like python-can's
interfaces, so a plug-in (tests/toy_backend.py) adds one without touching this file, in code::

    register_backend("toy", "toy_backend:ToyBackend")

or, for ``servo-app run --robot toy``, as an installed package's entry point (python-can's way too)::

    [project.entry-points."servo_app.backends"]
    toy = "toy_backend:ToyBackend"
"""

from __future__ import annotations

import importlib
import importlib.metadata
from abc import ABC, abstractmethod
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, ClassVar

from servo_app.errors import InvalidRequest as InvalidRequest  # re-exported: the I/O rules raise it
from servo_app.messages import Event
from servo_app.process_handle import ServoProcessHandle

# name -> (module, class): imported on first use, so an unused vendor costs nothing.
BACKENDS: dict[str, tuple[str, str]] = {
    "fanuc": ("servo_app.fanuc.backend", "FanucBackend"),
    "janome": ("servo_app.janome.backend", "JanomeBackend"),
}
DEFAULT_BACKEND = "fanuc"


@dataclass(frozen=True)
class AlarmInfo:
    """A catalogue entry: what the controller's code means and what to do about it."""

    code: str
    cause: str
    remedy: str
    warning: bool = False


@dataclass(frozen=True)
class Target:
    """Where the robot is: ``host:port`` to reach (or, for a listening backend, to listen on);
    ``embedded``: the backend's own simulator stands in for it."""

    host: str
    port: int
    embedded: bool


@dataclass
class ProcessOptions:
    """What the service hands every backend's servo process."""

    interval_ms: int | None
    lead: int
    log_dir: str
    limit_fraction: float
    flange_speed_cap: float | None
    payload_kg: float | None
    start_timeout_s: float
    input_slot: str | None


class RobotBackend(ABC):
    name: ClassVar[str]
    default_port: ClassVar[int]
    default_model: ClassVar[str]
    #: The robot connects to us (Janome's point job); else we reach the controller.
    listens: ClassVar[bool] = False
    #: The console may jog in Cartesian space (twists, pose targets).
    cartesian_jog: ClassVar[bool] = False
    #: The embedded simulator takes ``set_payload`` (the active tool's payload, servo_app.service.tools).
    simulator_payload: ClassVar[bool] = False
    #: I/O type -> assigned points that clients may read and write (empty: no I/O).
    default_io_allow: ClassVar[dict[str, int]] = {}

    def __init__(self, model: str | None, target: Target, io_allow: dict[str, int] | None = None) -> None:
        self.target = target
        self.model = self.resolve_model(model)
        self.profile: Any = self.load_profile(self.model)
        # Checked here, at start: a misspelled type or a bad count would otherwise show only at the
        # first access, as a refusal (or a 500) for I/O the configuration meant to allow.
        self._io_allow = dict(self.default_io_allow) if io_allow is None else self.check_io_allow(io_allow)

    # -- profiles
    @classmethod
    @abstractmethod
    def models(cls) -> list[str]:
        """The profile names this backend knows."""

    @classmethod
    def resolve_model(cls, model: str | None) -> str:
        """The profile to load for ``--model`` (None: the backend's default)."""
        return model or cls.default_model

    @abstractmethod
    def load_profile(self, model: str) -> Any: ...

    @property
    def display_name(self) -> str:
        return str(getattr(self.profile, "display_name", self.model))

    # -- the servo process and the simulator
    @abstractmethod
    def make_process(self, target: Target, options: ProcessOptions, on_event: Callable[[Event], None],
                     on_exit: Callable[[str], None]) -> ServoProcessHandle:
        """A (not yet started) servo process for ``target``."""

    def start_simulator(self, target: Target, sim_options: dict[str, Any], realtime_priority: int | None) -> Any:
        """Start the embedded simulator. A connecting backend's simulator serves ``target`` (port 0:
        any) and has ``address``; a listening backend's connects to ``target``. ``None``: none.

        The service calls its ``call(name, *args, timeout=S)`` (``events``: the alarm list; ``reset``;
        the backend's own controls) from several threads at once, and ``stop(timeout)`` at the end.
        A call not answered within ``timeout`` raises TimeoutError, a refused one RuntimeError.
        Optionally ``alive`` (its process runs) and ``restart()``: a reset starts again a simulator
        whose process died."""
        return None

    @property
    def simulator_first(self) -> bool:
        """The simulator must run before the servo process (it is the server)."""
        return not self.listens

    # -- what the API and the console show
    @abstractmethod
    def axes(self) -> list[dict[str, Any]]:
        """Each axis: name, unit, min, max, speed (the console's jog pad and bars)."""

    @abstractmethod
    def robot_view(self, q: list[float]) -> dict[str, Any]:
        """Geometry and drawing points for positions ``q`` (``GET /api/robot``)."""

    @abstractmethod
    def limits(self, state: dict[str, Any], options: ProcessOptions) -> dict[str, Any]:
        """The limits in force (``GET /api/limits``), from the live state where the controller sent them."""

    def alarm(self, code: str) -> AlarmInfo | None:
        """The catalogue entry for a controller alarm code, or None."""
        return None

    def flange_speed_cap(self, options: ProcessOptions, tables: Any = None) -> tuple[float, str] | None:
        """The flange-speed cap in force (mm/s) and where it comes from, for ``GET /api/limits`` and
        ``GET /api/robot``; ``tables`` as for :meth:`twist_flange_cap`. None: the backend has none."""
        return None

    def twist_flange_cap(self, options: ProcessOptions, tables: Any = None) -> float | None:
        """The flange speed (mm/s) above which the servo process refuses a twist (the TCP's speed plus
        the swing of a turn about the tool), for the input feeds to refuse at the door; None: it
        refuses none (it slows down instead). ``tables``: the limit tables the controller published
        (LimitTablesReceived), whose cap may be tighter than the configured one; None: none yet."""
        return None

    # -- poses
    def check_pose(self, xyzwpr: tuple[float, ...], tool_xyzwpr: tuple[float, ...] | None = None) -> None:
        """InvalidRequest for a pose (of the tool ``tool_xyzwpr``, None: the flange) that is surely wrong
        before any solve: in the wrong units, out of reach. Default: none is."""
        return None

    def target_bounds(self) -> list[tuple[float, float]] | None:
        """Per axis, the (lowest, highest) value a joint target can have, in the request's units: what
        the API documents (the target check refuses outside, and may refuse more). None: no bound known."""
        return None

    # -- I/O
    def io_allow(self) -> dict[str, int]:
        """I/O type -> assigned points that clients may read and write; empty: no I/O."""
        return dict(self._io_allow)

    def io_indexes(self) -> dict[str, tuple[int, int]]:
        """Canonical I/O type -> (first, last) index ``check_io`` allows (the API documents them);
        empty: no I/O. Default: none."""
        return {}

    def check_io_allow(self, io_allow: dict[str, int]) -> dict[str, int]:
        """``io_allow`` (type -> assigned points) checked for this backend; ValueError naming the key,
        its value and what is allowed. Default: a backend without I/O (no ``check_io``) takes none."""
        if io_allow and type(self).check_io is RobotBackend.check_io:
            raise ValueError(f"io_allow={io_allow!r}: the {self.name} backend has no I/O through its stream; "
                             "leave io_allow out")
        return dict(io_allow)

    def check_io(self, io_type: str, index: int) -> str:
        """The I/O type's canonical name if an access at ``index`` is allowed; else InvalidRequest."""
        raise InvalidRequest(f"type={io_type!r}: the {self.name} backend has no I/O through its stream")

    def io_window(self, io_type: str, point: int) -> tuple[int, int]:
        """(index, bit) of the access that reaches ``point``."""
        raise InvalidRequest(f"{io_type}[{point}]: the {self.name} backend has no I/O through its stream")

    def io_type_code(self, name: str) -> int:
        """The wire code of an I/O type that ``check_io`` allowed (what the status echoes)."""
        raise InvalidRequest(f"type={name!r}: the {self.name} backend has no I/O through its stream")

    def io_read_delay(self, lead: int) -> int:
        """Status packets from a read request to the one that carries its value."""
        return lead + 2


def register_backend(name: str, where: str) -> None:
    """Register a backend class by name: ``where`` is ``"module:Class"``."""
    module, _, cls = where.partition(":")
    if not module or not cls:
        raise ValueError(f"backend {name!r}: {where!r} must be 'module:Class'")
    BACKENDS[name] = (module, cls)


ENTRY_POINTS = "servo_app.backends"


def known_backends() -> dict[str, tuple[str, str]]:
    """The registered backends and those installed packages declare as entry points."""
    found = {ep.name: (ep.module, ep.attr) for ep in importlib.metadata.entry_points(group=ENTRY_POINTS)}
    return {**found, **BACKENDS}


def backend_class(name: str) -> type[RobotBackend]:
    known = known_backends()
    try:
        module, cls = known[name]
    except KeyError:
        raise ValueError(f"robot backend {name!r} is unknown (known: {', '.join(sorted(known))})") from None
    found = getattr(importlib.import_module(module), cls)
    if not (isinstance(found, type) and issubclass(found, RobotBackend)):
        raise TypeError(f"{module}:{cls} is not a RobotBackend")
    return found


def parse_robot(spec: str | None) -> tuple[str, Target]:
    """The ``--robot`` option: ``NAME:HOST[:PORT]`` or ``NAME`` alone (its embedded simulator);
    None means the default backend's embedded simulator."""
    if not spec:
        return DEFAULT_BACKEND, Target("127.0.0.1", 0, embedded=True)
    name, _, rest = spec.partition(":")
    backends = known_backends()
    known = ", ".join(f"{n}[:HOST[:PORT]]" for n in sorted(backends))
    if name not in backends:
        raise ValueError(f"--robot={spec!r}: unknown robot backend {name!r}; expected one of {known}")
    if not rest:
        return name, Target("127.0.0.1", 0, embedded=True)
    host, _, port = rest.partition(":")
    if not host:
        raise ValueError(f"--robot={spec!r}: the host is missing; expected {name}:HOST[:PORT]")
    try:
        number = int(port) if port else backend_class(name).default_port
    except ValueError:
        raise ValueError(f"--robot={spec!r}: port {port!r} is not a number") from None
    if not 0 <= number <= 65535:  # (the servo process's connect failed on 99999, after start-up)
        raise ValueError(f"--robot={spec!r}: port {number} is outside 0..65535")
    return name, Target(host, number, embedded=False)


def open_backend(spec: str | None, model: str | None, io_allow: dict[str, int] | None = None) -> RobotBackend:
    name, target = parse_robot(spec)
    return backend_class(name)(model, target, io_allow)
