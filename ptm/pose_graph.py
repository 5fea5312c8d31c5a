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
sigma_T^2, built once per partition. The minimiser P* is found by damped
Newton steps with analytic derivatives; the Gauss-Newton Hessian
H = J^T W J (+ topology Laplacian) at P* defines the Laplace proposal.

Linear algebra exploits the structure. Per set S the clique Laplacian is
(|S| I - 1 1^T) / sigma_T^2: a diagonal minus a rank-one term, so
H = A - U U^T with A the block-tridiagonal odometry Hessian plus a diagonal
(banded, half-bandwidth 5: a banded Cholesky costs O(d)) and U one column per
set and axis (r <= N columns). With A = L L^T and W = L^-1 U, solves use the
Woodbury identity, log det H = log det A + log det(I - W^T W), and draws from
N(0, H^-1) are L^-T (eps_1 + W L_K^-T eps_2) with K = I - W^T W = L_K L_K^T
(see :class:`BandedLowRankFactor`). Above ``sparse_above`` variables, where
r^2 d would dominate, a general sparse L D L^T (SuperLU with a symmetric
ordering and diagonal pivots) is used instead.

    >>> graph = PoseGraph(odometry, odometry_sqrt_information(covariances), sigma_topology=0.3)
    >>> fit = graph.fit(graph.dead_reckoning(), (0, 1, 2, 0))
    >>> fit.energy, fit.factor.log_det()
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cached_property
from typing import NamedTuple

import numpy as np
import scipy.linalg
import scipy.sparse
import scipy.sparse.linalg


__all__ = [
    "PoseGraph",
    "LaplaceFit",
    "Linearisation",
    "odometry_sqrt_information",
    "odometry_residuals",
    "odometry_jacobian_blocks",
    "odometry_second_order_blocks",
    "poses_from_vector",
]

#: Above this many variables the Hessian is factorised with sparse linear algebra.
SPARSE_ABOVE_DIMENSION = 600
#: The row of the diagonal in upper band storage of half-bandwidth 5 (two 3x3 blocks minus one).
BAND_DIAGONAL = 5


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


class _StepFrames(NamedTuple):
    """cos and sin of each step's starting heading, and the step's translation (u, v) in that frame."""

    cos: np.ndarray
    sin: np.ndarray
    u: np.ndarray
    v: np.ndarray


def _step_frames(poses) -> _StepFrames:
    previous, current = poses[..., :-1, :], poses[..., 1:, :]
    cos, sin = np.cos(previous[..., 2]), np.sin(previous[..., 2])
    dx = current[..., 0] - previous[..., 0]
    dy = current[..., 1] - previous[..., 1]
    return _StepFrames(cos, sin, cos * dx + sin * dy, -sin * dx + cos * dy)


def odometry_residuals(poses, odometry) -> np.ndarray:
    """r_k = (p_{k-1}^-1 o p_k) - o_k for poses of shape (..., N, 3); returns (..., N-1, 3).

    The angle residual is wrapped to [-pi, pi) (the energy is even in it, so the
    end point does not matter).
    """
    return np.stack(_residual_components(poses, odometry, _step_frames(poses)), axis=-1)


def _residual_components(poses, odometry, frames: _StepFrames) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The three components of :func:`odometry_residuals`, each of shape (..., N-1)."""
    angle = poses[..., 1:, 2] - poses[..., :-1, 2] - odometry[:, 2] + np.pi
    return frames.u - odometry[:, 0], frames.v - odometry[:, 1], np.remainder(angle, 2.0 * np.pi) - np.pi


def odometry_jacobian_blocks(poses) -> tuple[np.ndarray, np.ndarray]:
    """Analytic Jacobians of r_k with respect to p_{k-1} and p_k, each of shape (N-1, 3, 3).

    With R the rotation of p_{k-1} and delta = t_k - t_{k-1} expressed in its
    frame as (u, v): d(u, v)/d t_k = R^T, d(u, v)/d t_{k-1} = -R^T,
    d(u, v)/d theta_{k-1} = (v, -u), and the angle residual has slopes +1 / -1.
    """
    return _jacobian_blocks(_step_frames(poses))


def _jacobian_blocks(frames: _StepFrames) -> tuple[np.ndarray, np.ndarray]:
    cos, sin, u, v = frames
    steps = len(cos)
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


def odometry_second_order_blocks(poses, multipliers) -> tuple[np.ndarray, np.ndarray]:
    """Residual-weighted second derivatives sum_i m_ki d^2 r_ki of each step, shape (N-1, 3, 3) each.

    ``multipliers`` are m_k = Sigma_k^-1 r_k. Only the translation residual
    (u, v) is non-linear, and only through theta_{k-1}: d^2 u / d theta^2 = -u,
    d^2 v / d theta^2 = -v, d/d theta of d(u, v)/d t_k = ((-sin, cos), (-cos, -sin)),
    and the opposite for t_{k-1}. Returns the (p_{k-1}, p_{k-1}) and the
    (p_{k-1}, p_k) blocks; the (p_k, p_k) block is zero.
    """
    return _second_order_blocks(_step_frames(poses), multipliers)


def _second_order_blocks(frames: _StepFrames, multipliers) -> tuple[np.ndarray, np.ndarray]:
    cos, sin, u, v = frames
    m_u, m_v = multipliers[:, 0], multipliers[:, 1]
    theta_x_current = -m_u * sin - m_v * cos
    theta_y_current = m_u * cos - m_v * sin
    wrt_previous = np.zeros((len(cos), 3, 3))
    wrt_previous[:, 2, 2] = -m_u * u - m_v * v
    wrt_previous[:, 2, 0] = wrt_previous[:, 0, 2] = -theta_x_current
    wrt_previous[:, 2, 1] = wrt_previous[:, 1, 2] = -theta_y_current
    between = np.zeros((len(cos), 3, 3))
    between[:, 2, 0] = theta_x_current
    between[:, 2, 1] = theta_y_current
    return wrt_previous, between


@dataclass(frozen=True)
class LaplaceFit:
    """The minimiser of E for one partition and the factorised Hessian there."""

    x: np.ndarray  # the minimiser P*, shape (d,)
    energy: float  # E(P*)
    factor: "BandedLowRankFactor | SparseFactor"  # of the Gauss-Newton Hessian at P*
    iterations: int
    factorisations: int  # Cholesky / LU factorisations spent, failed attempts included
    converged: bool
    topology: "TopologyHessian"  # of the partition fitted


class Linearisation:
    """E of one partition at one state x, with its derivatives there.

    E is evaluated at once; the gradient and the Hessian blocks the first time
    they are asked for, from the same step frames and residuals (a rejected
    step needs only E). Hessian blocks come as one array of shape (2N-3, 3, 3):
    the N-1 diagonal blocks of poses 1..N-1, then the N-2 blocks
    (pose k-1, pose k) above the diagonal.
    """

    def __init__(self, graph: "PoseGraph", x, topology: "TopologyHessian"):
        self.graph, self.x, self.topology = graph, x, topology
        poses = poses_from_vector(x)
        self.frames = _step_frames(poses)
        self.residuals = _residual_components(poses, graph.odometry, self.frames)
        self.energy = float(graph._odometry_energy_of(self.residuals) + topology.energy(x))

    @cached_property
    def _multipliers(self) -> np.ndarray:  # Sigma_k^-1 r_k
        return np.einsum("kij,kj->ki", self.graph.information, np.stack(self.residuals, axis=-1))

    @cached_property
    def _jacobians(self) -> tuple[np.ndarray, np.ndarray]:
        return _jacobian_blocks(self.frames)

    @cached_property
    def gradient(self) -> np.ndarray:
        wrt_previous, wrt_current = self._jacobians
        multipliers = self._multipliers
        gradient_blocks = np.einsum("kji,kj->ki", wrt_current, multipliers)
        gradient_blocks[:-1] += np.einsum("kji,kj->ki", wrt_previous[1:], multipliers[1:])
        return gradient_blocks.ravel() + self.topology @ self.x

    @cached_property
    def gauss_newton(self) -> np.ndarray:
        """The blocks of J^T Sigma^-1 J, the odometry term's Gauss-Newton Hessian."""
        information = self.graph.information
        wrt_previous, wrt_current = self._jacobians
        steps = len(wrt_current)
        transposed_previous = np.swapaxes(wrt_previous, 1, 2)
        information_current = information @ wrt_current
        blocks = np.empty((2 * steps - 1, 3, 3))
        np.matmul(np.swapaxes(wrt_current, 1, 2), information_current, out=blocks[:steps])
        blocks[: steps - 1] += transposed_previous[1:] @ (information[1:] @ wrt_previous[1:])
        np.matmul(transposed_previous[1:], information_current[1:], out=blocks[steps:])
        return blocks

    @cached_property
    def damping_scale(self) -> np.ndarray:
        """The diagonal of the Gauss-Newton Hessian (odometry and topology): Levenberg-Marquardt damping."""
        steps = len(self.residuals[0])
        return np.diagonal(self.gauss_newton[:steps], axis1=1, axis2=2).ravel() + self.topology.diagonal

    @cached_property
    def second_order(self) -> np.ndarray:
        """The blocks of sum_k m_k . d^2 r_k, the rest of the odometry term's exact Hessian."""
        second_previous, second_between = _second_order_blocks(self.frames, self._multipliers)
        steps = len(second_previous)
        blocks = np.zeros((2 * steps - 1, 3, 3))
        blocks[: steps - 1] = second_previous[1:]
        blocks[steps:] = second_between[1:]
        return blocks


@dataclass(frozen=True)
class TopologyHessian:
    """H_T = (clique Laplacian of T) / sigma_T^2 on the free x and y coordinates.

    Held as star_diagonal - low_rank low_rank^T (the banded factor's form), and
    as COO entries when first asked for (the sparse factor's). The topology
    energy is the quadratic form 1/2 x^T H_T x (pose 0 sits at the origin, so
    its terms vanish).
    """

    labels: np.ndarray  # the partition, canonical
    star_diagonal: np.ndarray  # (d,): |S| / sigma_T^2 on the members of non-singleton sets
    low_rank: np.ndarray  # (d, r): per set and axis, 1 / sigma_T on the members' coordinates
    low_rank_transpose: "_MemberSums"  # its transpose as sums over members (one entry per coordinate)
    set_sizes: np.ndarray  # (r,): |S| of each column's set, pose 0 included
    origin_in_set: np.ndarray  # (r,): 1 where pose 0 belongs to the column's set

    def __matmul__(self, vector) -> np.ndarray:
        return self.star_diagonal * vector - self.low_rank @ (self.low_rank_transpose @ vector)

    @cached_property
    def diagonal(self) -> np.ndarray:
        """(d,): each member coordinate's own column of U contributes 1 / sigma_T^2 to U U^T."""
        return np.where(self.star_diagonal > 0.0, self.star_diagonal - self.low_rank_transpose.scale**2, 0.0)

    @cached_property
    def entries(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """COO (rows, cols, values) without duplicates: w (|S| - 1) on the diagonal of every
        member coordinate and -w between the same coordinate of two members, w = 1/sigma_T^2."""
        labels = self.labels
        sizes = np.bincount(labels)[labels]
        free_labels = labels[1:]
        first, second = np.nonzero((free_labels[:, None] == free_labels[None, :]) & (sizes[1:, None] > 1))
        weight = self.low_rank_transpose.scale**2
        pair_values = np.where(first == second, weight * (sizes[1:][first] - 1.0), -weight)
        return (np.concatenate([3 * first, 3 * first + 1]), np.concatenate([3 * second, 3 * second + 1]),
                np.concatenate([pair_values, pair_values]))

    def energy(self, states) -> np.ndarray:
        """1/2 sum_S sum_{i<j in S} |t_i - t_j|^2 / sigma_T^2 = 1/2 x^T H_T x for states of shape (..., d).

        Evaluated through the exact identity sum_{i<j in S} |t_i - t_j|^2 =
        |S| sum_{i in S} |t_i - mean_S|^2 (not the star energy
        sum |t_i - mean_S|^2, which weights sets differently), with pose 0 (at
        the origin) a member of its set, one coordinate axis at a time, in O(N)
        per state: the quadratic form itself cancels catastrophically far from
        the origin, and a fit compares energies to the last digit.
        """
        members = self.low_rank_transpose
        if not len(members.starts):
            return np.zeros(np.shape(states)[:-1])
        values = states[..., members.coordinates]
        means = np.add.reduceat(values, members.starts, axis=-1) / self.set_sizes
        deviations = values - means[..., members.columns]
        squares = np.add.reduceat(deviations * deviations, members.starts, axis=-1) + self.origin_in_set * means**2
        return 0.5 * members.scale**2 * (squares @ self.set_sizes)

    def energy_around(self, centre, offsets) -> np.ndarray:
        """The topology energy of centre + delta_s for offsets delta_s given as columns (d, S), by
        the exact expansion E_T(c) + (H_T c)^T delta + 1/2 (sum_i star_i delta_i^2 - |U^T delta|^2).

        The quadratic form cancels only on the scale of the offsets, not of the positions.
        """
        projected = self.low_rank_transpose @ offsets
        quadratic = self.star_diagonal @ (offsets * offsets) - np.einsum("rs,rs->s", projected, projected)
        return self.energy(centre) + (self @ centre) @ offsets + 0.5 * quadratic


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
    max_iterations : int
        Iteration limit of one fit.
    step_tolerance : float
        Converged when the Gauss-Newton step is below this in every coordinate.
    close_tolerance : float
        Newton steps below this trigger the convergence test.
    """

    def __init__(self, odometry, sqrt_information, sigma_topology: float,
                 sparse_above: int = SPARSE_ABOVE_DIMENSION, max_iterations: int = 100,
                 step_tolerance: float = 1e-7, close_tolerance: float = 1e-4):
        self.odometry = np.asarray(odometry, dtype=float)
        self.sqrt_information = np.asarray(sqrt_information, dtype=float)
        self.information = np.swapaxes(self.sqrt_information, 1, 2) @ self.sqrt_information
        # r_k^T W_k r_k = sum_{a<=b} c_kab r_ka r_kb with c_kaa = W_kaa and c_kab = 2 W_kab (zero terms left out)
        self._quadratic_terms = [(a, b, (1.0 if a == b else 2.0) * self.information[:, a, b])
                                 for a in range(3) for b in range(a, 3) if np.any(self.information[:, a, b])]
        self.sigma_topology = float(sigma_topology)
        self.n = len(self.odometry) + 1
        self.dimension = 3 * (self.n - 1)
        self.sparse = self.dimension > sparse_above
        self.max_iterations = int(max_iterations)
        self.step_tolerance = float(step_tolerance)
        self.close_tolerance = float(close_tolerance)
        self._block_rows, self._block_cols = _tridiagonal_block_indices(self.n - 1)
        self._band_rows, self._band_cols, self._band_sources = _band_indices(self.n - 1)

    def dead_reckoning(self) -> np.ndarray:
        """The state that composes the odometry rows exactly (zero odometry energy)."""
        poses = np.zeros((self.n, 3))
        for k, (dx, dy, dtheta) in enumerate(self.odometry, start=1):
            x, y, theta = poses[k - 1]
            cos, sin = math.cos(theta), math.sin(theta)
            poses[k] = (x + cos * dx - sin * dy, y + sin * dx + cos * dy, theta + dtheta)
        return poses[1:].ravel()

    def topology(self, labels) -> "TopologyHessian":
        """The topology term of the partition ``labels`` (canonical or not), for :meth:`energy` and :meth:`fit`."""
        return self._topology_hessian(np.asarray(labels))

    def energy(self, states, partition) -> np.ndarray:
        """E of each state in ``states`` (shape (..., d)) under ``partition`` (labels or a :meth:`topology`)."""
        topology = partition if isinstance(partition, TopologyHessian) else self.topology(partition)
        states = np.asarray(states, dtype=float)
        return self._odometry_energy(states) + topology.energy(states)

    def linearise(self, x, partition) -> "Linearisation":
        """E at the state ``x`` under ``partition`` (labels or a :meth:`topology`), and its derivatives."""
        topology = partition if isinstance(partition, TopologyHessian) else self.topology(partition)
        return Linearisation(self, np.asarray(x, dtype=float), topology)

    def energies_around(self, fit: "LaplaceFit", offsets) -> np.ndarray:
        """E(P* + delta_s) of the fitted partition for offsets delta_s given as columns (d, S).

        The topology term is exactly quadratic, so it is taken from its expansion
        around P* (:meth:`TopologyHessian.energy_around`), which is cheaper.
        """
        return self._odometry_energy(fit.x + offsets.T) + fit.topology.energy_around(fit.x, offsets)

    def _odometry_energy(self, states) -> np.ndarray:
        poses = poses_from_vector(states)
        return self._odometry_energy_of(_residual_components(poses, self.odometry, _step_frames(poses)))

    def _odometry_energy_of(self, residuals) -> np.ndarray:
        """1/2 sum_k r_k^T Sigma_k^-1 r_k from the three residual components."""
        return 0.5 * sum((residuals[a] * residuals[b]) @ coefficients for a, b, coefficients in self._quadratic_terms)

    def fit(self, start, partition) -> LaplaceFit:
        """Minimise E from ``start``; factorise the Gauss-Newton Hessian at the minimum.

        Steps are Newton steps on the exact Hessian (Gauss-Newton plus the
        residual-weighted second derivatives of the rotation), damped
        Levenberg-Marquardt style (lambda * diag of the Gauss-Newton Hessian)
        whenever the exact Hessian is indefinite or a step raises E: plain
        Gauss-Newton converges only linearly on the large residuals of an
        implausible topology, and samplers propose many of those. After an
        accepted step the same factor is reused once for a second
        (chord) step, about 15 % fewer factorisations on benchmark routes. Once a
        Newton step is below ``close_tolerance`` the Gauss-Newton Hessian -- the
        one SPEC §3.3 defines the Laplace proposal with -- is factorised; the
        fit is converged when its step is below ``step_tolerance`` in every
        coordinate (or its predicted decrease is below rounding of E). A fit
        that runs out of iterations is returned with ``converged=False``: its
        Hessian is still positive definite, so it still defines a valid
        importance-sampling proposal, and the caller records the failure.
        """
        topology = partition if isinstance(partition, TopologyHessian) else self.topology(partition)
        point = Linearisation(self, np.array(start, dtype=float), topology)
        energy = point.energy
        damping = 0.0
        close = False
        chord_factor = None  # the last accepted step's factor, reused once (a Shamanskii step)
        factorisations = 0
        for iteration in range(1, self.max_iterations + 1):
            if close:
                factor = self._factorised_hessian(topology, point.gauss_newton)
                factorisations += 1
                step = -factor.solve(point.gradient)
                if self._negligible(step, point.gradient, energy):
                    return LaplaceFit(point.x, energy, factor, iteration, factorisations, True, topology)
            if chord_factor is not None:
                step = -chord_factor.solve(point.gradient)
                chord_factor = None
                candidate = Linearisation(self, point.x + step, topology)
                if candidate.energy <= energy or self._negligible(step, point.gradient, energy):
                    close = np.max(np.abs(step)) < self.close_tolerance
                    point, energy = candidate, min(candidate.energy, energy)
                    continue
            exact = point.gauss_newton + point.second_order
            while True:
                factorisations += 1
                try:
                    factor = self._factorised_hessian(topology, exact,
                                                      damping * point.damping_scale if damping else None)
                except ValueError:  # indefinite: damp towards gradient descent
                    damping = max(1e-4, 10.0 * damping)
                    continue
                step = -factor.solve(point.gradient)
                candidate = Linearisation(self, point.x + step, topology)
                if candidate.energy <= energy or self._negligible(step, point.gradient, energy):
                    close = np.max(np.abs(step)) < self.close_tolerance
                    point, energy = candidate, min(candidate.energy, energy)
                    chord_factor = factor
                    damping = damping / 10.0 if damping > 1e-3 else 0.0
                    break
                damping = max(1e-4, 10.0 * damping)
        factor = self._factorised_hessian(topology, point.gauss_newton)
        return LaplaceFit(point.x, energy, factor, self.max_iterations, factorisations + 1, False, topology)

    def _negligible(self, step, gradient, energy) -> bool:
        predicted_decrease = -0.5 * float(gradient @ step)
        return np.max(np.abs(step)) < self.step_tolerance or predicted_decrease < 1e-15 * (1.0 + abs(energy))

    # -- linear algebra ---------------------------------------------------------------------------

    def _factorised_hessian(self, topology: TopologyHessian, blocks, added_diagonal=None):
        """Factorise the topology Laplacian + the block-tridiagonal odometry part (+ a diagonal)."""
        if self.sparse:
            return SparseFactor(self._hessian_matrix(topology, blocks, added_diagonal))
        band = np.zeros((6, self.dimension))
        band[self._band_rows, self._band_cols] = blocks.reshape(-1)[self._band_sources]
        band[BAND_DIAGONAL] += topology.star_diagonal
        if added_diagonal is not None:
            band[BAND_DIAGONAL] += added_diagonal
        return BandedLowRankFactor(band, topology.low_rank, topology.low_rank_transpose)

    def _hessian_matrix(self, topology: TopologyHessian, blocks, added_diagonal=None):
        """The assembled sparse (CSC) matrix: topology Laplacian + odometry blocks (+ a diagonal)."""
        poses = self.n - 1
        diagonal, above = blocks[:poses], blocks[poses:]
        topology_rows, topology_cols, topology_values = topology.entries
        values = np.concatenate([diagonal.ravel(), above.ravel(), np.swapaxes(above, 1, 2).ravel(), topology_values])
        rows = np.concatenate([self._block_rows, topology_rows])
        cols = np.concatenate([self._block_cols, topology_cols])
        matrix = scipy.sparse.csc_matrix((values, (rows, cols)), shape=(self.dimension, self.dimension))
        if added_diagonal is not None:
            matrix = matrix + scipy.sparse.diags(added_diagonal, format="csc")
        return matrix

    def _topology_hessian(self, labels) -> TopologyHessian:
        """w (|S| I - 1 1^T), w = 1/sigma_T^2, for every set S with two or more members, on the x and
        y coordinates of its free poses (pose 0 is fixed but still counts in |S|), as a star diagonal
        w |S| minus one column of U per set and axis (1/sigma_T on its members)."""
        sizes = np.bincount(labels)[labels]
        free_labels = labels[1:]
        weight = 1.0 / self.sigma_topology**2
        star_diagonal = np.zeros(self.dimension)
        members = np.flatnonzero(sizes[1:] > 1)
        for axis in (0, 1):
            star_diagonal[3 * members + axis] = weight * sizes[1:][members]
        set_labels = np.unique(free_labels[members])
        low_rank = np.zeros((self.dimension, 2 * len(set_labels)))
        column_of_set = np.searchsorted(set_labels, free_labels[members])
        for axis in (0, 1):
            low_rank[3 * members + axis, 2 * column_of_set + axis] = 1.0 / self.sigma_topology
        coordinates = np.concatenate([3 * members, 3 * members + 1])
        columns = np.concatenate([2 * column_of_set, 2 * column_of_set + 1])
        order = np.argsort(columns, kind="stable")
        starts = np.searchsorted(columns[order], np.arange(low_rank.shape[1]))
        set_sizes = np.zeros(low_rank.shape[1])
        set_sizes[columns] = sizes[1:][np.concatenate([members, members])]
        origin_in_set = np.zeros(low_rank.shape[1])
        origin_in_set[2 * np.flatnonzero(set_labels == labels[0])[:, None] + np.arange(2)] = 1.0
        return TopologyHessian(labels, star_diagonal, low_rank,
                               _MemberSums(coordinates[order], columns[order], starts, 1.0 / self.sigma_topology),
                               set_sizes, origin_in_set)


@dataclass(frozen=True)
class _MemberSums:
    """U^T as a linear map: column c of U holds ``scale`` on coordinates[starts[c]:starts[c + 1]]."""

    coordinates: np.ndarray
    columns: np.ndarray  # the column of each coordinate entry
    starts: np.ndarray
    scale: float

    def __matmul__(self, matrix) -> np.ndarray:
        if not len(self.starts):
            return np.zeros((0,) + np.shape(matrix)[1:])
        return self.scale * np.add.reduceat(matrix[self.coordinates], self.starts, axis=0)


class BandedLowRankFactor:
    """H = A - U U^T with A symmetric positive definite of half-bandwidth 5 (upper band storage).

    With A = L L^T (banded Cholesky, L = R^T stored as R in upper band storage:
    OpenBLAS solves with the upper band factor in either direction about 1.5
    times as fast as the transposed solve with a lower one) and W = L^-1 U,
    H = L (I - W W^T) L^T, so
    with K = I - W^T W = L_K L_K^T the Woodbury identity gives

        H^-1 b = L^-T (y + W K^-1 W^T y),    y = L^-1 b,
        log det H = log det A + log det K.

    Only forward substitutions (no back substitutions) build W.

    Raises ``ValueError`` when A or K is not positive definite (then neither is
    H, given A is).
    """

    def __init__(self, band, low_rank, low_rank_transpose: "_MemberSums"):
        # LAPACK is called directly: at N = 100 the scipy.linalg wrappers' checks cost as much as the work
        self.low_rank_transpose = low_rank_transpose
        self.band_factor, info = scipy.linalg.lapack.dpbtrf(band, lower=0)
        if info != 0:
            raise ValueError("the pose-graph Hessian is not positive definite")
        self.dimension = band.shape[1]
        self.whitened_low_rank = self._triangular_solve(low_rank) if low_rank.shape[1] else low_rank  # W = L^-1 U
        capacitance = np.eye(low_rank.shape[1]) - self.whitened_low_rank.T @ self.whitened_low_rank
        self.capacitance_factor, info = scipy.linalg.lapack.dpotrf(capacitance, lower=1)
        if info != 0:
            raise ValueError("the pose-graph Hessian is not positive definite")

    def _triangular_solve(self, rhs, transpose: bool = False) -> np.ndarray:
        """L^-1 rhs = R^-T rhs, or L^-T rhs = R^-1 rhs."""
        solution, info = scipy.linalg.lapack.dtbtrs(self.band_factor, rhs, uplo="U",
                                                    trans="N" if transpose else "T")
        if info != 0:
            raise ValueError(f"banded triangular solve failed (LAPACK info {info})")
        return solution

    def solve(self, rhs) -> np.ndarray:
        whitened = self._triangular_solve(np.reshape(rhs, (self.dimension, -1)))
        if self.capacitance_factor.shape[0]:
            correction, _ = scipy.linalg.lapack.dpotrs(self.capacitance_factor, self.whitened_low_rank.T @ whitened,
                                                       lower=1)
            whitened = whitened + self.whitened_low_rank @ correction
        return self._triangular_solve(whitened, transpose=True).reshape(np.shape(rhs))

    def log_det(self) -> float:
        return 2.0 * float(np.sum(np.log(self.band_factor[BAND_DIAGONAL])) + np.sum(np.log(np.diag(self.capacitance_factor))))

    def sample(self, noise_columns) -> tuple[np.ndarray, np.ndarray]:
        """Offsets delta_s ~ N(0, H^-1) as columns (d, S) from standard normal ``noise_columns``
        (at least d + r rows), and 1/2 delta_s^T H delta_s for each.

        delta = L^-T z with z = eps_1 + W L_K^-T eps_2, whose covariance
        I + W K^-1 W^T = (I - W W^T)^-1 makes Cov(delta) = H^-1; and
        delta^T H delta = |z|^2 - |W^T z|^2 = |z|^2 - |U^T delta|^2.
        """
        rank = self.capacitance_factor.shape[0]
        whitened = noise_columns[: self.dimension]
        if rank:
            coupled, _ = scipy.linalg.lapack.dtrtrs(self.capacitance_factor,
                                                    noise_columns[self.dimension:self.dimension + rank],
                                                    lower=1, trans=1)
            whitened = whitened + self.whitened_low_rank @ coupled
        offsets = self._triangular_solve(whitened, transpose=True)
        quadratic = np.einsum("ds,ds->s", whitened, whitened)
        if rank:
            quadratic -= np.einsum("rs,rs->s", projected := self.low_rank_transpose @ offsets, projected)
        return offsets, 0.5 * quadratic


class SparseFactor:
    """P^T H P = L D L^T of a sparse symmetric positive-definite matrix (SuperLU, diagonal pivots).

    With a symmetric fill-reducing ordering and no off-diagonal pivoting the LU
    factors of an SPD matrix are U = D L^T, so G = P L D^1/2 satisfies G G^T = H,
    and G^-T eps = H^-1 (G eps): one sparse product and one SuperLU solve.
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
        self.lower = self.lu.L.tocsr()

    def solve(self, rhs) -> np.ndarray:
        return self.lu.solve(rhs)

    def log_det(self) -> float:
        return float(np.sum(np.log(self.pivots)))

    def sample(self, noise_columns) -> tuple[np.ndarray, np.ndarray]:
        """Offsets G^-T eps_s ~ N(0, H^-1) as columns (d, S) from the first d rows of standard
        normal ``noise_columns``, and 1/2 delta_s^T H delta_s = 1/2 |eps_s|^2 for each."""
        noise = noise_columns[: len(self.pivots)]
        factor_times_noise = self.lower @ (noise * np.sqrt(self.pivots)[:, None])
        offsets = self.lu.solve(np.ascontiguousarray(factor_times_noise[self.lu.perm_c]))  # (P y)_i = y[perm_c[i]]
        return offsets, 0.5 * np.einsum("ds,ds->s", noise, noise)


def _band_indices(poses: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Where the upper triangle of the 3x3 blocks goes in upper band storage (A[i, j] at band[5 + i - j, j]).

    Blocks are laid out as in :class:`Linearisation` (diagonal blocks, then the
    blocks above the diagonal); returns (band row, band column, index into the
    flattened blocks) for every stored entry. Entries are enumerated in the lower
    triangle, A[j + m, j] for m = 0..5, and stored as their mirror A[j, j + m].
    """
    rows, cols, sources = [], [], []
    for a in range(3):
        for b in range(a + 1):  # diagonal block (i, i): entry (3i + a, 3i + b)
            pose = np.arange(poses)
            rows.append(np.full(poses, a - b))
            cols.append(3 * pose + b)
            sources.append(pose * 9 + 3 * a + b)
        for b in range(3):  # block (i + 1, i) = transpose of the block above: entry (3(i+1) + a, 3i + b)
            pose = np.arange(max(poses - 1, 0))
            rows.append(np.full(len(pose), 3 + a - b))
            cols.append(3 * pose + b)
            sources.append(9 * poses + pose * 9 + 3 * b + a)
    below_diagonal, cols = np.concatenate(rows), np.concatenate(cols)
    return BAND_DIAGONAL - below_diagonal, cols + below_diagonal, np.concatenate(sources)


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


