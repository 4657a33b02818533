# SE(2) pose graph and its sparse Gauss-Newton optimisation (node 0 anchored).
from __future__ import annotations

import numpy as np

from slam.pose import Pose2


class PoseGraph:
    """Nodes are poses; an edge (i, j, z) says node j seen from node i is z, with a diagonal
    information (1/σ² for x, y, theta). Robust edges (loop closures) get Cauchy weights."""

    def __init__(self) -> None:
        self.poses = np.zeros((0, 3))
        self._edges: list[tuple[int, int, Pose2, tuple[float, float, float], bool]] = []

    def add_node(self, pose: Pose2) -> int:
        self.poses = np.vstack([self.poses, np.asarray(pose, dtype=np.float64)[None, :]])
        return len(self.poses) - 1

    def add_edge(self, i: int, j: int, z: Pose2, sigmas: tuple[float, float, float],
                 robust: bool = False) -> None:
        info = (1 / sigmas[0] ** 2, 1 / sigmas[1] ** 2, 1 / sigmas[2] ** 2)
        self._edges.append((i, j, z, info, robust))

    @property
    def node_count(self) -> int:
        return len(self.poses)

    @property
    def edge_count(self) -> int:
        return len(self._edges)

    def pose(self, i: int) -> Pose2:
        x, y, t = self.poses[i]
        return (float(x), float(y), float(t))

    def truncate(self, count: int) -> None:
        """Keep only the first ``count`` edges (undo later additions)."""
        del self._edges[count:]

    def drop_robust_outliers(self, distance: float, angle: float) -> int:
        """Remove the robust edges (loop closures) that the optimised poses disagree with by
        more than ``distance`` m or ``angle`` rad; returns how many went."""
        keep = []
        for edge in self._edges:
            i, j, z, _, robust = edge
            if robust:
                err, _, _ = edge_errors(self.poses, np.array([i]), np.array([j]),
                                        np.array([z], dtype=np.float64))
                if float(np.hypot(err[0, 0], err[0, 1])) > distance or \
                        abs(float(err[0, 2])) > angle:
                    continue
            keep.append(edge)
        dropped = len(self._edges) - len(keep)
        self._edges = keep
        return dropped

    def optimize(self, iterations: int = 10, robust_scale: float = 3.0) -> float:
        """Gauss-Newton until the update is tiny; returns the final weighted squared error."""
        if not self._edges or len(self.poses) < 2:
            return 0.0
        idx_i = np.array([e[0] for e in self._edges])
        idx_j = np.array([e[1] for e in self._edges])
        z = np.array([e[2] for e in self._edges], dtype=np.float64)
        info = np.array([e[3] for e in self._edges], dtype=np.float64)
        robust = np.array([e[4] for e in self._edges])
        chi2 = 0.0
        for _ in range(iterations):
            err, jac_i, jac_j = edge_errors(self.poses, idx_i, idx_j, z)
            chi = np.einsum("ek,ek,ek->e", err, info, err)
            weight = np.where(robust, 1.0 / (1.0 + chi / robust_scale ** 2), 1.0)
            chi2 = float(np.sum(weight * chi))
            step = self._solve(idx_i, idx_j, err, jac_i, jac_j, info * weight[:, None])
            self.poses += step.reshape(-1, 3)
            self.poses[:, 2] = np.remainder(self.poses[:, 2] + np.pi, 2 * np.pi) - np.pi
            if np.abs(step).max() < 1e-5:
                break
        return chi2

    def _solve(self, idx_i: np.ndarray, idx_j: np.ndarray, err: np.ndarray,
               jac_i: np.ndarray, jac_j: np.ndarray, info: np.ndarray) -> np.ndarray:
        n = len(self.poses) * 3
        omega_i = jac_i * info[:, :, None]  # Ω J (diagonal Ω), shape (E, 3, 3)
        omega_j = jac_j * info[:, :, None]
        blocks = {
            (0, 0): np.einsum("eki,ekj->eij", jac_i, omega_i),
            (0, 1): np.einsum("eki,ekj->eij", jac_i, omega_j),
            (1, 0): np.einsum("eki,ekj->eij", jac_j, omega_i),
            (1, 1): np.einsum("eki,ekj->eij", jac_j, omega_j),
        }
        ends = (idx_i, idx_j)
        rows, cols, vals = [], [], []
        r3, c3 = np.meshgrid(np.arange(3), np.arange(3), indexing="ij")
        for (a, b), block in blocks.items():
            rows.append((ends[a][:, None, None] * 3 + r3).reshape(-1))
            cols.append((ends[b][:, None, None] * 3 + c3).reshape(-1))
            vals.append(block.reshape(-1))
        rows.append(np.arange(3))  # anchor node 0
        cols.append(np.arange(3))
        vals.append(np.full(3, 1e12))
        from scipy import sparse  # here, not at import: the daemon starts without scipy
        from scipy.sparse.linalg import spsolve

        hessian = sparse.coo_matrix((np.concatenate(vals), (np.concatenate(rows),
                                     np.concatenate(cols))), shape=(n, n)).tocsc()
        rhs = np.zeros(n)
        weighted = err * info
        np.add.at(rhs, (idx_i[:, None] * 3 + np.arange(3)).reshape(-1),
                  np.einsum("eki,ek->ei", jac_i, weighted).reshape(-1))
        np.add.at(rhs, (idx_j[:, None] * 3 + np.arange(3)).reshape(-1),
                  np.einsum("eki,ek->ei", jac_j, weighted).reshape(-1))
        return np.asarray(spsolve(hessian, -rhs))


def edge_errors(poses: np.ndarray, idx_i: np.ndarray, idx_j: np.ndarray,
                z: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Errors e = z⁻¹·(xi⁻¹·xj) as (dx, dy, dtheta) per edge, and de/dxi, de/dxj (E, 3, 3)."""
    xi, xj = poses[idx_i], poses[idx_j]
    ci, si = np.cos(xi[:, 2]), np.sin(xi[:, 2])
    cz, sz = np.cos(z[:, 2]), np.sin(z[:, 2])
    dx, dy = xj[:, 0] - xi[:, 0], xj[:, 1] - xi[:, 1]
    lx, ly = ci * dx + si * dy, -si * dx + ci * dy  # xj's position in xi's frame
    ex, ey = lx - z[:, 0], ly - z[:, 1]
    err = np.column_stack([cz * ex + sz * ey, -sz * ex + cz * ey,
                           np.remainder(xj[:, 2] - xi[:, 2] - z[:, 2] + np.pi, 2 * np.pi) - np.pi])
    count = len(idx_i)
    rz = np.stack([np.stack([cz, sz], 1), np.stack([-sz, cz], 1)], 1)  # Rz^T, (E, 2, 2)
    ri = np.stack([np.stack([ci, si], 1), np.stack([-si, ci], 1)], 1)  # Ri^T
    dri = np.stack([np.stack([-si, ci], 1), np.stack([-ci, -si], 1)], 1)  # d(Ri^T)/dθi
    rzri = np.einsum("eab,ebc->eac", rz, ri)
    jac_i = np.zeros((count, 3, 3))
    jac_j = np.zeros((count, 3, 3))
    jac_i[:, :2, :2] = -rzri
    jac_i[:, :2, 2] = np.einsum("eab,ebc,ec->ea", rz, dri, np.column_stack([dx, dy]))
    jac_i[:, 2, 2] = -1.0
    jac_j[:, :2, :2] = rzri
    jac_j[:, 2, 2] = 1.0
    return err, jac_i, jac_j
