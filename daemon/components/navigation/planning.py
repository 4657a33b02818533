# Where navigation folds revolutions into its costmap and plans: a worker process on the robot
# (the control tick never waits for the interpreter lock), or inline for the lockstep simulator.
from __future__ import annotations

import contextlib
import time
from collections.abc import Callable
from dataclasses import dataclass
from multiprocessing.shared_memory import SharedMemory
from typing import Any, TypeVar

import numpy as np

from daemon.workers import SupervisedWorker
from nav.costmap import Costmap, CostParams, GridArea
from nav.frontier import Frontier, find_frontiers, known_free_m2
from nav.planner import Plan, plan
from slam.pose import Pose2

T = TypeVar("T")
#: revolutions to fold in: each its pose in the costmap's frame and its returns (robot frame)
Scans = list[tuple[Pose2, np.ndarray, np.ndarray]]


@dataclass(frozen=True)
class Planned:
    """A plan, the costs it was made on, and how long folding and planning took (ms)."""

    plan: Plan
    costs: np.ndarray
    ms: float


@dataclass(frozen=True)
class Looked:
    """The frontiers seen from ``start``, the known free area (m²), and the costs."""

    frontiers: list[Frontier]
    explored_m2: float
    costs: np.ndarray


def fold(costmap: Costmap, scans: Scans) -> np.ndarray:
    """Fold the revolutions into the costmap; its costs now."""
    for pose, xs, ys in scans:
        costmap.add_scan(pose, xs, ys)
    return costmap.costs()


def fold_and_plan(costmap: Costmap, scans: Scans, start: Pose2, goal: Pose2,
                  block: int) -> Planned:
    started = time.perf_counter()
    costs = fold(costmap, scans)
    result = plan(costs, costmap.area, start[:2], goal[:2], block, costmap.params.line_cost)
    return Planned(result, costs, round(1000 * (time.perf_counter() - started), 1))


def fold_and_look(costmap: Costmap, scans: Scans, start: Pose2, min_cells: int,
                  block: int) -> Looked:
    costs = fold(costmap, scans)
    obstacles = costmap.obstacles()
    found = find_frontiers(costs, costmap.seen, obstacles, costmap.area, start[:2],
                           min_cells=min_cells, block=block)
    return Looked(found, known_free_m2(costmap.seen, obstacles, costmap.area.resolution), costs)


class SharedCells:
    """A costmap's evidence and seen arrays in shared memory: the worker writes them while it
    folds revolutions in, the daemon reads them (goal checks, the fetch) without a copy."""

    def __init__(self, area: GridArea) -> None:
        cells = area.height * area.width
        self.memory = SharedMemory(create=True, size=2 * cells)
        self.arrays = cells_in(self.memory, area)

    def close(self) -> None:
        """Free the shared memory (at once, or once the daemon's views of it are gone)."""
        self.memory.unlink()
        with contextlib.suppress(BufferError):  # the costmap's arrays still point into it:
            self.memory.close()  # then it is freed with them


def cells_in(memory: SharedMemory, area: GridArea) -> tuple[np.ndarray, np.ndarray]:
    shape, cells = (area.height, area.width), area.height * area.width
    evidence = np.ndarray(shape, dtype=np.int8, buffer=memory.buf, offset=0)
    seen = np.ndarray(shape, dtype=np.bool_, buffer=memory.buf, offset=cells)
    return evidence, seen


# -- the worker process ----------------------------------------------------------------------

_WORKER: tuple[SharedMemory, Costmap] | None = None


def _worker_start(name: str, area: GridArea, params: CostParams) -> None:
    global _WORKER
    memory = SharedMemory(name=name)
    _WORKER = memory, Costmap(area, params, cells_in(memory, area))


def _worker_costmap() -> Costmap:
    assert _WORKER is not None, "the planning worker was not started"
    return _WORKER[1]


def _worker_plan(scans: Scans, start: Pose2, goal: Pose2, block: int) -> Planned:
    return fold_and_plan(_worker_costmap(), scans, start, goal, block)


def _worker_look(scans: Scans, start: Pose2, min_cells: int, block: int) -> Looked:
    return fold_and_look(_worker_costmap(), scans, start, min_cells, block)


def _worker_ready() -> bool:
    return _WORKER is not None


class PlanningWorker:
    """The costmap in shared memory and the folding, planning and frontier search in one
    worker process; :attr:`costmap` is the daemon's view of the same cells. The daemon folds
    revolutions itself (:func:`fold`) only while no job runs."""

    def __init__(self, area: GridArea, params: CostParams) -> None:
        self.cells = SharedCells(area)
        self.costmap = Costmap(area, params, self.cells.arrays)
        name = self.cells.memory.name
        #: restarted on the same shared cells: a new worker loses nothing folded in
        self.worker = SupervisedWorker("planning", _worker_start,
                                       lambda: (name, area, params))

    async def _call(self, function: Callable[..., T], *args: Any) -> T:
        return await self.worker.call(function, *args)

    async def ready(self) -> bool:
        """Wait for the worker's start-up (its imports)."""
        return await self._call(_worker_ready)

    async def plan(self, scans: Scans, start: Pose2, goal: Pose2, block: int) -> Planned:
        return await self._call(_worker_plan, scans, start, goal, block)

    async def look(self, scans: Scans, start: Pose2, min_cells: int, block: int) -> Looked:
        return await self._call(_worker_look, scans, start, min_cells, block)

    def close(self) -> None:
        self.worker.close()
        self.cells.close()
