"""The pose graph of one topology: SE(2) odometry residuals, topology ties, Laplace fit.

Implements the energy of SPEC §3.3 (paper eq. 3, 13) and step 1 of its
evaluation, the Laplace approximation. The variables are the poses
p_i = (x_i, y_i, theta_i) of detections 1..N-1 flattened into one vector of
d = 3(N-1) numbers; pose 0 is fixed at the origin (the gauge). For a
partition T,

    E(P) = 1/2 sum_k r_k(P)^T Sigma_k^-1 r_k(P)  +  1/2 sum_{S in T} sum_{i<j in S} |t_i - t_j|^2 / sigma_T^2
    r_k  = (p_{k-1}^-1 o p_k) - o_k     (translation in the frame of p_{k-1}, angle wrapped)

The residual is the relative pose expressed in the frame of the earlier
detection minus the measured odometry row, so ``odometry_cov`` (given in that
same frame) whitens it directly. The topology term is exactly quadratic in the
positions: its Hessian is the graph Laplacian of the cliques of T divided by
sigma_T^2, built once per partition. The minimiser P* is found by
Gauss-Newton with Levenberg-Marquardt damping and analytic Jacobians; the
Gauss-Newton Hessian H = J^T W J (+ topology Laplacian) at P* is factorised
densely (Cholesky) or sparsely (SuperLU with a symmetric ordering and diagonal
pivots, i.e. an L D L^T factorisation) depending on d.

    >>> graph = PoseGraph(odometry, odometry_sqrt_information(covariances), sigma_topology=0.3)
    >>> fit = graph.fit(graph.dead_reckoning(), labels=(0, 1, 2, 0))
    >>> fit.energy, fit.factor.log_det()
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import scipy.linalg
import scipy.sparse
import scipy.sparse.linalg

from .dataset import wrap_angle

__all__ = [
    "PoseGraph",
    "LaplaceFit",
    "odometry_sqrt_information",
    "odometry_residuals",
    "odometry_jacobian_blocks",
    "poses_from_vector",
    "clique_pair_energy",
]

#: Above this many variables the Hessian is factorised with sparse linear algebra.
SPARSE_ABOVE_DIMENSION = 450


def odometry_sqrt_information(covariances) -> np.ndarray:
    """Per-step whitening matrices U_k with U_k^T U_k = Sigma_k^-1 (shape (N-1, 3, 3)).

    Raises ``ValueError`` naming the step when a covariance is not symmetric
    positive definite (its Cholesky factorisation fails).
    """
    covariances = np.asarray(covariances, dtype=float)
    if covariances.ndim != 3 or covariances.shape[1:] != (3, 3):
        raise ValueError(f"odometry_cov must have shape (N-1, 3, 3), got {covariances.shape}")
    if not np.all(np.isfinite(covariances)):
        raise ValueError("odometry_cov contains non-finite values")
    if not np.allclose(covariances, np.swapaxes(covariances, 1, 2), rtol=1e-9, atol=1e-12):
        raise ValueError("odometry_cov is not symmetric")
    try:
        lower = np.linalg.cholesky(covariances)
    except np.linalg.LinAlgError:
        eigenvalues = np.linalg.eigvalsh(covariances).min(axis=1)
        step = int(np.argmin(eigenvalues))
        raise ValueError(
            f"odometry_cov[{step}] is not positive definite (smallest eigenvalue {eigenvalues[step]:.3g})"
        ) from None
    identity = np.broadcast_to(np.eye(3), covariances.shape)
    return np.linalg.solve(lower, identity)  # U_k = L_k^-1, so U_k^T U_k = Sigma_k^-1


def poses_from_vector(x) -> np.ndarray:
    """Prepend the fixed origin pose: (..., 3(N-1)) state vectors -> (..., N, 3) poses."""
    x = np.asarray(x, dtype=float)
    poses = x.reshape(*x.shape[:-1], -1, 3)
    origin = np.zeros((*x.shape[:-1], 1, 3))
    return np.concatenate([origin, poses], axis=-2)


def odometry_residuals(poses, odometry) -> np.ndarray:
    """r_k = (p_{k-1}^-1 o p_k) - o_k for poses of shape (..., N, 3); returns (..., N-1, 3)."""
    previous, current = poses[..., :-1, :], poses[..., 1:, :]
    cos, sin = np.cos(previous[..., 2]), np.sin(previous[..., 2])
    dx = current[..., 0] - previous[..., 0]
    dy = current[..., 1] - previous[..., 1]
    residuals = np.empty(np.broadcast_shapes(current.shape, np.shape(odometry)))
    residuals[..., 0] = cos * dx + sin * dy - odometry[:, 0]
    residuals[..., 1] = -sin * dx + cos * dy - odometry[:, 1]
    residuals[..., 2] = wrap_angle(current[..., 2] - previous[..., 2] - odometry[:, 2])
    return residuals


def odometry_jacobian_blocks(poses) -> tuple[np.ndarray, np.ndarray]:
    """Analytic Jacobians of r_k with respect to p_{k-1} and p_k, each of shape (N-1, 3, 3).

    With R the rotation of p_{k-1} and delta = t_k - t_{k-1} expressed in its
    frame as (u, v): d(u, v)/d t_k = R^T, d(u, v)/d t_{k-1} = -R^T,
    d(u, v)/d theta_{k-1} = (v, -u), and the angle residual has slopes +1 / -1.
    """
    previous, current = poses[:-1], poses[1:]
    cos, sin = np.cos(previous[:, 2]), np.sin(previous[:, 2])
    dx = current[:, 0] - previous[:, 0]
    dy = current[:, 1] - previous[:, 1]
    u = cos * dx + sin * dy
    v = -sin * dx + cos * dy
    steps = len(previous)
    wrt_current = np.zeros((steps, 3, 3))
    wrt_current[:, 0, 0] = cos
    wrt_current[:, 0, 1] = sin
    wrt_current[:, 1, 0] = -sin
    wrt_current[:, 1, 1] = cos
    wrt_current[:, 2, 2] = 1.0
    wrt_previous = -wrt_current
    wrt_previous[:, 0, 2] = v
    wrt_previous[:, 1, 2] = -u
    return wrt_previous, wrt_current


def clique_pair_energy(positions, labels, sigma_topology: float) -> np.ndarray:
    """1/2 sum_S sum_{i<j in S} |t_i - t_j|^2 / sigma_T^2 for positions of shape (..., N, 2).

    Uses the exact identity sum_{i<j in S} |t_i - t_j|^2 = |S| sum_{i in S} |t_i - mean_S|^2
    (not the star energy sum |t_i - mean_S|^2, which weights sets differently),
    in O(N) per configuration and without cancellation.
    """
    labels = np.asarray(labels)
    indicator = np.zeros((len(labels), int(labels.max()) + 1))
    indicator[np.arange(len(labels)), labels] = 1.0
    sizes = indicator.sum(axis=0)
    means = np.einsum("...nc,nm->...mc", positions, indicator) / sizes[:, None]
    deviations = positions - means[..., labels, :]
    squared = np.einsum("...nc,...nc->...n", deviations, deviations)
    return 0.5 * np.einsum("...n,n->...", squared, sizes[labels]) / sigma_topology**2


@dataclass(frozen=True)
class LaplaceFit:
    """The minimiser of E for one partition and the factorised Hessian there."""

    x: np.ndarray  # the minimiser P*, shape (d,)
    energy: float  # E(P*)
    factor: "DenseFactor | SparseFactor"  # of the Gauss-Newton Hessian at P*
    iterations: int
    converged: bool


class PoseGraph:
    """The odometry chain of one dataset; fits the pose graph of any partition of it.

    Parameters
    ----------
    odometry : (N-1, 3) array
        Relative motion rows, robot frame of the earlier detection.
    sqrt_information : (N-1, 3, 3) array
        Whitening matrices U_k with U_k^T U_k = Sigma_k^-1 (see :func:`odometry_sqrt_information`).
    sigma_topology : float
        Standard deviation [m] tying the positions of detections of the same place.
    sparse_above : int
        Use sparse linear algebra when d = 3(N-1) exceeds this.
    """

    def __init__(self, odometry, sqrt_information, sigma_topology: float,
                 sparse_above: int = SPARSE_ABOVE_DIMENSION, max_iterations: int = 100,
                 step_tolerance: float = 1e-10):
        self.odometry = np.asarray(odometry, dtype=float)
        self.sqrt_information = np.asarray(sqrt_information, dtype=float)
        self.sigma_topology = float(sigma_topology)
        self.n = len(self.odometry) + 1
        self.dimension = 3 * (self.n - 1)
        self.sparse = self.dimension > sparse_above
        self.max_iterations = int(max_iterations)
        self.step_tolerance = float(step_tolerance)
        self._block_rows, self._block_cols = _tridiagonal_block_indices(self.n - 1)

    def dead_reckoning(self) -> np.ndarray:
        """The state that composes the odometry rows exactly (zero odometry energy)."""
        poses = np.zeros((self.n, 3))
        for k, (dx, dy, dtheta) in enumerate(self.odometry, start=1):
            x, y, theta = poses[k - 1]
            cos, sin = math.cos(theta), math.sin(theta)
            poses[k] = (x + cos * dx - sin * dy, y + sin * dx + cos * dy, theta + dtheta)
        return poses[1:].ravel()

    def energy(self, states, labels) -> np.ndarray:
        """E of each state in ``states`` (shape (..., d)) under the partition ``labels``."""
        poses = poses_from_vector(states)
        whitened = np.einsum("kij,...kj->...ki", self.sqrt_information, odometry_residuals(poses, self.odometry))
        odometry_energy = 0.5 * np.einsum("...ki,...ki->...", whitened, whitened)
        return odometry_energy + clique_pair_energy(poses[..., :2], labels, self.sigma_topology)

    def fit(self, start, labels) -> LaplaceFit:
        """Minimise E from ``start`` by damped Gauss-Newton; factorise the Hessian at the minimum.

        Converged means the undamped Gauss-Newton step is below ``step_tolerance``
        in every coordinate, or its predicted decrease is below rounding of E.
        A fit that runs out of iterations is returned with ``converged=False``
        (its Hessian is still positive definite, so it still defines a valid
        importance-sampling proposal); the caller records it.
        """
        labels = np.asarray(labels)
        topology_rows, topology_cols, topology_values = self._topology_hessian_entries(labels)
        x = np.array(start, dtype=float)
        energy = float(self.energy(x, labels))
        damping = 0.0
        for iteration in range(1, self.max_iterations + 1):
            hessian, gradient = self._linearise(x, topology_rows, topology_cols, topology_values)
            while True:
                factor = self._factorise(hessian, damping)
                step = -factor.solve(gradient)
                predicted_decrease = -0.5 * float(gradient @ step)
                at_minimum = np.max(np.abs(step)) < self.step_tolerance or predicted_decrease < 1e-15 * (1.0 + energy)
                if damping == 0.0 and at_minimum:
                    return LaplaceFit(x, energy, factor, iteration, True)
                candidate = x + step
                candidate_energy = float(self.energy(candidate, labels))
                if candidate_energy <= energy:
                    x, energy = candidate, candidate_energy
                    damping = damping / 10.0 if damping > 1e-7 else 0.0
                    break
                if at_minimum:  # damped step too small to matter: retry undamped at this point
                    damping = 0.0
                    break
                damping = max(1e-6, 10.0 * damping)
        hessian, _ = self._linearise(x, topology_rows, topology_cols, topology_values)
        return LaplaceFit(x, energy, self._factorise(hessian, 0.0), self.max_iterations, False)

    # -- linear algebra ---------------------------------------------------------------------------

    def _linearise(self, x, topology_rows, topology_cols, topology_values):
        """Gauss-Newton Hessian and gradient of E at ``x``."""
        poses = poses_from_vector(x)
        residuals = odometry_residuals(poses, self.odometry)
        whitened = np.einsum("kij,kj->ki", self.sqrt_information, residuals)
        wrt_previous, wrt_current = odometry_jacobian_blocks(poses)
        jac_previous = self.sqrt_information @ wrt_previous
        jac_current = self.sqrt_information @ wrt_current
        gradient_blocks = np.einsum("kji,kj->ki", jac_current, whitened)
        gradient_blocks[:-1] += np.einsum("kji,kj->ki", jac_previous[1:], whitened[1:])
        gradient = gradient_blocks.ravel()
        gradient += _sparse_matvec(topology_rows, topology_cols, topology_values, x)
        diagonal = np.einsum("kji,kjl->kil", jac_current, jac_current)
        diagonal[:-1] += np.einsum("kji,kjl->kil", jac_previous[1:], jac_previous[1:])
        off_diagonal = np.einsum("kji,kjl->kil", jac_previous[1:], jac_current[1:])  # (pose k-1, pose k)
        block_values = np.concatenate(
            [diagonal.ravel(), off_diagonal.ravel(), np.swapaxes(off_diagonal, 1, 2).ravel()]
        )
        rows = np.concatenate([self._block_rows, topology_rows])
        cols = np.concatenate([self._block_cols, topology_cols])
        values = np.concatenate([block_values, topology_values])
        if self.sparse:
            hessian = scipy.sparse.csc_matrix((values, (rows, cols)), shape=(self.dimension,) * 2)
        else:
            flat = np.bincount(rows * self.dimension + cols, weights=values, minlength=self.dimension**2)
            hessian = flat.reshape(self.dimension, self.dimension)
        return hessian, gradient

    def _factorise(self, hessian, damping: float):
        if damping:
            diagonal = hessian.diagonal()
            hessian = hessian + (scipy.sparse.diags(damping * diagonal) if self.sparse else np.diag(damping * diagonal))
        return SparseFactor(hessian) if self.sparse else DenseFactor(hessian)

    def _topology_hessian_entries(self, labels):
        """COO entries of (clique Laplacian of T) / sigma_T^2 on the free x and y coordinates."""
        rows, cols, values = [], [], []
        weight = 1.0 / self.sigma_topology**2
        order = np.argsort(labels, kind="stable")
        boundaries = np.flatnonzero(np.diff(labels[order])) + 1
        for members in np.split(order, boundaries):
            size = len(members)
            free = members[members > 0] - 1
            if size < 2 or not len(free):
                continue
            block = weight * (size * np.eye(len(free)) - 1.0)  # (|S| I - 1 1^T) restricted to free poses
            block_rows = np.repeat(free, len(free))
            block_cols = np.tile(free, len(free))
            for axis in (0, 1):
                rows.append(3 * block_rows + axis)
                cols.append(3 * block_cols + axis)
                values.append(block.ravel())
        if not rows:
            return np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64), np.zeros(0)
        return np.concatenate(rows), np.concatenate(cols), np.concatenate(values)


class DenseFactor:
    """Cholesky H = L L^T of a dense symmetric positive-definite matrix."""

    def __init__(self, matrix):
        try:
            self.lower = scipy.linalg.cholesky(matrix, lower=True, check_finite=False)
        except np.linalg.LinAlgError:
            raise ValueError("the pose-graph Hessian is not positive definite") from None

    def solve(self, rhs) -> np.ndarray:
        return scipy.linalg.cho_solve((self.lower, True), rhs, check_finite=False)

    def log_det(self) -> float:
        return 2.0 * float(np.sum(np.log(np.diag(self.lower))))

    def whiten_inverse(self, noise) -> np.ndarray:
        """Rows L^-T eps_s for rows eps_s of ``noise``: draws from N(0, H^-1) given eps ~ N(0, I)."""
        return scipy.linalg.solve_triangular(self.lower, noise.T, trans="T", lower=True, check_finite=False).T


class SparseFactor:
    """P^T H P = L D L^T of a sparse symmetric positive-definite matrix (SuperLU, diagonal pivots).

    With a symmetric fill-reducing ordering and no off-diagonal pivoting the LU
    factors of an SPD matrix are U = D L^T, so G = P L D^1/2 satisfies G G^T = H
    and G^-T eps = P U^-1 D^1/2 eps.
    """

    def __init__(self, matrix):
        self.lu = scipy.sparse.linalg.splu(
            scipy.sparse.csc_matrix(matrix), permc_spec="MMD_AT_PLUS_A", diag_pivot_thresh=0.0,
            options={"SymmetricMode": True},
        )
        if not np.array_equal(self.lu.perm_r, self.lu.perm_c):
            raise ValueError("the sparse factorisation pivoted off the diagonal: Hessian not positive definite")
        self.pivots = self.lu.U.diagonal()
        if not np.all(self.pivots > 0.0):
            raise ValueError("the pose-graph Hessian is not positive definite")
        self.upper = self.lu.U.tocsr()

    def solve(self, rhs) -> np.ndarray:
        return self.lu.solve(rhs)

    def log_det(self) -> float:
        return float(np.sum(np.log(self.pivots)))

    def whiten_inverse(self, noise) -> np.ndarray:
        scaled = (noise * np.sqrt(self.pivots)).T
        solved = scipy.sparse.linalg.spsolve_triangular(self.upper, scaled, lower=False)
        return solved[self.lu.perm_c].T  # undo the symmetric ordering: x = P y, P[i, perm_c[i]] = 1


def _tridiagonal_block_indices(poses: int) -> tuple[np.ndarray, np.ndarray]:
    """Row and column indices of the 3x3 blocks (i,i), (i-1,i), (i,i-1) of a block-tridiagonal matrix."""
    within_rows, within_cols = np.divmod(np.arange(9), 3)

    def block(row_pose, col_pose):
        rows = (3 * row_pose[:, None] + within_rows).ravel()
        cols = (3 * col_pose[:, None] + within_cols).ravel()
        return rows, cols

    everyone = np.arange(poses)
    diagonal = block(everyone, everyone)
    upper = block(everyone[:-1], everyone[1:])
    lower = block(everyone[1:], everyone[:-1])
    return (np.concatenate([diagonal[0], upper[0], lower[0]]),
            np.concatenate([diagonal[1], upper[1], lower[1]]))


def _sparse_matvec(rows, cols, values, vector) -> np.ndarray:
    return np.bincount(rows, weights=values * vector[cols], minlength=len(vector))
