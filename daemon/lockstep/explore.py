# `arbiterd simulate --explore`: frontier exploration in lockstep, judged by ground truth.
from __future__ import annotations

import math
import time
from typing import Any

import numpy as np

from daemon.components.navigation.component import NavigationComponent
from daemon.config import load_config
from daemon.lockstep.runner import Lockstep
from sim.mapping_truth import clearances, flood, reachable_free_cells, world_grid
from sim.world import World
from slam.pose import Pose2

#: the worlds `simulate --explore` runs without --world
WORLDS = ("apartment", "warehouse")
#: an exploration still running after this long is stopped and judged (simulated s)
CAP_S = 1200.0
#: the truth grid the known share is counted on (m)
TRUTH_RESOLUTION = 0.05


def reachable_area(world: World, radius: float,
                   resolution: float = TRUTH_RESOLUTION) -> dict[str, Any]:
    """The free area the robot can reach from its start on the true world: cell centres
    (world frame, (N, 2)) where its round footprint fits, connected to the start (the
    ``robot`` cells); and every free point connected to those (``free``: also the strips
    between furniture and walls the footprint cannot enter)."""
    spec = world_grid(world, resolution)
    robot = reachable_free_cells(world, resolution, radius, grid=spec)
    xs, ys = spec.centres()
    free = flood(robot, clearances(world, xs, ys) > 0.0)
    return {"robot": np.column_stack((xs[robot], ys[robot])),
            "free": np.column_stack((xs[free], ys[free])), "cell_m2": resolution ** 2}


def known_share(nav: NavigationComponent, start: Pose2, points: np.ndarray) -> float:
    """The share of ``points`` (world frame) whose costmap cell the lidar has seen; the
    costmap's frame is odometry's, which starts at the robot's true start pose."""
    x0, y0, theta = start
    c, s = math.cos(theta), math.sin(theta)
    dx, dy = points[:, 0] - x0, points[:, 1] - y0
    ox, oy = c * dx + s * dy, -s * dx + c * dy
    area = nav.area
    cols = np.floor((ox - area.origin_x) / area.resolution).astype(np.int64)
    rows = np.floor((oy - area.origin_y) / area.resolution).astype(np.int64)
    inside = (cols >= 0) & (cols < area.width) & (rows >= 0) & (rows < area.height)
    seen = np.zeros(len(points), dtype=bool)
    seen[inside] = nav.costmap.seen[rows[inside], cols[inside]]
    return float(seen.mean()) if len(points) else 0.0


async def explore_run(world: str, seed: int = 1, cap_s: float = CAP_S) -> dict[str, Any]:
    """One exploration of ``world`` from an empty costmap: the autonomy's mode ``explore``
    until it ends (or ``cap_s``), judged on the true world."""
    wall = time.perf_counter()
    config = load_config(None, sim=True, env={})
    config.update("sim", {"world_file": world, "seed": seed})
    lockstep = Lockstep(config, navigation=True)
    nav = lockstep.navigation
    assert nav is not None
    sim_world = lockstep.world.world
    start: Pose2 = (sim_world.start.x, sim_world.start.y, sim_world.start.theta)
    radius = lockstep.world.geometry.footprint_radius
    await lockstep.begin()
    await lockstep.advance(0.3)  # the first revolutions
    refusal = lockstep.autonomy.request("explore", "simulate --explore")
    if refusal:
        raise ValueError(f"explore refused: {refusal}")
    began = lockstep.now
    await lockstep.advance(cap_s, until=lambda: not nav.exploring)
    capped = nav.exploring
    if capped:
        nav.stop_exploring(f"simulate cap of {cap_s:g} s")
    seconds = lockstep.now - began
    await lockstep.advance(0.5)  # come to rest
    truth = reachable_area(sim_world, radius)
    state = lockstep.world.physics.state
    metrics = lockstep.world.metrics_summary()
    status = nav.exploration()
    await lockstep.finish()
    return {
        "world": world, "seed": seed, "state": status["state"], "reason": status["reason"],
        "capped": capped, "seconds": round(seconds, 1),
        "known_pct": round(100 * known_share(nav, start, truth["robot"]), 2),
        "known_pct_all_free": round(100 * known_share(nav, start, truth["free"]), 2),
        "reachable_m2": round(len(truth["robot"]) * truth["cell_m2"], 2),
        "explored_m2": status["explored_m2"],
        "collisions": metrics["collisions"], "path_m": round(metrics["path_length_m"], 2),
        "goals": status["goals"], "failed_goals": status["failed_goals"],
        "blacklisted": status["blacklisted"],
        "home_error_m": round(math.hypot(state.x - start[0], state.y - start[1]), 3),
        "min_clearance_m": round(lockstep.min_clearance, 3),
        "wall_s": round(time.perf_counter() - wall, 1)}


def format_row(r: dict[str, Any]) -> str:
    return (f"  {r['world']:<10} seed {r['seed']}: {r['state']}{' (capped)' if r['capped'] else ''}"
            f" in {r['seconds']:.1f} s simulated; {r['known_pct']:.1f} % of the reachable free "
            f"area known ({r['known_pct_all_free']:.1f} % counting the strips the footprint "
            f"cannot enter), {r['explored_m2']:.1f} m2 explored, {r['collisions']} collisions, "
            f"{r['goals']} goals ({r['failed_goals']} failed), path {r['path_m']:.1f} m, back "
            f"within {r['home_error_m']:.2f} m of the start, nearest approach "
            f"{r['min_clearance_m']:.3f} m, {r['wall_s']:.0f} s wall"
            + (f"; {r['reason']}" if r['reason'] else ""))
