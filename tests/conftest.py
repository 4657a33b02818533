# The shared fixtures: the robot in-process, daemon subprocesses, and every driver's rig.
from __future__ import annotations

from collections.abc import AsyncIterator, Callable, Iterator
from pathlib import Path
from typing import Any

import pytest

from tests.support.daemon_subprocess import DaemonProcess
from tests.support.in_process_daemon import Robot, running_robot
from tests.support.rigs import RIGS, Rig


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
    """Each registered driver against its running emulator (``tests/support/rigs``), plus the
    ``l298n@pigpio`` variant: the test runs once per rig."""
    with RIGS[request.param](tmp_path) as running:
        yield running
