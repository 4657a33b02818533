# Readers for the Freiburg SLAM benchmark logs: ROS 1 bags (via rosbags) and CARMEN FLASER logs.
from __future__ import annotations

import math
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from slam.pose import Pose2, transform_points, wrap

Scan = tuple[float, Pose2, np.ndarray]  # (stamp s, odometry base pose, points (N, 2) in base frame)


@dataclass(frozen=True)
class Dataset:
    """One benchmark log: its data file and its relations file."""

    name: str
    log: Path
    relations: Path


# name -> (log file under freiburg/, relations file under freiburg/relations/)
FREIBURG: dict[str, tuple[str, str]] = {
    "aces": ("bags/aces.orig.bag", "aces.relations"),
    "mit-csail": ("clf/mit-csail.clf", "mit-csail.relations"),
    "fr079": ("bags/fr079.orig.bag", "fr079.relations"),
    "intel": ("bags/intel.orig.bag", "intel.relations"),
    "fr-clinic": ("bags/fr-clinic_robotlaser.orig.bag", "fr-clinic.relations"),
}


def freiburg_dataset(root: Path, name: str) -> Dataset:
    """The dataset ``name`` under ``root`` (the folder holding ``freiburg/``)."""
    log, relations = FREIBURG[name]
    base = Path(root) / "freiburg"
    return Dataset(name, base / log, base / "relations" / relations)


def read_scans(path: Path, max_range: float = math.inf,
               max_seconds: float = math.inf) -> Iterator[Scan]:
    """The scans of a ``.bag`` or ``.clf`` log, in order; returns beyond ``max_range`` are
    left out; stop after ``max_seconds`` of data."""
    reader = read_bag if Path(path).suffix == ".bag" else read_carmen
    first: float | None = None
    for stamp, odom, points in reader(Path(path), max_range):
        first = stamp if first is None else first
        if stamp - first > max_seconds:
            return
        yield stamp, odom, points


# ---------------------------------------------------------------------- geometry of a scan


def scan_points(ranges: np.ndarray, angles: np.ndarray, min_range: float,
                max_range: float) -> np.ndarray:
    """Valid returns (N, 2) in the sensor frame."""
    r = np.asarray(ranges, dtype=np.float64)
    ok = np.isfinite(r) & (r >= min_range) & (r <= max_range)
    return np.column_stack([r[ok] * np.cos(angles[ok]), r[ok] * np.sin(angles[ok])])


def yaw_of(q: Any) -> float:
    """Yaw of a geometry_msgs quaternion."""
    return math.atan2(2.0 * (q.w * q.z + q.x * q.y), 1.0 - 2.0 * (q.y * q.y + q.z * q.z))


def interpolate_pose(stamps: np.ndarray, poses: np.ndarray, t: float) -> Pose2:
    """Linear interpolation of a pose track (angles unwrapped between neighbours)."""
    i = int(np.searchsorted(stamps, t))
    if i <= 0:
        return (float(poses[0][0]), float(poses[0][1]), float(poses[0][2]))
    if i >= len(stamps):
        return (float(poses[-1][0]), float(poses[-1][1]), float(poses[-1][2]))
    t0, t1 = stamps[i - 1], stamps[i]
    a = 0.0 if t1 <= t0 else (t - t0) / (t1 - t0)
    p0, p1 = poses[i - 1], poses[i]
    dtheta = wrap(p1[2] - p0[2])
    return (p0[0] + a * (p1[0] - p0[0]), p0[1] + a * (p1[1] - p0[1]), wrap(p0[2] + a * dtheta))


# ---------------------------------------------------------------------- ROS 1 bags


def read_bag(path: Path, max_range: float = math.inf) -> Iterator[Scan]:
    """``/scan`` with ``/odom`` interpolated at each scan stamp and the ``/tf_static`` laser
    mount (base_link -> laser) applied. Needs the ``rosbags`` package (extra ``slam-data``)."""
    from rosbags.highlevel import AnyReader  # imported here: a test/bench-only dependency

    scans: list[tuple[float, np.ndarray, np.ndarray]] = []
    odom_t: list[float] = []
    odom_p: list[Pose2] = []
    mount: Pose2 = (0.0, 0.0, 0.0)
    with AnyReader([path]) as reader:
        for conn, _, raw in reader.messages():
            msg: Any = reader.deserialize(raw, conn.msgtype)
            if conn.topic == "/scan":
                scans.append(_laser_scan(msg, max_range))
            elif conn.topic == "/odom":
                pose = msg.pose.pose
                odom_t.append(_stamp(msg.header.stamp))
                odom_p.append((pose.position.x, pose.position.y, yaw_of(pose.orientation)))
            elif conn.topic == "/tf_static":
                mount = _laser_mount(msg, mount)
    order = np.argsort(odom_t, kind="stable")
    stamps, poses = np.asarray(odom_t)[order], np.asarray(odom_p, dtype=np.float64)[order]
    for stamp, ranges_points, _ in scans:
        yield stamp, interpolate_pose(stamps, poses, stamp), transform_points(mount, ranges_points)


def _stamp(stamp: Any) -> float:
    return float(stamp.sec) + float(stamp.nanosec) * 1e-9


def _laser_scan(msg: Any, max_range: float) -> tuple[float, np.ndarray, np.ndarray]:
    ranges = np.asarray(msg.ranges, dtype=np.float64)
    angles = msg.angle_min + np.arange(len(ranges)) * msg.angle_increment
    limit = min(max_range, float(msg.range_max))
    points = scan_points(ranges, angles, float(msg.range_min), limit)
    return _stamp(msg.header.stamp), points, ranges


def _laser_mount(msg: Any, default: Pose2) -> Pose2:
    for tf in msg.transforms:
        if tf.child_frame_id.lstrip("/") == "laser":
            t = tf.transform
            return (t.translation.x, t.translation.y, yaw_of(t.rotation))
    return default


# ---------------------------------------------------------------------- CARMEN logs

CARMEN_NO_RETURN = 81.0  # CARMEN writes 81.91 (and similar) for "no return"


def read_carmen(path: Path, max_range: float = math.inf) -> Iterator[Scan]:
    """FLASER lines: 180° of beams, the odometry is the second pose triple (the one the
    Freiburg evaluator reads), the stamp is the ipc_timestamp; the laser sits at the base."""
    with open(path, encoding="ascii") as log:
        for line in log:
            fields = line.split()
            if not fields or fields[0] != "FLASER":
                continue
            count = int(fields[1])
            ranges = np.asarray(fields[2:2 + count], dtype=np.float64)
            rest = fields[2 + count:]
            odom = (float(rest[3]), float(rest[4]), float(rest[5]))
            angles = np.linspace(-math.pi / 2, math.pi / 2, count)
            limit = min(max_range, CARMEN_NO_RETURN)
            yield float(rest[6]), odom, scan_points(ranges, angles, 0.01, limit)

