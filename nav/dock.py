# A charging dock shaped as a V: its geometry from the docked pose, and its fit to lidar points.
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

Array = npt.NDArray[np.float64]
Pose2 = tuple[float, float, float]

#: the robot touches the charging contacts within this of the docked pose (m, rad)
CONTACT_M, CONTACT_RAD = 0.03, math.radians(10.0)


@dataclass(frozen=True)
class DockShape:
    """A V of two straight arms ``arm_m`` long, ``opening_deg`` apart, open toward the robot.
    Docked, the robot's round footprint (``radius_m``) stands ``clearance_m`` from each arm,
    facing the apex. A dock's pose is the robot's pose when docked."""

    arm_m: float = 0.30
    opening_deg: float = 120.0
    clearance_m: float = 0.03
    radius_m: float = 0.2

    @property
    def half(self) -> float:
        return math.radians(self.opening_deg) / 2.0

    @property
    def apex_m(self) -> float:
        """From the docked robot's centre to the apex (m)."""
        return (self.radius_m + self.clearance_m) / math.sin(self.half)

    def apex(self, docked: Pose2) -> tuple[float, float]:
        x, y, theta = docked
        return x + self.apex_m * math.cos(theta), y + self.apex_m * math.sin(theta)

    def arms(self, docked: Pose2) -> list[tuple[float, float, float, float]]:
        """The two arms as segments (x1, y1, x2, y2) from the apex outward."""
        ax, ay = self.apex(docked)
        out = docked[2] + math.pi  # from the apex toward the robot
        return [(ax, ay, ax + self.arm_m * math.cos(out + s * self.half),
                 ay + self.arm_m * math.sin(out + s * self.half)) for s in (1.0, -1.0)]

    def docked_from_apex(self, ax: float, ay: float, axis: float) -> Pose2:
        """The docked pose of the V whose apex is (ax, ay), opening along ``axis``."""
        return (ax + self.apex_m * math.cos(axis), ay + self.apex_m * math.sin(axis),
                math.remainder(axis + math.pi, math.tau))

    def staging(self, docked: Pose2, distance: float) -> Pose2:
        """``distance`` straight back from the docked pose, facing the dock."""
        x, y, theta = docked
        return x - distance * math.cos(theta), y - distance * math.sin(theta), theta


@dataclass(frozen=True)
class DockFit:
    """A V found in a scan: the docked pose it implies (in the points' frame), the RMS of
    the points from their arm (m) and the points on each arm."""

    docked: Pose2
    rms_m: float
    points: tuple[int, int]


def _across_fit(px: Array, py: Array, ux: float,
                uy: float) -> tuple[float, float, float, float, float]:
    """The line through points near a line of direction (ux, uy): their offset across it
    regressed on their position along it (the lidar's noise is along its rays, so a total
    least squares fit would lean toward them): centroid, unit direction, RMS residual."""
    along = px * ux + py * uy
    across = py * ux - px * uy
    a0, c0 = float(along.mean()), float(across.mean())
    spread = float(((along - a0) ** 2).sum())
    slope = float(((along - a0) * (across - c0)).sum()) / spread if spread > 0 else 0.0
    residual = across - c0 - slope * (along - a0)
    norm = math.hypot(1.0, slope)
    dx, dy = (ux - slope * uy) / norm, (uy + slope * ux) / norm
    cx, cy = a0 * ux - c0 * uy, a0 * uy + c0 * ux
    return cx, cy, dx, dy, float(np.sqrt(np.mean(residual ** 2))) / norm


def _strongest_line(px: Array, py: Array, heading: float, spread: float,
                    width: float) -> tuple[float, float, int]:
    """The line within ``spread`` of ``heading`` through the most points (a Hough search in
    1° steps, ``width`` wide): its heading, its offset along the normal, its points."""
    best = (heading, 0.0, 0)
    for angle in heading + np.radians(np.arange(-spread, spread + 0.5, 1.0)):
        offsets = np.sort(py * math.cos(angle) - px * math.sin(angle))
        if not len(offsets):
            break
        counts = np.searchsorted(offsets, offsets + width, side="right") - \
            np.arange(len(offsets))
        i = int(counts.argmax())
        if counts[i] > best[2]:
            best = (float(angle), float(offsets[i] + width / 2.0), int(counts[i]))
    return best


def fit_v(px: Array, py: Array, guess: Pose2, shape: DockShape, *, window_m: float = 0.3,
          band_m: float = 0.05, min_points: int = 6) -> DockFit | None:
    """The V near ``guess`` (a docked pose in the points' frame, within ``window_m`` and
    about 15° of the truth), fitted to the points: each arm found as the line through the
    most points near its expected heading, then a total least squares line through the
    points within ``band_m`` of it on the arm's length; the apex where the lines cross, the
    axis their bisector. None when an arm has too few points or the lines do not make the
    shape's opening (within 15°)."""
    keep = np.isfinite(px) & np.isfinite(py)
    px, py = np.asarray(px, dtype=float)[keep], np.asarray(py, dtype=float)[keep]
    ax, ay = shape.apex(guess)
    near = np.hypot(px - ax, py - ay) <= shape.arm_m + window_m
    x, y = px[near], py[near]
    out = guess[2] + math.pi
    found = []
    for side in (1.0, -1.0):
        heading, offset, count = _strongest_line(x, y, out + side * shape.half, 20.0, band_m)
        if count < min_points:
            return None
        found.append((heading, offset))
    (h1, o1), (h2, o2) = found
    # crossing of the lines n_i . p = o_i with n_i = (-sin h_i, cos h_i)
    det = -math.sin(h1) * math.cos(h2) + math.sin(h2) * math.cos(h1)
    if abs(det) < 1e-6:
        return None
    apex_x = (o1 * math.cos(h2) - o2 * math.cos(h1)) / det
    apex_y = (o1 * math.sin(h2) - o2 * math.sin(h1)) / det
    lines, counts = [], []
    # which part of an arm a point is on, from its bearing alone (the lidar's noise is along
    # its rays: a cut on the noisy position near the apex would keep the points the noise
    # pulled one way)
    bearing = np.arctan2(y, x)
    bx, by = np.cos(bearing), np.sin(bearing)
    for heading, offset in found:
        ux, uy = math.cos(heading), math.sin(heading)
        across = np.abs(y * ux - x * uy - offset)
        slant = uy * bx - ux * by
        with np.errstate(divide="ignore", invalid="ignore"):
            part = (apex_x * by - apex_y * bx) / slant
        on = (part > 0.03) & (part < shape.arm_m - 0.01) & (across < band_m)
        if int(on.sum()) < min_points:
            return None
        cx, cy, dx, dy, rms = _across_fit(x[on], y[on], ux, uy)
        lines.append((cx, cy, dx, dy, rms))
        counts.append(int(on.sum()))
    (c1x, c1y, d1x, d1y, r1), (c2x, c2y, d2x, d2y, r2) = lines
    cross = d1x * d2y - d1y * d2x
    angle = math.acos(max(-1.0, min(1.0, d1x * d2x + d1y * d2y)))
    if abs(cross) < 1e-6 or abs(angle - 2 * shape.half) > math.radians(15.0):
        return None
    t = ((c2x - c1x) * d2y - (c2y - c1y) * d2x) / cross
    axis = math.atan2(d1y + d2y, d1x + d2x)
    docked = shape.docked_from_apex(c1x + t * d1x, c1y + t * d1y, axis)
    rms = math.sqrt((r1 * r1 * counts[0] + r2 * r2 * counts[1]) / sum(counts))
    return DockFit(docked, rms, (counts[0], counts[1]))


def in_contact(robot: Pose2, docked: Pose2) -> bool:
    """The robot's contacts touch the dock's (within :data:`CONTACT_M` and
    :data:`CONTACT_RAD` of the docked pose)."""
    return math.hypot(robot[0] - docked[0], robot[1] - docked[1]) <= CONTACT_M and \
        abs(math.remainder(robot[2] - docked[2], math.tau)) <= CONTACT_RAD
