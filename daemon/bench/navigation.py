# Benchmark suite "navigation": goals in `arbiterd simulate` by ground truth, tracking, costs.
from __future__ import annotations

import asyncio
import json
import logging
import math
import time
from pathlib import Path
from typing import Any

import numpy as np

from daemon.bench import BenchResult
from daemon.components.navigation import component as navigation_component
from daemon.components.navigation.messages import GoalRequest
from daemon.components.navigation.planning import Planned, Scans
from daemon.lockstep.navigation import (
    NavigationRun,
    figure_eight_run,
    planning_cost,
    summarise,
)
from nav.costmap import Costmap
from nav.pursuit import Pursuit, PursuitSettings, densify, figure_eight
from slam.pose import Pose2

SUITE = "navigation"
WORLDS = ("apartment", "warehouse", "loop")
#: per world and seed: reachable goals, unreachable ones
GOALS, UNREACHABLE = 7, 2


def goal_runs(seeds: range, reachable: int = GOALS, unreachable: int = UNREACHABLE,
              drift: bool = False) -> list[dict[str, Any]]:
    """Every world and seed, each from an empty costmap; one row per goal. ``drift``: a
    drifting base, the mapper running and the goals in its map frame."""
    rows: list[dict[str, Any]] = []
    for world in WORLDS:
        for seed in seeds:
            run = NavigationRun(world, seed, reachable=reachable, unreachable=unreachable,
                                mapping=drift, drift=drift)
            rows += asyncio.run(run.run())
    return rows


def drift_results(seeds: range, goals: int) -> list[BenchResult]:
    """Goals in the map frame on a drifting base (2 % calibration errors and slip)."""
    rows = goal_runs(seeds, goals, 0, drift=True)
    s = summarise(rows)["all"]
    return [BenchResult(SUITE, "drifting base, map-frame goals: reached", s["success_rate"],
                        "", ">= 0.97", s["success_rate"] >= 0.97,
                        f"{s['reached']}/{s['reachable']}, {s['collisions']} collisions, "
                        f"path ratio mean {s['ratio_mean']}; {len(seeds)} seed(s) x {goals} "
                        "goals per world, mapper on, 2 % calibration errors + slip")]


def control_cost_us(ticks: int = 4000) -> float:
    """Mean wall time of one follower step on the figure-eight (µs)."""
    pursuit = Pursuit(PursuitSettings(), densify(figure_eight(4.0), 0.05), None, loop=True)
    x = y = theta = 0.0
    started = time.perf_counter()
    for _ in range(ticks):
        command = pursuit.step((x, y, theta), 0.3)
        theta += command.w * 0.05
        x += command.v * 0.05 * math.cos(theta)
        y += command.v * 0.05 * math.sin(theta)
    return 1e6 * (time.perf_counter() - started) / ticks


async def decision_cost_us(seconds: float = 20.0) -> tuple[float, float]:
    """Median and 99th percentile wall time of one navigation decision in the control tick
    while following a goal across the apartment (the component's tick hook without the plan,
    which runs in a worker process in the daemon; µs)."""
    run = NavigationRun("apartment", 1, reachable=0, unreachable=0)
    lockstep, nav = run.lockstep, run.navigation
    spent = [0.0]  # plan time so far
    decisions: list[float] = []
    tick, plan_job = nav._tick, navigation_component.fold_and_plan

    def timed_tick(now: float) -> None:
        before, planned = time.perf_counter(), spent[0]
        deciding = nav.navigator.active and now >= nav._next_decision
        tick(now)
        if deciding:
            decisions.append(time.perf_counter() - before - (spent[0] - planned))

    def timed_plan(costmap: Costmap, scans: Scans, start: Pose2, goal: Pose2,
                   block: int) -> Planned:
        before = time.perf_counter()
        result = plan_job(costmap, scans, start, goal, block)
        spent[0] += time.perf_counter() - before
        return result

    sources = lockstep.control.tick_sources._items  # the component's hook, timed in place
    sources[sources.index(tick)] = timed_tick
    navigation_component.fold_and_plan = timed_plan  # the inline planner, timed
    try:
        await lockstep.begin()
        await lockstep.advance(0.3)
        nav.request(GoalRequest(nav.odom_frame, 3.0, 4.5, None))  # into the far bedroom
        await lockstep.advance(seconds)
        await lockstep.finish()
    finally:
        navigation_component.fold_and_plan = plan_job
    micros = 1e6 * np.array(decisions)
    return float(np.median(micros)), float(np.percentile(micros, 99))


def _goal_results(rows: list[dict[str, Any]], note: str) -> list[BenchResult]:
    summary = summarise(rows)
    out = []
    for world in [*WORLDS, "all"]:
        s = summary.get(world)
        if s is None or not s["reachable"]:
            continue
        failures = "; ".join(f"{n}x {k}" for k, n in s["failures"].items()) or "none"
        out += [
            BenchResult(SUITE, f"{world}: goals reached (0.10 m / 0.1 rad, true pose)",
                        s["success_rate"], "", ">= 0.97", s["success_rate"] >= 0.97,
                        f"{s['reached']}/{s['reachable']}; failures: {failures}; {note}"),
            BenchResult(SUITE, f"{world}: collisions", s["collisions"], "", "0",
                        s["collisions"] == 0),
            BenchResult(SUITE, f"{world}: path length / true shortest, mean",
                        s["ratio_mean"] or 0.0, "", "<= 1.3",
                        (s["ratio_mean"] or 0.0) <= 1.3,
                        f"max {s['ratio_max']}, {s['ratio_over_1_3']} goals over 1.3"),
            BenchResult(SUITE, f"{world}: unreachable goals failed", s["unreachable_failed"] /
                        max(1, s["unreachable"]), "", "1.0",
                        s["unreachable_failed"] == s["unreachable"],
                        f"{s['unreachable_failed']}/{s['unreachable']}, slowest "
                        f"{s['unreachable_max_s']} s (target <= 60 s)"),
        ]
    return out


def run(quick: bool) -> list[BenchResult]:
    logging.getLogger("arbiterd").setLevel(logging.ERROR)
    seeds = range(1, 2) if quick else range(1, 6)
    rows = goal_runs(seeds)
    dump = Path("navigation-goals.json")
    dump.write_text("\n".join(json.dumps(r) for r in rows) + "\n")
    results = _goal_results(rows, f"{len(seeds)} seeds x {GOALS} goals + {UNREACHABLE} "
                            f"unreachable per world, from an empty map; rows in {dump}")
    results += drift_results(range(1, 2), 2 if quick else 4)
    eight = asyncio.run(figure_eight_run(4.0, 0.3))
    results.append(BenchResult(SUITE, "figure-eight (4 m) tracking error RMS, true pose",
                               eight["true_rms_m"], "m", "<= 0.05", eight["true_rms_m"] <= 0.05,
                               f"max {eight['true_max_m']} m at 0.3 m/s; {eight['state']}"))
    cost = planning_cost()
    total = round(cost["cost_grid_ms"] + cost["plan_ms"], 1)
    results.append(BenchResult(SUITE, "plan across 40 x 40 m at 0.05 m", total, "ms",
                               "<= 50", total <= 50, f"cost grid {cost['cost_grid_ms']} ms + "
                               f"search {cost['plan_ms']} ms (blocks of 4 cells), best of 7; "
                               f"in-run baseline {cost['baseline_ms']} ms"))
    results.append(BenchResult(SUITE, "in-run baseline: exact distance transform of that map",
                               cost["baseline_ms"], "ms",
                               note="scipy's distance_transform_edt of the 800 x 800 cells, "
                               "timed in turn with the plans; the plan is "
                               f"{total / max(cost['baseline_ms'], 1e-3):.2f}x it"))
    tick = control_cost_us()
    results.append(BenchResult(SUITE, "follower step", round(tick, 1), "us"))
    median, p99 = asyncio.run(decision_cost_us())
    results.append(BenchResult(SUITE, "navigation decision per control tick, median",
                               round(median, 1), "us", "<= 300", median <= 300.0,
                               f"p99 {p99:.0f} us (a new plan taken, the state published); "
                               "state machine + follower + checks, the plan excluded (a worker "
                               "thread in the daemon)"))
    return results


