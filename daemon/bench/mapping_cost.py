# Benchmark suite "mapping-cost": mapper ms per 360-ray revolution beside the lidar decode, and
# control tick lateness with the mapping worker on and off in the same daemon.
from __future__ import annotations

import asyncio
import contextlib
import math
import tempfile
import time
from pathlib import Path

import numpy as np

from daemon.app import Daemon
from daemon.bench import BenchResult, bench_daemon, run_quietly
from daemon.bench.turns import lateness_in_turns, lateness_results
from daemon.telemetry import SCAN
from sensors.rplidar import synth
from sensors.rplidar.requests import Ans
from sensors.rplidar.streams import Samples, StreamParser
from sensors.scan import LaserScan
from sim.raycast import RayCaster
from sim.world import World, load_world
from slam.mapper import Mapper, MapperConfig
from slam.pose import Pose2, compose

SUITE = "mapping-cost"
RAYS = 360
WORLD = "apartment"
MS_TARGET = 5.0
RATE_HZ = 10.0


def _path(world: World, revolutions: int) -> list[Pose2]:
    """A drive through the world: 0.3 m/s, turning away from walls (0.1 s a revolution)."""
    pose: Pose2 = (world.start.x, world.start.y, world.start.theta)
    poses = []
    turn = 0.0
    for i in range(revolutions):
        ahead = compose(pose, (0.6, 0.0, 0.0))
        if world.clearance(ahead[0], ahead[1]) < 0.45:
            turn = 0.6 if i % 40 < 20 else -0.6
        else:
            turn *= 0.8
        step = (0.03, 0.0, turn * 0.1)
        nxt = compose(pose, step)
        clear = world.clearance(nxt[0], nxt[1]) > 0.25
        pose = nxt if clear else (pose[0], pose[1], pose[2] + 0.3)
        poses.append(pose)
    return poses


def revolution_costs(revolutions: int) -> tuple[list[float], list[float], int]:
    """Per revolution: seconds to decode its RPLIDAR bytes (standard nodes), seconds for the
    mapper (match + key scan + integration + loop closure) on the decoded points; and the key
    scans made. Same loop, same process, one after the other."""
    world = load_world(WORLD)
    angles = np.arange(RAYS) * (2 * math.pi / RAYS)
    caster = RayCaster(world, angles)
    mapper = Mapper(MapperConfig())
    decode_s: list[float] = []
    map_s: list[float] = []
    start = world.start
    origin = (start.x, start.y, start.theta)
    for pose in _path(world, revolutions):
        ranges = np.minimum(caster.cast(*pose), 40.0)
        quality = np.where(np.isfinite(ranges) & (ranges < 12.0), 47, 0)
        distance = np.where(quality > 0, ranges * 1000.0, 0.0)
        stream = synth.STREAM_DESCRIPTORS[Ans.NODE].encode() + synth.encode_nodes(
            np.degrees(angles), distance, quality, np.arange(RAYS) == 0)
        t0 = time.perf_counter()
        parser = StreamParser()
        runs = [e for e in parser.feed(stream) if isinstance(e, Samples)]
        angle_deg = np.concatenate([r.angle_deg for r in runs])
        dist_mm = np.concatenate([r.distance_mm for r in runs])
        ok = dist_mm > 0
        rad = np.radians(angle_deg[ok])
        points = np.column_stack([dist_mm[ok] * 1e-3 * np.cos(rad),
                                  dist_mm[ok] * 1e-3 * np.sin(rad)])
        t1 = time.perf_counter()
        odom = compose((-origin[0], -origin[1], 0.0), pose)  # any odometry frame will do
        mapper.add_scan(odom, points, len(map_s) / RATE_HZ)
        t2 = time.perf_counter()
        decode_s.append(t1 - t0)
        map_s.append(t2 - t1)
    return decode_s, map_s, int(mapper.health()["key_scans"])


def _scan(caster: RayCaster, pose: Pose2, stamp: float) -> LaserScan:
    ranges = caster.cast(*pose).astype(np.float32)
    ranges[~np.isfinite(ranges) | (ranges > 12.0)] = np.inf
    return LaserScan(stamp, "laser", 0.0, 2 * math.pi * (RAYS - 1) / RAYS, 2 * math.pi / RAYS,
                     0.1 / RAYS, 0.1, 0.15, 12.0, ranges, np.full(RAYS, 47, dtype=np.float32))


async def publish_scans(daemon: Daemon, stop: asyncio.Event) -> None:
    """A 10 Hz lidar driving through the apartment (scans on the bus, as the lidar does)."""
    world = load_world(WORLD)
    caster = RayCaster(world, np.arange(RAYS) * (2 * math.pi / RAYS))
    path = _path(world, 600)
    i = 0
    while not stop.is_set():
        daemon.bus.publish(SCAN, _scan(caster, path[i % len(path)], time.time()))
        i += 1
        with contextlib.suppress(TimeoutError):
            await asyncio.wait_for(stop.wait(), 1.0 / RATE_HZ)


async def _tick_results(quick: bool) -> list[BenchResult]:
    with tempfile.TemporaryDirectory(prefix="arbiterd-bench-") as tmp:
        extra = f'[mapping]\nenabled = true\ndirectory = "{Path(tmp) / "maps"}"\n'
        async with bench_daemon(Path(tmp), extra, serve_scan=True) as (daemon, _url):
            mapping = next(c for c in daemon.components if c.name == "mapping")
            stop = asyncio.Event()
            scans = asyncio.create_task(publish_scans(daemon, stop))
            runner = mapping.runner
            await asyncio.sleep(1.0)  # the worker's start-up

            def switch(on: bool) -> None:
                # off: the component drops revolutions (no runner); on: they go to the worker
                mapping.runner = runner if on else None

            turns = await lateness_in_turns(daemon, quick, switch)
            mapping.runner = runner
            scans_done = mapping.counters.scans
            stop.set()
            await scans
    return lateness_results(
        SUITE, turns, baseline="off",
        off=("tick lateness p99, mapping off",
             "same daemon, 360-ray scans on the bus at 10 Hz, revolutions dropped"),
        on=("tick lateness p99, mapping on",
            f"{scans_done} revolutions mapped by the worker process; off/on {turns.schedule}"))


def run(quick: bool) -> list[BenchResult]:
    revolutions = 300 if quick else 1500
    decode_s, map_s, keys = revolution_costs(revolutions)
    decode_ms = float(np.median(decode_s)) * 1e3
    map_ms = float(np.median(map_s)) * 1e3
    return [
        BenchResult(SUITE, "mapper per 360-ray revolution, median", round(map_ms, 3), "ms",
                    f"<= {MS_TARGET}", map_ms <= MS_TARGET,
                    f"p95 {np.percentile(map_s, 95) * 1e3:.1f} ms, max {max(map_s) * 1e3:.0f} ms; "
                    f"{revolutions} revolutions ({revolutions / RATE_HZ:g} s at 10 Hz) through "
                    f"the {WORLD}, {keys} key scans; matching, key scans, integration, loop "
                    "closures"),
        BenchResult(SUITE, "lidar decode per 360-ray revolution, median", round(decode_ms, 3),
                    "ms", note="the same revolutions' RPLIDAR bytes (standard nodes) through "
                    "the daemon's parser, in the same loop"),
        *run_quietly(_tick_results(quick)),
    ]
