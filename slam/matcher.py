# Scan-to-map matching: correlative search over a pose window, then Gauss-Newton on a distance map.
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from slam.field import SEARCH_PAD, DistanceField
from slam.pose import Pose2, transform_points, wrap

GATHER_BLOCK = 1 << 18  # cells one correlative gather reads at most (2 MB of indices)


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
    # every rotation at once: (turns, points) cells, then (turns, shifts) scores
    ks = np.arange(-turns, turns + 1)
    thetas = center[2] + ks * window.angular_step
    cos, sin = np.cos(thetas)[:, None], np.sin(thetas)[:, None]
    px, py = points[None, :, 0], points[None, :, 1]
    inv = 1.0 / field.resolution
    col = np.floor((px * cos - py * sin + (center[0] - field.origin_x)) * inv).astype(np.intp)
    row = np.floor((px * sin + py * cos + (center[1] - field.origin_y)) * inv).astype(np.intp)
    col += SEARCH_PAD
    row += SEARCH_PAD
    # points that no shift brings into the field read a cell whose every shift is border
    near = (col >= most) & (col < padded_w - most) & (row >= most) & (row < padded_h - most)
    base = np.where(near, row * padded_w + col, most * padded_w + most)
    # in blocks of rotations, so a wide search (a loop closure's 25 x 1681 x 90) never holds
    # more than GATHER_BLOCK indices at once
    scores = np.empty((len(ks), len(shifts)), dtype=like.dtype)
    per = max(1, GATHER_BLOCK // (len(shifts) * max(1, len(points))))
    for first in range(0, len(ks), per):
        block = base[first:first + per]
        scores[first:first + per] = like[block[:, None, :] + shifts[None, :, None]].mean(axis=2)
    ranked = scores * (1.0 - penalty * (spread[None, :]
                                        + ((ks / max(1, turns)) ** 2)[:, None]))
    if prior_sigmas is not None:
        ox, oy = center[0] - prior[0], center[1] - prior[1]
        offset_sq = (((offsets[:, None] * field.resolution + oy) ** 2
                      + (offsets[None, :] * field.resolution + ox) ** 2).reshape(-1))
        turn_sq = np.array([wrap(float(t) - prior[2]) for t in thetas]) ** 2
        mahalanobis = (offset_sq[None, :] / prior_sigmas[0] ** 2
                       + turn_sq[:, None] / prior_sigmas[1] ** 2)
        ranked = ranked / (1.0 + mahalanobis / 4.0)
    # the first maximum: the lowest rotation, then the first shift, among equals
    best = int(np.argmax(ranked))
    k, i = divmod(best, len(shifts))
    dy, dx = offsets[i // len(offsets)], offsets[i % len(offsets)]
    pose = (center[0] + dx * field.resolution, center[1] + dy * field.resolution,
            wrap(center[2] + int(ks[k]) * window.angular_step))
    return pose, float(scores[k, i])


def refine(field: DistanceField, points: np.ndarray, start: Pose2, sigma: float,
           iterations: int = 12, robust_distance: float = 0.1, prior: Pose2 | None = None,
           prior_weights: tuple[float, float] = (0.0, 0.0)) -> Match:
    """Gauss-Newton on the mean squared distance of the points to the nearest occupied cell,
    with Huber weights past ``robust_distance`` (points at the field's truncation count 0),
    plus ``prior_weights`` (per m², per rad²) x the squared offset from ``prior`` (the
    odometry prediction, as Cartographer's translation and rotation weights): along a
    corridor, or wherever the scan says little, the pose stays with the prediction.

    On this field Gauss-Newton often overshoots and then swings between two poses (the
    bilinear valleys at the walls are flatter than the V of a true distance); once a pose
    comes back to within the stopping threshold (1e-4 m / rad) of the pose two steps
    before, the remaining iterations are not run: their end is the member of the cycle the
    iteration count lands on."""
    return _refine(field, points, start, sigma, iterations, robust_distance, prior,
                   prior_weights)[0]


def _refine(field: DistanceField, points: np.ndarray, start: Pose2, sigma: float,
            iterations: int = 12, robust_distance: float = 0.1, prior: Pose2 | None = None,
            prior_weights: tuple[float, float] = (0.0, 0.0)) -> tuple[Match, float]:
    """``refine``, and the score at ``start``."""
    x, y, theta = start
    information = np.zeros((3, 3))
    px, py, pt = start if prior is None else prior
    lam = np.array([prior_weights[0], prior_weights[0], prior_weights[1]])
    # the points in cells (2, N); the field's gradient is per cell, so the Jacobian in
    # cells is scaled back to metres in the 3x3 products
    inv = 1.0 / field.resolution
    cells = np.ascontiguousarray(np.asarray(points, dtype=np.float64).T) * inv
    to_metres = np.array([inv, inv, 1.0])
    outer = np.outer(to_metres, to_metres)
    base_u, base_v = 0.5 - field.origin_x * inv, 0.5 - field.origin_y * inv
    cutoff = field.max_distance * 0.99
    jac = np.empty((3, cells.shape[1]))
    ridge = np.diag([1e-6, 1e-6, 1e-6])
    start_score = math.nan
    # per step: the pose it reached and the information it was linearised with
    trail: list[tuple[float, float, float, np.ndarray]] = []
    for i in range(iterations):
        c, s = math.cos(theta), math.sin(theta)
        # the points rotated (cells); also the lever arm of the angle's derivative
        rotated = np.array([[c, -s], [s, c]]) @ cells
        d, grad = field.lookup_cells(rotated + np.array([[x * inv + base_u],
                                                         [y * inv + base_v]]))
        assert grad is not None
        if i == 0:
            start_score = _score(d, sigma)
        used = d < cutoff
        count = int(np.count_nonzero(used))
        if count < 6:
            break
        # Huber: 1 up to robust_distance, robust_distance / d past it; 0 at the truncation
        weight = robust_distance / np.maximum(d, robust_distance)
        weight *= used
        jac[:2] = grad
        np.multiply(grad[1], rotated[0], out=jac[2])
        jac[2] -= grad[0] * rotated[1]
        weighted = jac * weight
        information = (weighted @ jac.T) * outer
        gradient = (weighted @ d) * to_metres
        if lam.any():  # the prior, in the units of the mean over the points
            offset = np.array([x - px, y - py, wrap(theta - pt)])
            information = information + np.diag(lam * count)
            gradient = gradient + lam * count * offset
        sx, sy, st = _solve3(information + ridge, gradient)
        x, y, theta = x - sx, y - sy, wrap(theta - st)
        if abs(sx) + abs(sy) < 1e-4 and abs(st) < 1e-4:
            break
        trail.append((x, y, theta, information))
        if len(trail) >= 3:
            bx, by, bt, _ = trail[-3]
            if abs(x - bx) + abs(y - by) < 1e-4 and abs(wrap(theta - bt)) < 1e-4:
                # a two-cycle: the remaining steps alternate between the last two poses
                if (iterations - i - 1) % 2 == 1:
                    x, y, theta, information = trail[-2]
                break
    pose = (float(x), float(y), float(theta))
    if math.isnan(start_score):
        start_score = field.score(transform_points(start, points), sigma)
    return Match(pose, field.score(transform_points(pose, points), sigma), information), \
        start_score


def _solve3(a: np.ndarray, b: np.ndarray) -> tuple[float, float, float]:
    """x with a x = b for a symmetric 3x3 ``a`` (Cramer's rule on Python floats: a tenth of
    np.linalg.solve's call overhead at this size)."""
    (a00, a01, a02), (_, a11, a12), (_, _, a22) = a.tolist()
    b0, b1, b2 = b.tolist()
    c00 = a11 * a22 - a12 * a12
    c01 = a02 * a12 - a01 * a22
    c02 = a01 * a12 - a02 * a11
    det = a00 * c00 + a01 * c01 + a02 * c02
    if det == 0.0 or not math.isfinite(det):
        x = np.linalg.lstsq(a, b, rcond=None)[0]
        return float(x[0]), float(x[1]), float(x[2])
    c11 = a00 * a22 - a02 * a02
    c12 = a01 * a02 - a00 * a12
    c22 = a00 * a11 - a01 * a01
    return ((c00 * b0 + c01 * b1 + c02 * b2) / det, (c01 * b0 + c11 * b1 + c12 * b2) / det,
            (c02 * b0 + c12 * b1 + c22 * b2) / det)


def _score(d: np.ndarray, sigma: float) -> float:
    """DistanceField.score from the points' bilinear distances."""
    if len(d) == 0:
        return 0.0
    return float(np.mean(np.exp(d * d * (-1.0 / (2 * sigma * sigma)))))


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
    refined, searched = _refine(field, points, center, sigma, prior=prior,
                                prior_weights=prior_weights)
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


def _huber_cost(d: np.ndarray, robust_distance: float, cutoff: float) -> float:
    """Sum of Huber losses of the distances below ``cutoff`` (the field's truncation)."""
    used = d[d < cutoff]
    quad = np.minimum(used, robust_distance)
    return float(np.sum(quad * (used - 0.5 * quad)))


def polish(field: DistanceField, points: np.ndarray, start: Pose2, iterations: int = 8,
           robust_distance: float = 0.1, tolerance: float = 1e-4,
           damping: float = 0.1) -> Pose2:
    """Levenberg-Marquardt on the Huber loss of the points' bilinear distances from ``start``:
    a step is taken only if it lowers the loss (else the damping grows), so it converges to
    the local minimum rather than swinging between two poses as plain Gauss-Newton does on
    this field (``damping``: the starting Marquardt factor, x0.1 after a step taken, x10
    after one refused). Slower than ``refine``; meant for an offline pass."""
    inv = 1.0 / field.resolution
    cells = np.ascontiguousarray(np.asarray(points, dtype=np.float64).T) * inv
    base = np.array([[0.5 - field.origin_x * inv], [0.5 - field.origin_y * inv]])
    cutoff = field.max_distance * 0.99
    to_metres = np.array([inv, inv, 1.0])
    outer = np.outer(to_metres, to_metres)

    def evaluate(pose: Pose2, gradient: bool) -> tuple[float, np.ndarray, np.ndarray | None,
                                                      np.ndarray | None]:
        c, s = math.cos(pose[2]), math.sin(pose[2])
        rotated = np.array([[c, -s], [s, c]]) @ cells
        d, grad = field.lookup_cells(rotated + base + np.array([[pose[0] * inv],
                                                               [pose[1] * inv]]), gradient)
        return _huber_cost(d, robust_distance, cutoff), d, grad, rotated

    pose = start
    cost, d, grad, rotated = evaluate(pose, True)
    for _ in range(iterations):
        assert grad is not None and rotated is not None
        used = d < cutoff
        if int(np.count_nonzero(used)) < 6:
            break
        weight = robust_distance / np.maximum(d, robust_distance) * used
        jac = np.empty((3, d.size))
        jac[:2] = grad
        jac[2] = grad[1] * rotated[0] - grad[0] * rotated[1]
        weighted = jac * weight
        hessian = (weighted @ jac.T) * outer
        gradient = (weighted @ d) * to_metres
        while True:
            damped = hessian + damping * np.diag(np.diag(hessian) + 1e-9)
            sx, sy, st = _solve3(damped, gradient)
            trial = (pose[0] - sx, pose[1] - sy, wrap(pose[2] - st))
            trial_cost, trial_d, trial_grad, trial_rot = evaluate(trial, True)
            if trial_cost <= cost:
                break
            damping *= 10.0
            if damping > 1e6:
                return pose
        pose, cost, d, grad, rotated = trial, trial_cost, trial_d, trial_grad, trial_rot
        damping = max(damping / 10.0, 1e-6)
        if abs(sx) + abs(sy) < tolerance and abs(st) < tolerance:
            break
    return pose
