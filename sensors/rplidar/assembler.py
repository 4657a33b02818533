# Revolution assembly: parser samples → whole revolutions → LaserScan (ROS angle convention).
from __future__ import annotations

import itertools
import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from sensors.rplidar.records import F64, U8
from sensors.rplidar.streams import Discontinuity, EncoderReset, Event, Samples
from sensors.scan import LaserScan, finite_list

MAX_SAMPLES_PER_REVOLUTION = 8192
#: a revolution with fewer than this share of the samples a whole turn has is not published
MIN_FILL = 0.8
#: fewer samples than this cannot be a revolution of any RPLIDAR mode
MIN_SAMPLES_PER_REVOLUTION = 16


@dataclass
class Revolution:
    """One whole turn in device terms: clockwise degrees, mm (0 = no return), quality 0-63."""

    t: float  # wall clock of the first ray
    scan_time: float
    angle_deg: F64
    distance_mm: F64
    quality: U8

    def __len__(self) -> int:
        return len(self.angle_deg)

    def to_cli_json(self) -> dict[str, Any]:
        """The ``arbiterd lidar scan --json`` record; a missing return is ``null``."""
        ranges = np.where(self.distance_mm > 0, self.distance_mm / 1000.0, np.inf)
        return {"t": self.t, "angles_deg": self.angle_deg.tolist(),
                "ranges_m": finite_list(ranges), "quality": self.quality.tolist()}


@dataclass
class ScanGeometry:
    """How a revolution becomes a LaserScan."""

    frame_id: str = "laser"
    inverted: bool = False  # mounted upside down: device angles are then counter-clockwise
    angle_offset_deg: float = 0.0  # frame angle of the device's 0°
    bins: int = 0  # 0 = one ray per sample; N = fixed N bins over the full turn
    range_min: float = 0.15
    range_max: float = 12.0


class RevolutionAssembler:
    """Collects samples into whole revolutions; partial ones are discarded.

    A revolution starts at a sample flagged ``new_rev`` and ends where the next one starts; an
    encoder reset, a discontinuity or more than ``max_samples`` samples abandons the current one
    (``discarded``). A finished one with fewer than ``min_fill`` of the samples a whole turn has
    (360° over its median angle step), or fewer than ``min_samples``, is not published either
    (``short``). Sample times are
    estimated back from the chunk arrival time with the measured time per sample.
    """

    def __init__(self, max_samples: int = MAX_SAMPLES_PER_REVOLUTION,
                 sample_period: float = 0.0, min_fill: float = MIN_FILL,
                 min_samples: int = MIN_SAMPLES_PER_REVOLUTION) -> None:
        self.max_samples = max_samples
        self.sample_period = sample_period
        self.min_fill = min_fill
        self.min_samples = min_samples
        self.discarded = 0
        self.short = 0
        self.last_short: tuple[int, float] | None = None  # (samples, expected) of the last one
        self._parts: list[tuple[F64, F64, U8]] = []
        self._count = 0
        self._t_first: float | None = None

    def reset(self) -> None:
        """Drop the revolution in progress (stream restarted, device reset, ...)."""
        if self._t_first is not None:
            self.discarded += 1
        self._parts, self._count, self._t_first = [], 0, None

    def feed(self, events: list[Event], t_arrival: float) -> list[Revolution]:
        """Take a chunk's events (received at wall clock ``t_arrival``); return finished turns."""
        runs = [e for e in events if isinstance(e, Samples)]
        # samples that arrived after each run: the later runs and what the parser holds back
        after = sum(len(e) for e in runs) + (runs[-1].lag if runs else 0)
        done: list[Revolution] = []
        for event in events:
            if isinstance(event, EncoderReset | Discontinuity):
                self.reset()
            elif isinstance(event, Samples) and len(event):
                after -= len(event)
                done += self._take(event, t_arrival - after * self.sample_period)
        return done

    def _take(self, run: Samples, t_end: float) -> list[Revolution]:
        done: list[Revolution] = []
        starts = set(np.flatnonzero(run.new_rev).tolist())
        edges = sorted({0, *starts, len(run)})
        for first, end in itertools.pairwise(edges):
            if first in starts:
                t_first = t_end - (len(run) - 1 - first) * self.sample_period
                finished = self._close(t_first)
                if finished is not None:
                    done.append(finished)
                self._t_first = t_first
            if end > first and self._t_first is not None:
                self._append(run, first, end)
        return done

    def _append(self, run: Samples, first: int, end: int) -> None:
        self._parts.append((run.angle_deg[first:end], run.distance_mm[first:end],
                            run.quality[first:end]))
        self._count += end - first
        if self._count > self.max_samples:
            self.reset()

    def _close(self, t_next: float) -> Revolution | None:
        if self._t_first is None or not self._parts:
            return None
        angle, dist, quality = (np.concatenate(parts) for parts in zip(*self._parts, strict=True))
        self._parts, self._count = [], 0
        expected = expected_samples(angle)
        if len(angle) < max(self.min_fill * expected, self.min_samples):
            self.short += 1
            self.last_short = (len(angle), expected)
            return None
        scan_time = max(t_next - self._t_first, 0.0)
        if scan_time > 0:
            self.sample_period = scan_time / len(angle)
        return Revolution(self._t_first, scan_time, angle, dist, quality.astype(np.uint8))


def expected_samples(angle_deg: F64) -> float:
    """Samples a whole turn has at this revolution's median angle step (0 when unknown)."""
    steps = np.diff(angle_deg)
    steps = steps[(steps > 0) & (steps < 180)]
    if not len(steps):
        return 0.0
    return 360.0 / float(np.median(steps))


def to_laser_scan(rev: Revolution, geometry: ScanGeometry) -> LaserScan:
    """Convert a revolution into a LaserScan (radians, counter-clockwise, inf = no return)."""
    sign = 1.0 if geometry.inverted else -1.0
    theta = np.deg2rad(geometry.angle_offset_deg + sign * rev.angle_deg)
    theta = np.mod(theta + math.pi, 2 * math.pi) - math.pi
    ranges = np.where(rev.distance_mm > 0, rev.distance_mm / 1000.0, np.inf)
    intensity = rev.quality.astype(np.float64)
    scan = LaserScan(stamp=rev.t, frame_id=geometry.frame_id, scan_time=rev.scan_time,
                     range_min=geometry.range_min, range_max=geometry.range_max)
    if geometry.bins > 0:
        _fill_bins(scan, theta, ranges, intensity, geometry.bins)
    else:
        order = np.argsort(theta, kind="stable")
        theta, scan.ranges = theta[order], ranges[order].astype(np.float32)
        scan.intensities = intensity[order].astype(np.float32)
        scan.angle_min = float(theta[0]) if len(theta) else 0.0
        scan.angle_max = float(theta[-1]) if len(theta) else 0.0
        spread = scan.angle_max - scan.angle_min
        scan.angle_increment = spread / (len(theta) - 1) if len(theta) > 1 else 0.0
    rays = len(scan.ranges)
    scan.time_increment = rev.scan_time / rays if rays else 0.0
    return scan


def _fill_bins(scan: LaserScan, theta: F64, ranges: F64, intensity: F64, bins: int) -> None:
    """Angle compensation: each ray goes to the nearest of ``bins`` fixed angles (the nearest
    return wins when several share one)."""
    step = 2 * math.pi / bins
    index = np.rint((theta + math.pi) / step).astype(np.int64) % bins
    best = np.full(bins, np.inf)
    np.minimum.at(best, index, ranges)
    strength = np.zeros(bins)
    winner = ranges == best[index]
    np.maximum.at(strength, index[winner], intensity[winner])
    scan.angle_min, scan.angle_increment = -math.pi, step
    scan.angle_max = -math.pi + (bins - 1) * step
    scan.ranges, scan.intensities = best.astype(np.float32), strength.astype(np.float32)
