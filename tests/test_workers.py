# Worker processes (the mapper, the planner) are restarted when they die, and health says so.
from __future__ import annotations

import asyncio
import os
import signal
import time
from collections.abc import AsyncIterator
from pathlib import Path

import aiohttp
import pytest

from daemon.workers import SupervisedWorker, WorkerDown
from tests.support.in_process_daemon import InProcessDaemon, in_process_daemon
from tests.support.wait import eventually


def _nothing() -> None:
    return None


async def test_a_killed_worker_fails_its_job_and_comes_back() -> None:
    worker = SupervisedWorker("test", _nothing, lambda: (), backoff_s=(0.05, 1.0))
    try:
        pid = await worker.call(os.getpid)
        job = asyncio.ensure_future(worker.call(time.sleep, 30))
        os.kill(pid, signal.SIGKILL)
        with pytest.raises(WorkerDown, match="died during the job"):
            await job
        problem = worker.problem()
        assert problem is not None and problem[0] == "degraded", problem
        await eventually(lambda: worker.problem() is None, "the worker restarted")
        assert await worker.call(os.getpid) != pid and worker.restarts == 1
    finally:
        await asyncio.to_thread(worker.close)


async def test_restarts_that_keep_failing_turn_health_to_error() -> None:
    starts = iter(range(100))

    def args() -> tuple[int]:
        return (next(starts),)

    worker = SupervisedWorker("test", _die_after_first, args, backoff_s=(0.01, 0.02),
                              error_after=2)
    try:
        pid = await worker.call(os.getpid)
        os.kill(pid, signal.SIGKILL)
        await eventually(lambda: (p := worker.problem()) is not None and p[0] == "error",
                         "health to say error after two failed restarts")
        with pytest.raises(WorkerDown, match="is down"):
            await worker.call(os.getpid)
    finally:
        await asyncio.to_thread(worker.close)


def _die_after_first(start: int) -> None:
    if start > 0:
        os._exit(3)


@pytest.fixture
async def robot(tmp_path: Path) -> AsyncIterator[InProcessDaemon]:
    toml = f'[navigation]\nenabled = true\n[mapping]\nenabled = true\n' \
        f'directory = "{tmp_path / "maps"}"\n'
    async with in_process_daemon(tmp_path, toml) as robot:
        yield robot


async def health_of(robot: InProcessDaemon, name: str) -> dict[str, object]:
    async with aiohttp.ClientSession() as http, http.get(robot.http_url + "/api/health") as r:
        components: dict[str, dict[str, object]] = (await r.json())["components"]
        return components[name]


async def test_killing_the_planning_and_mapping_workers_is_survived(
        robot: InProcessDaemon) -> None:
    """Before: kill -9 on the planning process stopped the robot, then every goal failed
    with BrokenProcessPool, no worker was started again and health said navigation ok."""
    nav, mapping = robot.component("navigation"), robot.component("mapping")
    async with aiohttp.ClientSession() as http:
        async with http.post(robot.http_url + "/api/goal", json={"x": 0.4, "y": 0.0}) as r:
            assert r.status == 200, await r.text()
        await eventually(lambda: nav.worker is not None and nav.plan_ms is not None,
                         "the first plan from the worker")
        for component, supervised in (("navigation", nav.worker.worker),
                                      ("mapping", mapping.runner.worker)):
            pid = await supervised.call(os.getpid)
            killed = time.monotonic()
            os.kill(pid, signal.SIGKILL)
            await eventually(lambda s=supervised: s.problem() is not None, "the death seen")
            down = await health_of(robot, component)
            assert down["status"] == "degraded" and "worker is down" in str(down["problem"])
            await eventually(lambda s=supervised: s.problem() is None, "the worker back")
            print(f"{component}: back {time.monotonic() - killed:.1f} s after kill -9; "
                  f"health meanwhile: {down['status']}: {down['problem']}")
            assert (await health_of(robot, component))["status"] == "ok"
        assert nav.navigator.state == "failed" or nav.navigator.state != "planning"
        nav.plan_ms = None
        async with http.post(robot.http_url + "/api/goal", json={"x": 0.3, "y": 0.1}) as r:
            assert r.status == 200, await r.text()
        await eventually(lambda: nav.plan_ms is not None, "a plan from the new worker")
        scans = mapping.counters.scans
        await eventually(lambda: mapping.counters.scans > scans, "the mapper mapping again")
