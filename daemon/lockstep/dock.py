# `arbiterd simulate --dock N`: dockings from random poses in lockstep, judged by the true dock.
from __future__ import annotations

import math
import random
import time
from typing import Any

import numpy as np

from daemon.components.dock.component import DockComponent
from daemon.components.navigation.messages import GoalRequest
from daemon.config import load_config
from daemon.lockstep.fetch import draw_points
from daemon.lockstep.navigation import DRIFT
from daemon.lockstep.runner import Lockstep
from slam.pose import Pose2, between

#: a docking that has not ended after this long is a failure (simulated s)
DOCK_CAP_S = 240.0
#: driving to a random pose may take this long (simulated s)
WANDER_CAP_S = 200.0
#: targets: docked share, final position and heading error against the true dock
TARGETS = {"docked_share": 0.98, "error_m_max": 0.02, "error_deg_max": 2.0, "collisions": 0}


class DockRun:
    """One world and seed, a base that drifts: the dock is set where the world has it (in
    the odometry frame, which starts at the robot's true start pose); for each attempt the
    robot drives to a random pose by navigation, then goes home; judged by the true pose
    against the true dock."""

    def __init__(self, world: str, seed: int, attempts: int, *, drift: bool = True,
                 mapping: bool = True, charge: float = 0.6) -> None:
        config = load_config(None, sim=True, env={})
        config.update("sim", {"world_file": world, "seed": seed, "battery_charge": charge,
                              **(DRIFT if drift else {})})
        config.update("dock", {"go_home": False})
        self.lockstep = Lockstep(config, dock=True, mapping=mapping)
        dock = self.lockstep.dock
        assert dock is not None and self.lockstep.navigation is not None
        self.dock: DockComponent = dock
        sim_world = self.lockstep.world.world
        if not sim_world.docks:
            raise ValueError(f"the world {world!r} has no dock ([[docks]] in its file)")
        self.world_name, self.seed = world, seed
        self.start: Pose2 = (sim_world.start.x, sim_world.start.y, sim_world.start.theta)
        true = sim_world.docks[0]
        self.true_dock: Pose2 = (true.x, true.y, true.theta)
        radius = self.lockstep.world.geometry.footprint_radius
        rng = random.Random(seed)
        self.poses = [(x, y, rng.uniform(-math.pi, math.pi)) for (x, y), _ in
                      draw_points(sim_world, radius, rng, attempts)]

    async def run(self) -> list[dict[str, Any]]:
        lockstep = self.lockstep
        await lockstep.begin()
        await lockstep.advance(0.3)
        nav = lockstep.navigation
        assert nav is not None
        self.dock.set_dock(nav.frame, between(self.start, self.true_dock))
        results = []
        for pose in self.poses:
            results.append(await self.attempt(pose))
        await lockstep.finish()
        return results

    async def attempt(self, pose: Pose2) -> dict[str, Any]:
        lockstep, dock = self.lockstep, self.dock
        nav = lockstep.navigation
        assert nav is not None
        if dock.docked:
            dock.leave()
            await lockstep.advance(30.0, until=lambda: not dock.active)
        try:
            nav.request(GoalRequest(nav.frame, *between(self.start, pose)))
            await lockstep.advance(WANDER_CAP_S, until=lambda: not nav.navigator.active)
            nav.cancel("benchmark cap")
        except ValueError:
            pass
        await lockstep.advance(0.5)
        state = lockstep.world.physics.state
        out: dict[str, Any] = {"world": self.world_name, "seed": self.seed,
                               "from": [round(state.x, 2), round(state.y, 2)],
                               "distance_m": round(math.hypot(state.x - self.true_dock[0],
                                                              state.y - self.true_dock[1]), 2)}
        collisions = lockstep.world.metrics_summary()["collisions"]
        began = lockstep.now
        attempts = dock.attempts
        try:
            dock.go_home()
        except ValueError as exc:
            return {**out, "docked": False, "result": "refused", "reason": str(exc),
                    "seconds": 0.0, "collisions": 0}
        await lockstep.advance(DOCK_CAP_S, until=lambda: not dock.active)
        if dock.active:
            dock.cancel("benchmark cap")
        await lockstep.advance(0.5)
        state = lockstep.world.physics.state
        error_m = math.hypot(state.x - self.true_dock[0], state.y - self.true_dock[1])
        error_deg = math.degrees(abs(math.remainder(state.theta - self.true_dock[2], math.tau)))
        charging = lockstep.world.battery.report()["current"] < 0 or lockstep.world.on_charger()
        return {**out, "docked": dock.docked and charging, "result": dock.result,
                "reason": dock.reason, "seconds": round(lockstep.now - began, 2),
                "approaches": dock.attempts - attempts,
                "error_m": round(error_m, 4), "error_deg": round(error_deg, 3),
                "collisions": lockstep.world.metrics_summary()["collisions"] - collisions}


def summarise(rows: list[dict[str, Any]], wall_s: float | None = None) -> dict[str, Any]:
    """Attempts, docked, collisions, the worst final errors of the dockings, time per
    docking, failures by reason."""
    done = [r for r in rows if r["docked"]]
    failures: dict[str, int] = {}
    for r in rows:
        if not r["docked"]:
            key = f"{r['result']}: {r['reason']}"[:160]
            failures[key] = failures.get(key, 0) + 1
    errors_m = [r["error_m"] for r in done]
    errors_deg = [r["error_deg"] for r in done]
    seconds = [r["seconds"] for r in done]
    out = {"attempts": len(rows), "docked": len(done),
           "docked_share": round(len(done) / len(rows), 4) if rows else None,
           "collisions": sum(r["collisions"] for r in rows),
           "error_m_max": round(max(errors_m), 4) if errors_m else None,
           "error_m_mean": round(float(np.mean(errors_m)), 4) if errors_m else None,
           "error_deg_max": round(max(errors_deg), 3) if errors_deg else None,
           "error_deg_mean": round(float(np.mean(errors_deg)), 3) if errors_deg else None,
           "seconds_median": round(float(np.median(seconds)), 1) if seconds else None,
           "seconds_max": round(float(np.max(seconds)), 1) if seconds else None,
           "approaches_max": max((r.get("approaches", 0) for r in rows), default=0),
           "failures": failures, "targets": TARGETS}
    if wall_s is not None:
        out["wall_s"] = round(wall_s, 1)
    return out


async def dock_run(world: str, seed: int, attempts: int) -> list[dict[str, Any]]:
    started = time.perf_counter()
    rows = await DockRun(world, seed, attempts).run()
    del started
    return rows
