# Waiting in tests: the one poll-until-true loop (wait_for, eventually) and a Collector.
from __future__ import annotations

import asyncio
import inspect
import threading
import time
from collections.abc import Callable
from typing import Any, Generic, TypeVar

DEFAULT_WITHIN_S = 10.0
T = TypeVar("T")
#: What a wait is for, as its failure names it: text, or a function giving text built from the
#: state at the time of the failure (the last reading, a log).
What = str | Callable[[], str]


class Deadline:
    """The timeout wait_for and eventually share (and other waits: see rosbridge.Client),
    and the failure it ends in."""

    def __init__(self, what: What, within_s: float) -> None:
        self.what, self.within_s = what, within_s
        self.at = time.monotonic() + within_s

    def check(self) -> None:
        """Fail, naming what was waited for, once the deadline has passed."""
        if time.monotonic() > self.at:
            what = self.what() if callable(self.what) else self.what
            raise AssertionError(f"timed out after {self.within_s} s waiting for {what}")

    def remaining(self) -> float:
        """Seconds left, at least a millisecond (a timeout of 0 often means none at all)."""
        return max(self.at - time.monotonic(), 0.001)


def wait_for(condition: Callable[[], Any], what: What = "condition", *,
             within_s: float = DEFAULT_WITHIN_S, interval_s: float = 0.01) -> Any:
    """Poll ``condition`` (from plain code) until it returns something truthy, and return it;
    fail naming ``what`` after ``within_s``."""
    deadline = Deadline(what, within_s)
    while not (value := condition()):
        deadline.check()
        time.sleep(interval_s)
    return value


async def eventually(condition: Callable[[], Any], what: What = "condition", *,
                     within_s: float = DEFAULT_WITHIN_S, interval_s: float = 0.005) -> Any:
    """``wait_for`` for async tests: the event loop keeps running between polls.
    ``condition`` may be a coroutine function (it is awaited each time)."""
    deadline = Deadline(what, within_s)
    while not (value := await _result(condition())):
        deadline.check()
        await asyncio.sleep(interval_s)
    return value


async def _result(value: Any) -> Any:
    return await value if inspect.isawaitable(value) else value


class Collector(Generic[T]):
    """A callback that keeps what another thread hands it (e.g. a lidar manager's
    revolutions), for the test to count and wait for."""

    def __init__(self) -> None:
        self._items: list[T] = []
        self._lock = threading.Lock()

    def __call__(self, item: T) -> None:
        with self._lock:
            self._items.append(item)

    def count(self) -> int:
        with self._lock:
            return len(self._items)

    def items(self) -> list[T]:
        with self._lock:
            return list(self._items)

    def wait(self, count: int, what: str = "",
             within_s: float = DEFAULT_WITHIN_S) -> list[T]:
        """All items once there are ``count``; fail naming ``what`` after ``within_s``."""
        wait_for(lambda: self.count() >= count, what or f"{count} items", within_s=within_s)
        return self.items()
