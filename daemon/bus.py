# In-process publish/subscribe of telemetry: latest value per topic plus callbacks.
from __future__ import annotations

import logging
from collections.abc import Callable
from typing import Any

log = logging.getLogger(__name__)

Callback = Callable[[Any], None]


class Bus:
    """Synchronous fan-out of internal telemetry (``odom``, ``scan``, ``latency_report``, ...).

    ``publish`` runs in the publisher's context (the control tick, the lidar reader), so every
    callback must be quick and never block: a slow consumer copies the message into its own
    bounded latest-value queue and does its work elsewhere. A callback that raises is logged
    and does not stop the others.
    """

    def __init__(self) -> None:
        self._subscribers: dict[str, list[Callback]] = {}
        self._latest: dict[str, Any] = {}

    def subscribe(self, topic: str, callback: Callback) -> Callable[[], None]:
        """Call ``callback(message)`` on every publish to ``topic``; returns an unsubscriber."""
        self._subscribers.setdefault(topic, []).append(callback)

        def unsubscribe() -> None:
            callbacks = self._subscribers.get(topic, [])
            if callback in callbacks:
                callbacks.remove(callback)

        return unsubscribe

    def publish(self, topic: str, message: Any) -> None:
        self._latest[topic] = message
        for callback in tuple(self._subscribers.get(topic, ())):
            try:
                callback(message)
            except Exception:
                log.exception("subscriber of %s failed", topic)

    def latest(self, topic: str) -> Any | None:
        """The last message published on ``topic``, or ``None``."""
        return self._latest.get(topic)

    def topics(self) -> list[str]:
        return sorted(set(self._latest) | set(self._subscribers))
