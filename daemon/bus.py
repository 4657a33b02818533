# In-process publish/subscribe of telemetry: typed keys, latest value per key, callbacks.
from __future__ import annotations

import logging
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, Generic, TypeVar

log = logging.getLogger(__name__)

T = TypeVar("T")


@dataclass(frozen=True)
class BusKey(Generic[T]):
    """A bus topic and the type of what travels on it (Home Assistant's ``SignalType``):
    ``ODOM: BusKey[OdomSample] = BusKey("odom")``. Its owner declares it; publishers and
    subscribers import it, so a wrong payload type is a type error, not a runtime surprise."""

    name: str


class Bus:
    """Synchronous fan-out of internal telemetry (odometry, scans, latency reports, ...).

    ``publish`` runs in the publisher's context (the control tick, the lidar reader), so every
    callback must be quick and never block: a slow consumer copies the message into its own
    bounded latest-value queue and does its work elsewhere. A callback that raises is logged
    and does not stop the others.
    """

    def __init__(self) -> None:
        # tuples, replaced on (un)subscribe: publishing (per command, per tick) iterates
        # without copying, and a callback may (un)subscribe while it runs
        self._subscribers: dict[str, tuple[Callable[[Any], None], ...]] = {}
        self._latest: dict[str, Any] = {}

    def subscribe(self, key: BusKey[T], callback: Callable[[T], None]) -> Callable[[], None]:
        """Call ``callback(message)`` on every publish to ``key``; returns an unsubscriber."""
        self._subscribers[key.name] = (*self._subscribers.get(key.name, ()), callback)

        def unsubscribe() -> None:
            callbacks = list(self._subscribers.get(key.name, ()))
            if callback in callbacks:
                callbacks.remove(callback)
                self._subscribers[key.name] = tuple(callbacks)

        return unsubscribe

    def publish(self, key: BusKey[T], message: T) -> None:
        name = key.name
        self._latest[name] = message
        for callback in self._subscribers.get(name, ()):
            try:
                callback(message)
            except Exception:
                log.exception("subscriber of %s failed", name)

    def latest(self, key: BusKey[T]) -> T | None:
        """The last message published on ``key``, or ``None``."""
        message: T | None = self._latest.get(key.name)
        return message

    def subscribers(self, key: BusKey[Any]) -> int:
        return len(self._subscribers.get(key.name, ()))

    def topics(self) -> list[str]:
        return sorted(set(self._latest) | set(self._subscribers))
