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
