"""The odometry term log P(O | T) of one dataset: memoised, deterministic given the model's seed (docs/model.md
§3.3).

Binding an :class:`~ptm.odometry.OdometryModel` to a dataset builds the pose graph of its odometry
(:mod:`ptm.pose_graph`), the fitter of P* (:mod:`ptm.odometry.laplace`) and the importance sampler with its
common random numbers (:mod:`ptm.odometry.importance`). The value of a partition is a function of the
partition alone -- the fit's starts depend on nothing else and the random numbers are common -- so it is
memoised per canonical partition in a bounded LRU cache (step 3), and the MCMC target is a fixed distribution.
P* and H do not depend on the importance sampler's settings (seed, sample count, penalty), so terms that
differ only in those can share one memo of fits (:meth:`OdometryTerm.rebind`): comparing seeds or penalties on
one dataset then fits each partition once.

Besides its value the term offers the screen of a posterior it is part of (:meth:`OdometryTerm.screen`, an
:class:`~ptm.odometry.surrogate.OdometrySurrogate`), the optimised map of a partition
(:meth:`OdometryTerm.mode_poses`) and the term of the run one detection longer (:meth:`OdometryTerm.grown`,
:mod:`ptm.odometry.growth`). With a ``noise_scale_prior`` the value is integrated over the noise scale
(:mod:`ptm.odometry.noise_scale`; docs/model.md §3.3, "Noise scale").

    >>> from ptm import Dataset, OdometryModel
    >>> steps = np.tile([2.0, 0.0, np.pi / 2], (4, 1))                     # a 2 m square, back at the start
    >>> term = OdometryModel(0.05, 0.02, 0.1, penalty_radius=1.0, max_penalty=100.0).bind(Dataset(odometry=steps))
    >>> term.log_likelihood([0, 1, 2, 3, 0]) > term.log_likelihood([0, 1, 2, 3, 4])       # the loop closes
    True
    >>> term.log_likelihood([5, 6, 7, 8, 5]) == term.log_likelihood([0, 1, 2, 3, 0]), term.diagnostics()["evaluations"]
    (True, 2)
"""

from __future__ import annotations

import dataclasses
import math
import time

import numpy as np

from .._cache import BoundedCache
from ..partitions import Partition
from ..pose_graph import LaplaceFit, PoseGraph, odometry_sqrt_information, poses_from_vector
from .covariance_range import step_covariances
from .growth import ShorterRun, extends_by_one
from .importance import ImportanceSampler, OdometryEvaluation
from .laplace import LaplaceFitter
from .noise_scale import NoiseScalePrior
from .surrogate import OdometrySurrogate

__all__ = ["OdometryTerm"]

#: Failed fits listed by partition in the diagnostics (all of them are counted).
FAILURES_KEPT = 20
#: Bytes the memo of Laplace modes (:meth:`OdometryTerm.laplace_mode`) may hold: 8 d bytes a partition.
MODE_MEMO_BYTES = 32 * 1024 * 1024


class OdometryTerm:
    """log P(O | T) for one dataset: memoised, deterministic given the model's seed.

    Each miss is a Laplace fit (:meth:`fit`) and importance sampling around it. A fit that does not
    converge within the iteration limit is *recorded* (``diagnostics()["failures"]``, the first
    ``FAILURES_KEPT`` by partition in ``"failed_partitions"``) and its estimate is still used: the Gaussian
    at the last iterate is a valid importance-sampling proposal, only a less efficient one. A fit with no
    such Gaussian (non-finite energy, Hessian not positive definite) gives -inf (``"failures_minus_inf"``).
    A NaN or +inf estimate raises ``ValueError`` naming the partition.

    Attributes: ``model``, ``dataset``, ``n``, ``graph`` (the :class:`ptm.pose_graph.PoseGraph` of the
    dataset), ``fitter`` (its :class:`~ptm.odometry.laplace.LaplaceFitter`) and ``sampler`` (its
    :class:`~ptm.odometry.importance.ImportanceSampler`). :meth:`laplace_mode` is the state vector P*,
    remembered for recently evaluated partitions (what the screen expands around). ``shorter``, the modes of
    the run one detection shorter, is what :meth:`grown` passes.
    """

    name = "odometry"
    #: The model's settings that the Laplace fit depends on (with the dataset); the others only sample.
    FIT_SETTINGS = ("sigma_xy", "sigma_theta", "sigma_topology", "sparse_above")

    def __init__(self, model, dataset, shorter: ShorterRun | None = None):
        if dataset.odometry is None:
            raise ValueError("the odometry model needs a dataset with odometry (dataset.odometry is None)")
        self.model = model
        self.dataset = dataset  # the dataset bound (rebind binds other models to it)
        self.n = dataset.n
        covariances = step_covariances(model, dataset)
        self.graph = PoseGraph(dataset.odometry, odometry_sqrt_information(covariances), model.sigma_topology,
                               sparse_above=model.sparse_above)
        self.dimension = self.graph.dimension
        self.fitter = LaplaceFitter(self.graph, shorter)
        self.sampler = ImportanceSampler(self.graph, model.n_importance, model.seed, model.penalty_radius,
                                         model.max_penalty)
        self._fits: BoundedCache | None = None  # Laplace fits by partition, shared with rebound terms (rebind)
        self._cache = BoundedCache(model.cache_size)
        self.noise_scale_prior = model.noise_scale_prior
        self._scale_conditionals = BoundedCache(model.cache_size)  # s given T, kept by the evaluations
        self._modes = BoundedCache(max(1, MODE_MEMO_BYTES // (8 * max(self.dimension, 1))))
        self._converged_modes = BoundedCache(self._modes.maxsize)  # the same vectors, of converged fits only
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

    def screen(self, posterior) -> OdometrySurrogate:
        """The screen of ``posterior``'s global terms (the posterior's ``screen()`` protocol): an
        :class:`~ptm.odometry.surrogate.OdometrySurrogate`, which predicts how a move changes every odometry
        term of the posterior from the map estimate of the current partition (docs/model.md §3.4)."""
        return OdometrySurrogate(posterior)

    def rebind(self, model) -> "OdometryTerm":
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

            >>> from ptm import Dataset, OdometryModel
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
        detection), keeping this term's converged Laplace modes as starts (:mod:`ptm.odometry.growth`).
        ``ValueError`` where ``dataset`` does not extend this term's run by one detection with the same odometry
        rows and covariances."""
        if not extends_by_one(self.dataset, dataset):
            raise ValueError("the dataset does not extend this term's run by one detection with the same "
                             "odometry rows and covariances; bind the model to it instead (model.bind(dataset))")
        return OdometryTerm(self.model, dataset, ShorterRun(self._converged_modes, dataset.odometry[-1]))

    def fit(self, labels) -> LaplaceFit:
        """The Laplace fit that defines log P(O | T) of the partition ``labels`` (:mod:`ptm.odometry.laplace`):
        a function of the partition alone."""
        return self.fitter.fit(labels)

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

    def log_likelihood_upper_bound(self, num_places: int | None = None) -> float:
        """A bound no partition's log P(O | T) exceeds (of ``num_places`` places, or of any number): the
        all-singletons value without penalty.

        The ties and the penalty are >= 0, so exp(-E_T - Pen_T) <= exp(-E_all-distinct) at every P, and
        the all-distinct energy is a chain of independent Gaussian steps (docs/model.md §3.3):
        sum_k 1/2 log det(2 pi Sigma_k). :func:`ptm.exact_posterior` uses it to skip partitions whose
        cheap score leaves them no chance of mattering. With a ``noise_scale_prior`` and normalised ties,
        s^-(N-M) may exceed 1, so the bound grows by log int IG(s) s^-k ds at k = N - M (the largest over
        k < N where the number of places is not given).
        """
        _, log_det_whitening = np.linalg.slogdet(self.graph.sqrt_information)  # log |det U_k| = -1/2 log det Sigma_k
        bound = float(1.5 * (self.n - 1) * math.log(2.0 * math.pi) - log_det_whitening.sum())
        if self.noise_scale_prior is not None and self.model.normalised_ties:
            # det H >= det of the rows' information and E* >= 0, but s^-(N-M) may exceed 1 where s < 1
            ties = self.n - 1 if num_places is None else self.n - int(num_places)
            bound += self.noise_scale_prior.largest_log_marginal_gain(ties)
        return bound

    def noise_scale_conditional(self, partition) -> NoiseScalePrior:
        """The noise scale given ``partition``: IG(a + k, b + E*) with E* the energy of its Laplace mode at scale 1
        and k = N - M with normalised ties, else 0 (:mod:`ptm.odometry.noise_scale`). Kept from the partition's
        evaluation, else fitted now. ``ValueError`` without a ``noise_scale_prior`` or where the fit has no
        Gaussian (the partition's log-likelihood is -inf)."""
        if self.noise_scale_prior is None:
            raise ValueError("this odometry term has no noise_scale_prior: its noise scale is fixed at 1")
        labels = _canonical_labels(partition)
        if len(labels) != self.n:
            raise ValueError(f"a partition of this dataset has {self.n} labels, got {len(labels)}")
        conditional = self._scale_conditionals.get(labels)
        if conditional is None:
            if self.n == 1:
                return self.noise_scale_prior
            fit = self._shared_fit(np.asarray(labels))
            if fit.factor is None:
                raise ValueError(f"partition {labels} has no Laplace fit ({fit.failure}): its probability is 0")
            conditional = self.noise_scale_prior.conditional(fit.energy, self._scale_ties(np.asarray(labels)))
        return conditional

    def check_terms(self, terms) -> None:
        """Refuse the terms of a posterior (``ptm.Posterior`` calls this) that contradict the model's
        ``normalised_ties``: with a ``noise_scale_prior`` this term owns the normalised ties' dependence on the
        scale, -(N - M) log s, so exactly one :class:`ptm.TieNormaliser` of the same sigma_T must be among them
        where ``normalised_ties`` is True (else that dependence would count without its normaliser) and none
        where it is False (else the normaliser would count without its dependence on s)."""
        if self.noise_scale_prior is None:
            return
        normalisers = [term for term in terms if getattr(term, "completes_global_term", False)]
        if self.model.normalised_ties and len(normalisers) != 1:
            raise ValueError(f"the odometry model declares normalised_ties=True with its noise_scale_prior, so the "
                             f"posterior needs exactly one ptm.TieNormaliser; it has {len(normalisers)}")
        if not self.model.normalised_ties and normalisers:
            raise ValueError("the odometry model declares normalised_ties=False with its noise_scale_prior, but the "
                             f"posterior normalises the ties ({normalisers[0]!r}); declare normalised_ties=True")
        for normaliser in normalisers:
            if getattr(normaliser, "sigma_topology", None) != self.model.sigma_topology:
                raise ValueError(f"{normaliser!r} normalises ties of sigma_topology "
                                 f"{getattr(normaliser, 'sigma_topology', None)!r}, the odometry model's are "
                                 f"{self.model.sigma_topology!r}")

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
            "fits_from_shorter_run": self.fitter.from_shorter_run,
            "failures": self._failures,
            "failures_minus_inf": self._failed_fits,
            "failed_partitions": list(self._failed_partitions),
            "evaluation_ms_mean": 1e3 * self._seconds / evaluations if evaluations else math.nan,
            "linear_algebra": "sparse" if self.graph.sparse else "banded_low_rank",
        }

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
            if self.noise_scale_prior is None:
                evaluation = self.sampler.estimate(fit, labels)
            else:
                evaluation = self._scale_marginal_estimate(fit, labels)
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

    def _scale_marginal_estimate(self, fit: LaplaceFit, labels: np.ndarray) -> OdometryEvaluation:
        """log int IG(s) P(O | T, s) ds as docs/model.md §3.3, "Noise scale", defines it: the Laplace part
        integrated in closed form, times the importance-sampling correction IS / Laplace at the conditional
        mode s_hat = (b + E*) / (a + k + 1), where the graph's covariances are s_hat times the model's (same P*
        and common random numbers, the Hessian H / s_hat)."""
        ties = self._scale_ties(labels)
        conditional = self.noise_scale_prior.conditional(fit.energy, ties)
        self._scale_conditionals.put(tuple(labels.tolist()), conditional)
        scale = conditional.mode
        graph = PoseGraph(self.graph.odometry, self.graph.sqrt_information / math.sqrt(scale),
                          self.graph.sigma_topology * math.sqrt(scale), sparse_above=self.model.sparse_above)
        topology = graph.topology(labels)
        at_mode = graph.linearise(fit.x, topology)
        scaled = dataclasses.replace(fit, energy=at_mode.energy, topology=topology,
                                     factor=graph.factorise(topology, at_mode.gauss_newton))
        at_scale = self.sampler.on(graph).estimate(scaled, labels)
        laplace = (0.5 * self.dimension * math.log(2.0 * math.pi) - 0.5 * fit.factor.log_det()
                   + self.noise_scale_prior.log_marginal(fit.energy, ties))
        return dataclasses.replace(at_scale, laplace=laplace,
                                   log_likelihood=laplace + at_scale.log_likelihood - at_scale.laplace)

    def _scale_ties(self, labels: np.ndarray) -> int:
        """k, the power of 1/s the ties contribute: N - M where they are normalised, else 0."""
        return self.n - (int(labels.max()) + 1) if self.model.normalised_ties else 0

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

    def _remember_mode(self, labels: tuple, fit: LaplaceFit) -> None:
        self._modes.put(labels, fit.x)
        if fit.converged:
            self._converged_modes.put(labels, fit.x)

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


def _canonical_labels(partition) -> tuple[int, ...]:
    if isinstance(partition, Partition):
        return partition.labels
    return Partition.from_labels(partition).labels
