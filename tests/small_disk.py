"""A small disk of its own for a process, to fill for real: a tmpfs of a given size mounted in a private
mount namespace (util-linux's ``unshare``), so that the machine's own disks and mounts are never touched
and the mount ends with the process. Other processes reach its files with ``nsenter``."""

from __future__ import annotations

import functools
import shutil
import subprocess
import tempfile
from pathlib import Path
from typing import Any

# The mount, then the command in its place (sh's "$0" is the mount point, "$@" the command).
_MOUNT_THEN_EXEC = 'mount -t tmpfs -o size="$SMALL_DISK_KIB"k tmpfs "$0" && exec "$@"'


@functools.cache
def unavailable() -> str | None:
    """Why no small disk can be made here (no unshare or nsenter, or no right to mount), or None."""
    for tool in ("unshare", "nsenter", "mount"):
        if shutil.which(tool) is None:
            return f"{tool} is not installed"
    with tempfile.TemporaryDirectory() as d:
        r = subprocess.run(["unshare", "--mount", "--propagation", "private", "sh", "-c",
                            _MOUNT_THEN_EXEC, d, "true"], env={"SMALL_DISK_KIB": "64", "PATH": "/usr/bin:/bin"},
                           capture_output=True, text=True, timeout=10)
    return None if r.returncode == 0 else f"cannot mount a tmpfs in a mount namespace: {r.stderr.strip()}"


def launch(mount_point: Path, size_kib: int, argv: list[str], env: dict[str, str], **popen: Any
           ) -> subprocess.Popen[str]:
    """``argv`` run with a ``size_kib`` tmpfs at ``mount_point`` (an existing directory); its pid is the
    command's own (sh execs it)."""
    return subprocess.Popen(["unshare", "--mount", "--propagation", "private", "sh", "-c", _MOUNT_THEN_EXEC,
                             str(mount_point), *argv], env={**env, "SMALL_DISK_KIB": str(size_kib)}, text=True,
                            **popen)


def fill(pid: int, path: Path) -> None:
    """Fill the small disk of process ``pid`` with a file at ``path``, to its last byte."""
    r = subprocess.run(["nsenter", "--target", str(pid), "--mount", "--", "sh", "-c", 'cat /dev/zero > "$0"',
                        str(path)], capture_output=True, text=True, timeout=30)
    assert "No space left" in r.stderr, r.stderr


def free(pid: int, path: Path) -> None:
    """Remove the file at ``path`` from the small disk of process ``pid``."""
    subprocess.run(["nsenter", "--target", str(pid), "--mount", "--", "rm", "-f", str(path)], check=True,
                   timeout=10)


def read(pid: int, path: Path) -> str:
    """The text of the file at ``path`` on the small disk of process ``pid``."""
    return subprocess.run(["nsenter", "--target", str(pid), "--mount", "--", "cat", str(path)], check=True,
                          capture_output=True, text=True, timeout=10).stdout
