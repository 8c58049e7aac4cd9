"""The bridge's parts from the configuration: adapters, feeds and applications, which of them command
the arbiter directly, and the source names the servo process indexes.

Building only: nothing starts here. Each adapter's output slot and the feed registry call `on_sample`
for every sample, and each adapter's button events go to `on_button` too, so the bridge handles a
sample in the thread that publishes it.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

from servo_app.inputs.adapter import Clock, InputAdapter, SourceSpec
from servo_app.inputs.apps.base import Application
from servo_app.inputs.apps.config import AppConfig, build_application, source_kinds
from servo_app.inputs.config import InputsConfig, build_adapters
from servo_app.inputs.feed import FeedRegistry
from servo_app.inputs.feed.models import FeedSourceConfig
from servo_app.inputs.samples import ButtonEvent
from servo_app.inputs.slots import EventQueue, LatestValue

Slots = dict[str, tuple[LatestValue[Any], float]]  # source name -> (its slot, stale_after_s)


class _NotifyingSlot(LatestValue[Any]):
    """An adapter's output slot that tells the bridge about each sample."""

    def __init__(self, name: str, notify: Callable[[], None]) -> None:
        super().__init__(name)
        self._notify = notify

    def publish(self, value: Any, stamp: float | None = None) -> int:
        seq = super().publish(value, stamp)
        self._notify()
        return seq


class _ActingEvents(EventQueue[ButtonEvent]):
    """An adapter's button events, each also handed to the bridge (which picks the output actions)."""

    def __init__(self, on_event: Callable[[ButtonEvent], None]) -> None:
        super().__init__()
        self._on_event = on_event

    def put(self, item: ButtonEvent) -> None:
        super().put(item)
        self._on_event(item)


class _NotifyingFeeds(FeedRegistry):
    """The feed registry that tells the bridge about every message."""

    def __init__(self, sources: Mapping[str, FeedSourceConfig], notify: Callable[[], None], clock: Clock) -> None:
        self._notify = notify
        super().__init__(sources, clock=clock)

    def submit(self, source: str, message: Any) -> Any:
        try:
            return super().submit(source, message)
        finally:
            self._notify()


@dataclass(frozen=True)
class Wiring:
    adapters: list[InputAdapter]
    feeds: FeedRegistry
    kinds: dict[str, str]  # source name -> the kind of sample it publishes
    apps: list[Application]
    specs: dict[str, SourceSpec]  # the arbiter's sources: applications, and the sources none consumes
    source_names: list[str]  # the servo process's index of sources
    slots: Slots  # every source's slot, applications' too


def wire(cfg: InputsConfig, apps: Sequence[AppConfig], *, clock: Clock, on_sample: Callable[[], None],
         on_button: Callable[[ButtonEvent], None]) -> Wiring:
    adapters = build_adapters(cfg, clock=clock)
    for a in adapters:
        a.output = _NotifyingSlot(a.name, on_sample)  # before start: the adapter's thread publishes here
        a.events = _ActingEvents(on_button)
    feeds = _NotifyingFeeds(cfg.feeds, on_sample, clock)
    kinds = source_kinds(cfg)
    slots: Slots = {a.name: (a.output, a.stale_after_s) for a in adapters}
    slots.update({n: (feeds.slot(n), f.stale_after_s) for n, f in cfg.feeds.items()})
    applications = [build_application(c, slots, clock=clock) for c in apps]
    consumed = {src for c in apps for src in c.sources.values()}
    direct = [a.source_spec() for a in adapters if a.name not in consumed and kinds[a.name] != "measurement"]
    direct += [s for s in feeds.specs() if s.name not in consumed]
    specs = {s.name: s for s in direct + [app.source_spec() for app in applications]}
    # The servo process names a source by its index here; application inputs come after the
    # arbiter's sources so a stale stop can name the sensor that went quiet.
    names = list(specs)
    names += [ref.source for app in applications for ref in app.inputs.values() if ref.source not in names]
    return Wiring(adapters, feeds, kinds, applications, specs, list(dict.fromkeys(names)),
                  slots | {app.name: (app.output, app.stale_after_s) for app in applications})
