# `arbiterd simulate --mapping`: the mapping component in lockstep, judged against the truth.
from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np

from base.config import Config
from daemon.component import Plugs
from daemon.control.clock import VirtualClock
from daemon.mapping.component import MAP_POSE, MappingComponent
from daemon.mapping.mapfile import MapData, save_map
from daemon.mapping.messages import MapPose
from daemon.mapping.runner import snapshot_of
from daemon.mapping.settings import MappingSettings
from daemon.settings import RobotSettings
from sensors.scan import ScanPoints
from sim.mapping_truth import PoseErrors, map_precision_recall, truth_occupancy
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
            self.settings, plugs, points, maps_dir=Path("."), inline=True, wall_clock=clock,
            base_frame_id=robot.base_frame_id, odom_frame_id=robot.odom_frame_id)
        self.world = world
        start = world.start
        self.start: Pose2 = (start.x, start.y, start.theta)
        self.truth_at_cast = truth_at_cast
        self.mapped, self.odometry = PoseErrors(), PoseErrors()
        plugs.subscribe(MAP_POSE, self._score)

    async def start(self) -> None:
        await self.component.start()

    def _score(self, message: MapPose) -> None:
        truth = self.truth_at_cast.pop(message.stamp, None)
        odom = self.component.last_odom
        if truth is None or odom is None:
            return
        true_in_start = between(self.start, truth)
        self.mapped.add(message.result.pose, true_in_start)
        self.odometry.add(odom, true_in_start)

    def grid(self) -> MapData | None:
        runner = self.component.runner
        mapper = getattr(runner, "mapper", None)
        snapshot = snapshot_of(mapper, -1) if mapper is not None else None
        return snapshot.grid if snapshot is not None else None

    def map_quality(self, grid: MapData) -> tuple[float, float]:
        """Precision and recall of the map's walls against the world's, at one cell."""
        rows, cols = np.nonzero(grid.occupancy >= OCCUPIED)
        if not len(rows):
            return 0.0, 0.0
        res = grid.resolution
        xs = grid.origin_x + (cols + 0.5) * res
        ys = grid.origin_y + (rows + 0.5) * res
        c, s = math.cos(self.start[2]), math.sin(self.start[2])
        wx, wy = self.start[0] + c * xs - s * ys, self.start[1] + s * xs + c * ys
        x0, y0 = self.world_bounds()
        width = int(math.ceil((x0[1] - x0[0]) / res)) + 1
        height = int(math.ceil((y0[1] - y0[0]) / res)) + 1
        estimated = np.zeros((height, width), dtype=bool)
        ci = np.floor((wx - x0[0]) / res).astype(int)
        ri = np.floor((wy - y0[0]) / res).astype(int)
        inside = (ci >= 0) & (ci < width) & (ri >= 0) & (ri < height)
        estimated[ri[inside], ci[inside]] = True
        truth = truth_occupancy(self.world, res, x0[0], y0[0], width, height)
        precision, recall = map_precision_recall(estimated, truth, 1)
        # a wall the map puts beyond the world's bounds is a false one too
        return precision * inside.sum() / len(inside), recall

    def world_bounds(self) -> tuple[tuple[float, float], tuple[float, float]]:
        seg, circ = self.world.segment_array, self.world.circle_array
        xs = [seg[:, 0], seg[:, 2]] if len(seg) else []
        ys = [seg[:, 1], seg[:, 3]] if len(seg) else []
        if len(circ):
            xs += [circ[:, 0] - circ[:, 2], circ[:, 0] + circ[:, 2]]
            ys += [circ[:, 1] - circ[:, 2], circ[:, 1] + circ[:, 2]]
        x, y = np.concatenate(xs), np.concatenate(ys)
        return (float(x.min()) - 0.5, float(x.max()) + 0.5), \
            (float(y.min()) - 0.5, float(y.max()) + 0.5)

    def report(self, map_out: str | None = None) -> dict[str, Any]:
        out: dict[str, Any] = {"revolutions": self.component.counters.scans,
                               "pose_error": self.mapped.summary(),
                               "odometry_error": self.odometry.summary()}
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

