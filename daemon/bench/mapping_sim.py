# Benchmark suite "mapping-sim": the mapper in `arbiterd simulate` against the true pose and
# walls, beside odometry alone, in the worlds that need a map, explored by a drifting base.
from __future__ import annotations

import asyncio
import logging
import statistics
import time
from typing import Any

from daemon.bench import BenchResult
from daemon.config import load_config
from daemon.lockstep.explore import known_share, reachable_area
from daemon.lockstep.runner import Lockstep
from slam.pose import Pose2

SUITE = "mapping-sim"
WORLDS = ("apartment", "warehouse", "loop")
#: a base that drifts as a real one does: 2 % calibration errors, 2 % slip, 5 % dropouts
DRIFT = {"wheel_radius_error": 0.02, "wheel_separation_error": 0.02, "wheel_slip": 0.02,
         "lidar_dropout": 0.05}
#: /map every 60 s, not every 2 s: nothing reads it in the run, and each publication after a
#: graph optimisation re-renders the grid from every key scan (60 % of a run's time at 2 s)
MAP_PERIOD_S = 60.0
#: how often the drive is looked at (which mode runs) while a run goes on (simulated s)
CHECK_S = 1.0


async def _drive(lockstep: Lockstep, seconds: float) -> dict[str, Any]:
    """Explore (the autonomy's mode ``explore``, goals in the map frame) from the first
    revolutions on; when the exploration ends before ``seconds`` (done, or failed), wander for
    the rest of the run. What the exploration did."""
    nav = lockstep.navigation
    assert nav is not None
    await lockstep.begin()
    await lockstep.advance(0.3)  # the first revolutions
    refusal = lockstep.autonomy.request("explore", "mapping-sim")
    if refusal:
        raise ValueError(f"explore refused: {refusal}")
    await lockstep.advance(seconds - 0.3, until=lambda: not nav.exploring)
    explored = nav.exploration()
    ended = lockstep.now if not nav.exploring else None
    wander_s = 0.0
    while lockstep.now < seconds - 1e-6:
        if lockstep.autonomy.mode != "wander":
            refusal = lockstep.autonomy.request("wander", "mapping-sim: exploration ended")
            if refusal:
                raise ValueError(f"wander refused: {refusal}")
        step = min(CHECK_S, seconds - lockstep.now)
        await lockstep.advance(step)
        wander_s += step
    if nav.exploring:
        nav.stop_exploring("end of the run")
    return {"state": explored["state"], "reason": explored["reason"],
            "ended_s": None if ended is None else round(ended, 1),
            "goals": explored["goals"], "failed_goals": explored["failed_goals"],
            "wander_s": round(wander_s, 1)}


def simulate(world: str, seed: int, seconds: float) -> dict[str, Any]:
    """One run: ``seconds`` of exploration (then wander) with the mapper and the drifting
    base; the mapper's report, the exploration's, collisions and the area explored."""
    return asyncio.run(_simulate(world, seed, seconds))


async def _simulate(world: str, seed: int, seconds: float) -> dict[str, Any]:
    wall = time.perf_counter()
    config = load_config(None, sim=True, env={})
    config.update("sim", {**DRIFT, "world_file": world, "seed": seed})
    config.update("mapping", {"publish_period_s": MAP_PERIOD_S})
    lockstep = Lockstep(config, mapping=True, navigation=True)
    nav, probe = lockstep.navigation, lockstep.mapping
    assert nav is not None and probe is not None
    sim_world = lockstep.world.world
    start: Pose2 = (sim_world.start.x, sim_world.start.y, sim_world.start.theta)
    exploration = await _drive(lockstep, seconds)
    report: dict[str, Any] = probe.report()
    truth = reachable_area(sim_world, lockstep.world.geometry.footprint_radius)
    metrics = lockstep.world.metrics_summary()
    report.update({
        "world": world, "seed": seed, "exploration": exploration,
        "collisions": metrics["collisions"], "path_m": round(metrics["path_length_m"], 1),
        "explored_m2": nav.exploration()["explored_m2"],
        "known_pct": round(100 * known_share(nav, start, truth["robot"]), 1),
        "reachable_m2": round(len(truth["robot"]) * truth["cell_m2"], 1)})
    await lockstep.finish()
    report["wall_s"] = round(time.perf_counter() - wall, 1)
    return report


def _explored(exploration: dict[str, Any]) -> str:
    if exploration["ended_s"] is None:
        return "still exploring at the end"
    return f"exploration {exploration['state']} at {exploration['ended_s']} s"


def rows(world: str, runs: list[dict[str, Any]], seconds: float) -> list[BenchResult]:
    """The suite's figures for ``world`` from its runs (one per seed)."""
    mean = statistics.fmean
    note = (f"{len(runs)} seeds x {seconds:g} s: explore, then wander for the rest; 2 % "
            "calibration errors, 2 % slip, 5 % dropouts")
    rms = mean(r["pose_error"]["rms_m"] for r in runs)
    rms_deg = mean(r["pose_error"]["rms_deg"] for r in runs)
    odom = mean(r["odometry_error"]["rms_m"] for r in runs)
    odom_deg = mean(r["odometry_error"]["rms_deg"] for r in runs)
    precision = mean(r["map"]["precision"] for r in runs)
    recall = mean(r["map"]["recall"] for r in runs)
    per_seed = "; ".join(
        f"seed {r['seed']}: {r['pose_error']['rms_m']:.3f} m {r['pose_error']['rms_deg']:.2f}"
        f" deg (odometry {r['odometry_error']['rms_m']:.2f} m), P/R "
        f"{r['map']['precision']:.3f}/{r['map']['recall']:.3f}, " + _explored(r["exploration"])
        for r in runs)
    map_target = world != "loop"
    return [
        BenchResult(SUITE, f"{world}: map-frame pose error RMS", round(rms, 4), "m",
                    "<= 0.05 m", rms <= 0.05, f"odometry alone {odom:.3f} m; {note}"),
        BenchResult(SUITE, f"{world}: heading error RMS", round(rms_deg, 3), "deg",
                    "<= 2 deg", rms_deg <= 2.0, f"odometry alone {odom_deg:.2f} deg"),
        BenchResult(SUITE, f"{world}: worst per-seed pose error RMS", round(max(
            r["pose_error"]["rms_m"] for r in runs), 4), "m", note=per_seed),
        BenchResult(SUITE, f"{world}: worst pose error", round(max(
            r["pose_error"]["max_m"] for r in runs), 4), "m",
            note=f"odometry alone {max(r['odometry_error']['max_m'] for r in runs):.3f} m; "
                 f"heading {max(r['pose_error']['max_deg'] for r in runs):.2f} deg"),
        BenchResult(SUITE, f"{world}: map precision at one cell", round(precision, 4), "",
                    ">= 0.9" if map_target else "", precision >= 0.9 if map_target else None),
        BenchResult(SUITE, f"{world}: map recall at one cell (walls seen)", round(recall, 4),
                    "", ">= 0.9" if map_target else "", recall >= 0.9 if map_target else None),
        BenchResult(SUITE, f"{world}: collisions", sum(r["collisions"] for r in runs), "",
                    note="all seeds"),
        BenchResult(SUITE, f"{world}: explored area (costmap seen free)", round(mean(
            r["explored_m2"] for r in runs), 1), "m2",
            note=f"reachable free area known {mean(r['known_pct'] for r in runs):.1f} % of "
                 f"{runs[0]['reachable_m2']:g} m2; path {mean(r['path_m'] for r in runs):.0f} m"),
    ]


def run(quick: bool) -> list[BenchResult]:
    logging.getLogger("arbiterd").setLevel(logging.ERROR)
    seeds, seconds = (range(1, 2), 120.0) if quick else (range(1, 6), 600.0)
    return [result for world in WORLDS for result in rows(
        world, [simulate(world, seed, seconds) for seed in seeds], seconds)]
