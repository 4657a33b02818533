# The pigpiod keep-alive the pigpio and l298n drivers share: notice a lost pigpiod between writes.
from __future__ import annotations

import asyncio
import contextlib
import struct
from collections.abc import Awaitable, Callable
from typing import Any

from base.options import shared_option
from drivers.base import MotorDriver

#: The pigpiod link keys of both GPIO drivers' sections (the l298n driver uses them with
#: ``pin_factory = "pigpio"``): ``timeout: float = option(**LINK_TIMEOUT)`` and so on.
LINK_TIMEOUT = shared_option(1.0, "pigpiod connect and reply timeout, s", above=0.0, maxval=30.0)
LINK_WATCH_INTERVAL = shared_option(0.25, "how often to check pigpiod is still there, s (0 = "
                                    "only when writing)", minval=0.0)

#: Runs a blocking pigpio call on the driver's worker thread (``SerialExecutor.call``).
Call = Callable[[Callable[[], Any]], Awaitable[Any]]


def describe_io_error(exc: BaseException) -> str:
    """A short reason for a failed pigpio socket call."""
    if isinstance(exc, struct.error):  # the client read a short (empty) reply
        return "pigpiod closed the connection"
    if isinstance(exc, TimeoutError):
        return "no reply from pigpiod (timed out)"
    return f"{type(exc).__name__}: {exc}" if str(exc) else type(exc).__name__


class PigpiodWatch:
    """Asks pigpiod for its tick every ``interval`` s while ``driver`` has no fault.

    ``peer()`` gives the worker thread's call and the pigpio client to ask, or ``None`` once
    the driver is disconnected (that ends the watch). The first failed ask goes to
    ``lost(client, reason)`` and ends the watch too.
    """

    def __init__(self, driver: MotorDriver, interval: float,
                 peer: Callable[[], tuple[Call, Any] | None],
                 lost: Callable[[Any, str], None]) -> None:
        self._driver = driver
        self._interval = interval
        self._peer = peer
        self._lost = lost
        self._task: asyncio.Task[None] | None = None

    def start(self, name: str) -> None:
        """Start watching (nothing with ``interval`` 0: a lost pigpiod shows on a write)."""
        if self._interval > 0:
            self._task = asyncio.create_task(self._run(), name=name)

    async def stop(self) -> None:
        task, self._task = self._task, None
        if task is not None:
            task.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await task

    async def _run(self) -> None:
        while self._driver.fault is None:
            await asyncio.sleep(self._interval)
            peer = self._peer()
            if peer is None:
                return
            call, pi = peer
            try:
                await call(pi.get_current_tick)
            except Exception as exc:
                self._lost(pi, f"keep-alive failed: {describe_io_error(exc)}")
                return
