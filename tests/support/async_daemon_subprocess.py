# Async test harness: `arbiterd run` as a subprocess beside an emulator in the test's event loop.
from __future__ import annotations

import asyncio
import contextlib
import signal
import sys
from collections.abc import AsyncIterator
from pathlib import Path
from typing import Any

import aiohttp

from daemon.cli import _toml_value
from tests.support.paths import REPO
from tests.support.wait import eventually


class AsyncDaemonSubprocess:
    """``arbiterd run`` as a subprocess of the test's event loop, and its HTTP API (aiohttp)."""

    def __init__(self, process: asyncio.subprocess.Process, port: int,
                 session: aiohttp.ClientSession) -> None:
        self.process, self.base, self.session = process, f"http://127.0.0.1:{port}", session

    async def health(self) -> tuple[int, dict[str, Any]]:
        async with self.session.get(self.base + "/api/health") as response:
            return response.status, await response.json()

    async def cmd_vel(self, linear_x: float, angular_z: float = 0.0) -> int:
        body = {"linear": {"x": linear_x}, "angular": {"z": angular_z}}
        async with self.session.post(self.base + "/api/cmd_vel", json=body) as response:
            return response.status

    async def wait_health(self, status: str, within_s: float = 10.0) -> dict[str, Any]:
        """Poll ``/api/health`` until its status is ``status`` (503 goes with ``error``)."""

        async def reached() -> dict[str, Any] | None:
            assert self.process.returncode is None, "the daemon exited"
            with contextlib.suppress(aiohttp.ClientConnectionError):
                code, body = await self.health()
                if body["status"] == status:
                    assert code == (503 if status == "error" else 200)
                    return body
            return None

        body: dict[str, Any] = await eventually(
            reached, f"the daemon's health to become {status!r}", within_s=within_s,
            interval_s=0.05)
        return body


def driver_daemon_config(tmp_path: Path, driver: str, options: dict[str, Any],
                         http_port: int) -> Path:
    """A config driving ``driver`` at an emulator: HTTP on ``http_port``, no rosbridge, a
    long deadman (the tests hold commands across faults) and a quick reconnect back-off."""
    section = "\n".join(f"{key} = {_toml_value(value)}" for key, value in options.items())
    path = tmp_path / "arbiterd.toml"
    path.write_text(f"""
[driver]
type = "{driver}"

[driver.{driver}]
{section}

[control]
cmd_vel_timeout = 5.0
reconnect_min_s = 0.1
reconnect_max_s = 0.4

[http]
host = "127.0.0.1"
port = {http_port}

[rosbridge]
enabled = false
""")
    return path


@contextlib.asynccontextmanager
async def async_daemon_subprocess(config: Path, port: int,
                                  log: Path) -> AsyncIterator[AsyncDaemonSubprocess]:
    """Run the daemon until the block ends, then SIGTERM it and require exit status 0."""
    with log.open("wb") as log_file:
        process = await asyncio.create_subprocess_exec(
            sys.executable, "-m", "daemon.cli", "run", "--config", str(config), cwd=REPO,
            stdout=asyncio.subprocess.DEVNULL, stderr=log_file)
        async with reaped(process), aiohttp.ClientSession(
                timeout=aiohttp.ClientTimeout(total=5)) as session:
            client = AsyncDaemonSubprocess(process, port, session)
            await client.wait_health("ok", within_s=20.0)
            yield client
            await terminate_cleanly(process)


@contextlib.asynccontextmanager
async def reaped(process: asyncio.subprocess.Process) -> AsyncIterator[None]:
    """Kill ``process`` when the block ends with it still running (a failed test)."""
    try:
        yield
    finally:
        if process.returncode is None:
            process.kill()
            await process.wait()


async def terminate_cleanly(process: asyncio.subprocess.Process) -> None:
    """SIGTERM, and require the process to exit 0 within 10 s."""
    process.send_signal(signal.SIGTERM)
    assert await asyncio.wait_for(process.wait(), 10) == 0
