# Benchmark suite "safety": `arbiterd simulate` speed, collision-monitor cost, command latency.
from __future__ import annotations

import asyncio
import logging
import math
import statistics
import time

import numpy as np

from daemon.bench import BenchResult
from daemon.bus import Bus
from daemon.commands import Twist
from daemon.component import Plugs
from daemon.components.collision_monitor.component import SafetyComponent, monitor_settings
from daemon.components.collision_monitor.monitor import CollisionMonitor
from daemon.components.control.loop import ControlLoop
from daemon.config import Config, build_driver, load_config
from daemon.heap import collect_before_start, freeze_startup_heap, thaw
from daemon.latency import LatencyTracker, summarize
from daemon.lockstep.runner import Lockstep
from daemon.telemetry import SCAN
from sensors.scan import LaserScan
from sim.raycast import RayCaster, ray_angles
from sim.settings import SimConfig, SimSettings
from sim.stepper import SimWorld
from sim.world import generated_world

SUITE = "safety"
TARGET_REALTIME = 100.0
TARGET_EXEC_P99_MS = 0.2


def run(quick: bool) -> list[BenchResult]:
    logging.getLogger("arbiterd").setLevel(logging.ERROR)  # no change-of-action lines
    return [*_simulate_speed(30.0 if quick else 120.0), *_monitor_cost(200 if quick else 2000),
            *asyncio.run(_command_latency(2000 if quick else 20000))]


# -- arbiterd simulate ----------------------------------------------------------------------------

def _simulate_once(seconds: float, seed: int) -> tuple[float, float, float]:
    """Wall and CPU real-time factors of one wander run, and the bare world's factor over
    the same simulated time (the in-run baseline)."""
    config = load_config(None, sim=True, env={})
    config.update("sim", {"seed": seed})
    runner = Lockstep(config, autonomy="wander")
    wall, cpu = time.perf_counter(), time.process_time()
    asyncio.run(runner.run(seconds))
    wall, cpu = time.perf_counter() - wall, time.process_time() - cpu
    world = SimWorld(SimConfig.from_settings(config.get(SimSettings)))
    start = time.perf_counter()
    for index in range(round(seconds * world.config.physics_rate)):
        if index % 5 == 0:  # the world's own scans, as the runner casts them
            world.scan()
        world.command_twist(0.5, 0.3 * math.sin(index / 50.0))
        world.step()
    world_factor = seconds / (time.perf_counter() - start)
    world.close()
    return seconds / wall, seconds / cpu, world_factor


def _simulate_speed(seconds: float) -> list[BenchResult]:
    runs = [_simulate_once(seconds, seed) for seed in (1, 2, 3)]
    wall = statistics.median(r[0] for r in runs)
    cpu = statistics.median(r[1] for r in runs)
    world = statistics.median(r[2] for r in runs)
    note = (f"median of 3 x {seconds:.0f} s of wander (seeds 1-3), collision monitor on; "
            f"CPU-time factor {cpu:.0f}x; the world alone (50 Hz physics, 10 Hz scans) "
            f"{world:.0f}x in the same run")
    return [
        BenchResult(SUITE, "simulate real-time factor (wander + monitor)", round(wall, 1),
                    "x real time", target=f">= {TARGET_REALTIME:.0f}x",
                    ok=wall >= TARGET_REALTIME, note=note),
        BenchResult(SUITE, "simulate real-time factor on CPU time", round(cpu, 1),
                    "x real time", note="process CPU time: what a loaded machine leaves aside"),
        BenchResult(SUITE, "world alone real-time factor (baseline)", round(world, 1),
                    "x real time"),
    ]


# -- the monitor ----------------------------------------------------------------------------------

def _arena_scans(count: int) -> list[tuple[np.ndarray, np.ndarray]]:
    """360-ray revolutions of the default arena from poses along a line through it."""
    world = generated_world(1)
    caster = RayCaster(world, ray_angles(360), 0.1, 10.0)
    angles = ray_angles(360)
    scans = []
    for index in range(count):
        x, y = -6.0 + 12.0 * (index % 97) / 97, 0.3 * math.sin(index)
        if world.clearance(x, y) < 0.4:
            x, y = 0.0, 0.0
        ranges = caster.cast(x, y, 0.1 * index)
        valid = np.isfinite(ranges)
        scans.append((ranges[valid] * np.cos(angles[valid]),
                      ranges[valid] * np.sin(angles[valid])))
    return scans


def _monitor_cost(count: int) -> list[BenchResult]:
    config = load_config(None, env={})
    monitor = CollisionMonitor(monitor_settings(config))
    scans = _arena_scans(count)
    per_revolution, per_command = [], []
    for index, (px, py) in enumerate(scans):
        t = index * 0.1
        monitor.observe(t, 0.0, 0.0, 0.0)
        start = time.perf_counter()
        monitor.on_scan(px, py, t - 0.1, t)
        for twist in ((1.0, 0.0), (0.8, 0.6), (0.5, -1.0), (-0.3, 0.0)):  # bins they need
            monitor.limit(*twist, *twist, t)
        middle = time.perf_counter()
        for _ in range(10):
            monitor.limit(0.8, 0.6, 0.8, 0.6, t)
        per_revolution.append(middle - start)
        per_command.append((time.perf_counter() - middle) / 10)
    revolution_ms = statistics.median(per_revolution) * 1e3
    command_us = statistics.median(per_command) * 1e6
    return [
        BenchResult(SUITE, "collision monitor per revolution", round(revolution_ms, 3), "ms",
                    note=f"median of {count}: place 360 rays of the default arena and sweep "
                    "the footprint along 4 paths (both zones)"),
        BenchResult(SUITE, "collision monitor per command", round(command_us, 2), "us",
                    note="median: a target checked against the placed revolution (cached)"),
    ]


# -- receipt -> driver write with and without the monitor -----------------------------------------

async def _command_latency(count: int) -> list[BenchResult]:
    off = await _latency_p99(count, monitor=False)
    on = await _latency_p99(count, monitor=True)
    off2 = await _latency_p99(count, monitor=False)
    baseline = min(off, off2)
    note = (f"{count} back-to-back commands on the event path (a slowly steering teleop), "
            f"mock driver, revolutions of the default arena at 10 Hz; monitor off "
            f"{off:.4f} / {off2:.4f} ms before and after")
    return [
        BenchResult(SUITE, "receipt->driver write p99, monitor on", round(on, 4), "ms",
                    target=f"<= {TARGET_EXEC_P99_MS} ms", ok=on <= TARGET_EXEC_P99_MS,
                    note=note),
        BenchResult(SUITE, "receipt->driver write p99, monitor off", round(baseline, 4), "ms",
                    note="same run, the better of the two"),
    ]


async def _latency_p99(count: int, *, monitor: bool) -> float:
    config: Config = load_config(None, env={})
    latency = LatencyTracker(window=count)
    bus = Bus()
    loop = ControlLoop(config, build_driver(config, "mock"), bus, latency)
    if monitor:
        SafetyComponent(config, Plugs(loop, loop, bus), latency.metrics.registry)
    collect_before_start()
    await loop.start()
    freeze_startup_heap()  # as the daemon does once it has started
    feeder = asyncio.create_task(_feed_scans(bus))
    try:
        samples = []
        for index in range(count):
            t_recv = time.monotonic()  # a teleop steering slowly, as a joystick does
            twist = Twist(0.4 + 0.2 * math.sin(index / 300), 0.3 * math.sin(index / 170))
            applied = await loop.submit("bench", twist, t_recv=t_recv)
            assert applied.report is not None, applied.error
            samples.append(applied.report.exec_ms)
            if index % 20 == 0:
                await asyncio.sleep(0.002)  # ticks and revolutions arrive in between
    finally:
        feeder.cancel()
        await loop.stop()
        thaw()
    return float(summarize(samples)["p99"])


async def _feed_scans(bus: Bus) -> None:
    """Revolutions of the default arena as the lidar component would publish them."""
    world = generated_world(1)
    caster = RayCaster(world, ray_angles(360), 0.1, 10.0)
    step = 2.0 * math.pi / 360
    index = 0
    while True:
        ranges = caster.cast(0.0, 0.0, 0.05 * index).astype(np.float32)
        bus.publish(SCAN, LaserScan(stamp=time.time() - 0.1, angle_min=0.0,
                                      angle_max=step * 359, angle_increment=step,
                                      scan_time=0.1, range_min=0.1, range_max=10.0,
                                      ranges=ranges))
        index += 1
        await asyncio.sleep(0.1)


if __name__ == "__main__":
    for result in run(quick=True):
        print(f"{result.name:46} {result.value:>10} {result.unit:12} {result.target:10} "
              f"{result.note}")
