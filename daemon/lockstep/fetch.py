# `arbiterd simulate --fetch N`: random fetch missions driven in lockstep, judged by ground truth.
from __future__ import annotations

import math
import random
from typing import Any

import numpy as np

from daemon.components.fetch.component import FetchComponent
from daemon.components.fetch.sequence import FetchError
from daemon.config import load_config
from daemon.lockstep.navigation import GOAL_ROOM_M
from daemon.lockstep.runner import Lockstep
from sim.mapping_truth import clearances, reachable_free_cells, world_grid
from sim.world import World
from slam.pose import Pose2, between, compose

#: the object is delivered when it stands this near the drop point (true positions, m)
DELIVERED_M = 0.10
#: a fetch that has not ended after this long is counted as a failure (simulated s)
FETCH_CAP_S = 400.0
#: objects and drop points are drawn this far from any wall or obstacle at least (m)
POINT_ROOM_M = 0.5
#: the object and the drop point are at least this far apart (m)
MIN_APART_M = 2.0


def draw_points(world: World, radius: float, rng: random.Random,
                count: int) -> list[tuple[tuple[float, float], tuple[float, float]]]:
    """``count`` (object, drop) pairs: each point where the footprint could stand with room
    to spare, reachable from the start, ``POINT_ROOM_M`` clear of everything."""
    spec = world_grid(world, 0.1)
    room = reachable_free_cells(world, 0.1, radius + GOAL_ROOM_M, grid=spec)
    xs, ys = spec.centres()
    room &= clearances(world, xs, ys) > POINT_ROOM_M
    rows, cols = np.nonzero(room)

    def pick() -> tuple[float, float]:
        i = rng.randrange(len(rows))
        return (round(float(spec.origin_x + (cols[i] + 0.5) * spec.resolution), 2),
                round(float(spec.origin_y + (rows[i] + 0.5) * spec.resolution), 2))

    pairs: list[tuple[tuple[float, float], tuple[float, float]]] = []
    while len(pairs) < count:
        obj, drop = pick(), pick()
        if math.hypot(obj[0] - drop[0], obj[1] - drop[1]) >= MIN_APART_M:
            pairs.append((obj, drop))
    return pairs


class FetchRun:
    """One world and seed: the robot starts with an empty costmap; for each mission an object
    is placed at a random point, the fetch is sent (in the odometry frame, which starts at the
    robot's true start pose) and judged on the object's true position when it ends."""

    def __init__(self, world: str, seed: int, missions: int) -> None:
        config = load_config(None, sim=True, env={})
        config.update("sim", {"world_file": world, "seed": seed})
        self.lockstep = Lockstep(config, fetch=True)
        fetch = self.lockstep.fetch
        assert fetch is not None and fetch.sequence is not None
        self.fetch: FetchComponent = fetch
        self.world_name, self.seed = world, seed
        sim_world = self.lockstep.world.world
        self.start: Pose2 = (sim_world.start.x, sim_world.start.y, sim_world.start.theta)
        radius = self.lockstep.world.geometry.footprint_radius
        self.pairs = draw_points(sim_world, radius, random.Random(seed), missions)

    async def run(self) -> list[dict[str, Any]]:
        lockstep = self.lockstep
        await lockstep.begin()
        await lockstep.advance(0.3)  # the first revolutions
        results = [await self.mission(obj, drop) for obj, drop in self.pairs]
        await lockstep.finish()
        return results

    def _odom(self, point: tuple[float, float]) -> tuple[float, float]:
        x, y, _ = between(self.start, (*point, 0.0))
        return x, y

    async def mission(self, obj: tuple[float, float],
                      drop: tuple[float, float]) -> dict[str, Any]:
        lockstep, fetch = self.lockstep, self.fetch
        sequence = fetch.sequence
        assert sequence is not None
        objects = lockstep.world.objects
        objects.clear()
        item = objects.place(*obj)
        await lockstep.advance(0.3)  # a revolution that sees it
        collisions = lockstep.world.metrics_summary()["collisions"]
        began = lockstep.now
        out: dict[str, Any] = {"world": self.world_name, "seed": self.seed,
                               "object": list(obj), "drop": list(drop)}
        try:
            fetch.request(self._odom(obj), self._odom(drop))
        except FetchError as exc:
            return {**out, "result": "refused", "reason": str(exc), "seconds": 0.0,
                    "delivered": False, "collisions": 0, "object_contacts": 0}
        await lockstep.advance(FETCH_CAP_S, until=lambda: not sequence.active)
        if sequence.active:
            fetch.cancel("benchmark cap")
        await lockstep.advance(0.5)  # come to rest
        error = math.hypot(item.x - drop[0], item.y - drop[1])
        delivered = sequence.result == "succeeded" and not item.held and error <= DELIVERED_M
        truth = lockstep.world.physics.state
        odom = lockstep.control.odometry.reported
        pose = compose(self.start, (odom.x, odom.y, odom.theta))
        return {**out, "result": sequence.result, "reason": sequence.reason,
                "seconds": round(lockstep.now - began, 2),
                "state_times_s": {k: round(v, 2) for k, v in sequence.times.items()},
                "object_at": [round(item.x, 3), round(item.y, 3)], "held": item.held,
                "drop_error_m": round(error, 4), "delivered": delivered,
                "collisions": lockstep.world.metrics_summary()["collisions"] - collisions,
                "object_contacts": item.contacts,
                "odometry_error_m": round(math.hypot(pose[0] - truth.x, pose[1] - truth.y), 4)}


def summarise(results: list[dict[str, Any]]) -> dict[str, Any]:
    """Success rate, simulated time per delivered mission, collisions, failures by reason."""
    done = [r for r in results if r["delivered"]]
    times = [r["seconds"] for r in done]
    failures: dict[str, int] = {}
    for r in results:
        if not r["delivered"]:
            key = f"{r['result']}: {r['reason']}"[:160] if r["reason"] else \
                f"{r['result']}: object {r.get('drop_error_m')} m from the drop point"
            failures[key] = failures.get(key, 0) + 1
    errors = [r["drop_error_m"] for r in done]
    return {"missions": len(results), "delivered": len(done),
            "success_rate": round(len(done) / len(results), 4) if results else None,
            "seconds_mean": round(float(np.mean(times)), 1) if times else None,
            "seconds_median": round(float(np.median(times)), 1) if times else None,
            "seconds_max": round(float(np.max(times)), 1) if times else None,
            "drop_error_mean_m": round(float(np.mean(errors)), 4) if errors else None,
            "drop_error_max_m": round(float(np.max(errors)), 4) if errors else None,
            "collisions": sum(r["collisions"] for r in results),
            "object_contacts": sum(r["object_contacts"] for r in results),
            "failures": failures}
