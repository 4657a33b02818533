# Shutdown as an adversary sees it: nothing releases the e-stop or moves the robot once it
# began, and no client (a stalled download, a silent WebSocket) keeps the daemon from exiting.
from __future__ import annotations

import asyncio
import signal
import subprocess
import time
from collections.abc import AsyncIterator
from pathlib import Path

import aiohttp
import pytest

from daemon.app import STOP_TIMEOUT_S
from daemon.bus import Bus
from daemon.commands import Twist
from daemon.component import BaseComponent
from daemon.components.control.loop import ControlLoop
from daemon.config import build_driver, load_config
from daemon.latency import LatencyTracker
from tests.support.daemon_subprocess import DaemonSubprocess
from tests.support.deploy import SYSTEMD_DIR, unit_values
from tests.support.http_raw import LOCAL, stalled_download
from tests.support.in_process_daemon import in_process_daemon
from tests.support.rosbridge import TOKEN, WITH_TOKEN, Client, connect
from tests.support.wait import eventually

RECORDING = "arbiterd-stalled.mcap"


def stop_timeout_s() -> float:
    """``TimeoutStopSec=`` of the installed unit: how long systemd waits before SIGKILL."""
    values = unit_values((SYSTEMD_DIR / "arbiterd.service").read_text(), "Service",
                         "TimeoutStopSec")
    return float(values[-1])




async def refused(client: Client, topic: str, msg: dict[str, object]) -> str | None:
    """Publish ``msg`` and wait for the status error it earns; None once the socket is gone
    (the rosbridge component has stopped)."""
    seen = len(client.received)
    try:
        await client.send(op="publish", topic=topic, msg=msg)
        status = await client.expect(
            lambda m: client.received.index(m) >= seen and m.get("op") == "status"
            and topic in str(m.get("msg")), within=5, what=f"the refusal of {topic}")
    except (AssertionError, ConnectionError, aiohttp.ClientError):
        return None
    return str(status["msg"])


async def test_sigterm_with_a_stalled_download_exits_in_time_and_nothing_moves(
        tmp_path: Path) -> None:
    recordings = tmp_path / "recordings"
    recordings.mkdir()
    with (recordings / RECORDING).open("wb") as sparse:
        sparse.truncate(256 * 1024 * 1024)
    proc = DaemonSubprocess(tmp_path, WITH_TOKEN + f'[recorder]\ndirectory = "{recordings}"\n')
    with proc:
        assert proc.proc is not None
        downloader = stalled_download(proc.http_port, RECORDING)
        url = f"ws://{LOCAL}:{proc.ws_port}/?token={TOKEN}"
        async with connect(url) as client:
            await client.send(op="advertise", topic="/estop", type="std_msgs/msg/Bool")
            await client.send(op="advertise", topic="/cmd_vel", type="geometry_msgs/msg/Twist")
            await client.call("/rosapi/get_time")  # both advertisements are done
            assert not proc.wheels() or proc.wheels()[-1][1:] == (0.0, 0.0)
            t_term = time.monotonic()
            proc.proc.send_signal(signal.SIGTERM)
            await eventually(lambda: "shutting down" in proc.log(), "the shutdown to begin")
            answers: list[str] = []
            while proc.proc.poll() is None:
                release = await refused(client, "/estop", {"data": False})
                drive = await refused(client, "/cmd_vel", {"linear": {"x": 0.5}})
                if release is None or drive is None:
                    break
                answers += [release, drive]
            try:
                code: int | None = await asyncio.to_thread(proc.proc.wait, stop_timeout_s())
            except subprocess.TimeoutExpired:
                code = None  # systemd would SIGKILL it now
        elapsed = time.monotonic() - t_term
        downloader.close()
    moving = [row for row in proc.wheels() if row[1:] != (0.0, 0.0)]
    assert moving == [], f"the wheels turned during shutdown: {moving[:5]}"
    assert code == 0, f"exit {code} after {elapsed:.1f} s:\n{proc.log()[-3000:]}"
    assert elapsed < stop_timeout_s(), f"exit took {elapsed:.1f} s"
    assert answers, "the token holder's requests were never answered during the shutdown"
    assert all("shutting down" in answer for answer in answers), answers


# -- the control loop alone ---------------------------------------------------------------

@pytest.fixture
async def loop_under_test() -> AsyncIterator[ControlLoop]:
    config = load_config(None, env={})
    loop = ControlLoop(config, build_driver(config, "mock"), Bus(), LatencyTracker())
    await loop.start(realtime=False)
    yield loop
    await loop.stop()


async def test_after_halt_the_estop_cannot_be_released_nor_a_command_drive(
        loop_under_test: ControlLoop) -> None:
    loop = loop_under_test
    await loop.halt()
    refusal = loop.release_estop()
    assert refusal is not None and "shutting down" in refusal
    assert loop.arbiter.estop_engaged
    applied = await loop.submit("ws:1", Twist(0.5, 0.0), t_recv=loop.clock())
    assert not applied.accepted and "shutting down" in (applied.error or "")
    await loop.tick(loop.clock())
    assert loop.driver.commands[-1].left_rad_s == 0.0  # type: ignore[attr-defined]


class Hangs(BaseComponent):
    """A component whose stop() never returns by itself."""

    name = "hangs"

    def __init__(self) -> None:
        self.cancelled = asyncio.Event()

    async def stop(self) -> None:
        try:
            await asyncio.Event().wait()
        finally:
            self.cancelled.set()


async def test_a_component_that_does_not_stop_is_abandoned_in_time(
        tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    hangs = Hangs()
    async with in_process_daemon(tmp_path) as robot:
        robot.daemon.components.append(hangs)  # stopped first (reverse order)
        t0 = time.monotonic()
    elapsed = time.monotonic() - t0
    assert hangs.cancelled.is_set()
    assert elapsed < STOP_TIMEOUT_S + 2.0, f"shutdown took {elapsed:.1f} s"
    assert "stopping hangs took longer than 3.00 s; abandoned" in caplog.text
    assert not robot.moving()
