# The shared fixtures: the in-process daemon, daemon subprocesses, and every driver's rig.
from __future__ import annotations

from collections.abc import AsyncIterator, Iterator
from pathlib import Path
from typing import Any

import pytest

from tests.support.daemon_subprocess import DaemonSubprocess, StartDaemonSubprocess
from tests.support.in_process_daemon import InProcessDaemon, in_process_daemon
from tests.support.rigs import RIGS, Rig


@pytest.fixture
async def robot(tmp_path: Path) -> AsyncIterator[InProcessDaemon]:
    """The simulated robot: an InProcessDaemon with the default config."""
    async with in_process_daemon(tmp_path) as running:
        yield running


@pytest.fixture
def daemon_subprocess(tmp_path: Path) -> Iterator[StartDaemonSubprocess]:
    """A factory of ``arbiterd run`` subprocesses (``DaemonSubprocess``); each is killed at the
    end of the test if it is still running."""
    started: list[DaemonSubprocess] = []

    def start(extra_toml: str = "", **kw: Any) -> DaemonSubprocess:
        wait_ready = kw.pop("wait_ready", True)
        workdir = tmp_path / f"daemon{len(started)}"
        workdir.mkdir()
        process = DaemonSubprocess(workdir, extra_toml, **kw)
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
