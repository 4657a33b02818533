# Per-client budgets of the rosbridge server, a request-rate bucket, and a rate-limited log line.
from __future__ import annotations

import asyncio
import logging
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass, fields
from typing import Any

from base.rates import TokenBucket
from daemon.components.rosbridge.codec import FragmentLimits, over_limit

__all__ = ["Limits", "Pacer", "RateLimitedLog", "TokenBucket", "over_limit"]


@dataclass(frozen=True)
class Limits:
    """The ``[rosbridge]`` budgets one client works within (field name = config key)."""

    max_message_bytes: int = 1048576
    max_readonly_message_bytes: int = 16384
    ops_per_second: float = 1000.0
    ops_burst: int = 2000
    max_topics_per_client: int = 100
    max_subscriptions_per_client: int = 256
    max_services_per_client: int = 32
    max_pending_calls_per_client: int = 64
    call_timeout: float = 30.0
    max_fragment_sets_per_client: int = 8
    max_fragment_bytes_per_client: int = 2 * 1048576
    max_fragments_per_message: int = 100_000
    max_queue_length: int = 100
    fragments_per_second: float = 20_000.0

    @classmethod
    def from_config(cls, section: Mapping[str, Any]) -> Limits:
        return cls(**{f.name: section[f.name] for f in fields(cls)})

    @classmethod
    def from_settings(cls, settings: Any) -> Limits:
        """From the ``[rosbridge]`` settings (the limits are its keys of the same names)."""
        return cls(**{f.name: getattr(settings, f.name) for f in fields(cls)})

    def message_bytes(self, may_publish: bool) -> int:
        """The largest message a client may send: a client that may not publish needs no
        more than a subscribe or a rosapi call, and gets ``max_readonly_message_bytes``."""
        if may_publish:
            return self.max_message_bytes
        return min(self.max_message_bytes, self.max_readonly_message_bytes)

    def fragments(self, may_publish: bool = True) -> FragmentLimits:
        return FragmentLimits(self.message_bytes(may_publish),
                              self.max_fragment_sets_per_client,
                              self.max_fragment_bytes_per_client,
                              self.max_fragments_per_message)


class Pacer:
    """Work shared by every client at ``rate`` units per second (outgoing fragments): a
    client that asks for a message in a million pieces gets them, slowly, and the robot's
    loop keeps its time."""

    def __init__(self, rate: float, clock: Callable[[], float] = time.monotonic) -> None:
        self._bucket = TokenBucket(rate, max(1.0, rate / 20), clock)

    async def take(self, units: int) -> None:
        """Wait for this client's turn: callers are served in the order they asked."""
        wait = self._bucket.reserve(units)
        if wait > 0:
            await asyncio.sleep(wait)


class RateLimitedLog:
    """One log line per ``interval_s`` at most; the lines in between are counted and the
    count goes into the next line. Never a traceback: bad input is the client's problem."""

    def __init__(self, logger: logging.Logger, interval_s: float = 10.0,
                 clock: Callable[[], float] = time.monotonic) -> None:
        self.logger = logger
        self.interval_s = interval_s
        self.clock = clock
        self.suppressed = 0
        self._t_last = -1e18

    def __call__(self, level: int, message: str) -> None:
        now = self.clock()
        if now - self._t_last < self.interval_s:
            self.suppressed += 1
            return
        if self.suppressed:
            message += f" ({self.suppressed} more like it in the last {now - self._t_last:.0f} s)"
        self._t_last = now
        self.suppressed = 0
        self.logger.log(level, "%s", message)
