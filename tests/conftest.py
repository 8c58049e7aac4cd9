"""Suite-wide set-up: the garbage collector leaves the collected test modules alone.

The suite runs in one process, and the in-process services (uvicorn, the Zenoh interface) share it.
A full collection scans every tracked object; after collecting every module (numba, MuJoCo,
hypothesis, FastAPI ...), a full one took 0.14-0.18 s here, and up to 0.6 s later in the run, long
enough to hold a 0.2 s hold-to-run command past its hold. What exists once collection is done lives
until the end anyway: frozen, no later collection scans it again.

Hypothesis runs without its per-example deadline: on these shared two-core machines an example that
takes 2 ms can take 300 ms under load (test_clamp_norm_keeps_direction failed so), and a test that
checks values must not fail on time (timing lives in bench/).
"""

from __future__ import annotations

import gc

import pytest
from hypothesis import settings

settings.register_profile("servo_app", deadline=None)
settings.load_profile("servo_app")


def pytest_collection_finish(session: pytest.Session) -> None:
    gc.collect()
    gc.freeze()
