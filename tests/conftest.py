# The shared test vocabulary: waiting, comparing, ports, and the robot in-process or as a process.
from __future__ import annotations

import asyncio
import inspect
import threading
import time
from collections.abc import AsyncIterator, Callable, Iterator, Sequence
from contextlib import asynccontextmanager
from pathlib import Path
from typing import Any, Generic, TypeVar

import pytest

from daemon.app import Daemon
from daemon.config import load_config
from tests.support.daemon_subprocess import DaemonProcess, free_port
from tests.support.rigs import RIGS, Rig

__all__ = ["Collector", "DaemonProcess", "Rig", "Robot", "close_to", "eventually", "free_port",
           "running_robot", "wait_for"]

DEFAULT_WITHIN_S = 10.0
T = TypeVar("T")


def wait_for(condition: Callable[[], Any], what: str = "condition",
             within_s: float = DEFAULT_WITHIN_S, interval_s: float = 0.01) -> Any:
    """Poll ``condition`` (from plain code) until it returns something truthy, and return it;
    fail naming ``what`` after ``within_s``."""
    deadline = time.monotonic() + within_s
    while not (value := condition()):
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out after {within_s} s waiting for {what}")
        time.sleep(interval_s)
    return value


async def eventually(condition: Callable[[], Any], what: str = "condition",
                     within_s: float = DEFAULT_WITHIN_S, interval_s: float = 0.005) -> Any:
    """``wait_for`` for async tests: the event loop keeps running between polls.
    ``condition`` may be a coroutine function (it is awaited each time)."""
    deadline = time.monotonic() + within_s
    while not (value := await _result(condition())):
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out after {within_s} s waiting for {what}")
        await asyncio.sleep(interval_s)
    return value


async def _result(value: Any) -> Any:
    return await value if inspect.isawaitable(value) else value


def close_to(actual: float | Sequence[float], expected: float | Sequence[float],
             tol: float) -> bool:
    """Each value of ``actual`` within ``tol`` of ``expected`` (numbers or equal-length pairs)."""
    if isinstance(actual, int | float) and isinstance(expected, int | float):
        return abs(actual - expected) <= tol
    assert not isinstance(actual, int | float) and not isinstance(expected, int | float)
    return all(abs(a - e) <= tol for a, e in zip(actual, expected, strict=True))


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
        wait_for(lambda: self.count() >= count, what or f"{count} items", within_s)
        return self.items()


class Robot:
    """The daemon running in the test's own event loop (simulated mode), and where to reach it."""

    def __init__(self, daemon: Daemon, ws_port: int, http_port: int) -> None:
        self.daemon = daemon
        self.ws_url = f"ws://127.0.0.1:{ws_port}/"
        self.http_url = f"http://127.0.0.1:{http_port}"

    @property
    def ctx(self) -> Any:
        assert self.daemon.ctx is not None
        return self.daemon.ctx

    @property
    def driver(self) -> Any:
        return self.ctx.control.driver

    def component(self, name: str) -> Any:
        return next(c for c in self.daemon.components if c.name == name)

    def moving(self) -> bool:
        """The mock driver's last command turns a wheel."""
        commands = self.driver.commands
        return bool(commands) and any(
            abs(v) > 1e-6 for v in (commands[-1].left_rad_s, commands[-1].right_rad_s))


def may_drive(daemon: Daemon) -> bool:
    """The collision monitor, when there is one, has a fresh scan to judge commands by."""
    safety = daemon.ctx.control.status().get("safety", {}) if daemon.ctx else {}
    return not safety.get("enabled") or safety.get("zone") != "unknown"


@asynccontextmanager
async def running_robot(tmp_path: Path, extra_toml: str = "") -> AsyncIterator[Robot]:
    """``arbiterd run --sim`` with the mock driver, in-process, on free ports."""
    ws_port, http_port = free_port(), free_port()
    config_path = tmp_path / "arbiterd.toml"
    config_path.write_text(
        f'[http]\nhost = "127.0.0.1"\nport = {http_port}\n'
        f'[rosbridge]\nhost = "127.0.0.1"\nport = {ws_port}\n'
        f'[sim]\ndriver = "mock"\n' + extra_toml)
    daemon = Daemon(load_config(config_path, sim=True))
    task = asyncio.create_task(daemon.run())
    await eventually(lambda: daemon.state != "startup" or task.done(), "the daemon to start")
    assert not task.done(), f"daemon exited early: {task.result()}"
    await eventually(lambda: may_drive(daemon), "the lidar's first revolution (the collision "
                     "monitor holds the robot still until it has one)")
    try:
        yield Robot(daemon, ws_port, http_port)
    finally:
        daemon.request_shutdown("test over")
        await asyncio.wait_for(task, DEFAULT_WITHIN_S)


@pytest.fixture
async def robot(tmp_path: Path) -> AsyncIterator[Robot]:
    """The in-process robot with the default config."""
    async with running_robot(tmp_path) as running:
        yield running


@pytest.fixture
def daemon_process(tmp_path: Path) -> Iterator[Callable[..., DaemonProcess]]:
    """A factory of ``arbiterd run`` subprocesses (``DaemonProcess``); each is killed at the
    end of the test if it is still running."""
    started: list[DaemonProcess] = []

    def start(extra_toml: str = "", **kw: Any) -> DaemonProcess:
        wait_ready = kw.pop("wait_ready", True)
        workdir = tmp_path / f"daemon{len(started)}"
        workdir.mkdir()
        process = DaemonProcess(workdir, extra_toml, **kw)
        started.append(process)
        return process.start(wait_ready=wait_ready)

    yield start
    for process in started:
        process.__exit__(None, None, None)


@pytest.fixture(params=sorted(RIGS))
def rig(request: pytest.FixtureRequest, tmp_path: Path) -> Iterator[Rig]:
    """Each registered driver against its running emulator (``tests/rigs``), plus the
    ``l298n@pigpio`` variant: the test runs once per rig."""
    with RIGS[request.param](tmp_path) as running:
        yield running
