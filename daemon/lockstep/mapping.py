# `arbiterd simulate --mapping`: the mapping component in lockstep, judged against the truth.
from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np

from base.config import Config
from daemon.clock import VirtualClock
from daemon.component import Plugs
from daemon.components.mapping.component import MAP_POSE, MappingComponent, maps_directory
from daemon.components.mapping.mapfile import MapData, save_map
from daemon.components.mapping.messages import MapPose
from daemon.components.mapping.runner import snapshot_of
from daemon.components.mapping.settings import MappingSettings
from daemon.settings import RobotSettings
from sensors.scan import ScanPoints
from sim.mapping_truth import (
    PoseErrors,
    map_precision_recall,
    truth_occupancy,
    visible_walls,
    world_grid,
)
from sim.world import World
from slam.pose import Pose2, between

#: occupancy (percent) from which a cell of the estimated map counts as a wall
OCCUPIED = 65


class MappingProbe:
    """Runs the mapper inline (repeatable) and scores it per revolution: the map-frame pose
    against the true pose, beside odometry alone, both in the frame the robot started in."""

    def __init__(self, config: Config, plugs: Plugs, points: ScanPoints, clock: VirtualClock,
                 world: World, truth_at_cast: dict[float, Pose2]) -> None:
        config.update("mapping", {"enabled": True})
        robot = config.get(RobotSettings)
        self.settings = config.get(MappingSettings)
        self.component = MappingComponent(
            self.settings, plugs, points, inline=True, wall_clock=clock,
            maps_dir=maps_directory(self.settings) if self.settings.directory else Path("."),
            base_frame_id=robot.base_frame_id, odom_frame_id=robot.odom_frame_id)
        self.world = world
        start = world.start
        self.start_pose: Pose2 = (start.x, start.y, start.theta)
        self.truth_at_cast = truth_at_cast
        self.mapped, self.odometry = PoseErrors(), PoseErrors()
        self.true_poses: list[Pose2] = []
        #: per scored revolution: (stamp s, position error m, heading error rad)
        self.series: list[tuple[float, float, float]] = []
        plugs.subscribe(MAP_POSE, self._score)

    async def start(self) -> None:
        await self.component.start()

    def _score(self, message: MapPose) -> None:
        truth = self.truth_at_cast.pop(message.stamp, None)
        odom = self.component.last_odom
        if truth is None or odom is None:
            return
        true_in_start = between(self.start_pose, truth)
        self.true_poses.append(truth)
        self.mapped.add(message.result.pose, true_in_start)
        self.odometry.add(odom, true_in_start)
        est = message.result.pose
        self.series.append((message.stamp, math.hypot(est[0] - true_in_start[0],
                                                      est[1] - true_in_start[1]),
                            abs(math.remainder(est[2] - true_in_start[2], math.tau))))

    def grid(self) -> MapData | None:
        runner = self.component.runner
        mapper = getattr(runner, "mapper", None)
        snapshot = snapshot_of(mapper, -1) if mapper is not None else None
        return snapshot.grid if snapshot is not None else None

    def map_quality(self, grid: MapData) -> tuple[float, float]:
        """Precision and recall of the map's walls against the world's at one cell; recall
        over the walls a lidar saw from the true poses of the run's revolutions."""
        rows, cols = np.nonzero(grid.occupancy >= OCCUPIED)
        if not len(rows):
            return 0.0, 0.0
        res = grid.resolution
        xs = grid.origin_x + (cols + 0.5) * res
        ys = grid.origin_y + (rows + 0.5) * res
        c, s = math.cos(self.start_pose[2]), math.sin(self.start_pose[2])
        wx, wy = self.start_pose[0] + c * xs - s * ys, self.start_pose[1] + s * xs + c * ys
        spec = world_grid(self.world, res, margin=1.0)
        estimated = np.zeros((spec.height, spec.width), dtype=bool)
        ci = np.floor((wx - spec.origin_x) / res).astype(int)
        ri = np.floor((wy - spec.origin_y) / res).astype(int)
        inside = (ci >= 0) & (ci < spec.width) & (ri >= 0) & (ri < spec.height)
        estimated[ri[inside], ci[inside]] = True
        area = (res, spec.origin_x, spec.origin_y, spec.width, spec.height)
        truth = truth_occupancy(self.world, *area)
        seen = visible_walls(self.world, self.true_poses[::5], *area,
                             range_max=self.settings.max_range_m)
        precision, recall = map_precision_recall(estimated, truth, 1, observed=seen)
        # a wall the map puts beyond the world's bounds is a false one too
        return precision * inside.sum() / len(inside), recall

    def report(self, map_out: str | None = None) -> dict[str, Any]:
        out: dict[str, Any] = {"revolutions": self.component.counters.scans,
                               "pose_error": summary(self.mapped),
                               "odometry_error": summary(self.odometry)}
        grid = self.grid()
        if grid is not None:
            precision, recall = self.map_quality(grid)
            out["map"] = {"precision": round(precision, 4), "recall": round(recall, 4),
                          "width": grid.width, "height": grid.height,
                          "resolution": grid.resolution}
            if map_out:
                path = Path(map_out)
                _, yml = save_map(path.parent, path.name, grid)
                out["map"]["file"] = str(yml)
        return out


def summary(errors: PoseErrors) -> dict[str, float]:
    return {"rms_m": round(errors.rms_m, 4), "max_m": round(errors.max_m, 4),
            "rms_deg": round(errors.rms_deg, 3), "max_deg": round(errors.max_deg, 3),
            "count": errors.count}
