"""The service's start: the first servo process is launched before the embedded simulator it streams
to, so that its imports (numba's cached kernels, MuJoCo: 2-3 s of CPU) run while the simulator starts,
and told the simulator's address once that is up."""

from __future__ import annotations

import multiprocessing as mp
import socket
from pathlib import Path

import pytest
from test_api_harness import running_rig

from servo_app.service import ServiceConfig, ServoService

pytestmark = pytest.mark.e2e


def started_at(pid: int) -> int:
    """When the process started, in clock ticks since boot (/proc/PID/stat, field 22)."""
    return int(Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[19])


def process_exists(pid: int) -> bool:
    return Path(f"/proc/{pid}").exists()


def test_the_servo_process_is_launched_before_the_simulator_and_streams_to_it(tmp_path: Path) -> None:
    with running_rig(tmp_path) as rig:
        service = rig.service
        assert service.stream is not None and service.sim is not None
        servo_pid, sim_pid = service.stream.pid, service.sim.process.pid
        assert servo_pid is not None and sim_pid is not None
        # (Before: the servo process was spawned once the simulator had answered, a second or more later.)
        assert started_at(servo_pid) <= started_at(sim_pid)
        assert service.robot_address == service.sim.address  # it was told where the simulator listens
        h = rig.lease()
        assert rig.start_streaming(h)["link"] == "streaming"  # and streams to it there
        rig.end_and_wait(h)
    assert service.stream is None and not process_exists(servo_pid)


def test_a_simulator_that_cannot_start_leaves_no_servo_process_behind(tmp_path: Path) -> None:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as taken:
        taken.bind(("127.0.0.1", 0))
        service = ServoService(ServiceConfig(var_dir=tmp_path, sim_port=taken.getsockname()[1]))
        with pytest.raises(EOFError):  # (the simulator process ended: its port is taken)
            service.open()
    assert not [p for p in mp.active_children() if p.name == "servo process"], mp.active_children()
