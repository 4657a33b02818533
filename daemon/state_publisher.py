# A component's status on the bus: on change and at least every so often, from the control tick.
from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

from daemon.bus import BusKey
from daemon.component import Plugs

#: the default: at least once a second
PUBLISH_EVERY_S = 1.0


class StatePublisher:
    """Publishes a component's ``status()`` on the bus: on change (:meth:`publish`) and at least
    every ``every_s`` from the control tick."""

    def __init__(self, plugs: Plugs, key: BusKey[dict[str, Any]],
                 status: Callable[[], dict[str, Any]], every_s: float = PUBLISH_EVERY_S) -> None:
        self.bus = plugs.bus
        self.key = key
        self.status = status
        self.every_s = every_s
        self.last = -math.inf
        plugs.schedule(self.when_due)

    def when_due(self, now: float) -> float:
        """Publish unless a change did within ``every_s``; when to look again."""
        if now - self.last >= self.every_s:
            self.publish(now)
        return self.last + self.every_s

    def publish(self, now: float) -> None:
        self.last = now
        self.bus.publish(self.key, self.status())
