"""Metropolis-Hastings over topologies (paper eq. 10, Algorithm 1; docs/model.md §3.4).

Each step draws a move from a weighted list, asks it for a proposal T' and
accepts with probability min(1, P(T'|Z) q(T'->T) / (P(T|Z) q(T->T'))), in log
space. Only the sets a proposal changes are re-scored. With global terms
(odometry) and ``delayed_acceptance`` a proposal is first screened with the
cheap terms (prior + appearance), plus a surrogate's prediction s_T(T') of the
change of the global terms when one is given (``ptm.surrogate``), and only
survivors pay for the global terms; the second stage corrects exactly
(Christen & Fox 2005, :func:`second_stage_log_ratio`): with
r = log of the first stage's ratio,

    log alpha_2 = beta (global(T') - global(T) - s_T(T')) + min(r, beta (s_T(T') + s_T'(T))) - min(0, r),

which is beta (global(T') - global(T)) without a surrogate.

Several chains start from dispersed partitions (all distinct, all one place,
random), run from seeds spawned from one root, and are pooled; split R-hat
and effective sample sizes of log P and of the number of places are reported,
and the largest difference between two chains' co-assignment matrices. With
``max_doublings`` chains that disagree by those measures are run on, twice as
long each time (:func:`run_chains`). ``init`` may be a previous PTM over fewer detections: the chains then start
from its most probable topologies, each new detection placed by a draw from
its conditional under the cheap terms (incremental mapping, docs/model.md §3.7).

    >>> import numpy as np
    >>> from ptm import AppearanceModel, Dataset, PoissonPrior, Posterior
    >>> dataset = Dataset(signatures=np.array([[0.30, 0.10], [0.40, 0.05], [0.31, 0.11], [0.41, 0.04]]))
    >>> posterior = Posterior(dataset, PoissonPrior(2.0), [AppearanceModel(0.3, 0.05, 3.0, 2e-4)])
    >>> result = mcmc(posterior, n_samples=2_000, burn_in=200, seed=1, chains=2)
    >>> result.map(), result.traces["log_prob"].shape, "rhat_log_prob" in result.diagnostics
    ((0, 1, 0, 1), (2, 2000), True)
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass

import numpy as np

from .diagnostics import chains_agree, effective_sample_size, split_rhat
from .moves import (GibbsReassign, GuidedSplitMerge, MapReassign, MapWindowReallocation, SplitMerge, WindowReallocation,
                    apply_proposal, initial_state, proposed_log_cheap, proposed_partition)
from ._validation import count, share
from .partitions import Partition
from .result import PTM
from .surrogate import OdometrySurrogate

__all__ = ["mcmc", "chain_start", "checked_smc_start", "default_moves", "guided_moves", "guided_options",
           "warm_up_start", "metropolis_step", "second_stage_log_ratio", "start_labels", "StepInfo", "MoveMixture",
           "SampleRecorder", "run_chains", "ESTIMATES", "checked_estimate"]

_SMALLEST = 5e-324  # replaces a uniform draw of exactly 0 before taking its log
#: Warm-up steps per detection of :func:`guided_options` (:func:`warm_up_start`).
WARM_UP_PER_DETECTION = 100
#: The warm-up's cheap phase starts at this inverse temperature and anneals to 1 (:func:`warm_up_start`).
WARM_UP_FIRST_BETA = 0.05
#: Share of steps of :func:`guided_options` that skip the surrogate's screening (:class:`MoveMixture`). On three
#: 10 x 10 corridor grids (N = 115 and 121) the screened chains stayed in wrong partitions after two doublings;
#: with one step in twenty unscreened all four chains found the truth within the first 20 000 samples.
UNSCREENED_SHARE = 0.05
#: Share of the steps of :func:`default_moves` with a surrogate that are the map-steered window. On the demo's
#: nested_loops (12 detections, odometry alone, seeds 0-3) the default moves left three of four chains at
#: all-distinct (truth 0.21-0.75, chains disagreeing); with one step in ten the map-steered window, 0.985-1.000.
MAP_WINDOW_SHARE = 0.1


def default_moves(surrogate=None):
    """The paper's split/merge, mixed with single-detection Gibbs reassignment; with ``surrogate`` (an
    :class:`ptm.surrogate.OdometrySurrogate`), ``MAP_WINDOW_SHARE`` of the steps are the map-steered window
    (:class:`ptm.moves.MapWindowReallocation`), which closes a loop whose single closures are each worse than none."""
    if surrogate is None:
        return [(SplitMerge(), 0.5), (GibbsReassign(), 0.5)]
    rest = 0.5 * (1.0 - MAP_WINDOW_SHARE)
    return [(SplitMerge(), rest), (GibbsReassign(), rest), (MapWindowReallocation(surrogate), MAP_WINDOW_SHARE)]


def guided_moves(posterior, surrogate, map_window: bool = False):
    """Data-driven moves for many detections (docs/model.md §3.4): the guided split-merge (anchors by the pairs'
    Bayes factors), reassignment by the current map's prediction (``surrogate``, an
    :class:`ptm.surrogate.OdometrySurrogate` of ``posterior``, best shared with delayed acceptance), Gibbs
    reassignment, and the joint reallocation of a window of consecutive detections (a retraced corridor),
    steered by the cheap terms alone (:class:`ptm.moves.WindowReallocation`) or, with ``map_window``, by the map
    as well (:class:`ptm.moves.MapWindowReallocation`: on three 57-121-detection grids whose chains disagreed it
    made two of three agree, at up to 3.6 times the wall time, so it is not the default here)."""
    window = MapWindowReallocation(surrogate) if map_window else WindowReallocation()
    return [(GuidedSplitMerge(posterior), 0.35), (MapReassign(surrogate), 0.2), (GibbsReassign(), 0.35),
            (window, 0.1)]


def guided_options(posterior, delayed_acceptance: bool = True, map_window: bool = False) -> dict:
    """Keyword arguments of :func:`mcmc` and :func:`ptm.tempered_mcmc` for many detections (docs/model.md §3.4):
    :func:`guided_moves`, the odometry surrogate in delayed acceptance's first stage (with
    ``delayed_acceptance``), ``UNSCREENED_SHARE`` of the steps unscreened, and a warm-up of
    ``WARM_UP_PER_DETECTION`` x N steps per chain (:func:`warm_up_start`)::

        ptm.mcmc(posterior, 5_000, burn_in=500, chains=4, **guided_options(posterior))
    """
    surrogate = OdometrySurrogate(posterior)
    return {"moves": guided_moves(posterior, surrogate, map_window),
            "delayed_acceptance": surrogate if delayed_acceptance else False,
            "unscreened_share": UNSCREENED_SHARE, "warm_up": WARM_UP_PER_DETECTION * posterior.n}


def mcmc(posterior, n_samples: int, burn_in: int = 0, thin: int = 1, seed=None, chains: int = 1,
         init=None, moves=None, delayed_acceptance=False, warm_up: int = 0, max_doublings: int = 0,
         estimate: str = "frequency", unscreened_share: float = 0.0, smc_start: int = 0) -> PTM:
    """Sample the posterior over topologies; return the pooled histogram as a PTM.

    Parameters
    ----------
    posterior : ptm.Posterior
    n_samples : int
        Samples kept per chain (after burn-in, every ``thin``-th step).
    burn_in, thin : int
        Steps discarded at the start; keep one step in ``thin``.
    seed : int, SeedSequence or None
        Root seed; each chain gets its own spawned stream.
    chains : int
        Independent chains, pooled in the result.
    init : label sequence, PTM or None
        Starting partition of every chain; a PTM (possibly over fewer
        detections) starts the chains from its top topologies, extended.
    moves : list of moves or of (move, weight) pairs
        Defaults to :func:`default_moves`.
    delayed_acceptance : bool or surrogate
        Screen proposals with the cheap terms before evaluating global ones
        (``True``), or with the cheap terms plus a surrogate's prediction of
        the global terms' change (e.g. :class:`ptm.surrogate.OdometrySurrogate`).
    warm_up : int
        Steps on approximations of the posterior from each chain's start,
        before burn-in (:func:`warm_up_start`; with a surrogate as
        ``delayed_acceptance``, half of them on its approximate odometry term):
        the chains then enter the full posterior near its bulk instead of from
        the dispersed extremes.
    max_doublings : int
        While several chains disagree (:func:`ptm.diagnostics.chains_agree`),
        double the samples kept per chain, at most this many times
        (:func:`run_chains`); ``diagnostics["doublings"]`` says how many were needed.
    estimate : "frequency", "renormalised" or "auto"
        A topology's probability: its share of the kept samples, its posterior probability normalised over
        the topologies the chains visited, or the second where every chain visited nearly all of those
        (:class:`SampleRecorder`).
    unscreened_share : float in [0, 1]
        With a surrogate as ``delayed_acceptance``, the share of steps that skip its screening and accept on
        the exact ratio (:class:`MoveMixture`); ``diagnostics["unscreened_steps"]`` counts them.
    smc_start : int
        Particles of a sequential Monte Carlo pass over the detections that gives each chain its start, from
        the chain's own stream (:func:`ptm.online.smc_start`; 0: none). Instead of ``init`` and ``warm_up``.
    """
    n_samples = count("n_samples", n_samples, minimum=1)
    burn_in = count("burn_in", burn_in, minimum=0)
    thin = count("thin", thin, minimum=1)
    chains = count("chains", chains, minimum=1)
    warm_up = count("warm_up", warm_up, minimum=0)
    max_doublings = count("max_doublings", max_doublings, minimum=0)
    estimate = checked_estimate(estimate)
    smc_start = checked_smc_start(smc_start, init, warm_up)
    mixture = MoveMixture(moves if moves is not None else default_moves(), unscreened_share)
    root = seed if isinstance(seed, np.random.SeedSequence) else np.random.SeedSequence(seed)
    surrogate = None if isinstance(delayed_acceptance, bool) else delayed_acceptance
    started = time.perf_counter()
    runners = []
    for chain, chain_seed in enumerate(root.spawn(chains)):
        rng = np.random.default_rng(chain_seed)
        labels = chain_start(posterior, init, chain, rng, warm_up, surrogate, smc_start)
        runners.append(_Chain(posterior, initial_state(posterior, labels), rng, mixture, delayed_acceptance))
    recorder, doublings = run_chains(runners, n_samples, burn_in, thin, max_doublings, estimate)
    wall = time.perf_counter() - started
    kept = recorder.n_samples
    steps = chains * (burn_in + kept * thin)
    diagnostics = {"chains": chains, "steps": steps, "samples": chains * kept, "doublings": doublings,
                   "wall_s": wall, "steps_per_s": steps / wall if wall > 0 else float("inf"), **mixture.diagnostics()}
    diagnostics.update(screening_diagnostics(posterior, delayed_acceptance))
    return recorder.result("mcmc", diagnostics)


class _Chain:
    """One Metropolis-Hastings chain of :func:`mcmc`: :meth:`step` advances it and returns its state."""

    def __init__(self, posterior, state, rng, mixture: "MoveMixture", delayed_acceptance):
        self.posterior, self.state, self.rng = posterior, state, rng
        self.mixture, self.delayed_acceptance = mixture, delayed_acceptance

    def step(self):
        self.state, _ = self.mixture.step(self.posterior, self.state, self.rng,
                                          delayed_acceptance=self.delayed_acceptance)
        return self.state


def run_chains(chains, n_samples: int, burn_in: int = 0, thin: int = 1, max_doublings: int = 0,
               estimate: str = "frequency") -> tuple["SampleRecorder", int]:
    """Run ``chains`` (objects whose ``step()`` advances one chain and returns the state to record) for
    ``burn_in + n_samples * thin`` steps each, keeping every ``thin``-th state after the burn-in; then, while
    there are several chains and they disagree (:func:`ptm.diagnostics.chains_agree`), double ``n_samples``
    and continue every chain from where it stopped, at most ``max_doublings`` times.

    The burn-in stays as given. Each chain draws from its own stream and the target is a function of the
    partition alone, so an extended run keeps exactly the samples of a run started with the final
    ``n_samples``. ``estimate`` is the recorder's (:class:`SampleRecorder`), which the agreement is judged on.
    Returns the recorder and the number of doublings made.
    """
    recorder = SampleRecorder(len(chains), n_samples, estimate)
    taken = [0] * len(chains)
    doublings = 0
    while True:
        steps = burn_in + recorder.n_samples * thin
        for index, chain in enumerate(chains):
            for step in range(taken[index], steps):
                state = chain.step()
                kept, remainder = divmod(step - burn_in + 1, thin)
                if step >= burn_in and remainder == 0:
                    recorder.keep(index, kept - 1, state)
            taken[index] = steps
            recorder.flush()
        if doublings == max_doublings or len(chains) < 2 or chains_agree(recorder.convergence()):
            return recorder, doublings
        doublings += 1
        recorder.extend(2 * recorder.n_samples)


@dataclass(frozen=True)
class StepInfo:
    """What one Metropolis-Hastings step did (kept apart from the chain state)."""

    proposed: bool          # the move proposed a different partition
    accepted: bool
    screened_out: bool      # rejected by the cheap first stage of delayed acceptance
    global_evaluated: bool  # the global (odometry) terms were evaluated


_NOTHING_PROPOSED = StepInfo(False, False, False, False)


def metropolis_step(posterior, state, rng, move, inverse_temperature: float = 1.0,
                    delayed_acceptance=False):
    """One MH step targeting P(T|Z)^inverse_temperature; returns (state, StepInfo).

    ``delayed_acceptance``: False, True (a first stage on the cheap terms), or
    a surrogate whose ``screening_change(partition, removed_sets, added_sets)``
    joins the cheap terms in the first stage.
    """
    proposal = move.propose(rng, state, posterior)
    if proposal is None:
        return state, _NOTHING_PROPOSED
    log_cheap, added_scores = proposed_log_cheap(posterior, state, proposal)
    log_ratio = inverse_temperature * (log_cheap - state.log_cheap) + proposal.log_q_ratio
    log_uniform = math.log(rng.random() or _SMALLEST)
    partition = None
    log_global = 0.0
    if proposal.reverse_log_q is not None:  # informed by the current map: evaluated exactly, never screened
        partition = proposed_partition(state, proposal)
        if posterior.has_global_terms:
            log_global = posterior.global_log_prob(partition)
            log_ratio += inverse_temperature * (log_global - state.log_global)
        if log_ratio > -math.inf:
            log_ratio += proposal.reverse_log_q(partition)
    elif posterior.has_global_terms and delayed_acceptance:
        surrogate = None if delayed_acceptance is True else delayed_acceptance
        removed = [state.blocks[index] for index in proposal.removed]
        if hasattr(surrogate, "screening_change_bound") and log_uniform >= log_ratio + inverse_temperature * (
                surrogate.screening_change_bound(state.partition, removed, proposal.added)):
            return state, StepInfo(True, False, True, False)  # out at an upper bound: out at the prediction too
        predicted = 0.0 if surrogate is None else surrogate.screening_change(state.partition, removed,
                                                                              proposal.added)
        screening_ratio = log_ratio + inverse_temperature * predicted
        if log_uniform >= screening_ratio:
            return state, StepInfo(True, False, True, False)
        log_uniform = math.log(rng.random() or _SMALLEST)
        partition = proposed_partition(state, proposal)
        log_global = posterior.global_log_prob(partition)
        reverse_predicted = 0.0
        if surrogate is not None and math.isfinite(log_global) and math.isfinite(state.log_global):
            reverse_predicted = surrogate.screening_change(partition, proposal.added, removed)
        log_ratio = second_stage_log_ratio(inverse_temperature * (log_global - state.log_global),
                                           inverse_temperature * predicted, inverse_temperature * reverse_predicted,
                                           screening_ratio)
    elif posterior.has_global_terms:
        partition = proposed_partition(state, proposal)
        log_global = posterior.global_log_prob(partition)
        log_ratio += inverse_temperature * (log_global - state.log_global)
    evaluated = partition is not None and posterior.has_global_terms
    if not log_uniform < log_ratio:
        return state, StepInfo(True, False, False, evaluated)
    if partition is None:
        partition = proposed_partition(state, proposal)
    return (apply_proposal(state, proposal, partition, added_scores, log_cheap, log_global),
            StepInfo(True, True, False, evaluated))


def second_stage_log_ratio(global_change: float, predicted: float, reverse_predicted: float,
                           screening_ratio: float) -> float:
    """log of the second stage's ratio of delayed acceptance (Christen & Fox 2005), all terms tempered.

    The first stage accepts T -> T' with a_1(T, T') = min(1, exp(r)), r = ``screening_ratio`` (the
    cheap terms, the proposal ratio and the prediction s_T(T') = ``predicted``); the reverse move's
    first stage, predicted from T', has r' = s_T'(T) + s_T(T') - r (``reverse_predicted`` = s_T'(T)).
    The second stage accepts with

        min(1, P(T') q(T'->T) a_1(T', T) / (P(T) q(T->T') a_1(T, T')))
          = min(1, exp(global_change - predicted + min(r, predicted + reverse_predicted) - min(0, r))),

    so that each transition's probability P(T) q a_1 a_2 is symmetric: detailed balance for the exact
    target whatever the surrogate. Without one (both predictions 0) it is exp(global_change).
    """
    return global_change - predicted + (min(screening_ratio, predicted + reverse_predicted) - min(0.0, screening_ratio))


def screening_diagnostics(posterior, delayed_acceptance) -> dict:
    """The posterior's diagnostics, and the surrogate's under ``"surrogate"`` when delayed acceptance used one."""
    diagnostics = posterior.diagnostics()
    if hasattr(delayed_acceptance, "diagnostics"):
        diagnostics["surrogate"] = delayed_acceptance.diagnostics()
    return diagnostics


class MoveMixture:
    """Draws one move per step from a weighted list and tallies what each move did.

    With ``unscreened_share`` > 0 and global terms to screen, each step skips delayed acceptance's screening
    with that probability and accepts on the exact ratio: a mixture, chosen independently of the state, of
    two kernels that each keep the posterior, so it keeps it too. A surrogate that mispredicts where the chain sits (a map that a wrong
    merge distorts) makes the screened kernel reject the very move that repairs it; the unscreened steps let
    such a move through at its exact odds (docs/model.md §3.4).
    """

    def __init__(self, moves, unscreened_share: float = 0.0):
        self.moves, weights = _weighted_moves(moves)
        self._cumulative = np.cumsum(weights) / np.sum(weights)
        self.unscreened_share = share("unscreened_share", unscreened_share)
        self.proposed = np.zeros(len(self.moves), dtype=np.int64)
        self.accepted = np.zeros(len(self.moves), dtype=np.int64)
        self.screened_out = 0
        self.global_evaluations = 0
        self.unscreened = 0

    def step(self, posterior, state, rng, inverse_temperature=1.0, delayed_acceptance=False):
        which = 0 if len(self.moves) == 1 else int(np.searchsorted(self._cumulative, rng.random(), side="right"))
        if (delayed_acceptance is not False and posterior.has_global_terms and self.unscreened_share
                and rng.random() < self.unscreened_share):
            delayed_acceptance = False
            self.unscreened += 1
        state, info = metropolis_step(posterior, state, rng, self.moves[which], inverse_temperature,
                                      delayed_acceptance)
        self.proposed[which] += 1
        self.accepted[which] += info.accepted
        self.screened_out += info.screened_out
        self.global_evaluations += info.global_evaluated
        return state, info

    def diagnostics(self) -> dict:
        return {
            "acceptance_rate": float(self.accepted.sum() / max(self.proposed.sum(), 1)),
            "acceptance_by_move": {getattr(move, "name", type(move).__name__): float(a / max(p, 1))
                                   for move, a, p in zip(self.moves, self.accepted, self.proposed)},
            "global_evaluations": int(self.global_evaluations),
            "screened_out": int(self.screened_out),
            "unscreened_steps": int(self.unscreened),
        }


#: How a sampler turns its chains into probabilities (:class:`SampleRecorder`).
ESTIMATES = ("frequency", "renormalised", "auto")
#: ``estimate = "auto"`` renormalises when every chain visited topologies holding at least this share of the
#: renormalised mass of all chains' (:meth:`SampleRecorder.chain_coverage`), strays apart.
RENORMALISE_COVERAGE = 0.99
#: A chain whose visited topologies hold less than this share of that mass is a stray: it sits in a mode that the
#: renormalised estimate gives almost nothing (less than this share, so no co-assignment moves by more), and
#: ``"auto"`` judges the coverage of the other chains alone. In seven runs on 57-121-detection grids one chain of four
#: stayed 8.6-321 nats below the others' topologies; the frequencies gave its partition a quarter of the mass.
STRAY_CHAIN_MASS = 0.01


def checked_estimate(estimate: str) -> str:
    """``estimate`` if it is one of :data:`ESTIMATES`, else ``ValueError``."""
    if estimate not in ESTIMATES:
        raise ValueError(f"estimate must be one of {', '.join(ESTIMATES)}, got {estimate!r}")
    return estimate


class SampleRecorder:
    """Pools kept samples into a histogram (run-length counted, also per chain) and per-chain traces.

    With ``estimate = "frequency"`` a topology's probability is the share of kept samples in it. With
    ``"renormalised"`` it is P(T|Z) itself, normalised over the distinct topologies the chains visited:
    exp(log P(T|Z)) / sum over visited T' of exp(log P(T'|Z)) (docs/model.md §3.4). Both converge to the
    posterior; the second has no Monte-Carlo error in the ratios between visited topologies, and puts no mass
    where no chain went: its total variation from the posterior is exactly the posterior mass of the topologies
    never visited. It is the better estimate where the chains have found all of the posterior's bulk and
    revisit it (a peaked posterior, a sampler that moves rarely), and a biased one where they keep finding new
    topologies (a flat posterior over very many). ``"auto"`` decides by the chains themselves: renormalised
    when each of several chains visited topologies holding at least ``RENORMALISE_COVERAGE`` of the
    renormalised mass of all of them (:meth:`chain_coverage`), frequency otherwise;
    ``diagnostics["estimate"]`` says which was used. A stray chain, whose topologies hold less than
    ``STRAY_CHAIN_MASS`` of that mass (a mode it never left, far below the others'), is not asked to cover the
    others' (:meth:`chain_coverages`): their frequencies would give its mode a whole chain's share. At least two
    chains that are not strays must cover it.
    """

    def __init__(self, chains: int, n_samples: int, estimate: str = "frequency"):
        self.estimate = checked_estimate(estimate)
        self.n_samples = n_samples
        self.counts: dict[Partition, int] = {}
        self.chain_counts: list[dict[Partition, int]] = [{} for _ in range(chains)]
        self.log_prob = np.empty((chains, n_samples))
        self.num_places = np.empty((chains, n_samples), dtype=np.int32)
        # One recorded log P per partition (the first computed): chains update log P incrementally, so their
        # values of one partition differ in the last digits, which rank-based R-hat would count as disagreement.
        self._log_prob_of: dict[Partition, float] = {}
        self._current = None
        self._chain = 0
        self._run_length = 0
        self._convergence = (-1, {})  # (samples recorded, their convergence diagnostics)

    def keep(self, chain: int, index: int, state) -> None:
        self.log_prob[chain, index] = self._log_prob_of.setdefault(state.partition, state.log_prob)
        self.num_places[chain, index] = len(state.blocks)
        if state.partition is not self._current or chain != self._chain:
            self.flush()
            self._current, self._chain = state.partition, chain
        self._run_length += 1

    def flush(self) -> None:
        if self._run_length:
            self.counts[self._current] = self.counts.get(self._current, 0) + self._run_length
            per_chain = self.chain_counts[self._chain]
            per_chain[self._current] = per_chain.get(self._current, 0) + self._run_length
        self._current, self._run_length = None, 0

    def extend(self, n_samples: int) -> None:
        """Make room for ``n_samples`` per chain (more than now), keeping what was recorded."""
        grown = n_samples - self.n_samples
        self.log_prob = np.pad(self.log_prob, ((0, 0), (0, grown)))
        self.num_places = np.pad(self.num_places, ((0, 0), (0, grown)))
        self.n_samples = n_samples

    def chain_coverages(self) -> np.ndarray:
        """Each chain's share of the renormalised mass of every visited topology: the mass of the topologies it
        visited itself (1 for each when the chains visited the same topologies)."""
        self.flush()
        mass = dict(zip(self.counts, self._weights(self.counts, "renormalised")))
        total = sum(mass.values())
        return np.array([sum(mass[partition] for partition in counts) / total for counts in self.chain_counts])

    def chain_coverage(self) -> float:
        """The smallest of :meth:`chain_coverages` (NaN with one chain)."""
        return float(self.chain_coverages().min()) if len(self.chain_counts) > 1 else math.nan

    def strays(self) -> dict:
        """The stray chains (``STRAY_CHAIN_MASS``): ``stray_chains``, their number, and where there are some,
        ``stray_mass_max``, the largest share of the renormalised mass that one of them visited, and
        ``stray_log_prob_gap``, how far the best topology a stray visited lies below the best of all [nats]."""
        coverages = self.chain_coverages()
        stray = np.flatnonzero(coverages < STRAY_CHAIN_MASS)
        if not len(stray):
            return {"stray_chains": 0}
        best = max(self._log_prob_of[partition] for partition in self.counts)
        best_of_strays = max(self._log_prob_of[partition] for index in stray for partition in self.chain_counts[index])
        return {"stray_chains": len(stray), "stray_mass_max": float(coverages[stray].max()),
                "stray_log_prob_gap": float(best - best_of_strays)}

    def resolved_estimate(self) -> str:
        """The estimate used: :attr:`estimate`, with ``"auto"`` resolved by :meth:`chain_coverages` of the chains
        that are not strays (at least two of them: one chain alone is no evidence that the bulk was found)."""
        if self.estimate != "auto":
            return self.estimate
        if len(self.chain_counts) < 2:
            return "frequency"
        coverages = self.chain_coverages()
        judged = coverages[coverages >= STRAY_CHAIN_MASS]
        return "renormalised" if len(judged) >= 2 and judged.min() >= RENORMALISE_COVERAGE else "frequency"

    def convergence(self) -> dict:
        """Split R-hat and ESS of log P and of the number of places (with 4 or more samples per chain), and
        for several chains the largest difference between two chains' co-assignments, the chains'
        coverage of the visited topologies (:meth:`chain_coverage`), the stray chains (:meth:`strays`) and the
        estimate resolved (:meth:`resolved_estimate`); else {}."""
        self.flush()
        recorded = sum(self.counts.values())
        if self._convergence[0] == recorded:
            return dict(self._convergence[1])
        chains, n_samples = self.log_prob.shape
        diagnostics = {}
        if chains > 1 and n_samples >= 4:
            for name, trace in (("log_prob", self.log_prob), ("num_places", self.num_places)):
                diagnostics[f"rhat_{name}"] = split_rhat(trace)
                diagnostics[f"ess_{name}"] = effective_sample_size(trace)
        if chains > 1:
            diagnostics["coassignment_max_difference"] = self.coassignment_max_difference()
            diagnostics["chain_coverage_min"] = self.chain_coverage()
            diagnostics.update(self.strays())
            diagnostics["estimate"] = self.resolved_estimate()  # what ptm.diagnostics.chains_agree judges by
        self._convergence = (recorded, diagnostics)
        return dict(diagnostics)

    def result(self, method: str, diagnostics: dict) -> PTM:
        diagnostics.update(self.convergence())
        diagnostics["n_distinct"] = len(self.counts)
        estimate = self.resolved_estimate()
        diagnostics["estimate"] = estimate
        return PTM(np.array([partition.labels for partition in self.counts], dtype=np.int32),
                   self._weights(self.counts, estimate), method, diagnostics,
                   traces={"log_prob": self.log_prob, "num_places": self.num_places})

    def _weights(self, counts: dict, estimate: str) -> np.ndarray:
        """Unnormalised probabilities of the visited topologies ``counts`` (partition -> samples kept) under a
        resolved ``estimate``: their sample counts, or exp(log P) scaled by the largest."""
        if estimate == "frequency":
            return np.array(list(counts.values()), dtype=float)
        log_probs = np.array([self._log_prob_of[partition] for partition in counts])
        return np.exp(log_probs - log_probs.max())

    def coassignment_max_difference(self) -> float:
        """max over pairs of chains and detections (i, j) of |C_a(i, j) - C_b(i, j)|, C_c the co-assignment
        matrix of chain c's own estimate (its samples alone, under :meth:`resolved_estimate`): 0 when the chains
        agree on which detections share a place."""
        estimate = self.resolved_estimate()
        matrices = [PTM(np.array([partition.labels for partition in counts], dtype=np.int32),
                        self._weights(counts, estimate), "chain").coassignment() for counts in self.chain_counts]
        return float(max(np.abs(first - second).max()
                         for index, first in enumerate(matrices) for second in matrices[index + 1:]))


def chain_start(posterior, init, chain: int, rng, warm_up: int = 0, surrogate=None,
                smc_particles: int = 0) -> tuple[int, ...]:
    """Where chain number ``chain`` starts (shared by :func:`mcmc` and :func:`ptm.tempered_mcmc`): a draw from an
    SMC pass of ``smc_particles`` particles (:func:`ptm.online.smc_start`), or else :func:`start_labels` followed
    by ``warm_up`` steps of :func:`warm_up_start`."""
    if smc_particles:
        from .online import smc_start  # the online mapper's rejuvenation is built from this module's moves

        return smc_start(posterior, smc_particles, rng)
    labels = start_labels(posterior, init, chain, rng)
    return warm_up_start(posterior, labels, warm_up, rng, surrogate) if warm_up else labels


def checked_smc_start(smc_start, init, warm_up: int) -> int:
    """``smc_start`` as a particle count >= 0; refused beside ``init`` or ``warm_up``, which it replaces."""
    smc_start = count("smc_start", smc_start, minimum=0)
    if smc_start and (init is not None or warm_up):
        raise ValueError("smc_start replaces init and warm_up: give one way to start the chains, not both")
    return smc_start


def start_labels(posterior, init, chain: int, rng) -> tuple[int, ...]:
    """The partition chain number ``chain`` starts from (shared by :func:`mcmc` and :func:`ptm.tempered_mcmc`).

    Without ``init`` the chains are dispersed: chain 0, 3, ... starts from all
    detections distinct, chain 1, 4, ... from all at one place, the others from
    random labels drawn with ``rng``. ``init`` may be a label sequence (every
    chain starts there) or a :class:`ptm.PTM` over the first n <= N
    detections: chain c starts from its (c + 1)-th most probable topology
    (cycling when it has fewer), each new detection placed by a draw from its
    conditional under the cheap terms.
    """
    n = posterior.n
    if init is None:
        if chain % 3 == 0:
            return tuple(range(n))
        if chain % 3 == 1:
            return (0,) * n
        return tuple(int(x) for x in rng.integers(0, max(1, n // 2), size=n))
    if isinstance(init, PTM):
        if init.n > n:
            raise ValueError(f"init PTM is over {init.n} detections, more than the posterior's {n}")
        tops = init.top(chain + 1)
        labels = list(tops[chain % len(tops)][0])
        for detection in range(init.n, n):
            labels.append(_draw_placement(posterior, labels, detection, rng))
        return tuple(labels)
    labels = tuple(init)
    if len(labels) != n:
        raise ValueError(f"init has {len(labels)} labels, the posterior has N={n}")
    return labels


def warm_up_start(posterior, labels, steps: int, rng, surrogate=None) -> tuple[int, ...]:
    """The partition after ``steps`` Metropolis-Hastings steps from ``labels`` on approximations of the
    posterior that evaluate no importance sampling: a start near the posterior's bulk, still dispersed across
    chains, instead of an extreme (all distinct, all one place) where the odometry term is far from any
    mode and its estimate rough (docs/model.md §3.4).

    The first steps (all of them without ``surrogate``) target the cheap terms alone (prior and appearance,
    without the terms that complete the odometry term such as :class:`ptm.TieNormaliser`:
    :meth:`ptm.Posterior.standalone_block_score`; guided split-merge and Gibbs reassignment, half and half),
    raised to an inverse temperature that rises geometrically from ``WARM_UP_FIRST_BETA`` to 1 over their
    first half (:func:`_annealed`): at 1 from the
    start, a chain started with all detections at one place stays there when appearance alone cannot pull a
    single detection out of the crowd (a 57-detection grid: 234 nats below the truth). The last half, with an
    :class:`ptm.surrogate.OdometrySurrogate`, adds its approximate odometry term (Laplace value and
    expected penalty, :meth:`~ptm.surrogate.OdometrySurrogate.approximate_log_likelihood`), with the guided
    moves (the window steered by the cheap terms alone) and the surrogate screening delayed acceptance. Each
    approximate value costs a Laplace fit.
    """
    cheap_steps = steps if surrogate is None else steps - steps // 2
    cheap = _WarmUpTarget(posterior)
    mixture = MoveMixture([(GuidedSplitMerge(posterior), 0.5), (GibbsReassign(), 0.5)])
    state = initial_state(cheap, labels)
    for step in range(cheap_steps):
        state, _ = mixture.step(cheap, state, rng, inverse_temperature=_annealed(step, cheap_steps))
    if surrogate is not None and steps > cheap_steps:
        approximate = _WarmUpTarget(posterior, surrogate.approximate_log_likelihood)
        mixture = MoveMixture(guided_moves(posterior, surrogate))
        state = initial_state(approximate, state.partition.labels)
        for _ in range(steps - cheap_steps):
            state, _ = mixture.step(approximate, state, rng, delayed_acceptance=surrogate)
    return state.partition.labels


def _annealed(step: int, steps: int) -> float:
    """Inverse temperature of warm-up step ``step`` of ``steps``: geometric from ``WARM_UP_FIRST_BETA`` to 1
    over the first half, then 1."""
    progress = min(1.0, 2.0 * step / steps)
    return WARM_UP_FIRST_BETA ** (1.0 - progress)


class _WarmUpTarget:
    """A posterior seen with its global terms replaced (by nothing, or by an approximation): what the
    moves and the step read of it."""

    def __init__(self, posterior, global_log_prob=None):
        self.n = posterior.n
        # Without the global terms, the terms that complete one are left out too (ptm.TieNormaliser); where there
        # are none, the memoised block score itself (no extra call in the warm-up's inner loop).
        leaves_out = global_log_prob is None and posterior.completing_terms
        self.block_score = posterior.standalone_block_score if leaves_out else posterior.block_score
        self.log_prior_by_size = posterior.log_prior_by_size
        self.partition = posterior.partition
        self.has_global_terms = global_log_prob is not None
        self._global_log_prob = global_log_prob

    def global_log_prob(self, partition) -> float:
        return 0.0 if self._global_log_prob is None else self._global_log_prob(partition)


def _draw_placement(posterior, labels: list[int], detection: int, rng) -> int:
    """Label for a new detection, drawn from its conditional under the cheap terms of the first
    ``detection + 1`` detections (existing places or a new one), less the terms that complete a global one."""
    score = posterior.standalone_block_score
    blocks: dict[int, list[int]] = {}
    for index, label in enumerate(labels):
        blocks.setdefault(label, []).append(index)
    places = len(blocks)
    log_weights = []
    candidates = list(blocks) + [max(blocks, default=-1) + 1]
    for label in candidates:
        members = tuple(blocks.get(label, [])) + (detection,)
        gain = score(members) - (score(tuple(blocks[label])) if label in blocks else 0.0)
        log_weights.append(gain + (0.0 if label in blocks else _new_place_log_odds(posterior, places)))
    log_weights = np.array(log_weights)
    probabilities = np.exp(log_weights - log_weights.max())
    probabilities /= probabilities.sum()
    return candidates[int(rng.choice(len(candidates), p=probabilities))]


def _new_place_log_odds(posterior, places: int) -> float:
    """Prior log-odds of opening place number ``places + 1`` versus joining one (full-N prior)."""
    table = posterior.log_prior_by_size
    return table[min(places + 1, len(table) - 1)] - table[max(places, 1)]


def _weighted_moves(moves):
    move_list, weights = [], []
    for item in moves:
        move, weight = item if isinstance(item, tuple) else (item, 1.0)
        if not hasattr(move, "propose"):
            raise ValueError(f"{move!r} is not a move: it has no propose(rng, state, posterior)")
        if not (isinstance(weight, (int, float)) and math.isfinite(weight) and weight > 0):
            raise ValueError(f"move weights must be positive, got {weight!r}")
        move_list.append(move)
        weights.append(float(weight))
    if not move_list:
        raise ValueError("mcmc needs at least one move")
    return move_list, np.array(weights)
