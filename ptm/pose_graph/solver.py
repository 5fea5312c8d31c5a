"""The pose-graph solver: minimise the energy of one topology and factorise its Hessian (the Laplace fit).

Step 1 of the evaluation of log P(O | T) in docs/model.md §3.3 (paper
eq. 3, 13-14). For a partition T the energy over the free poses is

    E(P) = E_odometry(P) + E_T(P)

(:mod:`ptm.pose_graph.residuals` and :mod:`ptm.pose_graph.topology`). The
minimiser P* is found by damped Newton steps with analytic derivatives
(:class:`Linearisation`); the Gauss-Newton Hessian H = J^T W J + H_T at P*,
factorised with the structure of :mod:`ptm.pose_graph.factorisation`,
defines the Laplace proposal N(P*, H^-1). The starts the odometry model fits
from (:mod:`ptm.odometry.laplace`) are dead reckoning (:func:`ptm.se2.dead_reckoning`)
and a correction of it that depends on the partition alone, the chordal
relaxation's headings with their optimal positions (:meth:`PoseGraph.chordal_start`).

    >>> import numpy as np
    >>> from ptm.pose_graph import odometry_sqrt_information
    >>> odometry = np.tile([2.0, 0.0, np.pi / 2], (4, 1))            # a 2 m square, back at the start
    >>> covariances = np.broadcast_to(np.diag([0.01, 0.01, 0.0025]), (4, 3, 3))
    >>> graph = PoseGraph(odometry, odometry_sqrt_information(covariances), sigma_topology=0.3)
    >>> fit = graph.fit(graph.dead_reckoning(), [0, 1, 2, 3, 0])     # detection 4 closes the loop
    >>> fit.converged, round(float(fit.energy), 6)
    (True, 0.0)
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cached_property

import numpy as np
import scipy.sparse
import scipy.sparse.linalg

from .. import se2
from .chordal import chordal_headings
from .factorisation import BandedLowRankFactor, HessianLayout, SparseFactor
from .residuals import StepFrames, StepInformation, poses_from_vector
from .topology import TopologyHessian

__all__ = ["PoseGraph", "LaplaceFit", "Linearisation", "OdometryLinearisation", "SPARSE_ABOVE_DIMENSION"]

#: Above this many variables the Hessian is factorised with sparse linear algebra.
SPARSE_ABOVE_DIMENSION = 600
#: Levenberg-Marquardt damping (relative to the Gauss-Newton diagonal): the first value after an undamped
#: step fails, and the value beyond which a fit gives up (a step that short that still raises E means the
#: energy is not finite or not smooth there).
MIN_DAMPING, MAX_DAMPING = 1e-4, 1e12
#: Shares of a step that raised E tried, in order, before the damping grows (a backtracking line search).
BACKTRACKING = (0.5, 0.25, 0.125)
#: A step whose predicted decrease of E is below this share of 1 + |E| ends a fit: E is then within about that
#: of its minimum, while its rounding error on large graphs (a sum of hundreds of terms) is about 1e-14 of
#: it, so a stricter test can leave a fit at its minimum raising the damping until it gives up.
NEGLIGIBLE_DECREASE = 1e-13


@dataclass(frozen=True)
class LaplaceFit:
    """The minimiser of E for one partition and the factorised Hessian there."""

    x: np.ndarray  # the minimiser P*, shape (d,)
    energy: float  # E(P*)
    factor: BandedLowRankFactor | SparseFactor | None  # of the Gauss-Newton Hessian at P* (None: failed fit)
    iterations: int
    factorisations: int  # Cholesky / LU factorisations spent, failed attempts included
    converged: bool
    topology: TopologyHessian  # of the partition fitted
    failure: str = ""  # why the fit did not converge ("" when it did)


class OdometryLinearisation:
    """The odometry term of E at one state x, with its derivatives there (no topology: shared by all partitions).

    E_odometry is evaluated at once; the gradient and the Hessian blocks the first
    time they are asked for, from the same step frames and residuals (a rejected
    step needs only E). Hessian blocks come as one array of shape (2N-3, 3, 3):
    the N-1 diagonal blocks of poses 1..N-1, then the N-2 blocks
    (pose k-1, pose k) above the diagonal.
    """

    def __init__(self, graph: "PoseGraph", x):
        self.graph, self.x = graph, x
        self.frames = StepFrames.of(poses_from_vector(x))
        self.residuals = self.frames.residuals(graph.odometry)
        self.energy = graph.step_information.energy(self.residuals)

    @cached_property
    def _multipliers(self) -> np.ndarray:  # Sigma_k^-1 r_k
        return self.graph.step_information.multipliers(self.residuals)

    @cached_property
    def _jacobians(self) -> tuple[np.ndarray, np.ndarray]:
        return self.frames.jacobian_blocks()

    @cached_property
    def gradient(self) -> np.ndarray:
        wrt_previous, wrt_current = self._jacobians
        multipliers = self._multipliers
        gradient_blocks = np.einsum("kji,kj->ki", wrt_current, multipliers)
        gradient_blocks[:-1] += np.einsum("kji,kj->ki", wrt_previous[1:], multipliers[1:])
        return gradient_blocks.ravel()

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
    def second_order(self) -> np.ndarray:
        """The blocks of sum_k m_k . d^2 r_k, the rest of the odometry term's exact Hessian."""
        second_previous, second_between = self.frames.second_order_blocks(self._multipliers)
        steps = len(second_previous)
        blocks = np.zeros((2 * steps - 1, 3, 3))
        blocks[: steps - 1] = second_previous[1:]
        blocks[steps:] = second_between[1:]
        return blocks


class Linearisation:
    """E of one partition at one state x, with its derivatives there: the odometry part
    (:class:`OdometryLinearisation`, whose Hessian blocks these are) plus the topology term."""

    def __init__(self, graph: "PoseGraph", x, topology: TopologyHessian,
                 odometry: OdometryLinearisation | None = None):
        self.graph, self.x, self.topology = graph, x, topology
        self.odometry = odometry if odometry is not None else OdometryLinearisation(graph, x)
        self.energy = float(self.odometry.energy + topology.energy(x))

    @cached_property
    def gradient(self) -> np.ndarray:
        return self.odometry.gradient + self.topology @ self.x

    @property
    def gauss_newton(self) -> np.ndarray:
        """The blocks of J^T Sigma^-1 J, the odometry term's Gauss-Newton Hessian."""
        return self.odometry.gauss_newton

    @property
    def second_order(self) -> np.ndarray:
        """The blocks of sum_k m_k . d^2 r_k, the rest of the odometry term's exact Hessian."""
        return self.odometry.second_order

    @cached_property
    def damping_scale(self) -> np.ndarray:
        """The diagonal of the Gauss-Newton Hessian (odometry and topology): Levenberg-Marquardt damping."""
        steps = self.graph.n - 1
        return np.diagonal(self.gauss_newton[:steps], axis1=1, axis2=2).ravel() + self.topology.diagonal


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
                 sparse_above: int = SPARSE_ABOVE_DIMENSION, max_iterations: int = 200,
                 step_tolerance: float = 1e-7, close_tolerance: float = 1e-4):
        self.odometry = np.asarray(odometry, dtype=float)
        self.step_information = StepInformation(sqrt_information)
        self.sqrt_information = self.step_information.sqrt_information
        self.information = self.step_information.information
        self.sigma_topology = float(sigma_topology)
        self.n = len(self.odometry) + 1
        self.dimension = 3 * (self.n - 1)
        self.sparse = self.dimension > sparse_above
        self.max_iterations = int(max_iterations)
        self.step_tolerance = float(step_tolerance)
        self.close_tolerance = float(close_tolerance)
        self.layout = HessianLayout(self.n - 1)
        self._dead_reckoning = self.dead_reckoning()

    @cached_property
    def _at_dead_reckoning(self) -> OdometryLinearisation:
        return OdometryLinearisation(self, self._dead_reckoning)

    def dead_reckoning(self) -> np.ndarray:
        """The state that composes the odometry rows exactly (zero odometry energy): :func:`ptm.se2.dead_reckoning`."""
        return se2.dead_reckoning(self.odometry)[1:].ravel()

    def chordal_start(self, partition) -> np.ndarray:
        """The headings of the chordal relaxation (:func:`ptm.pose_graph.chordal.chordal_headings`) and the
        positions at their optimum given those headings (:meth:`positions_given_headings`): two sparse
        linear solves, a start that depends on the partition only."""
        topology = partition if isinstance(partition, TopologyHessian) else self.topology(partition)
        state = self._dead_reckoning.copy()
        state[2::3] = chordal_headings(self.odometry, self.information, topology)
        return self.positions_given_headings(state, topology)

    def positions_given_headings(self, x, partition) -> np.ndarray:
        """``x`` with the positions moved to the minimum of E over positions, its headings held: with the
        headings fixed, the residuals are linear in the positions and the ties quadratic, so this is one
        Newton step in the positions (one sparse solve)."""
        topology = partition if isinstance(partition, TopologyHessian) else self.topology(partition)
        point = self.linearise(x, topology)
        state = point.x.copy()
        state[self.layout.positions] -= scipy.sparse.linalg.spsolve(
            self.layout.position_matrix(topology, point.gauss_newton), point.gradient[self.layout.positions])
        return state

    def topology(self, labels) -> TopologyHessian:
        """The topology term of the partition ``labels`` (canonical or not), for :meth:`energy` and :meth:`fit`."""
        return TopologyHessian.of(np.asarray(labels), self.sigma_topology)

    def energy(self, states, partition) -> np.ndarray:
        """E of each state in ``states`` (shape (..., d)) under ``partition`` (labels or a :meth:`topology`)."""
        topology = partition if isinstance(partition, TopologyHessian) else self.topology(partition)
        states = np.asarray(states, dtype=float)
        return self.odometry_energy(states) + topology.energy(states)

    def linearise(self, x, partition) -> Linearisation:
        """E at the state ``x`` under ``partition`` (labels or a :meth:`topology`), and its derivatives."""
        topology = partition if isinstance(partition, TopologyHessian) else self.topology(partition)
        x = np.asarray(x, dtype=float)
        # every partition's fit from dead reckoning starts there: its odometry part is remembered
        at_dead_reckoning = self._at_dead_reckoning if np.array_equal(x, self._dead_reckoning) else None
        return Linearisation(self, x, topology, at_dead_reckoning)

    def energies_around(self, fit: LaplaceFit, offsets) -> np.ndarray:
        """E(P* + delta_s) of the fitted partition for offsets delta_s given as columns (d, S).

        The topology term is exactly quadratic, so it is taken from its expansion
        around P* (:meth:`TopologyHessian.energy_around`), which is cheaper.
        """
        return self.odometry_energy(fit.x + offsets.T) + fit.topology.energy_around(fit.x, offsets)

    def odometry_energy(self, states) -> np.ndarray:
        """The odometry term 1/2 sum_k r_k^T Sigma_k^-1 r_k of each state in ``states`` (shape (..., d))."""
        return self.step_information.energy(StepFrames.of(poses_from_vector(states)).residuals(self.odometry))

    def fit(self, start, partition) -> LaplaceFit:
        """Minimise E from ``start``; factorise the Gauss-Newton Hessian at the minimum.

        Steps are Newton steps on the exact Hessian (Gauss-Newton plus the
        residual-weighted second derivatives of the rotation), damped
        Levenberg-Marquardt style (lambda * diag of the Gauss-Newton Hessian)
        whenever a step raises E even when shortened to 1/2, 1/4 or 1/8 of itself
        (a backtracking line search: along a nearly flat bend of the trajectory
        the Newton direction is right and only its length wrong, while damping
        suppresses that direction). Where the exact Hessian is indefinite the
        undamped Gauss-Newton step is tried first. Plain Gauss-Newton converges
        only linearly on the large residuals of an implausible topology, and
        samplers propose many of those. After an
        accepted step the same factor is reused once for a second
        (chord) step, which saves factorisations. Once a
        Newton step is below ``close_tolerance`` the Gauss-Newton Hessian -- the
        one docs/model.md §3.3 defines the Laplace proposal with -- is factorised; the
        fit is converged when its step is below ``step_tolerance`` in every
        coordinate (or its predicted decrease is below ``NEGLIGIBLE_DECREASE`` of 1 + |E|).

        The damping lambda follows Nielsen's schedule: a rejected step multiplies
        it by 2, 4, 8, ... (from ``MIN_DAMPING``), an accepted one divides it by
        at most 3, by less when the quadratic model predicted the decrease
        poorly, and it is dropped only below ``MIN_DAMPING / 100``. A fit that
        runs out of iterations, starts at a non-finite energy or finds no
        decrease up to ``MAX_DAMPING`` is returned with ``converged=False`` and
        the reason in ``failure``, at its last finite iterate: its Gauss-Newton
        Hessian is positive definite there, so it still defines a valid
        importance-sampling proposal (``factor`` is None where it does not), and
        the caller records the failure.
        """
        topology = partition if isinstance(partition, TopologyHessian) else self.topology(partition)
        point = self.linearise(np.array(start, dtype=float), topology)
        energy = point.energy
        if not math.isfinite(energy):
            return self._unconverged(point, topology, 0, 0, "non-finite energy at the start")
        damping, growth = 0.0, 2.0  # lambda and Nielsen's nu
        close = False
        chord_factor = None  # the last accepted step's factor, reused once (a Shamanskii step)
        factorisations = 0
        for iteration in range(1, self.max_iterations + 1):
            if close:
                factor = self.factorise(topology, point.gauss_newton)
                factorisations += 1
                step = -factor.solve(point.gradient)
                if self._negligible(step, point.gradient, energy):
                    return LaplaceFit(point.x, energy, factor, iteration, factorisations, True, topology)
            if chord_factor is not None:
                step = -chord_factor.solve(point.gradient)
                chord_factor = None
                candidate = Linearisation(self, point.x + step, topology)
                if math.isfinite(candidate.energy) and (candidate.energy <= energy
                                                        or self._negligible(step, point.gradient, energy)):
                    close = np.max(np.abs(step)) < self.close_tolerance
                    point, energy = candidate, min(candidate.energy, energy)
                    continue
            hessian = exact = point.gauss_newton + point.second_order
            while True:  # bounded: every pass multiplies the damping by >= 2 up to MAX_DAMPING
                if damping > MAX_DAMPING:
                    return self._unconverged(point, topology, iteration, factorisations,
                                             f"no decrease of E at damping {MAX_DAMPING:g}")
                factorisations += 1
                try:
                    factor = self.factorise(topology, hessian,
                                            damping * point.damping_scale if damping else None)
                except ValueError:
                    if not damping and hessian is exact:
                        # indefinite, undamped: the Gauss-Newton Hessian is positive definite, and its
                        # step a descent direction that the line search can shorten
                        hessian = point.gauss_newton
                        continue
                    damping = max(MIN_DAMPING, 10.0 * damping)  # damp towards gradient descent
                    continue
                step = -factor.solve(point.gradient)
                candidate = Linearisation(self, point.x + step, topology)
                decrease = energy - candidate.energy
                if not math.isfinite(candidate.energy) or (decrease < 0.0
                                                           and not self._negligible(step, point.gradient, energy)):
                    shortened = self._backtracked(point, step, topology)
                    if shortened is not None:  # the direction was right, its length not: keep the damping
                        step, candidate = shortened
                        close = np.max(np.abs(step)) < self.close_tolerance
                        point, energy = candidate, candidate.energy
                        chord_factor = factor
                        break
                if math.isfinite(candidate.energy) and (decrease >= 0.0
                                                        or self._negligible(step, point.gradient, energy)):
                    if damping:
                        # Nielsen's rule: the better the quadratic model predicted the decrease, the more
                        # the damping falls, but at most by 3 per step (never from 1e-3 straight to 0,
                        # which alternated overshooting undamped steps with creeping damped ones on large
                        # graphs); below MIN_DAMPING / 100 it no longer changes a step and is dropped.
                        # Predicted decrease of the exact quadratic model for (H + lambda D) s = -g:
                        # -(g.s + 1/2 s^T H s) = 1/2 (-g.s + lambda s^T D s).
                        predicted = 0.5 * (-float(point.gradient @ step)
                                           + damping * float(point.damping_scale @ step**2))
                        gain = decrease / predicted if predicted > 0.0 else 0.0
                        damping *= max(1.0 / 3.0, 1.0 - (2.0 * min(gain, 1.0) - 1.0) ** 3)
                        damping = damping if damping >= 1e-2 * MIN_DAMPING else 0.0
                    growth = 2.0
                    close = np.max(np.abs(step)) < self.close_tolerance
                    point, energy = candidate, min(candidate.energy, energy)
                    chord_factor = factor
                    break
                damping = max(MIN_DAMPING, growth * damping)
                growth *= 2.0
        return self._unconverged(point, topology, self.max_iterations, factorisations,
                                 f"not converged in {self.max_iterations} iterations")

    def _unconverged(self, point: Linearisation, topology: TopologyHessian, iterations: int,
                     factorisations: int, reason: str) -> LaplaceFit:
        """The fit at the last accepted iterate, marked ``converged=False`` with the ``reason``; its
        Gauss-Newton factor when the energy there is finite and that Hessian is positive definite, else
        ``factor=None`` (no proposal: the caller gives the partition log-likelihood -inf)."""
        factor = None
        if math.isfinite(point.energy) and np.all(np.isfinite(point.x)):
            try:
                factor = self.factorise(topology, point.gauss_newton)
                factorisations += 1
            except ValueError:
                reason += "; Gauss-Newton Hessian not positive definite"
        return LaplaceFit(point.x, point.energy, factor, iterations, factorisations, False, topology, reason)

    def _backtracked(self, point: Linearisation, step, topology: TopologyHessian):
        """(the shortened step, its Linearisation) for the first share in ``BACKTRACKING`` of ``step`` that
        lowers E from ``point``, or None. Along a nearly flat direction of E (a trajectory bending where
        only weak ties hold it, the Hessian's smallest eigenvalue orders of magnitude below its largest)
        the Newton step is right in direction but too long, and the damping that would shorten it
        suppresses that direction altogether: fits there would creep for hundreds of iterations."""
        energy = point.energy
        for share in BACKTRACKING:
            candidate = Linearisation(self, point.x + share * step, topology)
            if candidate.energy < energy:
                return share * step, candidate
        return None

    def _negligible(self, step, gradient, energy) -> bool:
        predicted_decrease = -0.5 * float(gradient @ step)
        return (np.max(np.abs(step)) < self.step_tolerance
                or predicted_decrease < NEGLIGIBLE_DECREASE * (1.0 + abs(energy)))

    # -- linear algebra ---------------------------------------------------------------------------

    def factorise(self, topology: TopologyHessian, blocks, added_diagonal=None):
        """Factorise the topology Hessian + the block-tridiagonal odometry ``blocks`` (laid out as in
        :class:`Linearisation`) + an optional diagonal, banded + low rank or sparse as configured.

        Raises ``ValueError`` when the sum is not positive definite.
        """
        return self.layout.factorise(topology, blocks, added_diagonal, sparse=self.sparse)

    def hessian_matrix(self, topology: TopologyHessian, blocks, added_diagonal=None):
        """The same sum assembled as a sparse (CSC) matrix (for checks and dense comparisons)."""
        return self.layout.matrix(topology, blocks, added_diagonal)
