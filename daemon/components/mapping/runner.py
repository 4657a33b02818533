# Where the mapper runs: in a worker process on the robot (the control tick never waits on
# it), or inline for the lockstep simulator and offline builds (repeatable, simulated time).
from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, Protocol, TypeVar

import numpy as np

from daemon.components.mapping.mapfile import MapData
from daemon.workers import SupervisedWorker
from slam.grid import OccupancyGrid
from slam.mapper import Mapper, MapperConfig, ScanResult
from slam.pose import Pose2

T = TypeVar("T")


@dataclass(frozen=True)
class MapSnapshot:
    """The map as it is now, with the version it had (a change bumps it)."""

    grid: MapData
    version: int


class MapperRunner(Protocol):
    """The mapper behind an async interface, wherever it runs."""

    async def add_scan(self, odom_pose: Pose2, points_xy: np.ndarray,
                       stamp: float) -> ScanResult: ...

    async def set_pose(self, pose: Pose2, odom_pose: Pose2 | None) -> None: ...

    async def find_pose(self) -> None: ...

    async def snapshot(self, newer_than: int) -> MapSnapshot | None: ...

    async def health(self) -> dict[str, Any]: ...

    async def trajectory(self) -> list[tuple[float, Pose2]]: ...

    def close(self) -> None: ...


# -- the mapper's side (in this process or the worker's) ----------------------------------------

def new_mapper(config: MapperConfig, grid: MapData | None, pose: Pose2) -> Mapper:
    fixed = None if grid is None else OccupancyGrid.from_occupancy(
        grid.occupancy, grid.resolution, grid.origin_x, grid.origin_y)
    return Mapper(config, fixed, pose)


def snapshot_of(mapper: Mapper, newer_than: int) -> MapSnapshot | None:
    grid = mapper.grid
    if grid.version <= newer_than:
        return None
    return MapSnapshot(MapData(grid.occupancy(), grid.resolution, grid.origin_x, grid.origin_y),
                       grid.version)


class InlineRunner:
    """The mapper called directly (the lockstep simulator, `arbiterd map build`)."""

    def __init__(self, config: MapperConfig, grid: MapData | None = None,
                 pose: Pose2 = (0.0, 0.0, 0.0)) -> None:
        self.mapper = new_mapper(config, grid, pose)

    async def add_scan(self, odom_pose: Pose2, points_xy: np.ndarray,
                       stamp: float) -> ScanResult:
        return self.mapper.add_scan(odom_pose, points_xy, stamp)

    async def set_pose(self, pose: Pose2, odom_pose: Pose2 | None) -> None:
        self.mapper.set_pose(pose, odom_pose)

    async def find_pose(self) -> None:
        self.mapper.find_pose()

    async def snapshot(self, newer_than: int) -> MapSnapshot | None:
        return snapshot_of(self.mapper, newer_than)

    async def health(self) -> dict[str, Any]:
        return self.mapper.health()

    async def trajectory(self) -> list[tuple[float, Pose2]]:
        return list(self.mapper.trajectory)

    def close(self) -> None:
        pass


# -- the worker process ----------------------------------------------------------------------

_WORKER: Mapper | None = None


def _worker_start(config: MapperConfig, grid: MapData | None, pose: Pose2) -> None:
    global _WORKER
    _WORKER = new_mapper(config, grid, pose)


def _worker() -> Mapper:
    assert _WORKER is not None, "the mapping worker was not started"
    return _WORKER


def _worker_add_scan(odom_pose: Pose2, points_xy: np.ndarray, stamp: float) -> ScanResult:
    return _worker().add_scan(odom_pose, points_xy, stamp)


def _worker_set_pose(pose: Pose2, odom_pose: Pose2 | None) -> None:
    _worker().set_pose(pose, odom_pose)


def _worker_find_pose() -> None:
    _worker().find_pose()


def _worker_snapshot(newer_than: int) -> MapSnapshot | None:
    return snapshot_of(_worker(), newer_than)


def _worker_health() -> dict[str, Any]:
    return _worker().health()


def _worker_trajectory() -> list[tuple[float, Pose2]]:
    return list(_worker().trajectory)


class ProcessRunner:
    """The mapper in one worker process: its CPU time is not the event loop's (the GIL is not
    shared), and a Pi 4 gives it a core of its own. Calls are answered in order."""

    def __init__(self, config: MapperConfig, grid: MapData | None = None,
                 pose: Pose2 = (0.0, 0.0, 0.0)) -> None:
        #: where a restarted mapper starts: the saved map (localize) or a new one, at the
        #: pose the last revolution gave (:meth:`moved_to`)
        self.start_pose = pose
        self.worker = SupervisedWorker("mapping", _worker_start,
                                       lambda: (config, grid, self.start_pose))

    def moved_to(self, pose: Pose2) -> None:
        self.start_pose = pose

    async def _call(self, function: Callable[..., T], *args: Any) -> T:
        return await self.worker.call(function, *args)

    async def add_scan(self, odom_pose: Pose2, points_xy: np.ndarray,
                       stamp: float) -> ScanResult:
        return await self._call(_worker_add_scan, odom_pose, points_xy, stamp)

    async def set_pose(self, pose: Pose2, odom_pose: Pose2 | None) -> None:
        await self._call(_worker_set_pose, pose, odom_pose)

    async def find_pose(self) -> None:
        await self._call(_worker_find_pose)

    async def snapshot(self, newer_than: int) -> MapSnapshot | None:
        return await self._call(_worker_snapshot, newer_than)

    async def health(self) -> dict[str, Any]:
        return await self._call(_worker_health)

    async def trajectory(self) -> list[tuple[float, Pose2]]:
        return await self._call(_worker_trajectory)

    def close(self) -> None:
        self.worker.close()
