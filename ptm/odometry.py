"""The odometry likelihood log P(O | T): Laplace proposal plus importance sampling.

Implements SPEC §3.3 (paper eq. 3 and 11-14). For a partition T,

    log P(O | T) = log integral exp(-E(P) - Pen(P)) dP,
    Pen(P) = sum over pairs i<j in different sets of f(|t_i - t_j|),
    f(d) = max_penalty * (1 - d / penalty_radius)^3 for d < penalty_radius, else 0,

with E the pose-graph energy of :mod:`ptm.pose_graph` (odometry distortion
plus the topology tie, both in the 1/2 r^T Sigma^-1 r convention). The
integral is evaluated as the paper does: a Laplace fit Q = N(P*, H^-1) of E,
then importance sampling from Q,

    log w_s = -E(P_s) - Pen(P_s) + (d/2) log 2 pi - 1/2 log det H + 1/2 (P_s - P*)^T H (P_s - P*),
    P_s ~ N(P*, H^-1),    log P(O | T) = logsumexp_s(log w_s) - log S.

(With a factor H = L L^T and P_s = P* + L^-T eps_s the last term is the
SPEC's 1/2 |eps_s|^2; the structured factor of :mod:`ptm.pose_graph` draws
P_s from d + r normals instead and evaluates the quadratic form directly.)
The noise matrix eps (S x (d + N)) is drawn once per bound term from the model's
seed (common random numbers), so the estimate is a deterministic function of
the partition and the MCMC target is well defined; results are memoised per
canonical partition in a bounded LRU cache.

    >>> model = OdometryModel(sigma_xy=0.1, sigma_theta=0.05, sigma_topology=0.3,
    ...                       penalty_radius=2.5, max_penalty=100.0, n_importance=100, seed=0)
    >>> ptm.Posterior(dataset, ptm.PoissonPrior(2.0), [model]).log_prob([0, 1, 2, 0])
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass

import numpy as np
import scipy.spatial.distance

from ._cache import BoundedCache
from ._validation import non_negative, positive
from .partitions import Partition
from .pose_graph import SPARSE_ABOVE_DIMENSION, LaplaceFit, PoseGraph, odometry_sqrt_information, poses_from_vector

__all__ = ["OdometryModel", "OdometryTerm", "OdometryEvaluation", "landmark_penalty"]

#: Bytes of one importance-sampling temporary (see ``OdometryTerm._sample_chunks``).
IMPORTANCE_CHUNK_BYTES = 128 * 1024


def landmark_penalty(positions, pairs, penalty_radius: float, max_penalty: float) -> np.ndarray:
    """Pen = sum over ``pairs`` (i, j) of f(|t_i - t_j|) for positions of shape (..., N, 2) (eq. 11-12).

    The caller passes the pairs in different sets (and may leave out pairs that
    cannot come within the radius: they contribute exactly 0).
    """
    first, second = pairs
    separation = positions[..., first, :] - positions[..., second, :]
    distances = np.hypot(separation[..., 0], separation[..., 1])
    closeness = np.clip(1.0 - distances / penalty_radius, 0.0, None)
    return max_penalty * np.sum(closeness**3, axis=-1)


@dataclass(frozen=True)
class OdometryEvaluation:
    """One uncached evaluation of log P(O | T) and how trustworthy it is."""

    log_likelihood: float  # the importance-sampling estimate
    laplace: float  # -E(P*) + (d/2) log 2 pi - 1/2 log det H (no penalty)
    standard_error: float  # delta-method Monte-Carlo standard error of the estimate [nats]
    ess: float  # effective sample size of the importance weights
    iterations: int  # Newton / Gauss-Newton / Levenberg-Marquardt iterations
    factorisations: int  # Hessian factorisations spent by the fit
    converged: bool
    solution: np.ndarray  # P*, the (d,) state vector of poses 1..N-1


class OdometryModel:
    """Specification of the odometry likelihood; ``bind(dataset)`` gives the term.

    Parameters
    ----------
    sigma_xy, sigma_theta : float
        Per-step odometry standard deviations [m, rad]; the covariance of a step
        is diag(sigma_xy^2, sigma_xy^2, sigma_theta^2) unless the dataset
        carries ``odometry_cov``, which then wins.
    sigma_topology : float
        Standard deviation [m] of the tie between positions of detections in the same set.
    penalty_radius : float
        D [m]: distinct places closer than this are penalised.
    max_penalty : float
        P_max [nats], the penalty at distance 0; 0 switches the density prior off.
    n_importance : int
        Importance samples S per evaluation.
    seed : int or numpy.random.SeedSequence
        Seed of the common random numbers.
    cache_size : int
        Bound on the per-partition memo.
    sparse_above : int
        Use sparse linear algebra when d = 3(N-1) exceeds this.
    """

    def __init__(self, sigma_xy: float = 0.1, sigma_theta: float = 0.05, sigma_topology: float = 0.3,
                 penalty_radius: float = 2.5, max_penalty: float = 100.0, n_importance: int = 100,
                 seed=0, cache_size: int = 100_000, sparse_above: int = SPARSE_ABOVE_DIMENSION):
        self.sigma_xy = positive("sigma_xy", sigma_xy)
        self.sigma_theta = positive("sigma_theta", sigma_theta)
        self.sigma_topology = positive("sigma_topology", sigma_topology)
        self.penalty_radius = positive("penalty_radius", penalty_radius)
        self.max_penalty = non_negative("max_penalty", max_penalty)
        if int(n_importance) != n_importance or n_importance < 1:
            raise ValueError(f"n_importance must be a positive integer, got {n_importance!r}")
        self.n_importance = int(n_importance)
        self.seed = seed
        self.cache_size = cache_size
        self.sparse_above = int(sparse_above)

    def bind(self, dataset) -> "OdometryTerm":
        """The likelihood term of this model for ``dataset`` (which must carry odometry)."""
        return OdometryTerm(self, dataset)

    def __repr__(self) -> str:
        return (f"OdometryModel(sigma_xy={self.sigma_xy}, sigma_theta={self.sigma_theta}, "
                f"sigma_topology={self.sigma_topology}, penalty_radius={self.penalty_radius}, "
                f"max_penalty={self.max_penalty}, n_importance={self.n_importance}, seed={self.seed!r})")


class OdometryTerm:
    """log P(O | T) for one dataset: memoised, deterministic given the model's seed.

    Each miss is a Laplace fit warm-started from the last solved partition's
    optimum, the most likely partition's optimum or dead reckoning, whichever
    is lowest in energy under the new partition, and converged tightly, so the value does not depend on the
    start beyond ~1e-9 relative. A fit that does not converge within the
    iteration limit is *recorded* (``diagnostics()["failures"]``) and its
    estimate is still used: the Gaussian at the last iterate is a valid
    importance-sampling proposal, only a less efficient one. A NaN or +inf
    estimate raises ``ValueError`` naming the partition.
    """

    name = "odometry"

    def __init__(self, model: OdometryModel, dataset):
        if dataset.odometry is None:
            raise ValueError("the odometry model needs a dataset with odometry (dataset.odometry is None)")
        self.model = model
        self.n = dataset.n
        steps = self.n - 1
        if dataset.odometry_cov is not None:
            covariances = dataset.odometry_cov
        else:
            variances = [model.sigma_xy**2, model.sigma_xy**2, model.sigma_theta**2]
            covariances = np.broadcast_to(np.diag(variances), (steps, 3, 3))
        self.graph = PoseGraph(dataset.odometry, odometry_sqrt_information(covariances), model.sigma_topology,
                               sparse_above=model.sparse_above)
        self.dimension = self.graph.dimension
        generator = np.random.default_rng(model.seed if isinstance(model.seed, np.random.SeedSequence)
                                          else np.random.SeedSequence(model.seed))
        # d rows for the poses plus up to N for the low-rank part of the factor (one per set and axis)
        noise = generator.standard_normal((model.n_importance, self.dimension + self.n))
        self._noise_columns = np.asfortranarray(noise.T)  # the layout LAPACK's triangular solves take as is
        # Samples are weighted in chunks whose temporaries (S x N x 3 poses and the like) stay under 128 KiB:
        # glibc hands larger freed blocks back to the operating system by default, and faulting them in again
        # on every evaluation cost about 1 ms of the 5 at N = 100.
        chunks = math.ceil(model.n_importance * 3 * self.n * 8 / IMPORTANCE_CHUNK_BYTES)
        chunk_size = math.ceil(model.n_importance / chunks)
        self._sample_chunks = [slice(begin, begin + chunk_size) for begin in range(0, model.n_importance, chunk_size)]
        self._pair_first, self._pair_second = np.triu_indices(self.n, k=1)
        self._dead_reckoning = self.graph.dead_reckoning()
        self._last_solution = self._dead_reckoning
        self._best_solution, self._best_value = self._dead_reckoning, -math.inf
        self._cache = BoundedCache(model.cache_size)
        self._evaluations = 0
        self._failures = 0
        self._iterations_total = 0
        self._iterations_max = 0
        self._factorisations_total = 0
        self._ess_total = 0.0
        self._ess_min = math.inf
        self._seconds = 0.0

    def log_likelihood(self, partition) -> float:
        """log P(O | T) of a :class:`ptm.Partition` or any label sequence (memoised)."""
        labels = _canonical_labels(partition)
        value = self._cache.get(labels)
        if value is None:
            value = self._evaluate_canonical(np.asarray(labels)).log_likelihood
            self._cache.put(labels, value)
        return value

    def evaluate(self, partition) -> OdometryEvaluation:
        """Compute log P(O | T) without the cache (records the evaluation in the diagnostics)."""
        return self._evaluate_canonical(np.asarray(_canonical_labels(partition)))

    def _evaluate_canonical(self, labels: np.ndarray) -> OdometryEvaluation:
        if len(labels) != self.n:
            raise ValueError(f"a partition of this dataset has {self.n} labels, got {len(labels)}")
        started = time.perf_counter()
        if self.n == 1:  # no free pose: the integral over a 0-dimensional space is 1
            return OdometryEvaluation(0.0, 0.0, 0.0, float(self.model.n_importance), 0, 0, True, np.zeros(0))
        topology = self.graph.topology(labels)
        fit = self.graph.fit(self._warm_start(topology), topology)
        evaluation = self._importance_sample(fit, labels)
        if not math.isfinite(evaluation.log_likelihood):
            raise ValueError(
                f"odometry log-likelihood of partition {tuple(labels.tolist())} is {evaluation.log_likelihood}"
            )
        self._last_solution = fit.x
        if evaluation.log_likelihood > self._best_value:
            self._best_solution, self._best_value = fit.x, evaluation.log_likelihood
        self._record(evaluation, time.perf_counter() - started)
        return evaluation

    def diagnostics(self) -> dict:
        """Cache use, importance-sampling quality and optimiser effort so far."""
        evaluations = self._evaluations
        return {
            **self._cache.stats(),
            "evaluations": evaluations,
            "ess_mean": self._ess_total / evaluations if evaluations else math.nan,
            "ess_min": self._ess_min if evaluations else math.nan,
            "n_importance": self.model.n_importance,
            "lm_iterations_mean": self._iterations_total / evaluations if evaluations else math.nan,
            "lm_iterations_max": self._iterations_max,
            "factorisations_mean": self._factorisations_total / evaluations if evaluations else math.nan,
            "failures": self._failures,
            "evaluation_ms_mean": 1e3 * self._seconds / evaluations if evaluations else math.nan,
            "linear_algebra": "sparse" if self.graph.sparse else "banded_low_rank",
        }

    # -- internals ------------------------------------------------------------------------------

    def _warm_start(self, topology) -> np.ndarray:
        """The lowest-energy start under ``topology`` among the last optimum, the optimum of the most
        likely partition so far (a sampler's current state usually is one of the likely ones) and
        dead reckoning."""
        candidates = (self._last_solution, self._best_solution, self._dead_reckoning)
        energies = self.graph.energy(np.stack(candidates), topology)
        return candidates[int(np.argmin(energies))]

    def _importance_sample(self, fit: LaplaceFit, labels) -> OdometryEvaluation:
        log_proposal_norm = 0.5 * self.dimension * math.log(2.0 * math.pi) - 0.5 * fit.factor.log_det()
        log_weights = log_proposal_norm + np.concatenate([
            self._log_weight_terms(fit, labels, self._noise_columns[:, chunk]) for chunk in self._sample_chunks
        ])
        largest = float(log_weights.max())
        weights = np.exp(log_weights - largest)
        estimate = largest + math.log(float(weights.mean()))
        ess = float(weights.sum() ** 2 / np.sum(weights**2))
        standard_error = float(weights.std() / (weights.mean() * math.sqrt(len(weights))))
        return OdometryEvaluation(
            log_likelihood=estimate,
            laplace=log_proposal_norm - fit.energy,
            standard_error=standard_error,
            ess=ess,
            iterations=fit.iterations,
            factorisations=fit.factorisations,
            converged=fit.converged,
            solution=fit.x,
        )

    def _log_weight_terms(self, fit: LaplaceFit, labels, noise_columns) -> np.ndarray:
        """1/2 delta^T H delta - E(P* + delta) - Pen(P* + delta) for the samples drawn from ``noise_columns``."""
        offsets, half_quadratic = fit.factor.sample(noise_columns)
        states = fit.x + offsets.T
        return half_quadratic - self.graph.energies_around(fit, offsets) - self._penalties(states, offsets, fit.x, labels)

    def _penalties(self, states, offsets, centre, labels) -> np.ndarray:
        """Pen of every sample (``states``: (S, d), their ``offsets`` from the ``centre`` P*: (d, S));
        pairs that no sample can bring within the radius are skipped exactly."""
        if self.model.max_penalty == 0.0 or self.n < 2:
            return np.zeros(len(states))
        reach = np.zeros(self.n)
        reach[1:] = np.sqrt(np.max(offsets[0::3] ** 2 + offsets[1::3] ** 2, axis=1))
        # triangle inequality: |t_i^s - t_j^s| >= |t_i* - t_j*| - reach_i - reach_j; pdist orders
        # the pairs as triu_indices does
        centre_distance = scipy.spatial.distance.pdist(poses_from_vector(centre)[:, :2])
        near = np.flatnonzero(centre_distance < self.model.penalty_radius + 2.0 * reach.max())
        first, second = self._pair_first[near], self._pair_second[near]
        may_touch = ((labels[first] != labels[second])
                     & (centre_distance[near] - reach[first] - reach[second] < self.model.penalty_radius))
        pairs = (first[may_touch], second[may_touch])
        return landmark_penalty(poses_from_vector(states)[..., :2], pairs, self.model.penalty_radius,
                                self.model.max_penalty)

    def _record(self, evaluation: OdometryEvaluation, seconds: float) -> None:
        self._evaluations += 1
        self._failures += not evaluation.converged
        self._iterations_total += evaluation.iterations
        self._iterations_max = max(self._iterations_max, evaluation.iterations)
        self._factorisations_total += evaluation.factorisations
        self._ess_total += evaluation.ess
        self._ess_min = min(self._ess_min, evaluation.ess)
        self._seconds += seconds

    def __repr__(self) -> str:
        return f"OdometryTerm(n={self.n}, model={self.model!r})"


def _canonical_labels(partition) -> tuple[int, ...]:
    if isinstance(partition, Partition):
        return partition.labels
    return Partition.from_labels(partition).labels
