# Per-scan poses fused with the odometry between them: a chain least squares, noise from the data.
from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from slam.graph import edge_errors
from slam.pose import Pose2, between, wrap

#: lower bound of a learnt standard deviation (m or rad): keeps the system well conditioned
SIGMA_FLOOR = 1e-6


def lag_residuals(poses: Sequence[Pose2], odometry: Sequence[Pose2], lag: int) -> np.ndarray:
    """(x, y, θ) of the odometry's motion over ``lag`` scans seen from the poses' motion."""
    out = np.empty((max(0, len(poses) - lag), 3))
    for i in range(len(out)):
        d = between(between(odometry[i], odometry[i + lag]), between(poses[i], poses[i + lag]))
        out[i] = (d[0], d[1], wrap(d[2]))
    return out


def robust_variance(residuals: np.ndarray) -> np.ndarray:
    """Per column, the mean square about zero that the median absolute value implies (normal
    noise): not about the median, so that a bias (odometry over-reading every motion) counts
    as error, growing with the lag faster than a random walk."""
    if len(residuals) == 0:
        return np.zeros(residuals.shape[1])
    return np.asarray((1.4826 * np.median(np.abs(residuals), axis=0)) ** 2)


def learn_noise(poses: Sequence[Pose2], odometry: Sequence[Pose2],
                long_lag: int = 4) -> tuple[np.ndarray, np.ndarray]:
    """(standard deviation of a pose, of one step of odometry), per component (x, y, θ),
    learnt from how the poses' motion and the odometry's disagree over 1 and ``long_lag``
    scans: independent pose errors add 2 sd_pose² to every lag, odometry's random walk
    sd_step² a scan, so v(k) = k sd_step² + 2 sd_pose². Where odometry's error grows faster
    than a random walk's (a bias, or MIT CSAIL's odometry), sd_pose comes out at the floor and
    the poses stay as they are. An odometry error that does not add up over the scans (stamp
    jitter) is taken for pose noise: the model cannot tell the two apart."""
    short = robust_variance(lag_residuals(poses, odometry, 1))
    long = robust_variance(lag_residuals(poses, odometry, long_lag))
    step = np.maximum((long - short) / (long_lag - 1), SIGMA_FLOOR ** 2)
    pose = np.maximum((short - step) / 2, SIGMA_FLOOR ** 2)
    return np.sqrt(pose), np.sqrt(step)


def smooth(poses: Sequence[Pose2], odometry: Sequence[Pose2], pose_sigma: np.ndarray,
           step_sigma: np.ndarray, iterations: int = 10, robust_scale: float = 3.0) -> list[Pose2]:
    """The poses that best fit both ``poses`` (each with the standard deviations
    ``pose_sigma`` in its own frame) and the odometry's motion between consecutive scans
    (``step_sigma``, Cauchy-weighted at ``robust_scale`` so that a wheel slip does not pull
    the poses): Gauss-Newton on the chain's block-tridiagonal normal equations."""
    from scipy import sparse  # here, not at import: the daemon starts without scipy
    from scipy.sparse.linalg import spsolve

    n = len(poses)
    if n < 2:
        return list(poses)
    z = np.asarray(poses, dtype=np.float64)
    steps = np.asarray([between(odometry[i], odometry[i + 1]) for i in range(n - 1)])
    x = z.copy()
    pose_info = 1.0 / np.asarray(pose_sigma, dtype=np.float64) ** 2
    step_info = 1.0 / np.asarray(step_sigma, dtype=np.float64) ** 2
    idx_i, idx_j = np.arange(n - 1), np.arange(1, n)
    r3, c3 = np.meshgrid(np.arange(3), np.arange(3), indexing="ij")
    c, s = np.cos(z[:, 2]), np.sin(z[:, 2])
    rot = np.stack([np.stack([c, -s], 1), np.stack([s, c], 1)], 1)  # R(z), (n, 2, 2)
    # the pose terms' information in world axes: R diag(λx, λy) Rᵀ, and λθ
    unary = np.zeros((n, 3, 3))
    unary[:, :2, :2] = np.einsum("nab,b,ncb->nac", rot, pose_info[:2], rot)
    unary[:, 2, 2] = pose_info[2]
    for _ in range(iterations):
        err, jac_i, jac_j = edge_errors(x, idx_i, idx_j, steps)
        chi = np.einsum("ek,k,ek->e", err, step_info, err)
        info = step_info[None, :] * (1.0 / (1.0 + chi / robust_scale ** 2))[:, None]
        residual = x - z
        residual[:, 2] = np.remainder(residual[:, 2] + np.pi, 2 * np.pi) - np.pi
        rhs = np.einsum("nab,nb->na", unary, residual)
        rows, cols, vals = [(np.arange(n)[:, None, None] * 3 + r3).reshape(-1)], \
            [(np.arange(n)[:, None, None] * 3 + c3).reshape(-1)], [unary.reshape(-1)]
        weighted = err * info
        ends = (idx_i, idx_j)
        jacs = (jac_i, jac_j)
        for a in (0, 1):
            np.add.at(rhs, ends[a], np.einsum("eki,ek->ei", jacs[a], weighted))
            for b in (0, 1):
                block = np.einsum("eki,ek,ekj->eij", jacs[a], info, jacs[b])
                rows.append((ends[a][:, None, None] * 3 + r3).reshape(-1))
                cols.append((ends[b][:, None, None] * 3 + c3).reshape(-1))
                vals.append(block.reshape(-1))
        hessian = sparse.coo_matrix((np.concatenate(vals), (np.concatenate(rows),
                                     np.concatenate(cols))), shape=(3 * n, 3 * n)).tocsc()
        step = np.asarray(spsolve(hessian, -rhs.reshape(-1))).reshape(n, 3)
        x += step
        x[:, 2] = np.remainder(x[:, 2] + np.pi, 2 * np.pi) - np.pi
        if np.abs(step).max() < 1e-7:
            break
    return [(float(a), float(b), float(t)) for a, b, t in x]
