# `arbiterd simulate --day HOURS`: missions on the simulated battery, going home by itself.
from __future__ import annotations

import math
import random
import tempfile
import time
from typing import Any

from daemon.components.dock.component import DockComponent
from daemon.components.fetch.sequence import FetchError
from daemon.components.navigation.messages import GoalRequest
from daemon.config import load_config
from daemon.lockstep.fetch import draw_points
from daemon.lockstep.runner import Lockstep
from slam.pose import Pose2, between

#: a mission (goal or fetch) that has not ended after this long is canceled (simulated s)
MISSION_CAP_S = 400.0
#: between two missions the robot stands this long (the power policy looks once a second)
GAP_S = 3.0
#: docked, the robot leaves for the next mission once charged to this
RESUME_AT = 0.95
#: the charge at the start of the day
START_CHARGE = 1.0


class DayRun:
    """A loop of missions (a random goal, then a fetch between random points, in turn) in one
    world for ``hours`` simulated hours, mapping on; with ``battery`` the simulated pack
    drains and the power policy sends the robot home (it resumes once charged to
    :data:`RESUME_AT`), else the pack never drains (the comparison)."""

    def __init__(self, world: str, seed: int, hours: float, *, battery: bool,
                 mapping: bool = False, drain: float = 1.0) -> None:
        config = load_config(None, sim=True, env={})
        self.maps = tempfile.TemporaryDirectory(prefix="arbiterd-day-")
        config.update("mapping", {"directory": self.maps.name})
        config.update("sim", {"world_file": world, "seed": seed,
                              "battery_charge": START_CHARGE,
                              "battery_drain": drain if battery else 0.0})
        self.lockstep = Lockstep(config, fetch=True, dock=True, mapping=mapping)
        dock = self.lockstep.dock
        assert dock is not None
        self.dock: DockComponent = dock
        self.hours, self.with_battery = hours, battery
        sim_world = self.lockstep.world.world
        if not sim_world.docks:
            raise ValueError(f"the world {world!r} has no dock ([[docks]] in its file)")
        self.start: Pose2 = (sim_world.start.x, sim_world.start.y, sim_world.start.theta)
        true = sim_world.docks[0]
        self.true_dock: Pose2 = (true.x, true.y, true.theta)
        self.rng = random.Random(seed)
        radius = self.lockstep.world.geometry.footprint_radius
        self.sim_world, self.radius = sim_world, radius
        self.counts = {"missions_started": 0, "missions_done": 0, "goals_done": 0,
                       "fetches_done": 0, "missions_refused": 0, "critical_reached": 0,
                       "dockings": 0, "homings": 0, "homing_failures": 0}
        self.lowest = 1.0

    def _odom(self, pose: Pose2) -> Pose2:
        return between(self.start, pose)

    async def run(self) -> dict[str, Any]:
        lockstep, dock = self.lockstep, self.dock
        started = time.perf_counter()
        await lockstep.begin()
        await lockstep.advance(0.3)
        nav = lockstep.navigation
        assert nav is not None
        dock.set_dock(nav.frame, self._odom(self.true_dock))
        end = self.hours * 3600.0
        kind = 0
        while lockstep.now < end:
            if dock.active:
                await self._advance(min(60.0, end - lockstep.now), lambda: not dock.active)
                if not dock.active and dock.result == "failed":
                    self.counts["homing_failures"] += 1
                continue
            if dock.docked:
                if self._charge() < RESUME_AT:
                    await self._advance(min(60.0, end - lockstep.now))
                    continue
                dock.leave()
                await self._advance(60.0, lambda: not dock.active)
            await self._mission(kind)
            kind += 1
            await self._advance(GAP_S)
        summary = lockstep.world.metrics_summary()
        self.counts["dockings"] = dock.dockings
        self.counts["homings"] = dock.homings
        await lockstep.finish()
        self.maps.cleanup()
        return {"battery": "simulated" if self.with_battery else "infinite",
                "hours": self.hours, **self.counts,
                "collisions": summary["collisions"],
                "lowest_charge": round(self.lowest, 4),
                "path_length_m": summary["path_length_m"],
                "wall_s": round(time.perf_counter() - started, 1)}

    def _charge(self) -> float:
        battery = self.lockstep.battery
        assert battery is not None
        reading = battery.latest
        return reading.percentage if reading is not None else 1.0

    async def _advance(self, seconds: float, until: Any = None) -> None:
        battery = self.lockstep.battery
        assert battery is not None
        level = battery.level

        def check() -> bool:
            nonlocal level
            if battery.level == "critical" and level != "critical":
                self.counts["critical_reached"] += 1
            level = battery.level
            self.lowest = min(self.lowest, self._charge())
            return bool(until is not None and until())

        await self.lockstep.advance(seconds, until=check)

    async def _mission(self, kind: int) -> None:
        lockstep = self.lockstep
        nav, fetch = lockstep.navigation, lockstep.fetch
        assert nav is not None and fetch is not None and fetch.sequence is not None
        sequence = fetch.sequence
        (a, b), = draw_points(self.sim_world, self.radius, self.rng, 1)
        self.counts["missions_started"] += 1
        try:
            if kind % 2 == 0:
                nav.request(GoalRequest(nav.frame, *self._odom(
                    (*a, self.rng.uniform(-math.pi, math.pi)))))
                await self._advance(MISSION_CAP_S, lambda: not nav.navigator.active)
                done = nav.navigator.state == "succeeded"
                self.counts["goals_done"] += done
            else:
                lockstep.world.objects.clear()
                lockstep.world.objects.place(*a)
                await self._advance(0.3)
                fetch.request(self._odom((*a, 0.0))[:2], self._odom((*b, 0.0))[:2])
                await self._advance(MISSION_CAP_S, lambda: not sequence.active)
                done = sequence.result == "succeeded"
                self.counts["fetches_done"] += done
        except (ValueError, FetchError):
            self.counts["missions_refused"] += 1
            return
        if nav.navigator.active:
            nav.cancel("mission cap")
        if sequence.active:
            fetch.cancel("mission cap")
        self.counts["missions_done"] += done


async def day_run(world: str, seed: int, hours: float) -> dict[str, Any]:
    """The day on the simulated battery, beside the same missions on an infinite one."""
    real = await DayRun(world, seed, hours, battery=True).run()
    infinite = await DayRun(world, seed, hours, battery=False).run()
    return {**real, "infinite_battery": infinite}
