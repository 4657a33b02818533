# Control benchmarks: receipt -> driver write latency (mock driver) and 50 Hz tick lateness.
from __future__ import annotations

import asyncio
import time

from daemon.bench import BenchResult
from daemon.bus import Bus
from daemon.commands import Twist
from daemon.components.control.loop import ControlLoop
from daemon.config import build_driver, load_config
from daemon.heap import collect_before_start, freeze_startup_heap, thaw
from daemon.latency import LatencyTracker, summarize

SUITE = "control"


def run(quick: bool) -> list[BenchResult]:
    return asyncio.run(_run(quick))


async def _run(quick: bool) -> list[BenchResult]:
    config = load_config(None, env={})
    config.update("driver", {"type": "mock"})
    latency = LatencyTracker(window=100000)
    loop = ControlLoop(config, build_driver(config, "mock"), Bus(), latency)
    collect_before_start()
    await loop.start()
    freeze_startup_heap()  # as the daemon does once it has started
    try:
        exec_ms = await _command_latency(loop, 2000 if quick else 20000)
        latency.tick_late_ms.clear()
        await _commands_at(loop, 100.0, 3.0 if quick else 20.0)
        tick = summarize(latency.tick_late_ms)
    finally:
        await loop.stop()
        thaw()
    stats = summarize(exec_ms)
    return [
        BenchResult(SUITE, "receipt->driver write p50 (mock)", stats["p50"], "ms"),
        BenchResult(SUITE, "receipt->driver write p99 (mock)", stats["p99"], "ms",
                    "<= 0.2 ms", stats["p99"] <= 0.2, f"{stats['count']} commands"),
        BenchResult(SUITE, "tick lateness p50 at 50 Hz", tick["p50"], "ms"),
        BenchResult(SUITE, "tick lateness p99 at 50 Hz", tick["p99"], "ms", "<= 1 ms",
                    tick["p99"] <= 1.0, f"{tick['count']} ticks, 100 Hz commands meanwhile"),
    ]


async def _command_latency(loop: ControlLoop, count: int) -> list[float]:
    """Back-to-back commands on the event path; each timed from receipt to driver write."""
    samples = []
    for i in range(count):
        t_recv = time.monotonic()
        applied = await loop.submit("bench", Twist(0.2 + (i % 10) * 0.01, 0.1), t_recv=t_recv)
        assert applied.report is not None, applied.error
        samples.append(applied.report.exec_ms)
        if i % 50 == 0:
            await asyncio.sleep(0)  # let ticks run as they would between real commands
    return samples


async def _commands_at(loop: ControlLoop, rate_hz: float, seconds: float) -> None:
    period = 1.0 / rate_hz
    deadline = time.monotonic()
    end = deadline + seconds
    while deadline < end:
        deadline += period
        await asyncio.sleep(max(0.0, deadline - time.monotonic()))
        await loop.submit("bench", Twist(0.3, 0.2), t_recv=time.monotonic())
