# Scan-to-map matching: correlative search over a pose window, then Gauss-Newton on a distance map.
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from slam.field import SEARCH_PAD, DistanceField
from slam.pose import Pose2, transform_points, wrap


@dataclass(frozen=True)
class SearchWindow:
    """A correlative search: ± ``linear`` m in steps of ``linear_step``, ± ``angular`` rad in
    steps of ``angular_step``, scored with likelihood width ``sigma`` (m)."""

    linear: float
    angular: float
    linear_step: float
    angular_step: float
    sigma: float


@dataclass(frozen=True)
class Match:
    """A matched pose, its score (0..1) and the Gauss-Newton information (3x3) at it."""

    pose: Pose2
    score: float
    information: np.ndarray


def subsample(points: np.ndarray, at_most: int) -> np.ndarray:
    """Every k-th point so that at most ``at_most`` remain."""
    step = max(1, math.ceil(len(points) / at_most))
    return points[::step]


def correlative_search(field: DistanceField, points: np.ndarray, center: Pose2,
                       window: SearchWindow) -> tuple[Pose2, float]:
    """The pose in the window whose points best land on occupied cells (nearest-cell
    likelihood), and its mean likelihood. Translations are whole cells of the field."""
    like = field.likelihood(window.sigma).reshape(-1)
    padded_w, padded_h = field.width + 2 * SEARCH_PAD, field.height + 2 * SEARCH_PAD
    cell_step = max(1, round(window.linear_step / field.resolution))
    reach = min(round(window.linear / (cell_step * field.resolution)),
                SEARCH_PAD // 2 // cell_step)
    most = reach * cell_step  # the largest shift in cells
    offsets = np.arange(-reach, reach + 1) * cell_step
    shifts = (offsets[:, None] * padded_w + offsets[None, :]).reshape(-1)  # (dy, dx) flattened
    turns = round(window.angular / window.angular_step) if window.angular_step > 0 else 0
    # a mild preference for the centre of the window breaks ties on repetitive structure
    spread = ((offsets[:, None] ** 2 + offsets[None, :] ** 2).reshape(-1)
              / max(1, reach * cell_step) ** 2)
    best: tuple[float, Pose2, float] = (-math.inf, center, 0.0)
    for k in range(-turns, turns + 1):
        theta = center[2] + k * window.angular_step
        world = transform_points((center[0], center[1], theta), points)
        col = np.floor((world[:, 0] - field.origin_x) / field.resolution).astype(np.int64)
        row = np.floor((world[:, 1] - field.origin_y) / field.resolution).astype(np.int64)
        col, row = col + SEARCH_PAD, row + SEARCH_PAD
        # points that no shift brings into the field read a cell whose every shift is border
        near = (col >= most) & (col < padded_w - most) & (row >= most) & (row < padded_h - most)
        col, row = np.where(near, col, most), np.where(near, row, most)
        scores = like[(row * padded_w + col)[None, :] + shifts[:, None]].mean(axis=1)
        ranked = scores * (1.0 - 0.05 * (spread + (k / max(1, turns)) ** 2))
        i = int(np.argmax(ranked))
        if ranked[i] > best[0]:
            dy, dx = offsets[i // len(offsets)], offsets[i % len(offsets)]
            best = (float(ranked[i]), (center[0] + dx * field.resolution,
                                       center[1] + dy * field.resolution, wrap(theta)),
                    float(scores[i]))
    return best[1], best[2]


def refine(field: DistanceField, points: np.ndarray, start: Pose2, sigma: float,
           iterations: int = 12, robust_distance: float = 0.1) -> Match:
    """Gauss-Newton on the squared distances of the points to the nearest occupied cell,
    with Huber weights past ``robust_distance``; points at the field's truncation count 0."""
    x, y, theta = start
    information = np.zeros((3, 3))
    for _ in range(iterations):
        c, s = math.cos(theta), math.sin(theta)
        world = transform_points((x, y, theta), points)
        d, gx, gy = field.lookup(world)
        used = d < field.max_distance * 0.99
        weight = np.where(d > robust_distance, robust_distance / np.maximum(d, 1e-9), 1.0) * used
        jac = np.column_stack([gx, gy, gx * (-s * points[:, 0] - c * points[:, 1])
                               + gy * (c * points[:, 0] - s * points[:, 1])])
        information = (jac * weight[:, None]).T @ jac
        gradient = (jac * weight[:, None]).T @ d
        if np.count_nonzero(used) < 6:
            break
        step = np.linalg.solve(information + np.diag([1e-6, 1e-6, 1e-6]), -gradient)
        x, y, theta = x + step[0], y + step[1], wrap(theta + step[2])
        if abs(step[0]) + abs(step[1]) < 1e-4 and abs(step[2]) < 1e-4:
            break
    pose = (float(x), float(y), float(theta))
    return Match(pose, field.score(transform_points(pose, points), sigma), information)


def match(field: DistanceField, points: np.ndarray, prior: Pose2,
          windows: tuple[SearchWindow, ...], sigma: float, search_points: int = 90) -> Match:
    """Coarse-to-fine correlative searches (each centred on the last's best) then refinement;
    the refined pose is kept only if it scores at least as well as the search's."""
    sparse = subsample(points, search_points)
    center = prior
    for window in windows:
        center, _ = correlative_search(field, sparse, center, window)
    refined = refine(field, points, center, sigma)
    searched = field.score(transform_points(center, points), sigma)
    if refined.score + 1e-9 >= searched:
        return refined
    return Match(center, searched, refined.information)
