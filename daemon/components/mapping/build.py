# `arbiterd map build`: the mapper run offline over a flight recording's /scan and /odom.
from __future__ import annotations

import bisect
import csv
import math
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from mcap.exceptions import McapError
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory

from daemon.components.mapping.mapfile import MapData
from sensors.scan import LaserScan, ScanPoints
from slam.mapper import Mapper, MapperConfig
from slam.pose import Pose2


class RecordingError(ValueError):
    """A recording the mapper cannot use; the text names the file and what is missing."""


@dataclass
class Timeline:
    """Odometry poses by stamp, to place each revolution at its own time."""

    stamps: list[float] = field(default_factory=list)
    poses: list[Pose2] = field(default_factory=list)

    def add(self, stamp: float, pose: Pose2) -> None:
        self.stamps.append(stamp)
        self.poses.append(pose)

    def at(self, t: float) -> Pose2 | None:
        """Interpolated between the two samples around ``t``; None outside them (by more
        than a tenth of a second)."""
        i = bisect.bisect_left(self.stamps, t)
        if i == 0:
            return self.poses[0] if self.stamps and self.stamps[0] - t < 0.1 else None
        if i == len(self.stamps):
            return self.poses[-1] if t - self.stamps[-1] < 0.1 else None
        t0, t1 = self.stamps[i - 1], self.stamps[i]
        p0, p1 = self.poses[i - 1], self.poses[i]
        f = (t - t0) / (t1 - t0) if t1 > t0 else 0.0
        turn = math.remainder(p1[2] - p0[2], math.tau)
        return (p0[0] + f * (p1[0] - p0[0]), p0[1] + f * (p1[1] - p0[1]), p0[2] + f * turn)


@dataclass
class Revolution:
    stamp: float
    frame_id: str
    angle_min: float
    angle_increment: float
    range_min: float
    range_max: float
    ranges: np.ndarray


@dataclass
class BuildResult:
    grid: MapData
    trajectory: list[tuple[float, Pose2]]
    used: int
    matched: int
    #: with the offline stages: what the far-loop search found and accepted
    far_loops: dict[str, int] | None = None


def _stamp(header: Any) -> float:
    return float(header.stamp.sec) + float(header.stamp.nanosec) * 1e-9


def _yaw(q: Any) -> float:
    return math.atan2(2.0 * (q.w * q.z + q.x * q.y), 1.0 - 2.0 * (q.y * q.y + q.z * q.z))


def read_recording(path: Path) -> tuple[Timeline, list[Revolution], ScanPoints]:
    """/odom, /scan and the lidar's mount (/tf_static) from an arbiterd MCAP recording."""
    odometry, scans = Timeline(), []
    mount = (0.0, 0.0, 0.0)
    try:
        with open(path, "rb") as stream:
            reader = make_reader(stream, decoder_factories=[DecoderFactory()])
            for _, channel, _, msg in reader.iter_decoded_messages(
                    topics=["/odom", "/scan", "/tf_static"]):
                if channel.topic == "/odom":
                    p = msg.pose.pose
                    odometry.add(_stamp(msg.header),
                                 (p.position.x, p.position.y, _yaw(p.orientation)))
                elif channel.topic == "/scan":
                    scans.append(Revolution(_stamp(msg.header), msg.header.frame_id,
                                            msg.angle_min, msg.angle_increment, msg.range_min,
                                            msg.range_max, np.asarray(msg.ranges, np.float32)))
                else:
                    mount = _mount(msg, mount)
    except FileNotFoundError:
        raise RecordingError(f"{path}: no such recording") from None
    except (McapError, ValueError, EOFError, OSError) as exc:
        raise RecordingError(f"{path}: not a readable MCAP recording: {exc}") from None
    if not scans:
        raise RecordingError(f"{path}: no /scan messages: record with the lidar enabled "
                             "([lidar] enabled, [recorder] on)")
    if not odometry.stamps:
        raise RecordingError(f"{path}: no /odom messages: the mapper needs odometry")
    x, y, yaw = mount
    return odometry, scans, ScanPoints(x, y, math.degrees(yaw))


def _mount(msg: Any, current: tuple[float, float, float]) -> tuple[float, float, float]:
    for t in msg.transforms:
        if t.child_frame_id == "laser" or t.child_frame_id.endswith("laser"):
            tr = t.transform
            return (tr.translation.x, tr.translation.y, _yaw(tr.rotation))
    return current


def points_of(scan: Revolution, points: ScanPoints) -> np.ndarray:
    """A revolution's valid returns in the robot frame, as the live daemon converts them."""
    count = len(scan.ranges)
    laser = LaserScan(stamp=scan.stamp, frame_id=scan.frame_id, angle_min=scan.angle_min,
                      angle_max=scan.angle_min + scan.angle_increment * max(count - 1, 0),
                      angle_increment=scan.angle_increment, range_min=scan.range_min,
                      range_max=scan.range_max, ranges=scan.ranges)
    xs, ys = points(laser)
    return np.column_stack((xs, ys))


def revolutions(odometry: Timeline, scans: list[Revolution],
                points: ScanPoints) -> Iterator[tuple[float, Pose2, np.ndarray]]:
    for scan in scans:
        pose = odometry.at(scan.stamp)
        if pose is not None:
            yield scan.stamp, pose, points_of(scan, points)


def scans_of(path: Path) -> Iterator[tuple[float, Pose2, np.ndarray]]:
    """(stamp, odometry pose, points in the robot frame) per revolution: from an arbiterd
    MCAP recording, or from a ROS 1 bag or a CARMEN log (the Freiburg benchmark's formats)."""
    if path.suffix in (".bag", ".clf"):
        return _logged_scans(path)
    odometry, scans, points = read_recording(path)
    return revolutions(odometry, scans, points)


def _logged_scans(path: Path) -> Iterator[tuple[float, Pose2, np.ndarray]]:
    if not path.is_file():
        raise RecordingError(f"{path}: no such log")
    try:
        from slam.datasets import read_scans
        yield from read_scans(path)
    except ModuleNotFoundError as exc:
        raise RecordingError(f"{path}: reading ROS 1 bags needs the rosbags package "
                             f"({exc}): pip install rosbags") from None


def build_map(path: Path, config: MapperConfig, refine: bool = False,
              max_seconds: float = math.inf) -> BuildResult:
    """Run the mapper over the recording (its first ``max_seconds``), in recorded order. With
    ``refine``, then the offline stages the SLAM benchmark runs: a final optimisation, the
    search for returns after a long tour (far loops), and the trajectory polished scan by scan
    against the optimised map and fused with the odometry (docs/mapping-algorithm.md)."""
    mapper = Mapper(config)
    used = matched = 0
    points: list[np.ndarray] = []
    odometry: list[Pose2] = []
    first: float | None = None
    for stamp, pose, xy in scans_of(path):
        first = stamp if first is None else first
        if stamp - first > max_seconds:
            break
        result = mapper.add_scan(pose, xy, stamp)
        used += 1
        matched += bool(result.matched)
        if refine:
            points.append(xy)
            odometry.append(pose)
    if not used:
        raise RecordingError(f"{path}: no revolution has odometry at its time")
    far_loops = None
    trajectory = list(mapper.trajectory)
    if refine:
        mapper.optimize()
        far_loops = mapper.close_far_loops()
        trajectory = mapper.refined_trajectory(points, odometry=odometry)
    grid = mapper.grid
    data = MapData(grid.occupancy(), grid.resolution, grid.origin_x, grid.origin_y)
    return BuildResult(data, trajectory, used, matched, far_loops)


def write_trajectory(path: Path, trajectory: list[tuple[float, Pose2]]) -> None:
    """The corrected poses as CSV: stamp, x, y, theta (s, m, m, rad)."""
    with open(path, "w", newline="") as file:
        writer = csv.writer(file)
        writer.writerow(["stamp", "x", "y", "theta"])
        for stamp, (x, y, theta) in trajectory:
            writer.writerow([f"{stamp:.6f}", f"{x:.4f}", f"{y:.4f}", f"{theta:.5f}"])
