# `arbiterd simulate --navigation`: random goals driven in lockstep, judged by ground truth.
from __future__ import annotations

import math
import random
import time
from dataclasses import dataclass
from typing import Any

import numpy as np

from daemon.components.navigation.component import NavigationComponent
from daemon.components.navigation.messages import GoalRequest
from daemon.config import load_config
from daemon.lockstep.runner import Lockstep
from nav.costmap import GridArea
from nav.planner import cheapest_path, shortcut
from nav.pursuit import figure_eight, transform
from sim.mapping_truth import GridSpec, clearances, reachable_free_cells, world_grid
from sim.world import World
from slam.pose import Pose2, between

#: a goal is reached within this of the true pose (m, rad)
REACHED_M, REACHED_RAD = 0.10, 0.1
#: goals are drawn where the footprint keeps this much more room to the nearest surface (m)
GOAL_ROOM_M = 0.2
#: grid of the true shortest paths (m)
TRUTH_RESOLUTION = 0.05
#: a goal that has not ended after this long is counted as a failure (simulated s)
GOAL_CAP_S = 300.0
#: a base that drifts as a real one does (as the mapping-sim bench): 2 % calibration errors,
#: 2 % slip, 5 % lidar dropouts
DRIFT = {"wheel_radius_error": 0.02, "wheel_separation_error": 0.02, "wheel_slip": 0.02,
         "lidar_dropout": 0.05}


@dataclass(frozen=True)
class Goal:
    x: float
    y: float
    theta: float
    reachable: bool


def true_shortest(world: World, start: tuple[float, float], goal: tuple[float, float],
                  radius: float, resolution: float = TRUTH_RESOLUTION) -> float:
    """The shortest collision-free path for a round footprint of ``radius`` on the true
    world (8-connected grid path on the cells with room, then straightened; m)."""
    spec = world_grid(world, resolution, margin=0.5)
    xs, ys = spec.centres()
    costs = np.where(clearances(world, xs, ys) > radius, 1.0, np.inf).astype(np.float32)
    s, g = spec.cell_of(*start), spec.cell_of(*goal)
    costs[s] = costs[g] = 1.0
    cells, _ = cheapest_path(costs, s, g)
    if not cells:
        return math.inf
    cells = shortcut(costs, cells)
    points = np.array([(spec.origin_x + (c + 0.5) * resolution,
                        spec.origin_y + (r + 0.5) * resolution) for r, c in cells])
    points[0], points[-1] = start, goal
    return float(np.hypot(*np.diff(points, axis=0).T).sum())


def draw_goals(world: World, radius: float, rng: random.Random, reachable: int,
               unreachable: int) -> list[Goal]:
    """``reachable`` goals in the free space the robot can reach (with room to spare) and
    ``unreachable`` ones inside obstacles or in closed spaces, shuffled."""
    spec = world_grid(world, 0.1)
    room = reachable_free_cells(world, 0.1, radius + GOAL_ROOM_M, grid=spec)
    xs, ys = spec.centres()
    clear = clearances(world, xs, ys)
    walled_off = (clear > radius + GOAL_ROOM_M) & ~reachable_free_cells(
        world, 0.1, radius, grid=spec) & _inside_walls(world, spec)
    inside_obstacle = clear < -0.1
    goals = [_pick(spec, room, rng, True) for _ in range(reachable)]
    closed = walled_off | inside_obstacle
    if closed.any():
        goals += [_pick(spec, closed, rng, False) for _ in range(unreachable)]
    rng.shuffle(goals)
    return goals


def _inside_walls(world: World, spec: GridSpec) -> np.ndarray:
    """Cells within the box of the world's walls (a closed room is inside it)."""
    seg = world.segment_array
    xs, ys = spec.centres()
    return (xs > seg[:, [0, 2]].min()) & (xs < seg[:, [0, 2]].max()) & \
        (ys > seg[:, [1, 3]].min()) & (ys < seg[:, [1, 3]].max())


def _pick(spec: GridSpec, cells: np.ndarray, rng: random.Random, reachable: bool) -> Goal:
    rows, cols = np.nonzero(cells)
    i = rng.randrange(len(rows))
    x = spec.origin_x + (cols[i] + 0.5) * spec.resolution
    y = spec.origin_y + (rows[i] + 0.5) * spec.resolution
    return Goal(float(x), float(y), rng.uniform(-math.pi, math.pi), reachable)


class NavigationRun:
    """One world and seed: the robot starts with an empty costmap and is sent to each goal in
    turn (in the map frame with ``mapping``, else in the odometry frame; both start at the
    robot's true start pose); each is judged on the true pose."""

    def __init__(self, world: str, seed: int, *, reachable: int, unreachable: int,
                 mapping: bool = False, drift: bool = False) -> None:
        config = load_config(None, sim=True, env={})
        config.update("sim", {"world_file": world, "seed": seed, **(DRIFT if drift else {})})
        self.lockstep = Lockstep(config, navigation=True, mapping=mapping)
        nav = self.lockstep.navigation
        assert nav is not None
        self.navigation: NavigationComponent = nav
        self.world_name, self.seed = world, seed
        self.frame = nav.map_frame or nav.odom_frame
        sim_world = self.lockstep.world.world
        self.start: Pose2 = (sim_world.start.x, sim_world.start.y, sim_world.start.theta)
        self.radius = self.lockstep.world.geometry.footprint_radius
        self.goals = draw_goals(sim_world, self.radius, random.Random(seed), reachable,
                                unreachable)

    async def run(self) -> list[dict[str, Any]]:
        lockstep = self.lockstep
        await lockstep.begin()
        await lockstep.advance(0.3)  # the first revolutions
        results = [await self.drive_to(goal) for goal in self.goals]
        await lockstep.finish()
        return results

    async def drive_to(self, goal: Goal) -> dict[str, Any]:
        lockstep, nav = self.lockstep, self.navigation
        state = lockstep.world.physics.state
        here = (state.x, state.y)
        shortest = true_shortest(lockstep.world.world, here, (goal.x, goal.y), self.radius) \
            if goal.reachable else math.inf
        metrics = lockstep.world.metrics_summary()
        travelled, collisions = metrics["path_length_m"], metrics["collisions"]
        x, y, theta = between(self.start, (goal.x, goal.y, goal.theta))
        began = lockstep.now
        out: dict[str, Any] = {"world": self.world_name, "seed": self.seed,
                               "reachable": goal.reachable,
                               "goal": [round(goal.x, 2), round(goal.y, 2)]}
        try:
            nav.request(GoalRequest(self.frame, x, y, theta))
        except ValueError as exc:
            return {**out, "state": "refused", "reason": str(exc), "seconds": 0.0,
                    "reached": False, "collisions": 0, "ratio": None}
        await lockstep.advance(GOAL_CAP_S, until=lambda: not nav.navigator.active)
        if nav.navigator.active:
            nav.cancel("benchmark cap")
        await lockstep.advance(0.5)  # come to rest
        state = lockstep.world.physics.state
        metrics = lockstep.world.metrics_summary()
        error_m = math.hypot(state.x - goal.x, state.y - goal.y)
        error_rad = abs(math.remainder(state.theta - goal.theta, math.tau))
        length = metrics["path_length_m"] - travelled
        return {**out, "state": nav.navigator.state, "reason": nav.navigator.reason,
                "seconds": round(lockstep.now - began, 2),
                "error_m": round(error_m, 4), "error_rad": round(error_rad, 4),
                "reached": nav.navigator.state == "succeeded" and error_m <= REACHED_M
                and error_rad <= REACHED_RAD,
                "collisions": metrics["collisions"] - collisions,
                "path_m": round(length, 3), "shortest_m": round(shortest, 3),
                "ratio": round(length / shortest, 3) if math.isfinite(shortest)
                and shortest > 0.3 else None}


async def figure_eight_run(size: float, speed: float, seed: int = 1) -> dict[str, Any]:
    """The built-in figure-eight driven at ``speed`` in an empty arena: the follower's
    cross-track error (from odometry) and the true one (from the simulated pose)."""
    config = load_config(None, sim=True, env={})
    config.update("sim", {"seed": seed, "obstacles": 0, "arena_size": 3 * size + 4})
    config.update("navigation", {"max_speed": speed})
    lockstep = Lockstep(config, navigation=True)
    nav = lockstep.navigation
    assert nav is not None
    await lockstep.begin()
    await lockstep.advance(0.3)
    start = lockstep.world.physics.state
    origin: Pose2 = (start.x, start.y, start.theta)
    path = transform(figure_eight(size), origin)
    errors: list[float] = []

    def track() -> bool:
        s = lockstep.world.physics.state
        errors.append(float(np.hypot(path[:, 0] - s.x, path[:, 1] - s.y).min()))
        return not nav.navigator.active

    nav.request(GoalRequest(nav.odom_frame, path="figure_eight", size=size))
    began = lockstep.now
    await lockstep.advance(120.0, until=track)
    status = nav.status()
    await lockstep.finish()
    true = np.array(errors)
    return {"size_m": size, "speed_m_s": speed, "state": status["state"],
            "seconds": round(lockstep.now - began, 2),
            "tracking_rms_m": status["tracking"]["rms_m"],
            "tracking_max_m": status["tracking"]["max_m"],
            "true_rms_m": round(float(np.sqrt(np.mean(true ** 2))), 4),
            "true_max_m": round(float(true.max()), 4)}


def summarise(results: list[dict[str, Any]]) -> dict[str, Any]:
    """Per world and overall: success rate, collisions, path-length ratios, failures by
    reason; unreachable goals: failed share and the longest time to fail."""
    out: dict[str, Any] = {}
    for world in [*sorted({r["world"] for r in results}), "all"]:
        rows = [r for r in results if world in ("all", r["world"])]
        ok = [r for r in rows if r["reachable"]]
        bad = [r for r in rows if not r["reachable"]]
        ratios = [r["ratio"] for r in ok if r.get("ratio") is not None and r["reached"]]
        reasons: dict[str, int] = {}
        for r in ok:
            if not r["reached"]:
                key = f"{r['state']}: {r['reason']}"[:120]
                reasons[key] = reasons.get(key, 0) + 1
        out[world] = {
            "reachable": len(ok), "reached": sum(r["reached"] for r in ok),
            "success_rate": round(sum(r["reached"] for r in ok) / len(ok), 4) if ok else None,
            "collisions": sum(r.get("collisions", 0) for r in rows),
            "ratio_mean": round(float(np.mean(ratios)), 3) if ratios else None,
            "ratio_max": round(float(np.max(ratios)), 3) if ratios else None,
            "ratio_over_1_3": sum(x > 1.3 for x in ratios),
            "failures": reasons,
            "unreachable": len(bad),
            "unreachable_failed": sum(r["state"] in ("failed", "refused") for r in bad),
            "unreachable_max_s": max((r["seconds"] for r in bad), default=None)}
    return out


def planning_cost(size_m: float = 40.0, resolution: float = 0.05, block: int = 4,
                  repeats: int = 7) -> dict[str, Any]:
    """Wall time of one plan across a ``size_m`` square map of shelf rows at ``resolution``
    (the cost grid and the search measured apart; best of ``repeats``; ms), and beside it the
    in-run baseline: scipy's exact Euclidean distance transform of the same map, timed in
    turn with the plans (so both see the same machine load)."""
    from scipy import ndimage

    from nav.costmap import CostParams, cost_grid
    from nav.planner import plan
    cells = round(size_m / resolution)
    area = GridArea(resolution, -size_m / 2, -size_m / 2, cells, cells)
    obstacles = np.zeros((cells, cells), dtype=bool)
    rows = round(1.0 / resolution)
    for k in range(1, 8):  # shelf rows 1 m deep every 5 m, a gap in each, alternating ends
        r = round(k * 5.0 / resolution)
        obstacles[r:r + rows, round(2 / resolution):cells - round(2 / resolution)] = True
        gap = round((8 if k % 2 else 30) / resolution)
        obstacles[r:r + rows, gap:gap + round(1.5 / resolution)] = False
    seen = np.ones_like(obstacles)
    params = CostParams(radius_m=0.25)
    grid_ms, plan_ms, base_ms, found = [], [], [], None
    for _ in range(repeats):
        t0 = time.perf_counter()
        ndimage.distance_transform_edt(~obstacles)
        t1 = time.perf_counter()
        costs = cost_grid(obstacles, seen, resolution, params)
        t2 = time.perf_counter()
        found = plan(costs, area, (-size_m / 2 + 1, -size_m / 2 + 1),
                     (size_m / 2 - 1, size_m / 2 - 1), block)
        t3 = time.perf_counter()
        base_ms.append(1000 * (t1 - t0))
        grid_ms.append(1000 * (t2 - t1))
        plan_ms.append(1000 * (t3 - t2))
    assert found is not None
    length = float(np.hypot(*np.diff(found.points, axis=0).T).sum()) if found.found else None
    return {"map_m": size_m, "resolution_m": resolution, "block": block,
            "cost_grid_ms": round(min(grid_ms), 1), "plan_ms": round(min(plan_ms), 1),
            "baseline_ms": round(min(base_ms), 1),
            "path_m": round(length, 2) if length else None}
