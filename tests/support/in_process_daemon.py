# The daemon in the test's own event loop (simulated mode, mock driver), on free ports.
from __future__ import annotations

import asyncio
from collections.abc import AsyncIterator
from contextlib import asynccontextmanager
from pathlib import Path
from typing import Any

from daemon.app import Daemon
from daemon.config import load_config
from tests.support.net import free_port
from tests.support.wait import DEFAULT_WITHIN_S, eventually


class InProcessDaemon:
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
    def control(self) -> Any:
        """The control loop (white-box: components see it only as ``ctx.robot``)."""
        assert self.daemon.control is not None
        return self.daemon.control

    @property
    def driver(self) -> Any:
        return self.control.driver

    def component(self, name: str) -> Any:
        return next(c for c in self.daemon.components if c.name == name)

    def moving(self) -> bool:
        """The mock driver's last command turns a wheel."""
        commands = self.driver.commands
        return bool(commands) and any(
            abs(v) > 1e-6 for v in (commands[-1].left_rad_s, commands[-1].right_rad_s))


def may_drive(daemon: Daemon) -> bool:
    """The collision monitor, when there is one, has a fresh scan to judge commands by."""
    safety = daemon.control.status().get("safety", {}) if daemon.control else {}
    return not safety.get("enabled") or safety.get("zone") != "unknown"


@asynccontextmanager
async def in_process_daemon(tmp_path: Path,
                            extra_toml: str = "") -> AsyncIterator[InProcessDaemon]:
    """``arbiterd run --sim`` with the mock driver, in the test's event loop, on free ports."""
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
        yield InProcessDaemon(daemon, ws_port, http_port)
    finally:
        daemon.request_shutdown("test over")
        await asyncio.wait_for(task, DEFAULT_WITHIN_S)
