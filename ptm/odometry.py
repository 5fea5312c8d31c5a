"""The odometry likelihood log P(O | T): Laplace proposal (plus a penalty component) and importance sampling.

Implements docs/model.md §3.3 (paper eq. 3 and 11-14). For a partition T,

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
1/2 |eps_s|^2 of docs/model.md §3.3, step 2; the structured factor of :mod:`ptm.pose_graph` draws
P_s from d + r normals instead and evaluates the quadratic form directly.)

Where the samples are placed (erratum E12 of docs/model.md): by default each
draw delta_s ~ N(0, H^-1) is read in the relative poses between consecutive
detections, P_s = C(u* + K delta_s) with u* the increments of P*, K = du/dP
at P* and C the composition from the origin (:func:`compose_linearised_increments`).
Both maps have unit Jacobian, so the weight formula above holds with the
same 1/2 delta^T H delta; only the states differ. A Gaussian in the poses
(``sampling_coordinates="poses"``, the paper) cannot follow the arcs on which
an uncertain heading swings the later poses of a long route: on a
78-detection grid its ESS was 1 of 100 and its estimate 33 nats low.

Where the penalty is active at P* (a pair of different sets closer than the
radius), Q alone gives heavy-tailed weights: the integrand's mass sits where
Pen pushes the pair apart, in Q's tail. The proposal is then a defensive
mixture (the variant of docs/model.md §3.3 (erratum E10) built around argmin(E + Pen), kept
alongside Q). By default (``penalty_proposal="mode"``) its second component
is the Laplace fit of exp(-E - Pen) over all poses: P-dagger = argmin (E + Pen)
by Newton steps from P* and its Hessian H-dagger (:meth:`OdometryTerm.penalised_mode`),
drawn in the same coordinates as Q; a state's density under each component
is that of its offset from the component's centre (the maps have unit
Jacobian, :func:`linearised_increment_offsets` inverts the composition), and
the balance-heuristic weight is exp(-E - Pen) / (1/2 Q + 1/2 Q_1). A split
detection has to travel a metre or more from its former place-mates, every
heading on the way adjusted, which the variant below cannot follow.
``penalty_proposal="subspace"`` (what the committed results were run with)
fits only the penalised positions. Let t = B P be the positions of the detections in the penalised
pairs (2m numbers), S = B H^-1 B^T their covariance under Q and t* = B P*.
Component 1 is the Laplace fit of Q(P) exp(-Pen(P)) in t: the mode t† of
1/2 (t - t*)^T S^-1 (t - t*) + Pen(t) (damped Newton in 2m dimensions) and
the inverse Hessian S† there (of Pen's positive semi-definite part where the
exact one is indefinite); the other poses follow Q's conditional given t.
Half the samples come from each (stratified: the same eps columns, the first
half from Q), and the balance-heuristic weights are

    log w_s = -E(P_s) - Pen(P_s) - log( 1/2 Q(P_s) + 1/2 Q_1(P_s) ),
    Q_1(P) / Q(P) = N(B P; t†, S†) / N(B P; t*, S),

a ratio of 2m-dimensional normal densities, so the mixture costs 2m solves
with H and small dense algebra. The estimate is the mean weight; its
Monte-Carlo standard error is the delta-method se(log mean w) = se(mean w) /
mean w with the stratified variance sum_c n_c var_c(w) / S^2. Without an
active pair the estimator is exactly the single-Gaussian one above.

Which minimum is P*: E has several local minima on implausible partitions
(in the headings), and a fit started from the previous partition's optimum
made the value depend on the chain's history (by hundreds of nats). P* is
therefore defined from the partition alone: the fit is run from two fixed
starts and the converged minimum of lower energy counts. By default
(``fit_starts="chordal"``) they are the chordal relaxation's headings with
their optimal positions (two sparse linear solves,
:mod:`ptm.pose_graph.chordal`) and dead reckoning; ``"aligned"`` (the rule
until 2026-12-06) uses dead reckoning and dead reckoning with its positions
moved to their optimum, and on long runs misses the minimum by hundreds of
nats (docs/model.md §3.3, "Which minimum is P*"). A fit that fails (iteration cap,
non-finite energy) is counted and listed per partition in the diagnostics:
with a positive definite Hessian at its last iterate that Gaussian is the
(documented) fallback proposal; without one the partition gets -inf, never NaN.

The noise matrix eps (S x (d + N)) is drawn once per bound term from the model's
seed (common random numbers), so the estimate is a deterministic function of
the partition (the mode t† is converged to rounding, so it is as history-free
as P*) and the MCMC target is well defined; results are memoised per
canonical partition in a bounded LRU cache. P* and H do not depend on the
importance sampler's settings (seed, sample count, penalty), so terms that
differ only in those can share one memo of fits (``OdometryTerm.rebind``):
comparing seeds or penalties on one dataset then fits each partition once.

    >>> from ptm import Dataset, PoissonPrior, Posterior
    >>> steps = np.tile([2.0, 0.0, np.pi / 2], (4, 1)) + np.random.default_rng(0).normal(0.0, [0.05, 0.05, 0.02], (4, 3))
    >>> model = OdometryModel(sigma_xy=0.05, sigma_theta=0.02, sigma_topology=0.1,     # a 2 m square driven once
    ...                       penalty_radius=1.0, max_penalty=100.0, n_importance=100, seed=0)
    >>> posterior = Posterior(Dataset(odometry=steps), PoissonPrior(4.0), [model])
    >>> posterior.log_prob([0, 1, 2, 3, 0]) > posterior.log_prob([0, 1, 2, 3, 4])       # the loop closes
    True
"""

from __future__ import annotations

import dataclasses
import math
import time
from dataclasses import dataclass

import numpy as np
import scipy.linalg
import scipy.sparse
import scipy.spatial.distance
from scipy.special import logsumexp

from ._cache import BoundedCache
from ._validation import non_negative, positive
from .partitions import Partition
from .se2 import compose, relative_pose, wrap_angle
from .pose_graph import (SPARSE_ABOVE_DIMENSION, DenseFactor, LaplaceFit, PoseGraph, SparseFactor,
                         odometry_sqrt_information, poses_from_vector)

__all__ = ["OdometryModel", "OdometryTerm", "OdometryEvaluation", "PenaltyMixture", "PenalisedMode",
           "FIT_STARTS", "PENALTY_PROPOSALS", "SAMPLING_COORDINATES", "compose_linearised_increments",
           "linearised_increment_offsets", "landmark_penalty"]

#: Where the importance samples are drawn (``OdometryModel.sampling_coordinates``).
SAMPLING_COORDINATES = ("poses", "increments")
#: How the proposal accounts for the penalty (``OdometryModel.penalty_proposal``): a Laplace fit of E + Pen
#: over all poses, or only over the penalised detections' positions with the rest following linearly.
PENALTY_PROPOSALS = ("mode", "subspace")
#: The history-free starts of the Laplace fit whose lower minimum is P* (``OdometryModel.fit_starts``,
#: :meth:`OdometryTerm.starts`): "chordal", the chordal relaxation's headings and dead reckoning; "aligned",
#: dead reckoning with its positions aligned and dead reckoning (the rule until 2026-12-06).
FIT_STARTS = ("chordal", "aligned")
#: Iterations of the search for argmin (E + Pen) (:meth:`OdometryTerm.penalised_mode`), and the Newton
#: decrement [nats] below which it stops: the centre of a proposal needs no more (and it converges only
#: linearly on the Gauss-Newton Hessian, about ten times closer per iteration).
PENALISED_MODE_ITERATIONS = 100
PENALISED_MODE_TOLERANCE = 1e-3
#: Up to this many variables d the penalised mode's Hessians are dense (LAPACK), above it sparse (SuperLU):
#: at N = 9 the sparse matrices' construction cost four times the rest of an evaluation.
DENSE_MODE_DIMENSION = 150
#: Bytes of one importance-sampling temporary (see ``OdometryTerm.sample_chunks``).
IMPORTANCE_CHUNK_BYTES = 128 * 1024
#: Share of the samples the defensive component N(P*, H^-1) keeps when the penalty component is used.
DEFENSIVE_SHARE = 0.5
#: Failed fits listed by partition in the diagnostics (all of them are counted).
FAILURES_KEPT = 20
#: Bytes the memo of Laplace modes (:meth:`OdometryTerm.laplace_mode`) may hold: 8 d bytes a partition.
MODE_MEMO_BYTES = 32 * 1024 * 1024


def landmark_penalty(positions, pairs, penalty_radius: float, max_penalty: float) -> np.ndarray:
    """Pen = sum over ``pairs`` (i, j) of f(|t_i - t_j|) for positions of shape (..., N, 2) (eq. 11-12).

    The caller passes the pairs in different sets (and may leave out pairs that
    cannot come within the radius: they contribute exactly 0).
    """
    first, second = pairs
    x, y = positions[..., 0], positions[..., 1]  # gathered per coordinate: 2-4 times faster than (..., P, 2)
    across, along = x[..., first] - x[..., second], y[..., first] - y[..., second]
    closeness = np.maximum(1.0 - np.sqrt(across * across + along * along) / penalty_radius, 0.0)
    return max_penalty * np.sum(closeness * closeness * closeness, axis=-1)


@dataclass(frozen=True)
class OdometryEvaluation:
    """One uncached evaluation of log P(O | T) and how trustworthy it is."""

    log_likelihood: float  # the importance-sampling estimate
    laplace: float  # -E(P*) + (d/2) log 2 pi - 1/2 log det H (no penalty)
    standard_error: float  # delta-method Monte-Carlo standard error of the estimate [nats], stratified
    ess: float  # effective sample size of the importance weights
    iterations: int  # Newton / Gauss-Newton / Levenberg-Marquardt iterations
    factorisations: int  # Hessian factorisations spent by the fit
    converged: bool
    solution: np.ndarray  # P*, the (d,) state vector of poses 1..N-1
    penalty_shift: float = 0.0  # |P-dagger - P*| in the metric of H (0: no penalty component in the proposal)


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
    sampling_coordinates : {"poses", "increments"}
        Where the Laplace Gaussian is drawn: around P* in the poses (the
        paper), or in the relative poses between consecutive detections,
        pushed through the composition (module docstring). Both estimate the
        same integral; on long routes only "increments" does so with useful
        effective sample sizes.
    penalty_proposal : {"mode", "subspace"}
        Where the importance proposal's penalty component is fitted (``PENALTY_PROPOSALS``).
    fit_starts : {"chordal", "aligned"}
        The fixed starts whose lower converged minimum is P* (``FIT_STARTS``,
        :meth:`OdometryTerm.starts`). "chordal" (the default) starts from the
        chordal relaxation's headings and from dead reckoning; "aligned", from dead
        reckoning with its positions aligned and from dead reckoning, misses the
        minimum of long runs (docs/model.md §3.3, "Which minimum is P*").
    """

    def __init__(self, sigma_xy: float = 0.1, sigma_theta: float = 0.05, sigma_topology: float = 0.3,
                 penalty_radius: float = 2.5, max_penalty: float = 100.0, n_importance: int = 100,
                 seed=0, cache_size: int = 100_000, sparse_above: int = SPARSE_ABOVE_DIMENSION,
                 sampling_coordinates: str = "increments", penalty_proposal: str = "mode",
                 fit_starts: str = "chordal"):
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
        if sampling_coordinates not in SAMPLING_COORDINATES:
            raise ValueError(f"sampling_coordinates must be one of {SAMPLING_COORDINATES}, got {sampling_coordinates!r}")
        self.sampling_coordinates = sampling_coordinates
        if penalty_proposal not in PENALTY_PROPOSALS:
            raise ValueError(f"penalty_proposal must be one of {PENALTY_PROPOSALS}, got {penalty_proposal!r}")
        self.penalty_proposal = penalty_proposal
        if fit_starts not in FIT_STARTS:
            raise ValueError(f"fit_starts must be one of {FIT_STARTS}, got {fit_starts!r}")
        self.fit_starts = fit_starts

    def bind(self, dataset) -> "OdometryTerm":
        """The likelihood term of this model for ``dataset`` (which must carry odometry)."""
        return OdometryTerm(self, dataset)

    def __repr__(self) -> str:
        return (f"OdometryModel(sigma_xy={self.sigma_xy}, sigma_theta={self.sigma_theta}, "
                f"sigma_topology={self.sigma_topology}, penalty_radius={self.penalty_radius}, "
                f"max_penalty={self.max_penalty}, n_importance={self.n_importance}, seed={self.seed!r}, "
                f"sampling_coordinates={self.sampling_coordinates!r}, penalty_proposal={self.penalty_proposal!r}, "
                f"fit_starts={self.fit_starts!r})")


class OdometryTerm:
    """log P(O | T) for one dataset: memoised, deterministic given the model's seed.

    Each miss is a Laplace fit from the history-free :meth:`starts` (the
    lower converged minimum counts, :meth:`fit`), so the value is a function
    of the partition alone, whatever was evaluated before. A fit that does not
    converge within the iteration limit is *recorded*
    (``diagnostics()["failures"]``, the first ``FAILURES_KEPT`` by partition
    in ``"failed_partitions"``) and its estimate is still used: the Gaussian
    at the last iterate is a valid importance-sampling proposal, only a less
    efficient one. A fit with no such Gaussian (non-finite energy, Hessian not
    positive definite) gives -inf (``"failures_minus_inf"``). A NaN or +inf
    estimate raises ``ValueError`` naming the partition.

    Attributes: ``graph`` (the :class:`ptm.pose_graph.PoseGraph` of the
    dataset), ``noise_columns`` (the common random numbers, (d + N, S)
    standard normals) and ``sample_chunks`` (the slices of the samples weighted
    together). :meth:`mode_poses` is the optimised map of a topology (drawn by the
    harness's figures and written by :mod:`ptm.export`); :meth:`laplace_mode` is
    its state vector P*, remembered for recently evaluated partitions (what the
    odometry surrogate of :mod:`ptm.surrogate` expands around).
    """

    name = "odometry"

    def __init__(self, model: OdometryModel, dataset):
        if dataset.odometry is None:
            raise ValueError("the odometry model needs a dataset with odometry (dataset.odometry is None)")
        self.model = model
        self.dataset = dataset  # the dataset bound (rebind binds other models to it)
        self._fits: BoundedCache | None = None  # Laplace fits by partition, shared with rebound terms (rebind)
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
        self.noise_columns = np.asfortranarray(noise.T)  # the layout LAPACK's triangular solves take as is
        # Samples are weighted in chunks whose temporaries (S x N x 3 poses and the like) stay under 128 KiB:
        # glibc hands larger freed blocks back to the operating system by default, and faulting them in again
        # on every evaluation cost about 1 ms of the 5 at N = 100.
        chunks = math.ceil(model.n_importance * 3 * self.n * 8 / IMPORTANCE_CHUNK_BYTES)
        chunk_size = math.ceil(model.n_importance / chunks)
        self.sample_chunks = [slice(begin, begin + chunk_size) for begin in range(0, model.n_importance, chunk_size)]
        self._pair_first, self._pair_second = np.triu_indices(self.n, k=1)
        self._dead_reckoning = self.graph.dead_reckoning()
        self._cache = BoundedCache(model.cache_size)
        self._modes = BoundedCache(max(1, MODE_MEMO_BYTES // (8 * max(self.dimension, 1))))
        self._converged_modes = BoundedCache(self._modes.maxsize)  # the same vectors, of converged fits only
        self._shorter_modes: BoundedCache | None = None  # the converged modes of the run one detection shorter
        self._extended_fits = 0
        self._evaluations = 0
        self._failures = 0
        self._failed_fits = 0  # failures without a usable fit: log-likelihood -inf
        self._failed_partitions: list[dict] = []  # the first FAILURES_KEPT of them, with the reason
        self._iterations_total = 0
        self._iterations_max = 0
        self._factorisations_total = 0
        self._ess_total = 0.0
        self._ess_min = math.inf
        self._standard_error_total = 0.0
        self._standard_error_max = 0.0
        self._penalty_mixtures = 0
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

    #: The model's settings that the Laplace fit depends on (with the dataset); the others only sample.
    FIT_SETTINGS = ("sigma_xy", "sigma_theta", "sigma_topology", "sparse_above", "fit_starts")

    def rebind(self, model: OdometryModel) -> "OdometryTerm":
        """The term of ``model`` on this term's dataset, sharing one memo of Laplace fits with this term.

        The fit of a partition (:meth:`fit`, the larger part of an evaluation's cost) depends on the
        dataset and on ``FIT_SETTINGS`` only, so ``model`` must agree with this term's model on
        those (else ``ValueError``, naming them) and may differ in the importance sampler: ``seed``,
        ``n_importance``, ``penalty_radius``, ``max_penalty``, ``cache_size``. From this call on,
        this term, the new one and every term rebound from either keep the fits of the partitions
        they evaluate in one LRU memo (bounded by this term's ``cache_size``; a fit holds a factor
        of H, so this costs memory that a lone term does not spend), and each partition is fitted
        once between them. Values are those of ``model.bind(term.dataset)`` (a fit is a function
        of the partition alone); the diagnostics' iterations and factorisations are those of the
        fit used, however often it was reused. For checks of the Monte-Carlo error, such as the
        spread of a posterior over importance seeds:

            >>> from ptm import Dataset
            >>> steps = np.tile([2.0, 0.0, np.pi / 2], (4, 1))                     # a 2 m square driven once
            >>> term = OdometryModel(0.05, 0.02, 0.1, 1.0, 100.0, seed=0).bind(Dataset(odometry=steps))
            >>> others = [term.rebind(OdometryModel(0.05, 0.02, 0.1, 1.0, 100.0, seed=s)) for s in (1, 2)]
            >>> values = [t.log_likelihood([0, 1, 2, 3, 0]) for t in (term, *others)]   # one fit, three samplers
        """
        differing = [name for name in self.FIT_SETTINGS if getattr(model, name) != getattr(self.model, name)]
        if differing:
            raise ValueError("rebind shares Laplace fits, which depend on "
                             + ", ".join(f"{name} (this term's model: {getattr(self.model, name)!r}, "
                                         f"the new one: {getattr(model, name)!r})" for name in differing)
                             + "; bind the model to the dataset instead")
        if self._fits is None:
            self._fits = BoundedCache(self.model.cache_size)
        term = OdometryTerm(model, self.dataset)
        term._fits = self._fits
        return term

    def grown(self, dataset) -> "OdometryTerm":
        """This term's model bound to ``dataset``, the run one detection longer (the online mapper's next
        detection), keeping this term's converged Laplace modes as starts (:meth:`fit`). ``ValueError``
        where ``dataset`` does not extend this term's run by one detection with the same odometry rows
        and covariances."""
        rows = self.n - 1
        before, after = self.dataset.odometry_cov, dataset.odometry_cov
        extends = (dataset.odometry is not None and dataset.n == self.n + 1
                   and np.array_equal(dataset.odometry[:rows], self.dataset.odometry)
                   and (rows == 0 or (before is None) == (after is None))
                   and (before is None or np.array_equal(after[:rows], before)))
        if not extends:
            raise ValueError("the dataset does not extend this term's run by one detection with the same "
                             "odometry rows and covariances; bind the model to it instead (model.bind(dataset))")
        term = OdometryTerm(self.model, dataset)
        term._shorter_modes = self._converged_modes
        return term

    def _extended_start(self, labels: np.ndarray) -> np.ndarray | None:
        """The shorter run's converged mode of ``labels[:-1]`` with the last pose composed onto it by the last
        odometry row, where this term was grown, the last detection is a place of its own and the mode is
        remembered; else None."""
        if self._shorter_modes is None or labels[-1] in labels[:-1]:
            return None
        mode = self._shorter_modes.get(_canonical_labels(labels[:-1]))
        if mode is None:
            return None
        last_pose = mode[-3:] if len(mode) else np.zeros(3)
        return np.concatenate([mode, compose(last_pose, self.dataset.odometry[-1])])

    def _evaluate_canonical(self, labels: np.ndarray) -> OdometryEvaluation:
        if len(labels) != self.n:
            raise ValueError(f"a partition of this dataset has {self.n} labels, got {len(labels)}")
        started = time.perf_counter()
        if self.n == 1:  # no free pose: the integral over a 0-dimensional space is 1
            return OdometryEvaluation(0.0, 0.0, 0.0, float(self.model.n_importance), 0, 0, True, np.zeros(0))
        fit = self._shared_fit(labels)
        if fit.factor is None:  # no minimum and no proposal: the partition gets probability 0
            evaluation = OdometryEvaluation(-math.inf, -math.inf, math.inf, 0.0, fit.iterations,
                                            fit.factorisations, False, fit.x)
        else:
            self._remember_mode(tuple(labels.tolist()), fit)
            evaluation = self._importance_sample(fit, labels)
        if math.isnan(evaluation.log_likelihood) or evaluation.log_likelihood == math.inf:
            raise ValueError(
                f"odometry log-likelihood of partition {tuple(labels.tolist())} is {evaluation.log_likelihood}"
            )
        if not fit.converged:
            self._failed_fits += fit.factor is None
            if len(self._failed_partitions) < FAILURES_KEPT:
                self._failed_partitions.append({
                    "labels": labels.tolist(), "reason": fit.failure,
                    "fallback": "-inf" if fit.factor is None else "Laplace proposal at the last iterate"})
        self._record(evaluation, time.perf_counter() - started)
        return evaluation

    def log_likelihood_upper_bound(self) -> float:
        """A bound no partition's log P(O | T) exceeds: the all-singletons value without penalty.

        The ties and the penalty are >= 0, so exp(-E_T - Pen_T) <= exp(-E_all-distinct) at every P, and
        the all-distinct energy is a chain of independent Gaussian steps (docs/model.md §3.3):
        sum_k 1/2 log det(2 pi Sigma_k). :func:`ptm.exact_posterior` uses it to skip partitions whose
        cheap score leaves them no chance of mattering.
        """
        _, log_det_whitening = np.linalg.slogdet(self.graph.sqrt_information)  # log |det U_k| = -1/2 log det Sigma_k
        return float(1.5 * (self.n - 1) * math.log(2.0 * math.pi) - log_det_whitening.sum())

    def diagnostics(self) -> dict:
        """Cache use, importance-sampling quality and optimiser effort so far.

        ``mc_standard_error_mean`` / ``_max`` summarise the estimator's own Monte-Carlo standard
        error [nats] over the evaluations, ``penalty_proposal_rate`` the share of them that
        needed the penalty component of the proposal.
        """
        evaluations = self._evaluations
        return {
            **self._cache.stats(),
            "evaluations": evaluations,
            "ess_mean": self._ess_total / evaluations if evaluations else math.nan,
            "ess_min": self._ess_min if evaluations else math.nan,
            "mc_standard_error_mean": self._standard_error_total / evaluations if evaluations else math.nan,
            "mc_standard_error_max": self._standard_error_max if evaluations else math.nan,
            "penalty_proposal_rate": self._penalty_mixtures / evaluations if evaluations else math.nan,
            "n_importance": self.model.n_importance,
            "lm_iterations_mean": self._iterations_total / evaluations if evaluations else math.nan,
            "lm_iterations_max": self._iterations_max,
            "factorisations_mean": self._factorisations_total / evaluations if evaluations else math.nan,
            "fits_from_shorter_run": self._extended_fits,
            "failures": self._failures,
            "failures_minus_inf": self._failed_fits,
            "failed_partitions": list(self._failed_partitions),
            "evaluation_ms_mean": 1e3 * self._seconds / evaluations if evaluations else math.nan,
            "linear_algebra": "sparse" if self.graph.sparse else "banded_low_rank",
        }

    # -- the estimator's steps (public so that tests can check each one against dense algebra) ----------

    def starts(self, topology) -> tuple[np.ndarray, ...]:
        """The history-free starts of the Laplace fit of ``topology``, by ``model.fit_starts``: "chordal", the
        chordal relaxation's headings with their optimal positions
        (:meth:`ptm.pose_graph.PoseGraph.chordal_start`), then dead reckoning; "aligned", dead reckoning,
        then dead reckoning with the positions moved to their optimum given the dead-reckoned headings
        (:meth:`ptm.pose_graph.PoseGraph.aligned_start`)."""
        if self.model.fit_starts == "chordal":
            return self.graph.chordal_start(topology), self._dead_reckoning
        return self._dead_reckoning, self.graph.aligned_start(topology)

    def fit(self, labels) -> LaplaceFit:
        """The Laplace fit that defines log P(O | T): of the minima reached from :meth:`starts`, the
        converged one of lowest energy (the first on a tie); a function of the partition alone.

        A term grown from a run one detection shorter (:meth:`grown`) reaches it for a partition whose
        last detection is a place of its own from the shorter run's converged mode of the other detections,
        when it has one: with that detection a leaf of the pose graph, held by its odometry row alone, the
        minima of E are those of the shorter run with the leaf composed onto them (zero residual), both
        :meth:`starts` are the shorter run's with the leaf composed on, and the Newton steps from the
        extended mode only polish it (a few factorisations instead of tens). The value agrees with the
        fit from the starts to the solver's tolerance (``tests/test_online.py``).
        """
        labels = np.asarray(labels)
        topology = self.graph.topology(labels)
        start = self._extended_start(labels)
        if start is not None:
            polished = self.graph.fit(start, topology)
            if polished.converged:
                self._extended_fits += 1
                return polished
        fits = [self.graph.fit(start, topology) for start in self.starts(topology)]
        usable = [fit for fit in fits if fit.factor is not None] or fits[:1]
        best = min(usable, key=lambda fit: (not fit.converged, fit.energy))
        iterations = sum(fit.iterations for fit in fits)
        factorisations = sum(fit.factorisations for fit in fits)
        return dataclasses.replace(best, iterations=iterations, factorisations=factorisations)

    def _shared_fit(self, labels: np.ndarray) -> LaplaceFit:
        """:meth:`fit`, from the memo that rebound terms share (:meth:`rebind`) when there is one."""
        if self._fits is None:
            return self.fit(labels)
        key = tuple(labels.tolist())
        fit = self._fits.get(key)
        if fit is None:
            fit = self.fit(labels)
            self._fits.put(key, fit)
        return fit

    def mode_poses(self, partition) -> np.ndarray:
        """The optimised map of a topology: the (N, 3) detection poses (x, y, theta) of the Laplace mode P*.

        P* is the minimiser of the pose-graph energy E_T that :meth:`fit` defines
        (docs/model.md §3.3, step 1: odometry distortion plus the ties of
        ``partition``, without the penalty), in the frame of detection 0, which
        sits at the origin. ``ValueError`` for a partition of another length,
        and for a fit that did not converge (its last iterate is not a mode).
        """
        labels = np.asarray(_canonical_labels(partition))
        if len(labels) != self.n:
            raise ValueError(f"a partition of this dataset has {self.n} labels, got {len(labels)}")
        if self.n == 1:
            return np.zeros((1, 3))
        fit = self._shared_fit(labels)
        if not fit.converged:
            raise ValueError(f"the pose graph of partition {tuple(labels.tolist())} has no converged mode "
                             f"({fit.failure})")
        return poses_from_vector(fit.x)

    def laplace_mode(self, partition) -> np.ndarray | None:
        """P*, the (d,) state vector of the Laplace fit that defines log P(O | T) (:meth:`fit`), or None where
        that fit has no Gaussian (the partition's log-likelihood is -inf).

        Remembered from the partition's evaluation (a bounded memo of ``MODE_MEMO_BYTES``), else fitted
        now; either way the same vector, since the fit is a function of the partition alone. Unlike
        :meth:`mode_poses` an unconverged fit's last iterate is returned: its Gaussian is the one the
        estimate used.
        """
        labels = _canonical_labels(partition)
        if len(labels) != self.n:
            raise ValueError(f"a partition of this dataset has {self.n} labels, got {len(labels)}")
        if self.n == 1:
            return np.zeros(0)
        mode = self._modes.get(labels)
        if mode is None:
            fit = self.fit(np.asarray(labels))
            if fit.factor is None:
                return None
            mode = fit.x
            self._remember_mode(labels, fit)
        return mode

    def _remember_mode(self, labels: tuple, fit: LaplaceFit) -> None:
        self._modes.put(labels, fit.x)
        if fit.converged:
            self._converged_modes.put(labels, fit.x)

    def _importance_sample(self, fit: LaplaceFit, labels) -> OdometryEvaluation:
        log_proposal_norm = 0.5 * self.dimension * math.log(2.0 * math.pi) - 0.5 * fit.factor.log_det()
        centre_distance = scipy.spatial.distance.pdist(poses_from_vector(fit.x)[:, :2])
        if self.model.penalty_proposal == "mode" and (
                mixture := self.penalised_mode(fit, labels, centre_distance)) is not None:
            log_weights = np.concatenate([self.mode_mixture_log_weights(fit, mixture, labels, centre_distance, chunk)
                                          for chunk in self.sample_chunks])
        else:  # no active pair for "mode" (then also none for "subspace", whose mixture is None)
            mixture = self.penalty_mixture(fit, labels, centre_distance)
            log_weights = log_proposal_norm + np.concatenate([
                self.log_weight_terms(fit, labels, centre_distance, mixture, chunk) for chunk in self.sample_chunks
            ])
        # stratified (deterministic allocation) balance-heuristic estimator: the mean of all weights
        estimate = float(logsumexp(log_weights)) - math.log(len(log_weights))
        weights = np.exp(log_weights - float(log_weights.max()))  # scaled weights, for the ESS and the error
        mean = float(weights.mean())
        ess = float(weights.sum() ** 2 / np.sum(weights**2))
        total = len(weights)
        variance = sum((component.stop - component.start) * float(weights[component].var())
                       for component in (mixture.components if mixture is not None else (slice(0, total),))) / total**2
        standard_error = math.sqrt(variance) / mean  # delta method: se(log I) = se(I) / I
        return OdometryEvaluation(
            log_likelihood=estimate,
            laplace=log_proposal_norm - fit.energy,
            standard_error=standard_error,
            ess=ess,
            iterations=fit.iterations,
            factorisations=fit.factorisations,
            converged=fit.converged,
            solution=fit.x,
            penalty_shift=mixture.shift if mixture is not None else 0.0,
        )

    def penalised_mode(self, fit: LaplaceFit, labels, centre_distance) -> "PenalisedMode | None":
        """The Laplace fit of exp(-E - Pen) over all poses, the second component of the ``"mode"`` proposal,
        or None when no pair of different sets is within the penalty radius at P* (nothing to fit).

        P-dagger = argmin (E + Pen) is searched from P* (so it is a function of the partition alone) by
        Newton steps on the Gauss-Newton Hessian of E plus the positive semi-definite part of Pen's
        (positive definite, so every step descends) with backtracking, until the predicted decrease is
        below ``PENALISED_MODE_TOLERANCE``; the pairs counted are those of different sets within the
        radius at each iterate. The component's precision H-dagger is that Hessian at P-dagger (at least
        the Gauss-Newton Hessian of E, so never flatter than E allows). The Hessians are dense up to
        ``DENSE_MODE_DIMENSION`` variables, sparse (SuperLU) above.
        """
        if self.model.max_penalty == 0.0 or self.n < 2 or not len(self._penalised_pairs(centre_distance, labels)):
            return None
        positions = self.graph.layout.positions  # the x and y entries of the state, detection by detection

        def penalised(x):  # (E + Pen at x, its Linearisation of E, the pairs' penalty there)
            linearisation = self.graph.linearise(x, fit.topology)
            penalty = self._penalty_at(x, labels)
            return linearisation.energy + penalty(x[positions].reshape(-1, 2)), linearisation, penalty

        dense = self.dimension <= DENSE_MODE_DIMENSION
        factorise = DenseFactor if dense else SparseFactor

        def hessian(linearisation, penalty):  # the Hessian (Pen's positive semi-definite part) and the gradient
            _, gradient, penalty_hessian = penalty.derivatives(linearisation.x[positions].reshape(-1, 2),
                                                               sparse=not dense)
            matrix = self.graph.hessian_matrix(fit.topology, linearisation.gauss_newton)
            if dense:
                matrix = matrix.toarray()
                matrix[np.ix_(positions, positions)] += penalty_hessian
            else:
                matrix = matrix + scipy.sparse.csc_matrix(
                    (penalty_hessian.data, (positions[penalty_hessian.row], positions[penalty_hessian.col])),
                    shape=(self.dimension, self.dimension))
            full_gradient = linearisation.gradient.copy()
            full_gradient[positions] += gradient
            return matrix, full_gradient

        x = fit.x
        value, linearisation, penalty = penalised(x)
        for _ in range(PENALISED_MODE_ITERATIONS):
            matrix, gradient = hessian(linearisation, penalty)
            factor = factorise(matrix)
            step = -factor.solve(gradient)
            slope = float(gradient @ step)
            if -0.5 * slope < PENALISED_MODE_TOLERANCE:
                break
            length = 1.0
            while length > 1e-10:
                candidate = penalised(x + length * step)
                if candidate[0] <= value + 1e-4 * length * slope:
                    break
                length *= 0.5
            else:
                break
            x = x + length * step
            value, linearisation, penalty = candidate
        else:  # out of iterations after a step: the Hessian at the last iterate
            matrix, _ = hessian(linearisation, penalty)
            factor = factorise(matrix)
        centre_hessian = self.graph.hessian_matrix(fit.topology, self.graph.linearise(fit.x, fit.topology).gauss_newton)
        offset = self._offsets_from(fit.x, x[None, :])[:, 0]
        shift = math.sqrt(max(float(offset @ (centre_hessian @ offset)), 0.0))
        if shift < 1e-9:  # the penalty does not move the mode
            return None
        # H-dagger keeps Pen's positive semi-definite part, not its exact Hessian: the tangential part can
        # leave it barely positive definite, with draws hundreds of metres long in its flat direction (it
        # did, on a 95-detection grid: an estimate of +129 000 nats)
        counts, components = self._component_shares()
        half_log_two_pi = 0.5 * self.dimension * math.log(2.0 * math.pi)
        return PenalisedMode(
            centres=(fit.x, x), factors=(fit.factor, factor), hessians=(centre_hessian, matrix),
            log_norms=np.array([half_log_two_pi - 0.5 * f.log_det() for f in (fit.factor, factor)]),
            log_alphas=np.log(np.array(counts) / sum(counts)), components=components, shift=shift)

    def mode_mixture_log_weights(self, fit: LaplaceFit, mode: "PenalisedMode", labels, centre_distance,
                                 chunk: slice) -> np.ndarray:
        """log w = -E - Pen - log(alpha_0 q_0 + alpha_1 q_1) for the samples of ``chunk``: q_0 the Laplace
        Gaussian at P*, q_1 the one at P-dagger (:meth:`penalised_mode`), both in the sampling coordinates
        (where a state's density is that of its offset from the component's centre: the maps have unit
        Jacobian)."""
        states = []
        for centre, component, factor in zip(mode.centres, mode.components, mode.factors):
            columns = slice(max(chunk.start, component.start), min(chunk.stop, component.stop))
            if columns.start < columns.stop:
                offsets, _ = factor.sample(np.asfortranarray(self.noise_columns[:, columns]))
                states.append(self._placed(centre, offsets)[0])
        states = np.concatenate(states)
        log_densities = []
        for centre, matrix, log_norm, log_alpha in zip(mode.centres, mode.hessians, mode.log_norms, mode.log_alphas):
            offsets = self._offsets_from(centre, states)
            log_densities.append(log_alpha - log_norm - 0.5 * np.einsum("ds,ds->s", offsets, matrix @ offsets))
        from_centre = states.T - fit.x[:, None]
        return (-self.graph.energies_around(fit, from_centre)
                - self.penalties(states, from_centre, fit.x, labels, centre_distance)
                - logsumexp(log_densities, axis=0))

    def _offsets_from(self, centre, states) -> np.ndarray:
        """The offsets (d, S) that :meth:`_placed` maps to ``states`` (S, d) around ``centre``."""
        if self.model.sampling_coordinates == "poses":
            return states.T - centre[:, None]
        return linearised_increment_offsets(centre, states)

    def _penalised_pairs(self, distance, labels) -> np.ndarray:
        """Indices (into ``pdist`` order) of the pairs of different sets closer than the penalty radius."""
        near = np.flatnonzero(distance < self.model.penalty_radius)
        return near[labels[self._pair_first[near]] != labels[self._pair_second[near]]]

    def _penalty_at(self, x, labels) -> "_PairPenalty":
        """Pen over the positions of detections 1..N-1 (rows 0..N-2; detection 0 is the origin, row -1),
        counting the pairs of different sets within the radius at the state ``x``."""
        near = self._penalised_pairs(scipy.spatial.distance.pdist(poses_from_vector(x)[:, :2]), labels)
        return _PairPenalty((self._pair_first[near] - 1, self._pair_second[near] - 1), self.n - 1,
                            self.model.penalty_radius, self.model.max_penalty)

    def _component_shares(self) -> tuple[list, tuple]:
        """The samples of the two mixture components: their counts and slices (the defensive one first)."""
        total = self.model.n_importance
        counts = [total - int(total * (1.0 - DEFENSIVE_SHARE)), int(total * (1.0 - DEFENSIVE_SHARE))]
        bounds = np.cumsum([0] + counts)
        return counts, tuple(slice(bounds[c], bounds[c + 1]) for c in range(len(counts)))

    def log_weight_terms(self, fit: LaplaceFit, labels, centre_distance, mixture, chunk: slice) -> np.ndarray:
        """1/2 delta^T H delta - E(P* + delta) - Pen(P* + delta) for the samples of ``chunk`` without the
        penalty mixture; with it, -E - Pen - log(sum_c alpha_c exp(-Q_c)), Q_c = 1/2 (x - m_c)^T H (x - m_c)."""
        offsets, half_quadratic = fit.factor.sample(self.noise_columns[:, chunk])
        if mixture is None:
            states, offsets = self._placed(fit.x, offsets)
            return (half_quadratic - self.graph.energies_around(fit, offsets)
                    - self.penalties(states, offsets, fit.x, labels, centre_distance))
        # Component c draws the positions t of the penalised detections from N(t_c, S_c) and the rest of the
        # poses from q_0's conditional given t: delta' = delta + R (tau' - tau), R = H^-1 B^T S^-1, with
        # tau = B delta ~ N(0, S) and tau' = t_c - t* + L_c L^-1 tau. Then q_c(x) / q_0(x) is a ratio of
        # 2m-dimensional normal densities of tau', and 1/2 delta'^T H delta' = 1/2 delta^T H delta
        # - 1/2 |L^-1 tau|^2 + 1/2 |L^-1 tau'|^2 (since R^T H R = S^-1 and H R = B^T S^-1).
        component_of = mixture.component_of[chunk]
        local = _lower_solve(mixture.factor, mixture.selector.T @ offsets)  # L^-1 tau
        moved = local.copy()
        for c in range(1, len(mixture.means)):
            columns = component_of == c
            moved[:, columns] = mixture.means[c][:, None] + mixture.relative_factors[c] @ local[:, columns]
        offsets = offsets + mixture.regression @ (moved - local)  # R (tau' - tau) = H^-1 B^T L^-T (u' - u)
        quadratic_at_centre = half_quadratic + 0.5 * (np.einsum("ms,ms->s", moved, moved)
                                                      - np.einsum("ms,ms->s", local, local))
        exponents = np.empty((len(mixture.means), len(component_of)))
        for c, (mean, relative_factor, log_det) in enumerate(zip(mixture.means, mixture.relative_factors,
                                                                 mixture.relative_log_dets)):
            standardised = (moved if c == 0 else
                            _lower_solve(relative_factor, moved - mean[:, None]))
            exponents[c] = (mixture.log_alphas[c] - 0.5 * np.einsum("ms,ms->s", standardised, standardised)
                            - log_det + 0.5 * np.einsum("ms,ms->s", moved, moved))
        log_ratio = logsumexp(exponents, axis=0)  # log sum_c alpha_c q_c / q_0
        states, offsets = self._placed(fit.x, offsets)
        return (quadratic_at_centre - log_ratio - self.graph.energies_around(fit, offsets)
                - self.penalties(states, offsets, fit.x, labels, centre_distance))

    def _placed(self, centre, offsets) -> tuple[np.ndarray, np.ndarray]:
        """The sampled states (S, d) for proposal draws ``offsets`` (d, S) around P* = ``centre``, and
        their actual offsets from P*: P* + delta in "poses" coordinates, else
        :func:`compose_linearised_increments`."""
        if self.model.sampling_coordinates == "poses":
            return centre + offsets.T, offsets
        states = compose_linearised_increments(centre, offsets)
        return states, states.T - centre[:, None]

    def penalty_mixture(self, fit: LaplaceFit, labels, centre_distance) -> "PenaltyMixture | None":
        """The defensive mixture of N(P*, H^-1) and a Laplace fit of the penalised target, or None when no pair
        of different sets is within the penalty radius at P* (then P* is also a stationary point of E + Pen).

        The second component is the Laplace fit of q_0(x) exp(-Pen(x)) over the positions t = B x of
        the detections in the pairs penalised at P*: with S = B H^-1 B^T the covariance of t under
        q_0, the mode t-dagger of 1/2 (t - t*)^T S^-1 (t - t*) + Pen(t) (damped Newton steps in these
        2m dimensions) and the inverse Hessian there; the other poses follow q_0's conditional given t.
        """
        if self.model.max_penalty == 0.0 or self.n < 2:
            return None
        near = self._penalised_pairs(centre_distance, labels)
        if not len(near):
            return None
        first, second = self._pair_first[near], self._pair_second[near]
        detections = np.unique(np.concatenate([first, second]))
        detections = detections[detections > 0]  # pose 0 is fixed at the origin
        row = np.full(self.n, -1)  # pose 0 -> the origin row of _PairPenalty
        row[detections] = np.arange(len(detections))
        pairs = (row[first], row[second])
        selector = _position_selector(detections, self.dimension)  # B^T, (d, 2m)
        regression = fit.factor.solve(selector)  # H^-1 B^T
        covariance = selector.T @ regression  # S = B H^-1 B^T
        factor = np.linalg.cholesky(0.5 * (covariance + covariance.T))  # L
        centre = selector.T @ fit.x  # t*: the positions of the penalised detections at P*
        penalty = _PairPenalty(pairs, len(detections), self.model.penalty_radius, self.model.max_penalty)
        target = _penalty_mode(centre, factor, penalty)
        # everything below lives in coordinates u = L^-1 (t - t*), where q_0 is N(0, I)
        mean = _solve_triangular(factor, target - centre, lower=True)
        shift = float(np.linalg.norm(mean))  # |P-dagger - P*| in the metric of H
        if shift < 1e-9:  # the penalty does not move the mode
            return None
        for tangential in (True, False):  # the exact Hessian of Pen, else its positive semi-definite part
            _, _, hessian = penalty.derivatives(target.reshape(-1, 2), tangential=tangential)
            try:
                precision_factor = np.linalg.cholesky(np.eye(len(mean)) + factor.T @ hessian @ factor)
                break
            except np.linalg.LinAlgError:
                continue
        inverse = _solve_triangular(precision_factor, np.eye(len(mean)), lower=True)
        means = [np.zeros(len(mean)), mean]
        factors = [np.eye(len(mean)), np.linalg.cholesky(inverse.T @ inverse)]  # F F^T = precision^-1
        counts, components = self._component_shares()
        component_of = np.repeat(np.arange(len(means)), counts)
        return PenaltyMixture(
            selector=selector,
            regression=_solve_triangular(factor, regression.T, lower=True).T,
            factor=factor,
            means=means,
            relative_factors=factors,
            relative_log_dets=[float(np.sum(np.log(np.diag(f)))) for f in factors],
            log_alphas=np.log(np.array(counts) / sum(counts)),
            component_of=component_of,
            components=components,
            shift=shift,
        )

    def penalties(self, states, offsets, centre, labels, centre_distance) -> np.ndarray:
        """Pen of every sample (``states``: (S, d), their ``offsets`` from the ``centre`` P*: (d, S));
        pairs that no sample can bring within the radius are skipped exactly."""
        if self.model.max_penalty == 0.0 or self.n < 2:
            return np.zeros(len(states))
        reach = np.zeros(self.n)
        reach[1:] = np.sqrt(np.max(offsets[0::3] ** 2 + offsets[1::3] ** 2, axis=1))
        # triangle inequality: |t_i^s - t_j^s| >= |t_i* - t_j*| - reach_i - reach_j; pdist orders
        # the pairs as triu_indices does
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
        self._standard_error_total += evaluation.standard_error
        self._standard_error_max = max(self._standard_error_max, evaluation.standard_error)
        self._penalty_mixtures += evaluation.penalty_shift > 0.0
        self._seconds += seconds

    def __repr__(self) -> str:
        return f"OdometryTerm(n={self.n}, model={self.model!r})"


@dataclass(frozen=True)
class PenaltyMixture:
    """The proposal's components, in the coordinates u = L^-1 (t - t*) of the penalised detections'
    positions t = B x, where q_0 = N(P*, H^-1) has u ~ N(0, I): component c draws u from
    N(``means``[c], F_c F_c^T), F_c = ``relative_factors``[c], and the other poses from q_0's
    conditional given t."""

    selector: np.ndarray  # B^T, (d, 2m)
    regression: np.ndarray  # H^-1 B^T L^-T, (d, 2m): the shift of all poses per unit of u
    factor: np.ndarray  # L, lower Cholesky factor of S = B H^-1 B^T
    means: list  # (2m,) per component, component 0 at 0
    relative_factors: list  # (2m, 2m) lower triangular per component, component 0 the identity
    relative_log_dets: list  # log det F_c
    log_alphas: np.ndarray  # (K,): the share of the samples each component draws
    component_of: np.ndarray  # (S,): the component that draws sample s
    components: tuple  # slices of the samples of each component
    shift: float  # |u-dagger| = sqrt((P-dagger - P*)^T H (P-dagger - P*))


@dataclass(frozen=True)
class PenalisedMode:
    """The ``"mode"`` proposal: q_0 = the Laplace Gaussian at P* and q_1 = the one at P-dagger = argmin (E + Pen),
    each a Gaussian in the sampling coordinates around its centre."""

    centres: tuple  # (P*, P-dagger), (d,) each
    factors: tuple  # (the fit's factor of H, a DenseFactor or SparseFactor of H-dagger)
    hessians: tuple  # (d, d): H at P* (the Gauss-Newton Hessian of E, sparse) and H-dagger (dense or sparse)
    log_norms: np.ndarray  # (2,): d/2 log 2 pi - 1/2 log det H_c
    log_alphas: np.ndarray  # (2,): the share of the samples each component draws
    components: tuple  # slices of the samples of each component
    shift: float  # the offset of P-dagger from P* in the metric of H (its "distance" in standard deviations)


def compose_linearised_increments(centre, offsets) -> np.ndarray:
    """States (S, d) u -> P(u) for u = u* + K delta: ``offsets`` delta (d, S) mapped to relative poses.

    u* are the relative poses between consecutive detections at P* = ``centre``
    (d,), K = du/dP there, and P(u) composes u from the fixed origin. K and the
    composition are triangular with rotation (or unit) diagonal blocks, so both
    have determinant 1: if delta ~ N(0, H^-1), the state P(u* + K delta) has
    density N(delta; 0, H^-1) in the increments' coordinates, where the integral
    of exp(-E - Pen) is the same as in the poses'. The importance weights keep
    their form; only the states change. Odometry constrains the increments
    directly, so this Gaussian stays close to the integrand on long routes,
    whereas in the poses a heading error swings every later pose on an arc that
    a Gaussian in the poses cannot follow.

        >>> centre = np.array([1.0, 0.0, 0.5, 2.0, 0.5, 1.0])         # two poses after the origin
        >>> np.allclose(compose_linearised_increments(centre, np.zeros((6, 1))), centre)
        True
    """
    centre = np.asarray(centre, dtype=float)
    samples = offsets.shape[1]
    poses = poses_from_vector(centre)  # (N, 3), the origin first
    moves = np.concatenate([np.zeros((1, 3, samples)), offsets.reshape(-1, 3, samples)])  # (N, 3, S)
    before, after = poses[:-1], poses[1:]
    cos, sin = np.cos(before[:, 2])[:, None], np.sin(before[:, 2])[:, None]
    dx, dy = (after[:, 0] - before[:, 0])[:, None], (after[:, 1] - before[:, 1])[:, None]
    forward, left = cos * dx + sin * dy, -sin * dx + cos * dy  # u*: the step in the frame of the pose before
    ddx, ddy = moves[1:, 0] - moves[:-1, 0], moves[1:, 1] - moves[:-1, 1]
    turn_before = moves[:-1, 2]
    step_forward = forward + cos * ddx + sin * ddy + left * turn_before
    step_left = left - sin * ddx + cos * ddy - forward * turn_before
    step_turn = (after[:, 2] - before[:, 2])[:, None] + moves[1:, 2] - moves[:-1, 2]
    headings = np.cumsum(step_turn, axis=0)  # heading of pose k (the origin's is 0)
    heading_before = np.concatenate([np.zeros((1, samples)), headings[:-1]])
    cos_h, sin_h = np.cos(heading_before), np.sin(heading_before)
    x = np.cumsum(cos_h * step_forward - sin_h * step_left, axis=0)
    y = np.cumsum(sin_h * step_forward + cos_h * step_left, axis=0)
    return np.stack([x, y, headings], axis=1).reshape(-1, samples).T


def linearised_increment_offsets(centre, states) -> np.ndarray:
    """The inverse of :func:`compose_linearised_increments`: the offsets delta (d, S) with
    ``compose_linearised_increments(centre, delta) == states`` for states (S, d), i.e.
    delta = K^-1 (u(states) - u*), K^-1 the linearised composition at P* = ``centre``.

        >>> centre = np.array([1.0, 0.0, 0.5, 2.0, 0.5, 1.0])
        >>> delta = np.random.default_rng(0).normal(0.0, 0.1, (6, 3))
        >>> np.allclose(linearised_increment_offsets(centre, compose_linearised_increments(centre, delta)), delta)
        True
    """
    centre, states = np.asarray(centre, dtype=float), np.asarray(states, dtype=float)
    samples = states.shape[0]

    centre_poses = poses_from_vector(centre)[:, :, None]  # (N, 3, 1)
    sampled_poses = poses_from_vector(states)  # (S, N, 3)
    # u(states) - u*: (N - 1, 3, S), the step in the frame of the pose before and the turn
    change = np.moveaxis(relative_pose(sampled_poses[:, :-1], sampled_poses[:, 1:])
                         - relative_pose(centre_poses[:-1, :, 0], centre_poses[1:, :, 0]), 0, -1)
    change[:, 2] = wrap_angle(change[:, 2])
    turns = np.cumsum(change[:, 2], axis=0)  # the heading offset of poses 1..N-1
    turn_before = np.concatenate([np.zeros((1, samples)), turns[:-1]])
    before = centre_poses[:-1, :, 0]
    cos, sin = np.cos(before[:, 2])[:, None], np.sin(before[:, 2])[:, None]
    step_x = (centre_poses[1:, 0] - centre_poses[:-1, 0])  # (N - 1, 1)
    step_y = (centre_poses[1:, 1] - centre_poses[:-1, 1])
    # d t_k = d t_{k-1} + R(theta*_{k-1}) d s_k + d theta_{k-1} perp(t*_k - t*_{k-1}), perp(x, y) = (-y, x)
    x = np.cumsum(cos * change[:, 0] - sin * change[:, 1] - turn_before * step_y, axis=0)
    y = np.cumsum(sin * change[:, 0] + cos * change[:, 1] + turn_before * step_x, axis=0)
    return np.stack([x, y, turns], axis=1).reshape(-1, samples)


def _position_selector(detections, dimension: int) -> np.ndarray:
    """B^T (d, 2m): column 2q + a picks t_i[a] of the q-th of the free ``detections`` i >= 1."""
    matrix = np.zeros((dimension, 2 * len(detections)))
    for axis in (0, 1):
        matrix[3 * (detections - 1) + axis, 2 * np.arange(len(detections)) + axis] = 1.0
    return matrix


class _PairPenalty:
    """Pen(t) = sum over ``pairs`` (i, j) of rows of the positions t (m, 2) of f(|t_i - t_j|) (row -1: pose 0
    at the origin), and its derivatives; the pairs' index arithmetic is done once, for the many evaluations
    of one penalty mode."""

    def __init__(self, pairs, rows: int, penalty_radius: float, max_penalty: float):
        self.first, self.second = pairs
        self.rows = rows
        self.penalty_radius, self.max_penalty = penalty_radius, max_penalty
        padded_rows = rows + 1  # the origin appended
        first, second = self.first % padded_rows, self.second % padded_rows
        # entries summed in the order of np.add.at over the first then the second rows (so bit for bit
        # its sums): the gradient's (row, axis), the Hessian's (row, axis, row, axis) of each pair's block
        self._gradient_entries = (2 * np.concatenate([first, second])[:, None] + np.arange(2)).ravel()
        block_rows, block_cols = (np.concatenate([first, second, first, second]),
                                  np.concatenate([first, second, second, first]))
        axis_rows, axis_cols = np.divmod(np.arange(4), 2)
        self._hessian_entries = (((2 * block_rows[:, None] + axis_rows) * padded_rows + block_cols[:, None]) * 2
                                 + axis_cols).ravel()

    def _separations(self, positions):
        padded = np.concatenate([positions, np.zeros((1, 2))])  # row -1: the origin
        separation = padded[self.first] - padded[self.second]
        distances = np.hypot(separation[:, 0], separation[:, 1])
        closeness = np.clip(1.0 - distances / self.penalty_radius, 0.0, None)
        return separation, distances, closeness

    def __call__(self, positions) -> float:
        """Pen of the positions t (m, 2)."""
        return self.max_penalty * float(np.sum(self._separations(positions)[2] ** 3))

    def derivatives(self, positions, tangential: bool = False, sparse: bool = False):
        """Pen, its gradient (2m,) and its Hessian (2m, 2m) without the tangential part f'(d)/d (I - u u^T)
        of each pair, which is negative (as Gauss-Newton leaves out residual curvature): what is kept,
        f''(d) u u^T per pair, is positive semi-definite; with ``tangential`` the exact Hessian. With
        ``sparse`` the Hessian is a ``scipy.sparse.coo_matrix`` (duplicate entries to be summed)."""
        separation, distances, closeness = self._separations(positions)
        value = self.max_penalty * float(np.sum(closeness**3))
        units = separation / np.where(distances > 0.0, distances, np.inf)[:, None]
        slope = -3.0 * self.max_penalty / self.penalty_radius * closeness**2  # f'(d)
        curvature = 6.0 * self.max_penalty / self.penalty_radius**2 * closeness  # f''(d) >= 0
        pulls = slope[:, None] * units
        padded_size = 2 * (self.rows + 1)
        gradient = np.bincount(self._gradient_entries, weights=np.concatenate([pulls, -pulls]).ravel(),
                               minlength=padded_size)
        blocks = curvature[:, None, None] * units[:, :, None] * units[:, None, :]
        if tangential:
            bend = slope / np.where(distances > 0.0, distances, np.inf)
            blocks += bend[:, None, None] * (np.eye(2) - units[:, :, None] * units[:, None, :])
        entries = np.concatenate([blocks, blocks, -blocks, -blocks]).ravel()
        size = 2 * self.rows
        if sparse:  # the entries' flat indices into the padded matrix, without the origin's rows and columns
            rows, cols = np.divmod(self._hessian_entries, padded_size)
            kept = (rows < size) & (cols < size)
            return value, gradient[:size], scipy.sparse.coo_matrix((entries[kept], (rows[kept], cols[kept])),
                                                                   shape=(size, size))
        hessian = np.bincount(self._hessian_entries, weights=entries,
                              minlength=padded_size**2).reshape(padded_size, padded_size)
        return value, gradient[:size], hessian[:size, :size]


def _penalty_mode(centre, covariance_lower, penalty: _PairPenalty, max_iterations: int = 100) -> np.ndarray:
    """argmin_t 1/2 (t - t*)^T S^-1 (t - t*) + Pen(t) over the positions t (2m,) of the penalised
    detections, from t = t*, by Newton steps (on Pen's positive semi-definite Hessian part where
    the exact one makes the system indefinite) with backtracking.

    Converged to rounding (the mode has to be a smooth function of P*: a sampler's value of a
    partition must not depend on where its fit was warm-started).
    """
    precision, _ = scipy.linalg.lapack.dpotrs(covariance_lower, np.eye(len(centre)), lower=1)  # S^-1, as cho_solve
    point = centre.copy()

    def objective(t):
        offset = t - centre
        return 0.5 * float(offset @ precision @ offset) + penalty(t.reshape(-1, 2))

    value = objective(point)
    for _ in range(max_iterations):
        _, penalty_gradient, penalty_hessian = penalty.derivatives(point.reshape(-1, 2), tangential=True)
        gradient = precision @ (point - centre) + penalty_gradient
        try:
            step = -_positive_definite_solve(precision + penalty_hessian, gradient)
        except np.linalg.LinAlgError:
            _, _, penalty_hessian = penalty.derivatives(point.reshape(-1, 2))
            step = -_positive_definite_solve(precision + penalty_hessian, gradient)
        slope = float(gradient @ step)
        if slope > -1e-14 * (1.0 + abs(value)):
            break
        length = 1.0
        while length > 1e-10:
            candidate = point + length * step
            candidate_value = objective(candidate)
            if candidate_value <= value + 1e-4 * length * slope:
                break
            length *= 0.5
        else:
            break
        point, value = candidate, candidate_value
        if np.max(np.abs(length * step)) < 1e-12 * (1.0 + np.max(np.abs(point))):
            break
    return point


def _lower_solve(lower, rhs) -> np.ndarray:
    """lower^-1 rhs for a lower-triangular ``lower`` (LAPACK directly: the checked wrapper costs more here)."""
    solution, info = scipy.linalg.lapack.dtrtrs(lower, rhs, lower=1)
    if info != 0:
        raise ValueError(f"triangular solve failed (LAPACK info {info})")
    return solution


def _positive_definite_solve(matrix, rhs) -> np.ndarray:
    """matrix^-1 rhs by Cholesky; ``numpy.linalg.LinAlgError`` when matrix is not positive definite."""
    lower = np.linalg.cholesky(matrix)
    return _solve_triangular(lower.T, _solve_triangular(lower, rhs, lower=True), lower=False)


def _solve_triangular(matrix, rhs, lower: bool) -> np.ndarray:
    """``scipy.linalg.solve_triangular(matrix, rhs, lower=lower)``, calling LAPACK as it does (a C-ordered
    matrix transposed, so in Fortran order, and solved transposed) without its checks, which cost
    15-130 us a call here."""
    if matrix.flags.f_contiguous:
        solution, info = scipy.linalg.lapack.dtrtrs(matrix, rhs, lower=lower, trans=0)
    else:
        solution, info = scipy.linalg.lapack.dtrtrs(matrix.T, rhs, lower=not lower, trans=1)
    if info != 0:
        raise ValueError(f"triangular solve failed (LAPACK info {info})")
    return solution


def _canonical_labels(partition) -> tuple[int, ...]:
    if isinstance(partition, Partition):
        return partition.labels
    return Partition.from_labels(partition).labels
