# Bench suite "fleet": the fleet component's cost on the robot: tick lateness with it
# publishing ÷ paused (same run), and its CPU beside the same daemon without it.
from __future__ import annotations

import asyncio
import contextlib
import json
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

from daemon.bench import BenchResult, bench_daemon, free_port, percentile_ms, run_quietly
from daemon.bench.foxglove import synthetic_scan
from daemon.bench.process import _cpu_seconds
from daemon.telemetry import SCAN

SUITE = "fleet"
CPU_TARGET_PCT = 1.0
RATIO_TARGET = 1.1
SIM = "[sim]\nlidar_rays = 720\nlidar_rate = 10.0\n"


def _router(endpoint: str) -> Any:
    import zenoh

    from daemon.components.fleet.zconfig import router_config

    session = zenoh.open(zenoh.Config.from_json5(json.dumps(router_config(endpoint, None, []))))
    received = {"samples": 0, "bytes": 0}

    def count(sample: Any) -> None:
        received["samples"] += 1
        received["bytes"] += len(sample.payload.to_bytes())

    session.declare_subscriber("arbiterd/**", count)
    return session, received


def _fleet(endpoint: str) -> str:
    return (f'[fleet]\nenabled = true\nrouter = "{endpoint}"\nrobot_id = "bench"\n'
            "scan_rate = 0.5\n")


# -- tick lateness: fleet publishing vs paused, in turns -------------------------------------------

async def _publish_scans(daemon: Any, stop: asyncio.Event) -> None:
    while not stop.is_set():
        daemon.bus.publish(SCAN, synthetic_scan())
        with contextlib.suppress(TimeoutError):
            await asyncio.wait_for(stop.wait(), 0.1)


async def _lateness(daemon: Any, seconds: float) -> list[float]:
    daemon.latency.tick_late_ms.clear()
    await asyncio.sleep(seconds)
    return [ms / 1e3 for ms in daemon.latency.tick_late_ms]


async def _tick_results(quick: bool, endpoint: str) -> list[BenchResult]:
    seconds, segment = (4.0, 1.0) if quick else (30.0, 5.0)
    with tempfile.TemporaryDirectory(prefix="arbiterd-bench-fleet-") as tmp:
        async with bench_daemon(Path(tmp), _fleet(endpoint), serve_scan=True) as (daemon, _):
            fleet = next(c for c in daemon.components if c.name == "fleet")
            await asyncio.wait_for(fleet.joined.wait(), 20)
            send = fleet.outbox.send
            stop = asyncio.Event()
            scans = asyncio.create_task(_publish_scans(daemon, stop))
            on: list[float] = []
            off: list[float] = []
            for i in range(max(2, round(seconds / segment))):
                publishing = i % 2 == 1
                fleet.outbox.send = send if publishing else None
                (on if publishing else off).extend(await _lateness(daemon, segment))
            sent = sum(c.sent for c in fleet.outbox.channels.values())
            stop.set()
            await scans
    p_on, p_off = percentile_ms(on, 99), percentile_ms(off, 99)
    ratio = p_on / p_off if p_off > 0 else float("inf")
    return [
        BenchResult(SUITE, "tick lateness p99, fleet paused", round(p_off, 4), "ms",
                    note="same daemon, scans on the bus at 10 Hz, 50 Hz tick"),
        BenchResult(SUITE, "tick lateness p99, fleet publishing", round(p_on, 4), "ms",
                    note=f"{sent} samples sent at the defaults"),
        BenchResult(SUITE, "tick p99 publishing ÷ paused", round(ratio, 3), "x",
                    f"<= {RATIO_TARGET:g}", ratio <= RATIO_TARGET,
                    note=f"in turns of {segment:g} s over {seconds:g} s; paused = the tick's "
                    "latest-value stores only, no sender work"),
    ]


# -- CPU: two `arbiterd run --sim`, fleet on and off ----------------------------------------------

def _start(workdir: Path, extra: str) -> subprocess.Popen[bytes]:
    workdir.mkdir(parents=True)
    config = workdir / "arbiterd.toml"
    config.write_text(f"[http]\nhost = \"127.0.0.1\"\nport = {free_port()}\n"
                      f"[rosbridge]\nhost = \"127.0.0.1\"\nport = {free_port()}\n" + SIM + extra)
    return subprocess.Popen([sys.executable, "-m", "daemon.cli", "run", "--sim", "--config",
                             str(config)], stdout=subprocess.DEVNULL,
                            stderr=subprocess.DEVNULL)


def _cpu_results(quick: bool, endpoint: str, received: dict[str, int]) -> list[BenchResult]:
    windows, window_s = (3, 3.0) if quick else (6, 10.0)
    with tempfile.TemporaryDirectory(prefix="arbiterd-bench-fleet-") as tmp:
        on = _start(Path(tmp) / "on", _fleet(endpoint))
        off = _start(Path(tmp) / "off", "")
        try:
            deadline = time.monotonic() + 60
            while received["samples"] < 10 and time.monotonic() < deadline:
                time.sleep(0.2)
            extra: list[float] = []
            bytes0, t_start = received["bytes"], time.monotonic()
            for _ in range(windows):
                a0, b0, t0 = _cpu_seconds(on.pid), _cpu_seconds(off.pid), time.monotonic()
                time.sleep(window_s)
                a1, b1, t1 = _cpu_seconds(on.pid), _cpu_seconds(off.pid), time.monotonic()
                extra.append(100.0 * ((a1 - a0) - (b1 - b0)) / (t1 - t0))
            rate = (received["bytes"] - bytes0) / (time.monotonic() - t_start)
        finally:
            for proc in (on, off):
                proc.terminate()
                proc.wait(15)
    cpu = statistics.median(extra)
    return [BenchResult(SUITE, "fleet component CPU (on minus off)", round(cpu, 2),
                        "% of a core", f"<= {CPU_TARGET_PCT:g}", cpu <= CPU_TARGET_PCT,
                        note=f"median of {windows} windows of {window_s:g} s; two run --sim, "
                        "720-ray scans at 10 Hz"),
            BenchResult(SUITE, "bandwidth per robot at the defaults", round(rate / 1024, 2),
                        "KiB/s", note="what the router received from the robot")]


def run(quick: bool) -> list[BenchResult]:
    try:
        import zenoh  # noqa: F401
    except ImportError:
        return [BenchResult(SUITE, "skipped", 0.0, "", note="eclipse-zenoh is not installed "
                            "(the fleet extra)")]
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    router, received = _router(endpoint)
    try:
        results = run_quietly(_tick_results(quick, endpoint))
        return results + _cpu_results(quick, endpoint, received)
    finally:
        router.close()
