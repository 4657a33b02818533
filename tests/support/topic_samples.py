# Real payloads of the running daemon's topics: every optional part on, one bus payload per topic.
from __future__ import annotations

import asyncio
import contextlib
import os
from collections.abc import Callable, Iterable
from pathlib import Path
from typing import Any

from daemon.bus import Bus, BusKey
from daemon.registry import COMPONENTS
from tests.support.net import free_port


def everything(directory: Path) -> str:
    """A config that turns every optional part on: each component section's ``enabled`` key,
    the fault-injection route and the odometry transform. Every ``directory`` option (the
    recordings, the maps) points into ``directory``; the ROS 2 face, when there is one, stays
    on this machine (``discovery = "localhost"``) in a domain of this process's own; the
    Foxglove server listens on a free port of 127.0.0.1; the fleet looks for a router on one."""
    lines = []
    for spec in COMPONENTS:
        settings = spec.settings
        if settings is None or settings.SECTION in ("http", "rosbridge"):
            continue  # the test robot sets their addresses; they are on by default
        options = settings.OPTIONS
        keys = ["enabled = true"] if "enabled" in options else []
        if "directory" in options:
            keys.append(f'directory = "{directory / settings.SECTION}"')
        keys += {"control": ["allow_fault_injection = true", "enable_odom_tf = true"],
                 "ros2": ['discovery = "localhost"',
                          f"domain_id = {100 + os.getpid() % 100}"],
                 "foxglove": ['host = "127.0.0.1"', f"port = {free_port()}"],
                 # a router nobody runs: the robot keeps trying, on this machine only
                 "fleet": [f'router = "tcp/127.0.0.1:{free_port()}"'],
                 }.get(settings.SECTION, [])
        if keys:
            lines += [f"[{settings.SECTION}]", *keys]
    return "\n".join(lines) + "\n"


class BusSamples:
    """The first payload on each of some bus keys: the key's latest one when it has one (a
    latched topic published once at start), else the first published after this was made.
    Publishers may be on other threads: the waiting side is woken through the event loop."""

    def __init__(self, bus: Bus, keys: Iterable[BusKey[Any]]) -> None:
        self._loop = asyncio.get_running_loop()
        self._complete = asyncio.Event()
        by_name = {key.name: key for key in keys}
        self.wanted = set(by_name)
        self.samples: dict[str, Any] = {}
        self._removers: list[Callable[[], None]] = []
        for key in by_name.values():
            latest = bus.latest(key)
            if latest is not None:
                self.samples[key.name] = latest
            else:
                self._removers.append(bus.subscribe(key, self._taker(key.name)))
        self._check()

    def _taker(self, name: str) -> Callable[[Any], None]:
        def take(payload: Any) -> None:
            if self.samples.setdefault(name, payload) is payload:
                with contextlib.suppress(RuntimeError):  # the loop is closing
                    self._loop.call_soon_threadsafe(self._check)
        return take

    def _check(self) -> None:
        if self.missing() == []:
            self._complete.set()

    def missing(self) -> list[str]:
        """The bus keys without a sample yet."""
        return sorted(self.wanted - set(self.samples))

    async def wait(self, within_s: float) -> list[str]:
        """Wait until every key has a sample or ``within_s`` passed; the keys still without."""
        with contextlib.suppress(TimeoutError):
            await asyncio.wait_for(self._complete.wait(), within_s)
        return self.missing()

    def close(self) -> None:
        while self._removers:
            self._removers.pop()()
