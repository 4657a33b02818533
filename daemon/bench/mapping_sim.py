# Benchmark suite "mapping-sim": the mapper in `arbiterd simulate` against the true pose and
# walls, beside odometry alone, in the worlds that need a map, with a drifting base.
from __future__ import annotations

import asyncio
import logging
import statistics
from typing import Any

from daemon.bench import BenchResult
from daemon.config import load_config
from daemon.lockstep.runner import Lockstep

SUITE = "mapping-sim"
WORLDS = ("apartment", "warehouse", "loop")
#: a base that drifts as a real one does: 2 % calibration errors, 2 % slip, 5 % dropouts
DRIFT = {"wheel_radius_error": 0.02, "wheel_separation_error": 0.02, "wheel_slip": 0.02,
         "lidar_dropout": 0.05}


def simulate(world: str, seed: int, seconds: float) -> dict[str, Any]:
    config = load_config(None, sim=True, env={})
    config.update("sim", {**DRIFT, "world_file": world, "seed": seed})
    runner = Lockstep(config, autonomy="wander", mapping=True)
    report: dict[str, Any] = asyncio.run(runner.run(seconds))["mapping"]
    return report


def _world(world: str, seeds: range, seconds: float) -> list[BenchResult]:
    runs = [simulate(world, seed, seconds) for seed in seeds]
    mean = statistics.fmean
    note = f"{len(runs)} seeds x {seconds:g} s, wander, 2 % calibration error + slip"
    rms = mean(r["pose_error"]["rms_m"] for r in runs)
    rms_deg = mean(r["pose_error"]["rms_deg"] for r in runs)
    odom = mean(r["odometry_error"]["rms_m"] for r in runs)
    odom_deg = mean(r["odometry_error"]["rms_deg"] for r in runs)
    precision = mean(r["map"]["precision"] for r in runs)
    recall = mean(r["map"]["recall"] for r in runs)
    return [
        BenchResult(SUITE, f"{world}: map-frame pose error RMS", round(rms, 4), "m",
                    "<= 0.05 m", rms <= 0.05, f"odometry alone {odom:.3f} m; {note}"),
        BenchResult(SUITE, f"{world}: heading error RMS", round(rms_deg, 3), "deg",
                    "<= 2 deg", rms_deg <= 2.0, f"odometry alone {odom_deg:.2f} deg"),
        BenchResult(SUITE, f"{world}: worst pose error", round(max(
            r["pose_error"]["max_m"] for r in runs), 4), "m",
            note=f"odometry alone {max(r['odometry_error']['max_m'] for r in runs):.3f} m"),
        BenchResult(SUITE, f"{world}: map precision at one cell", round(precision, 4), "",
                    ">= 0.9" if world != "loop" else "", precision >= 0.9
                    if world != "loop" else None),
        BenchResult(SUITE, f"{world}: map recall at one cell (walls seen)", round(recall, 4),
                    "", ">= 0.9" if world != "loop" else "", recall >= 0.9
                    if world != "loop" else None),
    ]


def run(quick: bool) -> list[BenchResult]:
    logging.getLogger("arbiterd").setLevel(logging.ERROR)
    seeds, seconds = (range(1, 2), 120.0) if quick else (range(1, 6), 600.0)
    return [result for world in WORLDS for result in _world(world, seeds, seconds)]
