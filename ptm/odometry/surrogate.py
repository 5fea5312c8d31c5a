"""The screen of the odometry terms: how a move changes log P(O | T), predicted from the current map.

Implements the first stage of delayed acceptance with a surrogate (docs/model.md §3.4; Christen & Fox
2005) and the map estimates that steer the map-guided moves. The Laplace fit of the current partition T --
the mode P* and the Gauss-Newton Hessian H that define log P(O | T) (paper eq. 3, 13-14; docs/model.md §3.3,
step 1) -- is a Gaussian over the poses, Q = N(P*, H^-1), and the positions z of the detections a move
touches are z ~ N(mu, S) under it. A move that replaces some sets by others over the same detections
changes the pose-graph energy by the ties of the sets it adds minus those of the sets it removes, an exact
quadratic in z:

    Delta E(P) = 1/2 z^T M z,      M = (L_added - L_removed) / sigma_T^2  (on x and on y),

with L the clique Laplacian of each set (docs/model.md §3.3). Integrating it against Q predicts the change
of the Laplace value in closed form, and where the mode moves:

    log E_Q[exp(-1/2 z^T M z)] = -1/2 log det(I + S M) - 1/2 mu^T M (I + S M)^-1 mu,
    P*' = P* - H^-1 B^T M (I + S M)^-1 mu                       (B P = z)

(for a merge this is the Mahalanobis test of the tied detections' relative positions under their
marginal covariance plus sigma_T^2, with its Occam factor); the covariance of the positions becomes
C - C B^T M (I + S M)^-1 B C. The landmark-density penalty (eq. 11-12) enters as the estimator of §3.3 weighs
it, where the pair can move: each pair of detections in different sets contributes
log E[exp(-f(|t_i - t_j|))] under the Gaussian of its separation (8 x 8 Gauss-Hermite, or the density at 0
times the penalised area where the Gaussian is wider than the radius), the pairs taken as independent.
The prediction is

    s_T(T') = log E_Q[exp(-Delta E)] + sum_pairs' log E'[exp(-f)] - sum_pairs log E[exp(-f)],

updated only for the pairs with a detection of the move. It is a deterministic function of (T, T'): P*
is the history-free mode of the term's Laplace fit (:mod:`ptm.odometry.laplace`) and H is rebuilt there,
so the sampler's two-stage acceptance stays exact whatever the prediction's error (the second stage
corrects it). On a nearly linear pose graph without penalty the prediction equals the change of the
Laplace value. It cannot follow the importance-sampling part of implausible partitions, whose estimate
rests on a few of the samples and lies well below its Laplace value.

The terms it predicts are the posterior's global terms that expose their Laplace fit: ``laplace_mode(partition)``
(P*, or None where the fit has no Gaussian), ``graph`` (the :class:`ptm.pose_graph.PoseGraph`), ``n`` and
``model`` (with ``sigma_topology``, ``penalty_radius`` and ``max_penalty``) -- the odometry terms. Other global
terms are predicted not to change. A posterior gets this screen from its odometry term
(:meth:`ptm.odometry.OdometryTerm.screen`).

    >>> import numpy as np
    >>> from ptm import Dataset, OdometryModel, PoissonPrior, Posterior
    >>> steps = np.tile([2.0, 0.0, np.pi / 2], (4, 1))                     # a 2 m square, back at the start
    >>> model = OdometryModel(0.05, 0.02, sigma_topology=0.1, penalty_radius=1.0, max_penalty=100.0)
    >>> posterior = Posterior(Dataset(odometry=steps), PoissonPrior(4.0), [model])
    >>> surrogate = OdometrySurrogate(posterior)
    >>> start = posterior.partition([0, 1, 2, 3, 4])
    >>> closing = surrogate.predicted_change(start, [(0,), (4,)], [(0, 4)])   # detection 4 revisits 0
    >>> wrong = surrogate.predicted_change(start, [(0,), (2,)], [(0, 2)])     # 2 is 2.8 m from 0
    >>> closing > 0 > wrong
    True
"""

from __future__ import annotations

import functools
import math
import time
from dataclasses import dataclass, field

import numpy as np

from .._cache import BoundedCache
from ..partitions import Partition
from ..pose_graph import poses_from_vector

__all__ = ["OdometrySurrogate", "MapEstimate", "ConditionedMap"]

#: Map estimates kept (each holds the (2N, 2N) covariance of the positions): the current partitions of a
#: few chains and replicas, and the proposals the second stage just evaluated.
MAP_ESTIMATES_KEPT = 64
#: A pair's penalty term is recomputed for a move that shifts the mean of its separation by more than this
#: share of the separation's spread sqrt(trace Cov), or the covariance by more than this share of its trace
#: (else the term is kept as it was).
PAIR_TOLERANCE = 0.05
#: Gaussians of the positions kept for :meth:`OdometrySurrogate.conditioned_map` (the map-steered window meets one
#: per window start and state; each holds a (2N, 2N) covariance, 0.5 MB at N = 120).
OPEN_MAPS_KEPT = 128


@dataclass(frozen=True)
class MapEstimate:
    """The Laplace fit of one partition seen through the positions: where each detection is, how surely.

    ``positions`` (N, 2) and ``covariance`` (2N, 2N, coordinates ordered x_0, y_0, x_1, ...) are the mean and
    covariance of the positions under N(P*, H^-1); pose 0 is the origin, with zero variance. For every pair
    i < j (in the order of ``numpy.triu_indices``) the estimate keeps the mean and covariance of t_i - t_j
    and, for pairs in different sets, its penalty term log E[exp(-f(|t_i - t_j|))] (eq. 11-12).
    """

    labels: np.ndarray  # (N,) canonical labels of the partition
    positions: np.ndarray
    covariance: np.ndarray
    separations: np.ndarray  # (P, 2): mean of t_i - t_j
    separation_covariances: np.ndarray  # (P, 2, 2)
    penalty_terms: np.ndarray  # (P,): log E[exp(-f)] of the pairs in different sets, 0 for the others
    laplace: float  # -E(P*) + (d/2) log 2 pi - 1/2 log det H, the Laplace value of docs/model.md §3.3, step 1
    sigma_topology: float
    penalty_radius: float
    max_penalty: float
    given_back: np.ndarray  # (N,): minus the sum of each detection's penalty terms (>= 0)
    _last_tie: list = field(default_factory=lambda: [None, None], compare=False, repr=False)  # [move, its tie]

    @classmethod
    def of(cls, term, partition: Partition) -> "MapEstimate | None":
        """The estimate of ``partition`` under ``term``; None where its log-likelihood is -inf (no Gaussian)."""
        mode = term.laplace_mode(partition)
        if mode is None:
            return None
        positions, covariance, laplace = _position_gaussian(term, partition, mode)
        first, second = _pairs(term.n)
        blocks = covariance.reshape(term.n, 2, term.n, 2)
        own = blocks[np.arange(term.n), :, np.arange(term.n), :]  # (N, 2, 2)
        separations = positions[first] - positions[second]
        separation_covariances = own[first] + own[second] - blocks[first, :, second, :] - blocks[second, :, first, :]
        labels = np.asarray(partition.labels)
        model = term.model
        apart = np.flatnonzero(labels[first] != labels[second])
        penalty_terms = np.zeros(len(first))
        penalty_terms[apart] = _pair_log_expectations(separations[apart], separation_covariances[apart],
                                                      model.penalty_radius, model.max_penalty)
        given_back = -(np.bincount(first, penalty_terms, term.n) + np.bincount(second, penalty_terms, term.n))
        return cls(labels, positions, covariance, separations, separation_covariances, penalty_terms, laplace,
                   model.sigma_topology, model.penalty_radius, model.max_penalty, given_back)

    def predicted_change(self, removed, added) -> float:
        """s_T(T'): the predicted log P(O | T') - log P(O | T) when the sets ``removed`` are replaced by the
        sets ``added`` (both sequences of sorted tuples over the same detections).

        The penalty terms are summed over the pairs as if independent, and only pairs with a detection of
        the move are updated: those it puts apart or together, and those whose separation's distribution it
        shifts by more than ``PAIR_TOLERANCE`` of its spread (how the move bends the map elsewhere is left
        out).
        """
        tie = self._gaussian_tie(removed, added)
        if tie is None:
            return 0.0
        laplace_change, members, gain = tie
        if self.max_penalty == 0.0:
            return float(laplace_change)
        n = len(self.labels)
        coordinates = (2 * members[:, None] + np.arange(2)).ravel()
        coupling = self.covariance[:, coordinates]  # Cov(t, z): (2N, 2m)
        weighted = coupling @ gain  # Cov(t, z) K
        mean_shift = (weighted @ self.positions.ravel()[coordinates]).reshape(n, 2)  # each mean moves by minus this
        # F_kl = Cov(t_k, z) K Cov(z, t_l) (2 x 2 blocks, F_lk = F_kl^T): a pair's covariance shrinks by
        # F_ii + F_jj - F_ij - F_ji; only the diagonal blocks and the members' rows are needed
        own_shift = np.einsum("kai,kbi->kab", weighted.reshape(n, 2, -1), coupling.reshape(n, 2, -1))
        member_rows = (weighted[coordinates] @ coupling.T).reshape(len(members), 2, n, 2).transpose(0, 2, 1, 3)
        involved = np.zeros(n, dtype=bool)
        involved[members] = True
        partners = np.arange(n)
        keep = (~involved[None, :] | (partners[None, :] > members[:, None]))  # each pair with a member once
        which_member, partner = np.nonzero(keep)
        member = members[which_member]
        first, second = np.minimum(member, partner), np.maximum(member, partner)
        touched = _pair_indices(n)[first, second]  # the pairs with a member of the move
        separation_shift = mean_shift[first] - mean_shift[second]
        cross = member_rows[which_member, partner]
        covariance_shift = own_shift[member] + own_shift[partner] - cross - cross.transpose(0, 2, 1)
        labels = self.labels.copy()
        for index, block in enumerate(added):
            labels[list(block)] = n + index
        apart_before = self.labels[first] != self.labels[second]
        apart_after = labels[first] != labels[second]
        separation_covariances = self.separation_covariances[touched]
        spread_squared = separation_covariances[:, 0, 0] + separation_covariances[:, 1, 1]
        shifted = ((np.einsum("pa,pa->p", separation_shift, separation_shift) > PAIR_TOLERANCE**2 * spread_squared)
                   | (np.abs(covariance_shift).max(axis=(1, 2)) > PAIR_TOLERANCE * spread_squared))
        recomputed = np.flatnonzero(apart_after & (shifted | ~apart_before))
        dropped = touched[apart_before & (shifted | ~apart_after)]
        penalty_change = float(np.sum(_pair_log_expectations(
            self.separations[touched[recomputed]] - separation_shift[recomputed],
            separation_covariances[recomputed] - covariance_shift[recomputed],
            self.penalty_radius, self.max_penalty)) - np.sum(self.penalty_terms[dropped]))
        return float(laplace_change + penalty_change)

    def single_tie_changes(self, detection: int) -> np.ndarray:
        """For every detection j, the change of the Laplace value if ``detection`` were tied to j alone (0 for
        j = ``detection``): for their separation r ~ N(s, C),
        -1/2 log det(I + C / sigma_T^2) - 1/2 s^T (C + sigma_T^2 I)^-1 s.

        A set's clique tie adds one such tie per member, so the change of joining a set is at most the least
        of its members' values (in the Gaussian; how the tie bends the rest of the map is left out). One pass
        over N 2 x 2 matrices, for telling the sets a detection may join from those it cannot.
        """
        n = len(self.labels)
        others = np.arange(n) != detection
        pairs = _pair_indices(n)[detection, others]
        changes = np.zeros(n)
        changes[others] = _tie_changes(self.separations[pairs], self.separation_covariances[pairs], self.sigma_topology)
        return changes

    def predicted_change_bound(self, removed, added) -> float:
        """An upper bound of :meth:`predicted_change` without the pairs' update: its Gaussian tie part plus every
        penalty term of the pairs with a member of the move given back.

        The penalty terms are <= 0 before and after (log E[exp(-f)], f >= 0), and the prediction drops only
        terms of such pairs, so it gains at most these. A first stage that rejects the move at this bound
        rejects it at the prediction too (the first stage of delayed acceptance); the tie is kept for the
        prediction that may follow.
        """
        tie = self._gaussian_tie(removed, added)
        if tie is None:
            return 0.0
        laplace_change, members, _ = tie
        return float(laplace_change + np.sum(self.given_back[members]))

    def _gaussian_tie(self, removed, added):
        """The tie of the move (:meth:`_tie_of`), remembered for the last move asked about: a first stage asks
        for its bound (:meth:`predicted_change_bound`), then for the prediction."""
        move = (tuple(removed), tuple(added))
        if self._last_tie[0] != move:
            self._last_tie[:] = move, self._tie_of(removed, added)
        return self._last_tie[1]

    def _tie_of(self, removed, added):
        """(log E_Q[exp(-1/2 z^T M z)], the detections of z (sorted), K = M (I + S M)^-1), or None where
        I + S M is not numerically positive definite (it is in exact arithmetic)."""
        members = np.sort(np.concatenate([np.asarray(block, dtype=int) for block in added]))
        laplacian = np.zeros((len(members), len(members)))
        for blocks, sign in ((added, 1.0), (removed, -1.0)):
            for block in blocks:
                rows = np.searchsorted(members, block)
                laplacian[rows[:, None], rows] -= sign
                laplacian[rows, rows] += sign * len(block)
        precision = np.zeros((2 * len(members), 2 * len(members)))  # M = L / sigma_T^2 on x and on y
        precision[0::2, 0::2] = precision[1::2, 1::2] = laplacian / self.sigma_topology**2
        coordinates = (2 * members[:, None] + np.arange(2)).ravel()
        mean = self.positions.ravel()[coordinates]  # mu
        system = self.covariance[np.ix_(coordinates, coordinates)] @ precision  # I + S M
        system[np.diag_indices_from(system)] += 1.0
        sign, log_det = np.linalg.slogdet(system)
        if sign <= 0.0:
            return None
        gain = precision @ np.linalg.inv(system)  # symmetric
        return -0.5 * log_det - 0.5 * float(mean @ gain @ mean), members, gain


def _position_gaussian(term, partition: Partition, mode: np.ndarray):
    """The positions' mean (N, 2) and covariance (2N, 2N; x_0, y_0, x_1, ...) under N(P*, H^-1) at the
    Laplace mode ``mode`` of ``partition``, and the Laplace value there (docs/model.md §3.3, step 1)."""
    graph = term.graph
    topology = graph.topology(partition.labels)
    point = graph.linearise(mode, topology)
    factor = graph.factorise(topology, point.gauss_newton)
    laplace = -point.energy + 0.5 * graph.dimension * math.log(2.0 * math.pi) - 0.5 * factor.log_det()
    free_positions = np.flatnonzero(np.arange(graph.dimension) % 3 != 2)  # x, y of poses 1..N-1
    selector = np.zeros((graph.dimension, len(free_positions)))
    selector[free_positions, np.arange(len(free_positions))] = 1.0
    covariance = np.zeros((2 * term.n, 2 * term.n))
    covariance[2:, 2:] = factor.solve(selector)[free_positions]
    covariance = 0.5 * (covariance + covariance.T)
    return poses_from_vector(mode)[:, :2], covariance, laplace


@functools.lru_cache(maxsize=8)
def _pairs(n: int) -> tuple[np.ndarray, np.ndarray]:
    """All pairs i < j of n detections, in the order of ``numpy.triu_indices``."""
    return np.triu_indices(n, k=1)


@functools.lru_cache(maxsize=8)
def _pair_indices(n: int) -> np.ndarray:
    """(n, n): the position of pair {i, j} in :func:`_pairs`' order, either way round (-1 on the diagonal)."""
    first, second = _pairs(n)
    indices = np.full((n, n), -1)
    indices[first, second] = indices[second, first] = np.arange(len(first))
    return indices


#: The 8 x 8 Gauss-Hermite rule for expectations over a standard bivariate normal: nodes (64, 2), log weights.
_NODES_1D, _WEIGHTS_1D = np.polynomial.hermite_e.hermegauss(8)
_HERMITE_NODES = np.stack(np.meshgrid(_NODES_1D, _NODES_1D, indexing="ij"), axis=-1).reshape(-1, 2)
_HERMITE_LOG_WEIGHTS = np.log(np.outer(_WEIGHTS_1D, _WEIGHTS_1D).ravel() / (2.0 * math.pi))


def _pair_log_expectations(separations, covariances, penalty_radius: float, max_penalty: float) -> np.ndarray:
    """log E[exp(-f(|r|))] for each pair's separation r ~ N(separations[p], covariances[p]) (eq. 11-12).

    The penalty's effect on the likelihood is thus weighed where the pair can move (the estimator of
    docs/model.md §3.3 lets it), not at the mode, where it would be paid in full. A Gaussian narrower
    than the radius in some direction is integrated by the 8 x 8 Gauss-Hermite rule; a wider one is
    nearly flat over the disc |r| < D where f acts, so E[1 - exp(-f)] is its density at 0 times
    integral (1 - exp(-f(|r|))) dr. Pairs whose mean lies more than the radius plus three standard
    deviations from 0 get 0 (f = 0 there), as does everything without the penalty.
    """
    values = np.zeros(len(separations))
    if max_penalty == 0.0 or not len(separations):
        return values
    xx, xy, yy = covariances[:, 0, 0], covariances[:, 0, 1], covariances[:, 1, 1]
    determinant = np.maximum(xx * yy - xy**2, 0.0)
    half_gap = np.sqrt(np.maximum(0.25 * (xx - yy) ** 2 + xy**2, 0.0))
    largest, smallest = 0.5 * (xx + yy) + half_gap, 0.5 * (xx + yy) - half_gap  # eigenvalues
    near = np.hypot(separations[:, 0], separations[:, 1]) < penalty_radius + 3.0 * np.sqrt(np.maximum(largest, 0.0))
    wide = np.flatnonzero(near & (smallest >= penalty_radius**2))
    if len(wide):
        x, y = separations[wide, 0], separations[wide, 1]
        mahalanobis = (yy[wide] * x**2 - 2.0 * xy[wide] * x * y + xx[wide] * y**2) / determinant[wide]
        density = np.exp(-0.5 * mahalanobis) / (2.0 * math.pi * np.sqrt(determinant[wide]))
        values[wide] = np.log1p(-np.minimum(density * _penalised_area(penalty_radius, max_penalty), 0.5))
    narrow = np.flatnonzero(near & (smallest < penalty_radius**2))
    if len(narrow):
        root_xx = np.sqrt(np.maximum(xx[narrow], 1e-300))  # closed-form Cholesky factors of the 2 x 2 covariances
        lower = xy[narrow] / root_xx
        root_rest = np.sqrt(np.maximum(yy[narrow] - lower**2, 0.0))
        nodes_x, nodes_y = _HERMITE_NODES[:, 0], _HERMITE_NODES[:, 1]
        points_x = separations[narrow, 0, None] + root_xx[:, None] * nodes_x
        points_y = separations[narrow, 1, None] + lower[:, None] * nodes_x + root_rest[:, None] * nodes_y
        closeness = np.clip(1.0 - np.sqrt(points_x * points_x + points_y * points_y) / penalty_radius, 0.0, None)
        exponents = _HERMITE_LOG_WEIGHTS - max_penalty * closeness * closeness * closeness
        top = exponents.max(axis=1)
        values[narrow] = top + np.log(np.exp(exponents - top[:, None]).sum(axis=1))
    return values


@functools.lru_cache(maxsize=8)
def _penalised_area(penalty_radius: float, max_penalty: float) -> float:
    """integral over the plane of 1 - exp(-f(|r|)) = 2 pi integral_0^D (1 - exp(-f(rho))) rho d rho (32-point
    Gauss-Legendre on [0, D])."""
    nodes, weights = np.polynomial.legendre.leggauss(32)
    radii = 0.5 * penalty_radius * (nodes + 1.0)
    integrand = -np.expm1(-max_penalty * (1.0 - radii / penalty_radius) ** 3) * radii
    return float(math.pi * penalty_radius * np.sum(weights * integrand))


class ConditionedMap:
    """The positions of a map estimate, conditioned on ties one at a time: where the detections of a window
    are likely to be once some of them have joined their places (the map-steered window move, docs/model.md §3.4).

    Under each odometry term's Gaussian N(mu, C) of the positions (:class:`MapEstimate`), a tie of detection
    i to detection m is the observation t_i - t_m = 0 with noise sigma_T^2 I, and conditioning on it is a
    Kalman update of mu and C (rank 2, O(N^2)). The first tie of a retraced corridor pulls its neighbours
    onto their places too, so the ties after it are scored as they will be paid, not under the drift of the
    unconditioned map. :meth:`join_changes` scores joining each of some sets as :meth:`MapEstimate.single_tie_changes`
    to its most compatible member plus the landmark-density penalty given back (eq. 11-12, as in
    :meth:`OdometrySurrogate.join_estimates`), and :meth:`tie` conditions on the last scored join.
    """

    def __init__(self, gaussians):
        """``gaussians``: per odometry term, (positions (N, 2), covariance (2N, 2N), sigma_T, penalty radius,
        max penalty); copied, so that conditioning leaves them as they were."""
        self._terms = [(positions.ravel().copy(), covariance.copy(), sigma, radius, max_penalty)
                       for positions, covariance, sigma, radius, max_penalty in gaussians]
        self._best_members: list[int] = []

    def join_changes(self, detection: int, sets) -> np.ndarray:
        """For each of ``sets`` (sorted tuples without ``detection``), the estimated change of the odometry
        terms if ``detection`` joined it, under the map conditioned so far."""
        members = np.concatenate([np.asarray(block) for block in sets])
        starts = np.cumsum([0] + [len(block) for block in sets[:-1]])
        ties = np.zeros(len(members))
        given_back = np.zeros(len(sets))
        for mean, covariance, sigma, radius, max_penalty in self._terms:
            n = len(mean) // 2
            positions, blocks = mean.reshape(n, 2), covariance.reshape(n, 2, n, 2)
            separations = positions[detection] - positions[members]
            cross = blocks[detection, :, members, :]  # (k, 2, 2): Cov(t_i, t_m)
            spread = (blocks[detection, :, detection, :] + blocks[members, :, members, :]
                      - cross - cross.transpose(0, 2, 1))
            ties += _tie_changes(separations, spread, sigma)
            given_back -= np.add.reduceat(_pair_log_expectations(separations, spread, radius, max_penalty), starts)
        best = np.maximum.reduceat(ties, starts)
        self._best_members = [int(members[start + np.argmax(ties[start:start + len(block)])])
                              for start, block in zip(starts, sets)]
        return best + given_back

    def tie(self, detection: int, joined: int) -> None:
        """Condition every term's map on ``detection`` sitting at the place of set ``joined`` of the last
        :meth:`join_changes` (a tie to that set's most compatible member)."""
        member = self._best_members[joined]
        for mean, covariance, sigma, _, _ in self._terms:
            first, second = slice(2 * detection, 2 * detection + 2), slice(2 * member, 2 * member + 2)
            coupling = covariance[:, first] - covariance[:, second]  # Cov(t, t_i - t_m): (2N, 2)
            innovation = coupling[first] - coupling[second] + sigma**2 * np.eye(2)
            gain = np.linalg.solve(innovation, coupling.T).T
            mean -= gain @ (mean[first] - mean[second])
            covariance -= gain @ coupling.T


def _tie_changes(separations, covariances, sigma: float) -> np.ndarray:
    """The change of the Laplace value of one tie of noise sigma on each separation r ~ N(s, C) (in the
    Gaussian; :meth:`MapEstimate.single_tie_changes`): -1/2 log det(I + C / sigma^2) - 1/2 s^T (C + sigma^2 I)^-1 s."""
    variance = sigma**2
    xx, xy, yy = covariances[:, 0, 0] + variance, covariances[:, 0, 1], covariances[:, 1, 1] + variance
    determinant = xx * yy - xy * xy
    x, y = separations[:, 0], separations[:, 1]
    mahalanobis = (yy * x * x - 2.0 * xy * x * y + xx * y * y) / determinant
    return -0.5 * (np.log(determinant) - 2.0 * math.log(variance)) - 0.5 * mahalanobis


SCREENING_TRUST = 0.5  # the default weight of a prediction where it steers or screens a proposal (screening_change)


class OdometrySurrogate:
    """Predicts the change of a posterior's global terms from the map estimate of the current partition.

    ``predicted_change(partition, removed, added)`` is the sum over the posterior's odometry terms of
    :meth:`MapEstimate.predicted_change` (0 for other global terms, and for a partition whose odometry
    log-likelihood is -inf). It is the posterior's screen (``Posterior.screen()``, built by
    :meth:`ptm.odometry.OdometryTerm.screen`), which delayed acceptance and the map-guided moves read. Map
    estimates are memoised per partition (``MAP_ESTIMATES_KEPT``) and predictions per partition and proposal
    (``predictions_kept``): a chain near a mode proposes the same moves again and again.
    """

    def __init__(self, posterior, estimates_kept: int = MAP_ESTIMATES_KEPT, predictions_kept: int = 100_000,
                 screening_trust: float = SCREENING_TRUST):
        if not 0.0 < screening_trust <= 1.0:
            raise ValueError(f"screening_trust must lie in (0, 1], got {screening_trust!r}")
        self.screening_trust = float(screening_trust)
        self.terms = [term for term in posterior.global_terms if hasattr(term, "laplace_mode")]
        self._predicts_every_global_term = len(self.terms) == len(posterior.global_terms)
        self._estimates = BoundedCache(estimates_kept)
        self._gaussians = BoundedCache(OPEN_MAPS_KEPT)
        self._predictions = BoundedCache(predictions_kept)
        self._seconds = 0.0
        self._bounds = 0

    def map_estimates(self, partition: Partition) -> list[MapEstimate | None]:
        """The map estimate of ``partition`` under each odometry term (memoised)."""
        estimates = self._estimates.get(partition)
        if estimates is None:
            estimates = [MapEstimate.of(term, partition) for term in self.terms]
            self._estimates.put(partition, estimates)
        return estimates

    def predicted_change(self, partition: Partition, removed, added) -> float:
        """Predicted change of the global terms when, in ``partition``, the sets ``removed`` become ``added``."""
        key = (partition, tuple(added))  # the added sets fix the removed ones
        change = self._predictions.get(key)
        if change is None:
            started = time.perf_counter()
            change = float(sum(estimate.predicted_change(removed, added)
                               for estimate in self.map_estimates(partition) if estimate is not None))
            self._seconds += time.perf_counter() - started
            self._predictions.put(key, change)
        return change

    def opened_place_change(self, partition: Partition) -> float | None:
        """Predicted change of the global terms from the run without its last detection to ``partition``, where
        that detection is a place of its own (the online mapper's new place, :mod:`ptm.online`); None where the
        posterior has global terms other than odometry, -inf where a term has no Gaussian.

        Held by its odometry row alone, the last detection is a leaf of the pose graph: the minimum of E is the
        shorter run's with the leaf composed on (zero residual), and the Hessian gains the row's information
        through a Jacobian of determinant 1 (the Schur complement of the leaf leaves H as it was), so the Laplace
        value changes by exactly (3/2) log 2 pi + 1/2 log det Sigma_last. The penalty adds the leaf's pairs,
        log E[exp(-f)] each as in :meth:`MapEstimate.predicted_change` (all of them in different sets).
        """
        if not self._predicts_every_global_term:
            return None
        last = partition.n - 1
        if last < 1 or partition.labels[last] in partition.labels[:last]:
            raise ValueError(f"the last detection of {partition} is not a place of its own")
        change = 0.0
        for term, estimate in zip(self.terms, self.map_estimates(partition)):
            if estimate is None:
                return -math.inf
            _, log_det_whitening = np.linalg.slogdet(term.graph.sqrt_information[-1])  # -1/2 log det Sigma_last
            pairs = _pair_indices(partition.n)[last, :last]
            change += 1.5 * math.log(2.0 * math.pi) - log_det_whitening + float(np.sum(estimate.penalty_terms[pairs]))
        return change

    def screening_change_bound(self, partition: Partition, removed, added) -> float:
        """An upper bound of :meth:`screening_change`, cheaper where the prediction is not memoised:
        ``screening_trust`` times the sum of :meth:`MapEstimate.predicted_change_bound` (the memoised prediction
        where there is one)."""
        if (partition, tuple(added)) in self._predictions:
            return self.screening_change(partition, removed, added)
        self._bounds += 1
        return self.screening_trust * float(sum(estimate.predicted_change_bound(removed, added)
                                                for estimate in self.map_estimates(partition) if estimate is not None))

    def join_estimates(self, partition: Partition, detection: int) -> np.ndarray:
        """For each set of ``partition`` other than ``detection``'s own (a set of one), a cheap estimate of the
        change of the global terms if ``detection`` joined it: per odometry term, the least
        :meth:`MapEstimate.single_tie_changes` over the set's members for the Laplace part, plus the members'
        penalty terms given back. Meant only to pick the sets worth a :meth:`predicted_change`."""
        others = [block for block in partition.blocks if block != (detection,)]
        members = np.concatenate([np.asarray(block) for block in others])
        starts = np.cumsum([0] + [len(block) for block in others[:-1]])
        total = np.zeros(len(others))
        for estimate in self.map_estimates(partition):
            if estimate is not None:
                laplace = estimate.single_tie_changes(detection)[members]
                given_back = -estimate.penalty_terms[_pair_indices(len(estimate.labels))[detection, members]]
                total += np.minimum.reduceat(laplace, starts) + np.add.reduceat(given_back, starts)
        return total

    def conditioned_map(self, partition: Partition) -> ConditionedMap:
        """A fresh :class:`ConditionedMap` of the Laplace fits of ``partition`` (their Gaussians of the positions
        are memoised apart from the map estimates, ``OPEN_MAPS_KEPT``, without the pairs' arrays)."""
        gaussians = self._gaussians.get(partition)
        if gaussians is None:
            gaussians = []
            for term in self.terms:
                mode = term.laplace_mode(partition)
                if mode is not None:
                    positions, covariance, _ = _position_gaussian(term, partition, mode)
                    model = term.model
                    gaussians.append((positions, covariance, model.sigma_topology, model.penalty_radius,
                                      model.max_penalty))
            self._gaussians.put(partition, gaussians)
        return ConditionedMap(gaussians)

    def screening_change(self, partition: Partition, removed, added) -> float:
        """What proposals and the first stage of delayed acceptance use: ``screening_trust`` (default
        ``SCREENING_TRUST``) times :meth:`predicted_change`.

        The prediction overstates how much worse a split state is than its merge (its penalty sums pairs
        as if independent, Jensen's inequality in the split state), and it does so almost antisymmetrically,
        so a move whose forward and reverse predictions are both trusted in full pays the error twice in its
        Hastings ratio. Half the prediction is the locally balanced choice (Zanella 2020, g(t) = sqrt t):
        proposals lean towards what the map predicts, and a wrong prediction costs at most half of itself.
        Any deterministic screening keeps the chain exact (the second stage corrects it); full trust screens
        out more and so costs fewer odometry evaluations (the online mapper's few rejuvenation steps).
        """
        return self.screening_trust * self.predicted_change(partition, removed, added)

    def diagnostics(self) -> dict:
        """Predictions made and reused, map estimates built, the mean time of a prediction made [ms], and the
        bounds computed in their stead (:meth:`screening_change_bound`)."""
        made = self._predictions.misses
        return {
            "predictions": made + self._predictions.hits,
            "prediction_hit_rate": self._predictions.hit_rate,
            "map_estimates_built": self._estimates.misses,
            "prediction_ms_mean": 1e3 * self._seconds / made if made else math.nan,
            "prediction_bounds": self._bounds,
        }
