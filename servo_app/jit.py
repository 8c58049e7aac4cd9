"""Compiled kernels for the servo cycle: numba's ``njit``, compiled when their module is imported.

Why: the cycle works on 6-vectors, where each numpy call costs 1-2 us here, so a Python cycle is
made of hundreds of them; one compiled kernel call costs about 0.5 us.

- Every kernel declares its signature, so numba compiles it (or loads it from the on-disk cache) at
  import: nothing is ever compiled inside a cycle.
- ``cache=True`` keeps the machine code beside the module (``__pycache__``); ``scripts/install``
  fills it (``python -m servo_app.jit``), so a servo process loads kernels instead of compiling them.
- ``error_model="numpy"``: a division by zero gives inf/nan as numpy does, with no exception checks
  in the loops. ``fastmath`` stays off: results keep IEEE semantics (the float32-exact shaper guard
  and the equivalence tests rely on it).
"""

from __future__ import annotations

import importlib
import sys
import time
from collections.abc import Callable
from typing import Any, TypeVar

import numba

F = TypeVar("F", bound=Callable[..., Any])

# Modules that define kernels: imported by the warm-up below (add a module here when it gains kernels).
KERNEL_MODULES: tuple[str, ...] = (
    "servo_app.robots.kernels",
    "servo_app.motion.cycle_kernels",
    "servo_app.motion.shaper_kernels",
    "servo_app.motion.ik_kernels",
    "servo_app.motion.settle",
    "servo_app.fanuc.runner",
)


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
    if "-v" in sys.argv[1:]:  # quiet by default: scripts/install runs it on every start
        print(f"servo_app kernels ready: {len(KERNEL_MODULES)} modules in {seconds:.1f} s", file=sys.stderr)
