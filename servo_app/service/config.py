"""The service's configuration (``servo-app run`` options and what tests set)."""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any


@dataclass
class ServiceConfig:
    robot: str | None = None  # --robot NAME[:HOST[:PORT]]; None: the default backend's embedded simulator
    model: str | None = None  # the backend's profile; None: its default
    interval_ms: int | None = None
    # Two commands ahead in the controller's buffer: a lost status packet is made up at the next one,
    # and with lead 2 only three lost in a row starve the controller (MOTN-603). Measured with the
    # simulator dropping 5 % of status packets: lead 1 alarmed within 1 s, lead 2 ran 15 s clean
    # (tests/test_faults_e2e.py). The price is two intervals of extra response time.
    lead: int = 2
    var_dir: Path = Path("var")
    sim_port: int = 0  # embedded simulator port (0: any free port)
    limit_fraction: float = 0.9
    flange_speed_cap: float | None = None  # mm/s; None: $MAX_SPD. Held to the controller's $MAX_SPD when that is lower
    payload_kg: float | None = None
    # Options for the embedded simulator, on top of the backend's own defaults (FANUC: it starts at
    # the usual home, wrist bent down, as a cell would after a taught joint move before IBGN start).
    sim_options: dict[str, Any] = field(default_factory=dict)
    # I/O the service lets clients read and write (type -> assigned points); None: the backend's
    # default. An access outside it would make a FANUC controller post PRIO-023 and stop.
    io_allow: dict[str, int] | None = None
    alarm_poll_s: float = 0.05  # how often the embedded simulator's alarm list is read
    # The embedded simulator stands in for a controller, which keeps its timing whatever else runs.
    # At normal priority it was starved for 100 ms by a SCHED_FIFO process busy on its core (another
    # servo process warming up): the servo process then saw no status and the simulator posted
    # MOTN-603. Below the servo process's priority (20), so that one still comes first. None: leave.
    sim_realtime_priority: int | None = 10
    request_timeout_s: float = 2.0
    # A servo process that publishes no state for this long is stalled (stopped by a signal, stuck):
    # its loop publishes every ~20 ms (FANUC) or ~50 ms (Janome, idle) at most, and the controller
    # faults after a few missed commands. The service names the fault and ends it (SIGTERM, SIGKILL
    # after 1 s); a reset starts another. servo-app run --servo-stall-s; at least MIN_SERVO_STALL_S.
    servo_stall_s: float = 1.0
    # A control of the embedded simulator (reset, alarm list, override, ...) answers in milliseconds;
    # one not answered in this time fails (a reset: 503), so a stopped controller process cannot hold
    # a reset anywhere near the lease's 10 s, and the alarm monitor polls again.
    sim_call_timeout_s: float = 2.0
    # A start waits for the stream to run (status output, limit tables, the controller's waiting bit):
    # given up after this, with the reason (the request then answers 409).
    start_timeout_s: float = 5.0
    mcap_live: bool = False  # write NAME.mcap beside each session log as it is written (servo-app run --mcap)
    inputs_config: Path | None = None  # inputs TOML (servo-app run --inputs): adapters, feeds, applications
    tools_file: Path | None = None  # tools TOML (servo-app run --tools): [tools.NAME] xyzwpr, payload_kg
    tool: str | None = None  # the active tool at start (servo-app run --tool); None: the file's, else the flange

    def __post_init__(self) -> None:
        if (why := servo_stall_error(self.servo_stall_s)) is not None:
            raise ValueError(f"servo_stall_s={self.servo_stall_s!r}: {why}")

    @property
    def log_dir(self) -> Path:
        return self.var_dir / "sessions"


# An idle Janome servo process publishes every 50 ms (125 ms seen with no robot connected), and the
# watchdog looks every 0.1 s: below this, an idle process or a busy machine's scheduling would be
# taken for a stall (and the process ended).
MIN_SERVO_STALL_S = 0.5


def servo_stall_error(value: float) -> str | None:
    """Why ``value`` cannot be the servo stall time (what to give instead), or None."""
    if not math.isfinite(value) or value < MIN_SERVO_STALL_S:
        return (f"give a number of seconds of at least {MIN_SERVO_STALL_S} (default {ServiceConfig.servo_stall_s}): "
                f"a servo process that runs no cycle for that long is taken as stalled and ended")
    return None
