"""Online mapping: the posterior over topologies updated in place as each detection arrives (docs/model.md §3.8).

Sequential Monte Carlo over detections with resample-move (Gilks & Berzuini 2001; Chopin 2002). The
targets are the posteriors of the runs so far, pi_n(T) = P_n(T | Z_1..n) (paper eq. 1-2, with the prior
P_n of n detections, eq. 8-9), known up to their normalisers as pi~_n = exp(log P(T) + log-likelihoods).
P weighted particles (T^p, w^p), each a partition of the first n detections, stand for pi_n. When
detection n + 1 arrives (0-based index n):

1. *Extension.* Each particle's new detection joins one of its sets b or opens a new one, T (+) b, drawn
   from a proposal q(b | T) over those M + 1 options, and the weight becomes

       w' = w * pi~_{n+1}(T (+) b) / (pi~_n(T) q(b | T)).

   The proposal is the new detection's conditional under pi_{n+1} (the "locally optimal" one), with a
   cheap screen where the global (odometry) terms are expensive: every option gets the screened value
   cheap_{n+1}(T (+) b) + g + s(b), with g = global_n(T) + o(T) the particle's value so far plus the
   screen's change from opening a place (a leaf of the pose graph: exact in the Laplace value, plus the new
   detection's pairs' penalty; the screen's ``opened_place_change``, :meth:`ptm.Posterior.screen`) and s(b)
   its prediction of the change from opening a new place to joining b (a merge predicted from the map of
   T (+) new; for a set ``FAR_OPTION_NATS`` below the best on a cheaper estimate, that estimate). The options
   whose screened probability is at least ``screen`` get their exact value log pi~_{n+1} (the new place
   first, whose exact value then stands for g in the joins'), the others keep the screened one, and q is the
   normalised exponential of these values: at a revisit the unlikely new place costs no importance sampling.
   Where every option is exact (always without global terms) the incremental weight is the predictive
   probability of the new detection, sum_b pi~_{n+1}(T (+) b) / pi~_n(T), the same for every choice;
   otherwise the chosen option is evaluated exactly if it was not, so the weights use the true posterior
   whatever the screen: the particles target pi_{n+1} exactly (as P grows).
2. *Resampling.* With normalised weights W^p, the effective sample size ESS = 1 / sum_p (W^p)^2; below
   ``resample_below`` x P the particles are resampled systematically (one uniform u, the p-th copy at
   (u + p) / P of the cumulative weights) and the weights reset to equal.
3. *Rejuvenation.* Each particle takes one block move over the last ``reallocation_window`` detections
   (:class:`ptm.moves.TrailingReallocation`: they are allocated again jointly, in order) and then
   ``rejuvenation_steps`` Metropolis-Hastings steps of the default moves (:func:`ptm.moves.default_moves`),
   all targeting pi_{n+1}, screened by the posterior's screen in delayed acceptance when there are global
   terms (:func:`ptm.moves.metropolis_step`): invariant for pi_{n+1}, so the weights stand, and copies of one
   particle spread out again. The block move is what lets the particles change their mind about a
   retraced corridor: when a run of detections was aligned with the places one step off (each alone
   better there until the next detections arrive), no single move leads back, as each step alone loses
   probability.

The prior follows n in one of two ways. A prior object (``log_prob(n, m)``) is used at every n: with a
:class:`ptm.PoissonPrior` the rate counts the world's landmarks, visited or not, a number that does not
grow with the run, and the urn model is consistent (the prior of n detections is the marginal of that of
n + 1). A callable ``n -> prior`` gives each n its own, e.g. a calibrated rate that expects a share of n
places (:meth:`ptm.PoissonPrior.with_expected_places`); the targets then change non-consistently, which the
weights account for. Each update binds the models to the first n + 1 detections (``model.bind``), as a
chain started from a shorter run's PTM does (docs/model.md §3.7); a term that can grow into the longer run
keeps its memo (the appearance evidence of the sets seen so far).

:func:`smc_draw` runs such a pass over a whole posterior's detections and draws one partition from its
particles: the start of a chain of :func:`ptm.mcmc` (:mod:`ptm.starts`).

    >>> import numpy as np
    >>> import ptm
    >>> mapper = OnlineMapper(ptm.PoissonPrior(2.0), [ptm.AppearanceModel(0.3, 0.05, 3.0, 2e-4)], particles=64, seed=0)
    >>> for signature in [[0.30, 0.10], [0.40, 0.05], [0.31, 0.11], [0.41, 0.04]]:   # places A, B, A, B
    ...     result = mapper.add(signature=signature)
    >>> result.map(), result.diagnostics["particles"], len(result.diagnostics["latency_s"])
    ((0, 1, 0, 1), 64, 4)
"""

from __future__ import annotations

import math
import time

import numpy as np
from scipy.special import logsumexp

from ._threads import blas_threads, checked_blas_threads
from ._validation import count, finite_array, seed_sequence, share
from .dataset import Dataset
from .moves import MoveMixture, TrailingReallocation, default_moves, initial_state
from .partitions import Partition
from .posterior import Posterior
from .result import PTM

__all__ = ["OnlineMapper", "incremental_log_weight", "smc_draw", "systematic_resample"]

#: The screen's weight where it screens the rejuvenation's moves: whole, because a particle takes only a few
#: steps per detection and each screened-out proposal saves an evaluation of the global terms.
REJUVENATION_SCREENING_TRUST = 1.0
#: Options of a new detection whose cheap join estimate (the screen's ``join_estimates``) puts them this many nats
#: below the best keep that estimate instead of the screen's prediction: their probability in the proposal is then
#: about e^-30, and drawn, they are evaluated exactly like any other. The estimate falls below the prediction by a
#: few nats at most where the prediction is near the best, and it leaves a few predictions per partition instead of
#: one per set.
FAR_OPTION_NATS = 30.0


class OnlineMapper:
    """The posterior over topologies of a run that grows one detection at a time (sequential Monte Carlo).

    Parameters
    ----------
    prior : object with ``log_prob(n, m)``, or a callable ``n -> prior``
        The prior of every n (e.g. :class:`ptm.PoissonPrior`), or one per number of detections.
    models : iterable of models with ``bind(dataset)``
        Bound anew to the first n detections at each update.
    particles : int
        Number of particles P.
    rejuvenation_steps : int
        Metropolis-Hastings steps per particle after each detection (0: none).
    resample_below : float in [0, 1]
        Resample when the ESS falls below this share of P (0: never; 1: whenever the weights differ).
    screen : float in [0, 1]
        Options of the new detection whose screened probability is at least this are evaluated exactly
        before the draw (0: all of them, the locally optimal proposal).
    seed : int, SeedSequence or None
        Seed of the one random generator; the same seed and data give the same PTMs.
    reallocation_window : int
        Detections the block move of each rejuvenation allocates again (0: no block move).
    blas_threads : int or None
        Threads the BLAS libraries may use during an update (:mod:`ptm._threads`; restored after it), or None
        to leave the process's setting. One by default: an update is many small solves, which more threads
        slow down rather than speed up.

    After each :meth:`add`, ``posterior`` is the :class:`ptm.Posterior` of the detections so far and
    :meth:`result` the particles' PTM.
    """

    def __init__(self, prior, models, particles: int = 128, rejuvenation_steps: int = 2,
                 resample_below: float = 0.5, screen: float = 1e-3, seed=None, reallocation_window: int = 8,
                 blas_threads: int | None = 1):
        if hasattr(prior, "log_prob"):
            self._prior_of = lambda n: prior
        elif callable(prior):
            self._prior_of = prior
        else:
            raise TypeError(f"prior must have log_prob(n, m) or be a callable n -> prior, got {prior!r}")
        try:
            self.models = list(models)
        except TypeError:
            raise TypeError(f"models must be an iterable of models, got {models!r:.60}") from None
        for model in self.models:
            if not hasattr(model, "bind"):
                raise TypeError(f"{model!r} is not a model: the online mapper binds each model to the detections "
                                "so far (model.bind(dataset)), so it needs unbound models")
        self.particles = count("particles", particles, minimum=1)
        self.rejuvenation_steps = count("rejuvenation_steps", rejuvenation_steps, minimum=0)
        self.reallocation_window = count("reallocation_window", reallocation_window, minimum=0)
        self.resample_below = share("resample_below", resample_below)
        self.screen = share("screen", screen)
        self.blas_threads = checked_blas_threads(blas_threads)
        self._rng = np.random.default_rng(seed_sequence("seed", seed))
        self.posterior: Posterior | None = None
        self._signatures: np.ndarray | None = None  # (n, K), or None for a run without appearance
        self._odometry: np.ndarray | None = None  # (n - 1, 3), or None for a run without odometry
        self._odometry_cov: np.ndarray | None = None  # (n - 1, 3, 3), or None without covariances
        self._states = []  # one ChainState per particle, under self.posterior
        self._log_weights = np.zeros(0)
        self._ess: list[float] = []
        self._latency: list[float] = []
        self._resamplings = 0
        self._proposed = 0
        self._accepted = 0

    @property
    def n(self) -> int:
        """Number of detections so far."""
        return 0 if self.posterior is None else self.posterior.n

    def add(self, signature=None, odometry=None, odometry_cov=None) -> PTM:
        """Take detection n + 1 and update the posterior; return the new PTM (:meth:`result`).

        ``signature``: its appearance vector (K,), for every detection or for none. ``odometry``: the motion
        (dx, dy, dtheta) from the previous detection, in that detection's frame (docs/model.md §2.2); none
        for the first detection, then for every detection or for none. ``odometry_cov``: its 3 x 3
        covariance, with every odometry row or with none. A bad input is a ``ValueError`` and leaves the
        mapper as it was.
        """
        started = time.perf_counter()
        with blas_threads(self.blas_threads):
            self._update(*self._grown(signature, odometry, odometry_cov))
        self._latency.append(time.perf_counter() - started)
        return self.result()

    def extend(self, dataset, each=None) -> PTM:
        """:meth:`add` every detection of ``dataset`` in order (its signatures, odometry rows and covariances,
        those it has); ``each(n, ptm)`` after every update. Returns the PTM after the last detection."""
        result = self.result() if self.posterior is not None else None
        for index in range(dataset.n):
            row = index - 1
            with_odometry = dataset.odometry is not None and index > 0
            result = self.add(
                signature=None if dataset.signatures is None else dataset.signatures[index],
                odometry=dataset.odometry[row] if with_odometry else None,
                odometry_cov=dataset.odometry_cov[row] if with_odometry and dataset.odometry_cov is not None else None)
            if each is not None:
                each(self.n, result)
        return result

    def _update(self, signatures, odometry_rows, covariances) -> None:
        """Steps 1-3 for the detections ``signatures``, ``odometry_rows``, ``covariances`` (checked, the new one
        last)."""
        dataset = Dataset(signatures=signatures, odometry=odometry_rows, odometry_cov=covariances)
        posterior = Posterior(dataset, self._prior_of(dataset.n), self._bound(dataset))
        if self.posterior is None:
            states = [initial_state(posterior, (0,))] * self.particles
            log_weights = np.zeros(self.particles)
        else:
            screen = posterior.screen()
            states, log_weights = self._extended(posterior, screen)
            ess = _effective_sample_size(log_weights)
            self._ess.append(ess)
            if ess < self.resample_below * self.particles:
                chosen = systematic_resample(log_weights, self._rng)
                states, log_weights = [states[index] for index in chosen], np.zeros(self.particles)
                self._resamplings += 1
            states = self._rejuvenated(posterior, states, screen)
        self._signatures, self._odometry, self._odometry_cov = signatures, odometry_rows, covariances
        self.posterior, self._states, self._log_weights = posterior, states, log_weights

    def result(self) -> PTM:
        """The particles as a PTM (weights summed per partition), with the diagnostics: ``particles``,
        ``ess`` (after each extension, before resampling; P for the first detection), ``resamplings``,
        ``latency_s`` (wall seconds of each :meth:`add`), ``rejuvenation_acceptance`` and ``n_distinct``."""
        if self.posterior is None:
            raise ValueError("the online mapper has no detections yet: call add() first")
        weights = np.exp(self._log_weights - logsumexp(self._log_weights))
        mass: dict[Partition, float] = {}
        for state, weight in zip(self._states, weights):
            mass[state.partition] = mass.get(state.partition, 0.0) + float(weight)
        diagnostics = {
            "particles": self.particles, "ess": [float(self.particles)] + self._ess,
            "resamplings": self._resamplings, "latency_s": list(self._latency),
            "rejuvenation_acceptance": self._accepted / self._proposed if self._proposed else math.nan,
            "n_distinct": len(mass),
        }
        return PTM(np.array([partition.labels for partition in mass], dtype=np.int32),
                   np.array(list(mass.values())), "smc", diagnostics)

    # -- the three steps ------------------------------------------------------------------------------------------

    def _extended(self, posterior, screen):
        """Each particle extended by a draw of the new detection's place, and its new log weight (step 1)."""
        options_of: dict[Partition, _Options] = {}
        states, log_weights = [], np.empty(self.particles)
        for index, (state, log_weight) in enumerate(zip(self._states, self._log_weights)):
            options = options_of.get(state.partition)
            if options is None:
                options = options_of[state.partition] = _Options.of(posterior, screen, state.partition, self.screen,
                                                                    state.log_global)
            if log_weight == -math.inf or not np.isfinite(options.log_q).any():
                pick = len(options.candidates) - 1  # no mass anywhere: open a new place, weight 0
                extended = initial_state(posterior, options.candidates[pick])
                log_weights[index] = -math.inf
            else:
                pick = int(self._rng.choice(len(options.candidates), p=np.exp(options.log_q)))
                extended = options.state(posterior, pick)
                log_weights[index] = log_weight + incremental_log_weight(extended.log_prob, state.log_prob,
                                                                         options.log_q[pick])
            states.append(extended)
        if np.all(log_weights == -math.inf):
            raise ValueError(f"every particle has posterior probability 0 after detection {posterior.n}")
        return states, log_weights

    def _rejuvenated(self, posterior, states, screen):
        """Each particle after the block move and ``rejuvenation_steps`` MH steps, all invariant for
        ``posterior`` (step 3), delayed acceptance screened by ``screen`` at ``REJUVENATION_SCREENING_TRUST``."""
        screening = {"delayed_acceptance": posterior.has_global_terms,
                     "screen": None if screen is None else _Trusted(screen, REJUVENATION_SCREENING_TRUST)}
        if self.reallocation_window:
            block = MoveMixture([TrailingReallocation(self.reallocation_window)], **screening)
            states = [block.step(posterior, state, self._rng)[0] for state in states]
            self._proposed += int(block.proposed.sum())
            self._accepted += int(block.accepted.sum())
        if self.rejuvenation_steps == 0:
            return states
        mixture = MoveMixture(default_moves(), **screening)
        moved = []
        for state in states:
            for _ in range(self.rejuvenation_steps):
                state, _ = mixture.step(posterior, state, self._rng)
            moved.append(state)
        self._proposed += int(mixture.proposed.sum())
        self._accepted += int(mixture.accepted.sum())
        return moved

    # -- inputs ---------------------------------------------------------------------------------------------------

    def _bound(self, dataset) -> list:
        """Each model bound to the detections so far: a term of the last update that can grow (``grown``, e.g.
        :meth:`ptm.AppearanceTerm.grown`) is grown and keeps what it memoised, the others are bound anew."""
        if self.posterior is None:
            return [model.bind(dataset) for model in self.models]
        return [term.grown(dataset) if hasattr(term, "grown") else model.bind(dataset)
                for model, term in zip(self.models, self.posterior.terms)]

    def _grown(self, signature, odometry, odometry_cov):
        """The signatures, odometry rows and covariances with detection n + 1's appended, checked. A run
        without signatures has ``None`` for them; without odometry, ``None`` from the second detection on."""
        n = self.n + 1
        signatures = self._signatures
        if n > 1 and (signature is None) != (signatures is None):
            raise ValueError(f"detection {n} {'has a signature' if signature is not None else 'has none'}, unlike "
                             "the first: give a signature with every detection or with none")
        if signature is not None:
            row = finite_array("signature", signature, ndim=1)
            if row.size == 0:
                raise ValueError("signature must have K >= 1 components, got an empty array")
            if signatures is not None and row.size != signatures.shape[1]:
                raise ValueError(f"signature has {row.size} components, the earlier detections have "
                                 f"{signatures.shape[1]}")
            signatures = row[None, :] if signatures is None else np.vstack([signatures, row])
        if n == 1:
            if odometry is not None or odometry_cov is not None:
                raise ValueError("the first detection has no odometry: it is the origin of the run (an odometry "
                                 "row is the motion from the previous detection)")
            return signatures, np.empty((0, 3)), None
        rows, covariances = self._odometry, self._odometry_cov
        if odometry is None:
            if odometry_cov is not None:
                raise ValueError("odometry_cov given without odometry")
            if n > 2 and rows is not None:
                raise ValueError(f"detection {n} has no odometry row, unlike the ones before: give odometry with "
                                 "every detection after the first or with none")
            if signatures is None:
                raise ValueError(f"detection {n} has neither a signature nor odometry: nothing to map")
            return signatures, None, None
        if n > 2 and rows is None:
            raise ValueError(f"detection {n} has an odometry row, unlike the ones before: give odometry with every "
                             "detection after the first or with none")
        row = finite_array("odometry", odometry, ndim=1)
        if row.shape != (3,):
            raise ValueError(f"odometry must be one row (dx, dy, dtheta) of 3 numbers, got shape {row.shape}")
        if n > 2 and (odometry_cov is None) != (covariances is None):
            raise ValueError(f"detection {n} {'has an odometry_cov' if odometry_cov is not None else 'has none'}, "
                             "unlike the ones before: give odometry_cov with every odometry row or with none")
        if odometry_cov is not None:
            covariance = finite_array("odometry_cov", odometry_cov, ndim=2)
            if covariance.shape != (3, 3):
                raise ValueError(f"odometry_cov must be a 3 x 3 matrix, got shape {covariance.shape}")
            covariances = covariance[None] if covariances is None else np.concatenate([covariances, covariance[None]])
        return signatures, np.vstack([rows, row]), covariances


def smc_draw(posterior, particles: int, rng) -> tuple[int, ...]:
    """A partition drawn from an SMC pass over ``posterior``: its detections fed one by one to an
    :class:`OnlineMapper` of ``particles`` particles with the posterior's prior and models (seeded from ``rng``),
    and a partition drawn from its final particles by their weights.

    The pass builds the partition the way the run was walked: each detection joins one of the places so far
    or opens one, and the block move realigns the last ones, so a chain started there begins near the
    posterior's bulk, in a partition no single move leads to from a dispersed extreme (docs/model.md §3.4,
    "Starts").
    """
    dataset = posterior.dataset
    if dataset.signatures is None and dataset.odometry is None:
        raise ValueError("an SMC start needs the detections' signatures or odometry: this dataset has neither "
                         "(start the chains with start=\"dispersed\")")
    models = [_unbound(term) for term in posterior.terms]
    mapper = OnlineMapper(posterior.prior, models, particles=particles, seed=int(rng.integers(2**63)))
    result = mapper.extend(dataset)
    return tuple(int(label) for label in result.partitions[rng.choice(len(result), p=result.probabilities)])


def _unbound(term):
    """The model a posterior's term was bound from (or the term, where it binds anew itself)."""
    if hasattr(term, "model"):
        return term.model
    if hasattr(term, "bind"):
        return term
    raise ValueError(f"{term!r} cannot be bound to the first detections of the run: an SMC start needs the models "
                     "(or terms with a model or bind); start the chains with start=\"dispersed\"")


def incremental_log_weight(log_prob_extended: float, log_prob_before: float, log_q: float) -> float:
    """log of pi~_{n+1}(T (+) b) / (pi~_n(T) q(b | T)), the factor by which extending T to T (+) b changes a
    particle's weight (-inf where the extension has probability 0)."""
    if log_prob_extended == -math.inf:
        return -math.inf
    return log_prob_extended - log_prob_before - log_q


def systematic_resample(log_weights, rng) -> np.ndarray:
    """Indices of P particles drawn by systematic resampling: one uniform u, copy p at (u + p) / P of the
    cumulative normalised weights."""
    weights = np.exp(log_weights - logsumexp(log_weights))
    cumulative = np.cumsum(weights)
    points = (rng.random() + np.arange(len(weights))) / len(weights)
    return np.minimum(np.searchsorted(cumulative, points * cumulative[-1], side="right"), len(weights) - 1)


class _Options:
    """Where the new detection may go in one partition T of the earlier ones: the candidates T (+) b (each set,
    then a new place) and log q(b | T); the chain state of each candidate drawn, shared by the particles that
    draw it (its log pi~_{n+1} exact: found before the draw, or evaluated then)."""

    def __init__(self, candidates, log_q):
        self.candidates, self.log_q = candidates, log_q
        self._states = {}

    @classmethod
    def of(cls, posterior, predictor, partition: Partition, screen: float, log_global_before: float) -> _Options:
        """The options of ``partition``: screened by ``predictor`` (the posterior's screen, or None) where the
        global terms are expensive, and those at least ``screen`` likely evaluated exactly (step 1)."""
        new = partition.n
        blocks = partition.blocks
        candidates = [Partition(blocks[:j] + (block + (new,),) + blocks[j + 1:]) for j, block in enumerate(blocks)]
        candidates.append(Partition(blocks + ((new,),)))
        scores = np.array([posterior.block_score(block) for block in blocks])
        joined = np.array([posterior.block_score(block + (new,)) for block in blocks])
        log_prior = posterior.log_prior_by_size
        # cheap_log_prob of each candidate, from the sets' scores: one changed set per candidate
        values = scores.sum() + np.append(log_prior[len(blocks)] + joined - scores,
                                          log_prior[len(blocks) + 1] + posterior.block_score((new,)))
        if posterior.has_global_terms:
            alone = candidates[-1]
            predicted = np.zeros(len(candidates))
            opened = None
            if predictor is not None:
                predicted[:-1] = predictor.join_estimates(alone, new)
                rough = values + predicted
                for index in np.flatnonzero(rough[:-1] >= rough.max() - FAR_OPTION_NATS):
                    predicted[index] = predictor.predicted_change(alone, [blocks[index], (new,)],
                                                                  [blocks[index] + (new,)])
                opened = predictor.opened_place_change(alone)
            approximate = opened is not None and math.isfinite(log_global_before + opened)
            base = log_global_before + opened if approximate else posterior.global_log_prob(alone)
            screened = values + base + predicted
            likely = np.ones(len(candidates), dtype=bool)
            if math.isfinite(base) and np.all(np.isfinite(screened[:-1])):
                likely = np.exp(screened - logsumexp(screened)) >= screen
            if approximate and likely[-1]:  # a likely new place: the joins' predictions start from its exact value
                base = posterior.global_log_prob(alone)
                screened = values + base + predicted
                likely[:-1] |= not math.isfinite(base)
            for index in np.flatnonzero(likely[:-1]):  # the new place's value is exact by now, or it is unlikely
                screened[index] = values[index] + posterior.global_log_prob(candidates[index])
            values = screened
        total = logsumexp(values)
        return cls(candidates, values - total if math.isfinite(total) else np.full(len(values), -math.inf))

    def state(self, posterior, pick: int):
        """The chain state of candidate ``pick`` under ``posterior`` (its global terms evaluated, memoised)."""
        state = self._states.get(pick)
        if state is None:
            state = self._states[pick] = initial_state(posterior, self.candidates[pick])
        return state


class _Trusted:
    """A posterior's screen seen at another trust: its screening change and that change's upper bound (the
    change itself where the screen offers no bound) rescaled from the screen's own ``screening_trust`` (1 where
    it states none) to ``trust``."""

    def __init__(self, screen, trust: float):
        self.screen, self.scale = screen, trust / getattr(screen, "screening_trust", 1.0)
        self._bound = getattr(screen, "screening_change_bound", screen.screening_change)

    def screening_change(self, partition, removed, added) -> float:
        return self.scale * self.screen.screening_change(partition, removed, added)

    def screening_change_bound(self, partition, removed, added) -> float:
        return self.scale * self._bound(partition, removed, added)


def _effective_sample_size(log_weights) -> float:
    """1 / sum_p W_p^2 of the normalised weights."""
    weights = np.exp(log_weights - logsumexp(log_weights))
    return float(1.0 / np.sum(weights * weights))
