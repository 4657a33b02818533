# Bench suite "console": control tick lateness with one web console connected and driving,
# beside the idle figure of the same simulated robot in the same run.
from __future__ import annotations

import argparse
import asyncio
import contextlib
import json
import os
import shutil
import sys
import tempfile
import time
from collections.abc import AsyncIterator, Awaitable
from pathlib import Path
from typing import TYPE_CHECKING, Any

import aiohttp

from daemon.bench import BenchResult, free_port, run_quietly
from daemon.latency import LatencyTracker, summarize

if TYPE_CHECKING:
    from daemon.app import Daemon

SUITE = "console"
REPO = Path(__file__).resolve().parents[2]
BROWSER_CLIENT = REPO / "tests" / "console" / "console_client.mjs"
CHROMIUM = os.environ.get("ARBITERD_CHROMIUM", "/usr/bin/chromium")
STRING = "std_msgs/msg/String"
# What the page does (daemon/console/static/app.js): rosbridge subscriptions, a stamped command
# every 50 ms while driving, a link ping every 2 s, and HTTP polls (path -> period in s).
SUBSCRIPTIONS = [("/odom", {}), ("/scan", {}), ("/latency_reports", {}), ("/robot_info", {}),
                 ("/autonomy/state", {}), ("/rosout", {}),
                 ("/odom_ground_truth", {"throttle_rate": 100})]
POLLS = {"/api/health": 1.0, "/api/status": 0.25, "/api/latency": 2.0}
COMMAND_PERIOD_S = 0.05


# -- the console's traffic, replayed from a separate process ----------------------------------


async def replay(http_url: str, ws_url: str, seconds: float) -> dict[str, Any]:
    """One console driving in a circle for ``seconds``: the page's requests, without a browser."""
    counts = {"messages": 0, "commands": 0, "polls": 0}
    async with aiohttp.ClientSession() as session, session.ws_connect(ws_url) as ws:
        await ws.send_json({"op": "advertise", "topic": "/stamped_cmd_vel", "type": STRING})
        for topic, options in SUBSCRIPTIONS:
            await ws.send_json({"op": "subscribe", "topic": topic, **options})
        tasks = [asyncio.create_task(_read(ws, counts))]
        tasks += [asyncio.create_task(_poll(session, http_url + path, period, counts))
                  for path, period in POLLS.items()]
        tasks.append(asyncio.create_task(_ping(ws)))
        await _drive(ws, seconds, counts)
        for task in tasks:
            task.cancel()
    return counts


async def alternate(http_url: str, ws_url: str, window_s: float, cycles: int) -> dict[str, Any]:
    """``cycles`` times: ``window_s`` with no client, then ``window_s`` with one console
    connected and driving. The windows (monotonic s, the same clock as the daemon's) let the
    daemon side sort its ticks into the two, so both see the same machine load."""
    windows: dict[str, list[tuple[float, float]]] = {"idle": [], "console": []}
    totals = {"messages": 0, "commands": 0, "polls": 0}
    for _ in range(cycles):
        t0 = time.monotonic()
        await asyncio.sleep(window_s)
        windows["idle"].append((t0, time.monotonic()))
        t0 = time.monotonic()
        counts = await replay(http_url, ws_url, window_s)
        windows["console"].append((t0, time.monotonic()))
        for key, value in counts.items():
            totals[key] += value
    return {"windows": windows, **totals}


async def _read(ws: aiohttp.ClientWebSocketResponse, counts: dict[str, int]) -> None:
    async for message in ws:
        json.loads(message.data)  # the page parses every frame
        counts["messages"] += 1


async def _poll(session: aiohttp.ClientSession, url: str, period: float,
                counts: dict[str, int]) -> None:
    while True:
        async with session.get(url) as response:
            await response.json()
        counts["polls"] += 1
        await asyncio.sleep(period)


async def _ping(ws: aiohttp.ClientWebSocketResponse) -> None:
    while True:
        await ws.send_json({"op": "call_service", "id": "ping", "service": "/rosapi/get_time"})
        await asyncio.sleep(2.0)


async def _drive(ws: aiohttp.ClientWebSocketResponse, seconds: float,
                 counts: dict[str, int]) -> None:
    t_next = time.monotonic()
    t_end = t_next + seconds
    while t_next < t_end:
        body = {"linear": {"x": 0.3}, "angular": {"z": 0.6}, "id": f"bench-{counts['commands']}",
                "t_sent": time.time() * 1e3}
        await ws.send_json({"op": "publish", "topic": "/stamped_cmd_vel",
                            "msg": {"data": json.dumps(body)}})
        counts["commands"] += 1
        t_next += COMMAND_PERIOD_S
        await asyncio.sleep(max(0.0, t_next - time.monotonic()))
    await ws.send_json({"op": "publish", "topic": "/stamped_cmd_vel", "msg": {"data": json.dumps(
        {"linear": {"x": 0.0}, "angular": {"z": 0.0}, "id": "bench-stop"})}})


def worker_main(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(prog="python -m daemon.bench.console")
    parser.add_argument("--http", required=True)
    parser.add_argument("--ws", required=True)
    parser.add_argument("--seconds", type=float, default=3.0, help="one window")
    parser.add_argument("--cycles", type=int, default=0,
                        help="alternate idle and console windows this many times (0: one "
                        "console window only)")
    args = parser.parse_args(argv)
    if args.cycles:
        out = asyncio.run(alternate(args.http, args.ws, args.seconds, args.cycles))
    else:
        out = asyncio.run(replay(args.http, args.ws, args.seconds))
    print(json.dumps(out), flush=True)
    return 0


# -- the daemon side (this process) -----------------------------------------------------------


class TimedLatency(LatencyTracker):
    """Also keeps when each tick's lateness was recorded, to sort ticks into windows."""

    def __init__(self) -> None:
        super().__init__()
        self.timed_ticks: list[tuple[float, float]] = []

    def record_tick(self, lateness_s: float, late: bool) -> None:
        super().record_tick(lateness_s, late)
        self.timed_ticks.append((time.monotonic(), lateness_s * 1e3))

    def within(self, windows: list[tuple[float, float]]) -> list[float]:
        return [ms for t, ms in self.timed_ticks if any(a <= t <= b for a, b in windows)]


@contextlib.asynccontextmanager
async def sim_daemon(workdir: Path) -> AsyncIterator[tuple[Any, str, str]]:
    """The simulated robot (world, emulators, lidar) as ``arbiterd run --sim`` runs it."""
    from daemon.app import Daemon
    from daemon.config import load_config

    http_port, ws_port = free_port(), free_port()
    config_path = workdir / "bench.toml"
    config_path.write_text(f'[http]\nhost = "127.0.0.1"\nport = {http_port}\n'
                           f'[rosbridge]\nhost = "127.0.0.1"\nport = {ws_port}\n')
    daemon = Daemon(load_config(config_path, sim=True, env={}))
    daemon.latency = TimedLatency()
    task = asyncio.create_task(daemon.run())
    deadline = time.monotonic() + 30
    while daemon.health()["status"] != "ok" or daemon.state == "startup":
        if task.done() or time.monotonic() > deadline:
            raise RuntimeError(f"bench daemon did not become healthy: {daemon.status_line()}")
        await asyncio.sleep(0.05)
    try:
        yield daemon, f"http://127.0.0.1:{http_port}", f"ws://127.0.0.1:{ws_port}/"
    finally:
        daemon.request_shutdown("bench over")
        await task


async def _process(*args: str) -> str:
    proc = await asyncio.create_subprocess_exec(
        *args, stdout=asyncio.subprocess.PIPE, stderr=asyncio.subprocess.PIPE)
    out, err = await proc.communicate()
    if proc.returncode != 0:
        raise RuntimeError(f"{' '.join(args[:3])} failed: {(out + err).decode()[-2000:]}")
    return out.decode()


def browser_available() -> bool:
    """A checkout with the console's browser test installed (`./install.sh test`)."""
    modules = BROWSER_CLIENT.parent / "node_modules" / "playwright-core"
    return bool(shutil.which("node")) and Path(CHROMIUM).exists() and modules.is_dir()


async def _measure(daemon: Daemon, work: Awaitable[Any]) -> tuple[list[float], int, Any]:
    """Tick lateness samples and commands applied while ``work`` runs, and its result."""
    latency = daemon.latency
    latency.tick_late_ms.clear()
    commands = latency.commands
    result = await work
    return list(latency.tick_late_ms), latency.commands - commands, result


async def _run(quick: bool) -> list[BenchResult]:
    window, cycles = (1.0, 3) if quick else (1.5, 10)
    with tempfile.TemporaryDirectory(prefix="arbiterd-bench-") as tmp:
        async with sim_daemon(Path(tmp)) as (daemon, http_url, ws_url):
            out = await _process(sys.executable, "-m", "daemon.bench.console", "--http",
                                 http_url, "--ws", ws_url, "--seconds", str(window),
                                 "--cycles", str(cycles))
            replayed = json.loads(out.strip().splitlines()[-1])
            idle = daemon.latency.within(replayed["windows"]["idle"])
            driving = daemon.latency.within(replayed["windows"]["console"])
            browser = None
            if browser_available():
                browser = await _browser(daemon, http_url, window * cycles)
    return _results(idle, driving, replayed, browser, window, cycles)


async def _browser(daemon: Daemon, http_url: str, seconds: float) -> tuple[list[float], int, Any]:
    """The real page in headless Chromium; measured from when it starts driving."""
    proc = await asyncio.create_subprocess_exec(
        shutil.which("node") or "node", str(BROWSER_CLIENT), http_url + "/", "hold",
        "--seconds", str(seconds), stdout=asyncio.subprocess.PIPE,
        stderr=asyncio.subprocess.STDOUT)
    assert proc.stdout is not None
    lines = []
    while line := (await proc.stdout.readline()).decode():
        lines.append(line)
        if '"step":"driving"' in line:
            result = await _measure(daemon, proc.wait())
            lines += [(await proc.stdout.read()).decode()]
            if result[2] == 0:
                return result
    await proc.wait()
    raise RuntimeError(f"console_client.mjs hold failed: {''.join(lines)[-2000:]}")


def _p99(samples: list[float]) -> float:
    return float(summarize(samples).get("p99", float("nan")))


def _results(idle: list[float], driving: list[float], replayed: dict[str, Any],
             browser: tuple[list[float], int, Any] | None, window: float,
             cycles: int) -> list[BenchResult]:
    seconds = window * cycles
    out = [
        BenchResult(SUITE, "tick lateness p99 idle (sim)", _p99(idle), "ms",
                    note=f"simulated robot with its lidar, no client: {len(idle)} ticks in "
                    f"{cycles} windows of {window:g} s, interleaved with the console's"),
        BenchResult(SUITE, "tick lateness p99, one console driving", _p99(driving), "ms",
                    note=f"the console's traffic replayed from another process: "
                    f"{len(driving)} ticks; {replayed['commands']} commands at 20 Hz, "
                    f"{replayed['messages']} telemetry messages, {replayed['polls']} HTTP polls "
                    f"over {seconds:g} s"),
        BenchResult(SUITE, "console / idle tick lateness at p99", _p99(driving) / _p99(idle),
                    "x"),
    ]
    if browser is None:
        out.append(BenchResult(SUITE, "tick lateness p99, console in Chromium", float("nan"),
                               "ms", note="not measured: needs node, chromium and "
                               "tests/console/node_modules (./install.sh test in a checkout)"))
    else:
        b_ticks, b_commands, _ = browser
        out.append(BenchResult(SUITE, "tick lateness p99, console in Chromium", _p99(b_ticks),
                               "ms", note=f"the real page in headless Chromium on this machine "
                               f"(it shares the CPU), holding W+A for {seconds:g} s after the "
                               f"idle windows: {b_commands} commands"))
    return out


def run(quick: bool) -> list[BenchResult]:
    return run_quietly(_run(quick))


if __name__ == "__main__":
    sys.exit(worker_main(sys.argv[1:]))
