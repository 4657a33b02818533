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
                       window: SearchWindow, prior: Pose2 | None = None,
                       penalty: float = 0.05,
                       prior_sigmas: tuple[float, float] | None = None) -> tuple[Pose2, float]:
    """The pose in the window whose points best land on occupied cells (nearest-cell
    likelihood), and its mean likelihood. Translations are whole cells of the field.

    Candidates are ranked by their likelihood times 1 - ``penalty`` x (their squared offset
    from the centre in units of the window's half-widths), as Karto does: on weak or
    repetitive structure the pose nearest the centre wins. With
    ``prior_sigmas`` (m, rad: how far the prediction is typically off) the likelihood is also
    divided by 1 + m²/4, m the Mahalanobis offset from ``prior`` (a heavy-tailed prior: a
    correction the scan clearly supports still wins)."""
    prior = center if prior is None else prior
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
    half = max(1, reach * cell_step)
    spread = (offsets[:, None] ** 2 + offsets[None, :] ** 2).reshape(-1) / half ** 2
    # the offset of every shift from the prior (m²)
    ox, oy = center[0] - prior[0], center[1] - prior[1]
    offset_sq = (((offsets[:, None] * field.resolution + oy) ** 2
                  + (offsets[None, :] * field.resolution + ox) ** 2).reshape(-1))
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
        ranked = scores * (1.0 - penalty * (spread + (k / max(1, turns)) ** 2))
        if prior_sigmas is not None:
            mahalanobis = (offset_sq / prior_sigmas[0] ** 2
                           + (wrap(theta - prior[2]) / prior_sigmas[1]) ** 2)
            ranked = ranked / (1.0 + mahalanobis / 4.0)
        i = int(np.argmax(ranked))
        if ranked[i] > best[0]:
            dy, dx = offsets[i // len(offsets)], offsets[i % len(offsets)]
            best = (float(ranked[i]), (center[0] + dx * field.resolution,
                                       center[1] + dy * field.resolution, wrap(theta)),
                    float(scores[i]))
    return best[1], best[2]


def refine(field: DistanceField, points: np.ndarray, start: Pose2, sigma: float,
           iterations: int = 12, robust_distance: float = 0.1, prior: Pose2 | None = None,
           prior_weights: tuple[float, float] = (0.0, 0.0)) -> Match:
    """Gauss-Newton on the mean squared distance of the points to the nearest occupied cell,
    with Huber weights past ``robust_distance`` (points at the field's truncation count 0),
    plus ``prior_weights`` (per m², per rad²) x the squared offset from ``prior`` (the
    odometry prediction, as Cartographer's translation and rotation weights): along a
    corridor, or wherever the scan says little, the pose stays with the prediction."""
    x, y, theta = start
    information = np.zeros((3, 3))
    px, py, pt = start if prior is None else prior
    lam = np.array([prior_weights[0], prior_weights[0], prior_weights[1]])
    for _ in range(iterations):
        c, s = math.cos(theta), math.sin(theta)
        world = transform_points((x, y, theta), points)
        d, gx, gy = field.lookup(world)
        used = d < field.max_distance * 0.99
        weight = np.where(d > robust_distance, robust_distance / np.maximum(d, 1e-9), 1.0) * used
        jac = np.column_stack([gx, gy, gx * (-s * points[:, 0] - c * points[:, 1])
                               + gy * (c * points[:, 0] - s * points[:, 1])])
        count = np.count_nonzero(used)
        if count < 6:
            break
        information = (jac * weight[:, None]).T @ jac
        gradient = (jac * weight[:, None]).T @ d
        if lam.any():  # the prior, in the units of the mean over the points
            offset = np.array([x - px, y - py, wrap(theta - pt)])
            information = information + np.diag(lam * count)
            gradient = gradient + lam * count * offset
        step = np.linalg.solve(information + np.diag([1e-6, 1e-6, 1e-6]), -gradient)
        x, y, theta = x + step[0], y + step[1], wrap(theta + step[2])
        if abs(step[0]) + abs(step[1]) < 1e-4 and abs(step[2]) < 1e-4:
            break
    pose = (float(x), float(y), float(theta))
    return Match(pose, field.score(transform_points(pose, points), sigma), information)


def match(field: DistanceField, points: np.ndarray, prior: Pose2,
          windows: tuple[SearchWindow, ...], sigma: float, search_points: int = 90,
          penalty: float = 0.05, prior_weights: tuple[float, float] = (0.0, 0.0),
          tolerance: float = 0.0, prior_sigmas: tuple[float, float] | None = None,
          bounded: bool = False) -> Match:
    """Coarse-to-fine correlative searches (each centred on the last's best, ranked with
    ``penalty`` towards ``prior``) then refinement (``prior_weights``); the refined pose is
    kept if it scores at least as well as the search's, less ``tolerance`` (and, ``bounded``,
    if it stayed inside the first window)."""
    sparse = subsample(points, search_points)
    center = prior
    for window in windows:
        center, _ = correlative_search(field, sparse, center, window, prior, penalty,
                                       prior_sigmas)
    refined = refine(field, points, center, sigma, prior=prior, prior_weights=prior_weights)
    searched = field.score(transform_points(center, points), sigma)
    # bounded: a refinement that leaves the first window slid into another basin (Gauss-Newton
    # is unbounded), the pose searched for is not there
    outer = windows[0] if windows else None
    moved = (math.hypot(refined.pose[0] - prior[0], refined.pose[1] - prior[1]),
             abs(wrap(refined.pose[2] - prior[2])))
    near = not bounded or outer is None or (moved[0] <= outer.linear * math.sqrt(2)
                                            and moved[1] <= outer.angular)
    if near and refined.score + 1e-9 + tolerance >= searched:
        return refined
    return Match(center, searched, refined.information)
