# Benchmark suite registry: suite name -> module with `run(quick) -> list[BenchResult]`.
from __future__ import annotations

import asyncio
import contextlib
import logging
import socket
from collections.abc import AsyncIterator, Coroutine
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any, NamedTuple, TypeVar

import aiohttp

T = TypeVar("T")


@dataclass
class BenchResult:
    """One measured figure, with its target when it has one."""

    suite: str
    name: str
    value: float
    unit: str
    target: str = ""
    ok: bool | None = None
    note: str = ""

    def as_dict(self) -> dict[str, Any]:
        return asdict(self)


def percentile_ms(samples_s: list[float], pct: float) -> float:
    """The ``pct`` percentile (nearest rank) of durations in seconds, in milliseconds."""
    if not samples_s:
        return float("nan")
    ordered = sorted(samples_s)
    index = min(len(ordered) - 1, max(0, round(pct / 100 * (len(ordered) - 1))))
    return ordered[index] * 1e3


def ms_result(suite: str, name: str, value_ms: float, note: str = "") -> BenchResult:
    """A millisecond figure without a target."""
    return BenchResult(suite, name, round(value_ms, 4), "ms", note=note)


def run_quietly(main: Coroutine[Any, Any, T]) -> T:
    """Run a suite's coroutine with the daemon's own log quiet (errors only; the missing
    lidar of ``bench_daemon(serve_scan=True)`` is not even an error here)."""
    loggers = {logging.getLogger("arbiterd"): logging.ERROR,
               logging.getLogger("sensors"): logging.CRITICAL}
    levels = {log: log.level for log in loggers}
    for log, quiet in loggers.items():
        log.setLevel(quiet)
    try:
        return asyncio.run(main)
    finally:
        for log, level in levels.items():
            log.setLevel(level)


def free_port() -> int:
    """A TCP port on 127.0.0.1 that nothing listens on right now."""
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        port: int = sock.getsockname()[1]
        return port


@contextlib.asynccontextmanager
async def bench_daemon(workdir: Path, extra_toml: str = "", *,
                       serve_scan: bool = False) -> AsyncIterator[tuple[Any, str]]:
    """The daemon in this process on the mock driver, HTTP off: (daemon, rosbridge URL).

    No simulated world, so the figures are the bridge's, not the world's; ``extra_toml`` is
    appended to its configuration file in ``workdir``. ``serve_scan``: the lidar component
    is there, so the topic table has ``/scan``, on a port that does not exist (it retries with
    back-off; the suite publishes the scans on the bus itself) and with the collision monitor
    off, so that the figures stay the bridge's."""
    from daemon.app import Daemon
    from daemon.config import load_config

    ws_port = free_port()
    config_path = workdir / "bench.toml"
    lidar = (f'[lidar]\nenabled = true\nport = "{workdir / "no-lidar"}"\n'
             '[collision_monitor]\nenabled = false\n') if serve_scan else ""
    config_path.write_text(f'[http]\nenabled = false\nport = {free_port()}\n'
                           f'[rosbridge]\nhost = "127.0.0.1"\nport = {ws_port}\n'
                           '[driver]\ntype = "mock"\n' + lidar + extra_toml)
    daemon = Daemon(load_config(config_path))
    task = asyncio.create_task(daemon.run())
    while daemon.state == "startup":
        if task.done():
            raise RuntimeError(f"bench daemon did not start (exit {task.result()})")
        await asyncio.sleep(0.01)
    try:
        yield daemon, f"ws://127.0.0.1:{ws_port}/"
    finally:
        daemon.request_shutdown("bench over")
        await task


async def scan_subscribers(session: aiohttp.ClientSession, stack: contextlib.AsyncExitStack,
                           bridge_url: str, clients: int,
                           **options: Any) -> list[aiohttp.ClientWebSocketResponse]:
    """``clients`` WebSockets to the rosbridge at ``bridge_url``, each subscribed to /scan with
    ``options`` (e.g. compression); ``stack`` closes them."""
    sockets = [await stack.enter_async_context(session.ws_connect(bridge_url))
               for _ in range(clients)]
    for ws in sockets:
        await ws.send_json({"op": "subscribe", "topic": "/scan", **options})
    return sockets


class Suite(NamedTuple):
    """A benchmark suite: the module with ``def run(quick: bool) -> list[BenchResult]``, and
    what it measures (for ``arbiterd bench --help``)."""

    module: str
    what: str


#: suite name => its module and what it measures, in the order `arbiterd bench` runs them
SUITES: dict[str, Suite] = {
    "control": Suite("daemon.bench.control", "receipt -> driver write and tick lateness, "
                     "mock driver"),
    "lidar": Suite("daemon.bench.lidar", "RPLIDAR decoding against the Python peer decoders"),
    "drivers": Suite("daemon.bench.drivers", "command -> write latency of each driver against "
                     "its emulator"),
    "sim": Suite("daemon.bench.sim", "how much faster than real time the world steps"),
    "process": Suite("daemon.bench.process", "`arbiterd run`: time to READY, idle CPU and RSS"),
    "rosbridge": Suite("daemon.bench.rosbridge", "WebSocket round trip vs a bare aiohttp echo, "
                       "tick lateness under /scan clients"),
    "console": Suite("daemon.bench.console", "tick lateness with the web console driving"),
    "rosbridge-flood": Suite("daemon.bench.rosbridge_flood", "loop stalls and tick lateness "
                             "under hostile clients, RSS while fuzzing"),
    "safety": Suite("daemon.bench.safety", "`arbiterd simulate` speed, collision-monitor cost "
                    "and command latency"),
    "ros2": Suite("daemon.bench.ros2", "CPU of the ROS 2 face (DDS) beside the daemon without "
                  "it, /scan latency to an rclpy node"),
    "foxglove": Suite("daemon.bench.foxglove", "scan frames (JSON, cbor, cbor-raw); tick "
                      "lateness with the flight recorder off and on"),
    "fleet": Suite("daemon.bench.fleet", "the fleet component: tick lateness publishing ÷ "
                   "paused, its CPU beside the daemon without it, bandwidth per robot"),
    "slam": Suite("daemon.bench.slam", "the mapper over the Freiburg logs: relation errors "
                  "beside Cartographer and odometry, speed vs real time"),
    "mapping-sim": Suite("daemon.bench.mapping_sim", "the mapper in `arbiterd simulate`: pose "
                         "error and map quality against the true world, beside odometry, "
                         "apartment / warehouse / loop with a drifting base"),
    "navigation": Suite("daemon.bench.navigation", "goals in `arbiterd simulate` against the "
                        "true world: success, collisions, path length vs the shortest; "
                        "figure-eight tracking; planning and follower cost"),
    "navigation-tick": Suite("daemon.bench.navigation_tick", "tick lateness with a goal "
                             "planned and followed beside navigation idle, in turns"),
    "localize": Suite("daemon.bench.localize", "localisation in a saved map from 1 m / 30° "
                      "off, 20 trials in `arbiterd simulate`: converged within 0.05 m in 5 s"),
    "camera": Suite("daemon.bench.camera", "sim render + JPEG encode per frame; tick "
                    "lateness and CPU with an MJPEG viewer beside nobody watching"),
    "mapping-cost": Suite("daemon.bench.mapping_cost", "mapper ms per 360-ray revolution "
                          "beside the lidar decode; tick lateness, mapping on vs off"),
}


def suites_help() -> str:
    """The suites, one a line, for ``arbiterd bench --help``."""
    width = max(len(name) for name in SUITES)
    return "suites (--only SUITE, repeatable; default: all):\n" + "\n".join(
        f"  {name:<{width}}  {suite.what}" for name, suite in SUITES.items())
