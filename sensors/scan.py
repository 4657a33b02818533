# The LaserScan type (field names of sensor_msgs/LaserScan) published on the bus and /api/scan.
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import numpy.typing as npt

FloatArray = npt.NDArray[np.float32]


def _empty() -> FloatArray:
    return np.zeros(0, dtype=np.float32)


@dataclass
class LaserScan:
    """One whole revolution, shaped like ``sensor_msgs/LaserScan``.

    Angles are radians, counter-clockwise about the frame's z axis (ROS convention); ``ranges``
    are metres with ``inf`` for no return; ``stamp`` is the wall-clock time of the first ray.
    """

    stamp: float = 0.0
    frame_id: str = "laser"
    angle_min: float = 0.0
    angle_max: float = 0.0
    angle_increment: float = 0.0
    time_increment: float = 0.0
    scan_time: float = 0.0
    range_min: float = 0.0
    range_max: float = 0.0
    ranges: FloatArray = field(default_factory=_empty)
    intensities: FloatArray = field(default_factory=_empty)

    def to_json(self) -> dict[str, Any]:
        """A JSON-ready dict; non-finite numbers become ``null``."""
        return {
            "stamp": _finite(self.stamp),
            "frame_id": self.frame_id,
            "angle_min": _finite(self.angle_min),
            "angle_max": _finite(self.angle_max),
            "angle_increment": _finite(self.angle_increment),
            "time_increment": _finite(self.time_increment),
            "scan_time": _finite(self.scan_time),
            "range_min": _finite(self.range_min),
            "range_max": _finite(self.range_max),
            "ranges": finite_list(self.ranges),
            "intensities": finite_list(self.intensities),
        }


def _finite(value: float) -> float | None:
    return float(value) if math.isfinite(value) else None


def finite_list(values: npt.NDArray[Any]) -> list[float | None]:
    """Array → list with NaN/inf as ``None`` (JSON ``null``)."""
    as_float = np.asarray(values, dtype=np.float64)
    out: list[float | None] = as_float.tolist()
    if not np.isfinite(as_float).all():
        for i in np.flatnonzero(~np.isfinite(as_float)).tolist():
            out[i] = None
    return out


class ScanPoints:
    """LaserScan -> points in the robot frame, through the lidar's mounting pose."""

    def __init__(self, mount_x: float, mount_y: float, mount_yaw_deg: float) -> None:
        self.x, self.y, self.yaw = mount_x, mount_y, math.radians(mount_yaw_deg)
        self._key: tuple[float, float, int] | None = None
        self._cos = self._sin = np.zeros(0)
        self._last: tuple[LaserScan, tuple[np.ndarray, np.ndarray]] | None = None

    def __call__(self, scan: LaserScan) -> tuple[np.ndarray, np.ndarray]:
        """The scan's valid returns as (x, y) arrays; the same scan is converted once."""
        if self._last is not None and self._last[0] is scan:
            return self._last[1]
        points = self._convert(scan)
        self._last = (scan, points)
        return points

    def _convert(self, scan: LaserScan) -> tuple[np.ndarray, np.ndarray]:
        ranges = np.asarray(scan.ranges, dtype=np.float64)
        key = (float(scan.angle_min), float(scan.angle_increment), len(ranges))
        if key != self._key:
            angles = scan.angle_min + scan.angle_increment * np.arange(len(ranges)) + self.yaw
            self._cos, self._sin, self._key = np.cos(angles), np.sin(angles), key
        valid = np.isfinite(ranges) & (ranges >= scan.range_min)
        if scan.range_max > 0:
            valid &= ranges <= scan.range_max
        r = ranges[valid]
        return self.x + r * self._cos[valid], self.y + r * self._sin[valid]
