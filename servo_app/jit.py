"""Compiled kernels for the servo cycle: numba's ``njit``, compiled when their module is imported.

Why: the cycle works on 6-vectors, where each numpy call costs 1-2 us here, so a Python cycle is
made of hundreds of them; one compiled kernel call costs about 0.5 us.

- Every kernel declares its signature, so numba compiles it (or loads it from the on-disk cache) at
  import: nothing is ever compiled inside a cycle.
- ``cache=True`` keeps the machine code on disk; ``scripts/install`` fills the cache
  (``python -m servo_app.jit``), so a servo process loads kernels instead of compiling them.
- The cache lives in a directory named by a digest of every kernel source (``CACHE_DIR``). numba
  checks only a kernel's own file before it loads the kernel's machine code, so a kernel that calls a
  kernel of another module (``cycle_kernels`` calls ``robots.kernels``), or bakes in its constants,
  kept the old callee after that module alone changed: measured here, ``g(x) = f(x) * 10`` still gave
  the old ``f``'s 20 after ``f``'s file changed ``x + 1`` to ``x + 2``, and a ``git pull`` that touched
  only ``robots/kernels.py`` would have left the flange-speed guard on the old region test.
- ``error_model="numpy"``: a division by zero gives inf/nan as numpy does, with no exception checks
  in the loops. ``fastmath`` stays off: results keep IEEE semantics (the float32-exact shaper guard
  and the equivalence tests rely on it).
"""

from __future__ import annotations

import hashlib
import importlib
import os
import shutil
import sys
import time
from collections.abc import Callable, Iterable
from pathlib import Path
from typing import Any, TypeVar

import numba

F = TypeVar("F", bound=Callable[..., Any])

# Modules that define kernels: imported by the warm-up below (add a module here when it gains kernels).
KERNEL_MODULES: tuple[str, ...] = (
    "servo_app.motion.mujoco_c",
    "servo_app.robots.kernels",
    "servo_app.motion.cycle_kernels",
    "servo_app.motion.shaper_kernels",
    "servo_app.motion.ik_kernels",
    "servo_app.motion.settle",
    "servo_app.fanuc.runner",
)
# Everything the kernels' machine code is made of: their modules, what they declare for numba
# (MuJoCo's C functions) and how they are compiled (this module). tests/test_jit_cache.py checks that
# every module with a kernel is here.
KERNEL_SOURCES: tuple[str, ...] = (*KERNEL_MODULES, "servo_app.jit")
_PACKAGE_DIR = Path(__file__).resolve().parent
_CACHE_PREFIX = "servo_app-"


def source_path(module: str) -> Path:
    """A module of this package's source file, found without importing it."""
    return _PACKAGE_DIR.joinpath(*module.split(".")[1:]).with_suffix(".py")


def source_digest(paths: Iterable[Path]) -> str:
    """A digest of the files' names and bytes, in the order given."""
    h = hashlib.sha256()
    for path in paths:
        data = path.read_bytes()
        h.update(f"{path.name}\0{len(data)}\0".encode())
        h.update(data)
    return h.hexdigest()[:16]


def _writable_dir(path: Path) -> bool:
    try:
        path.mkdir(parents=True, exist_ok=True)
    except OSError:
        return False
    return os.access(path, os.W_OK | os.X_OK)


def cache_base(user_dir: str | None) -> Path:
    """Where the digest directories go: ``NUMBA_CACHE_DIR`` if set, else the package's ``__pycache__``,
    else (an installation that cannot be written to) the user's cache directory."""
    if user_dir:
        return Path(user_dir)
    in_tree = _PACKAGE_DIR / "__pycache__" / "numba"
    if _writable_dir(in_tree):
        return in_tree
    return Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "servo_app" / "numba"


def use_cache_for(sources: Iterable[Path], base: Path) -> Path:
    """Point numba's disk cache (``numba.config.CACHE_DIR``) at ``base``'s directory for this digest of
    ``sources``; kernels decorated after this call load from and save to it. The directory."""
    path = base / (_CACHE_PREFIX + source_digest(sources))
    numba.config.CACHE_DIR = str(path)
    return path


def prune_caches(base: Path, keep: Path) -> list[Path]:
    """Remove the digest directories under ``base`` other than ``keep`` (kernels of older sources)."""
    removed = []
    for path in base.glob(_CACHE_PREFIX + "*"):
        if path != keep and path.is_dir():
            shutil.rmtree(path, ignore_errors=True)
            removed.append(path)
    return removed


# Before any kernel module decorates a kernel: each imports this module first.
_BASE = cache_base(numba.config.CACHE_DIR or None)
CACHE_DIR = use_cache_for((source_path(m) for m in KERNEL_SOURCES), _BASE)


def kernel(signature: str | list[str]) -> Callable[[F], F]:
    """``@kernel("float64(float64[::1])")``: an eagerly compiled, cached, GIL-free numba function."""
    return numba.njit(signature, cache=True, nogil=True, error_model="numpy")  # type: ignore[no-any-return]


def warm_up() -> float:
    """Import every kernel module (compiling whatever the cache lacks); the seconds it took."""
    t0 = time.perf_counter()
    for name in KERNEL_MODULES:
        importlib.import_module(name)
    return time.perf_counter() - t0


if __name__ == "__main__":
    seconds = warm_up()
    pruned = prune_caches(_BASE, CACHE_DIR)
    if "-v" in sys.argv[1:]:  # quiet by default: scripts/install runs it on every start
        print(f"servo_app kernels ready: {len(KERNEL_MODULES)} modules in {seconds:.1f} s ({CACHE_DIR}; "
              f"{len(pruned)} older caches removed)", file=sys.stderr)
