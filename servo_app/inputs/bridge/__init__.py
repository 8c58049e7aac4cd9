"""The inputs bridge (API process): adapters, feeds and applications -> arbiter -> the servo's input slot.

Every sample is handled at once in the thread that publishes it (an adapter's thread, or the request
that carried a feed message): the applications whose inputs changed run, the arbiter picks who
commands, and that source's newest sample goes into the shared-memory slot the servo process reads
each cycle. The bridge's own thread keeps the clocks: it sleeps until the source in control
would go stale or an application's period comes round (tracking re-extrapolates between camera
frames). Each sample renews the servo's hold-to-run for the source's timeout plus `hold_grace_s`, so
the bridge's explicit "stale" always reaches the servo before its hold would run out by itself, and
the stop says which input it was.

One module a job, `InputsBridge` (core) the one object the service and the API use:

- wiring: adapters, feeds and applications from the configuration; which sources command; their names;
- loop: the threads (a sample is stepped where it is published; the bridge's thread keeps the clocks);
- pipeline: one pass (applications, arbitration, the shared-memory slot, the robot's state to apps);
- publication: which command goes into the slot and when (the stale marker and its latch), pure;
- buttons: output actions of button presses, through the service's I/O;
- status: the rows and views GET /api/state and GET /api/inputs show, pure.
"""

from servo_app.inputs.bridge.core import InputsBridge

__all__ = ["InputsBridge"]
