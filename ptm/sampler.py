"""Metropolis-Hastings over topologies (paper eq. 10, Algorithm 1; docs/model.md §3.4).

Each step draws a move from a weighted list, asks it for a proposal T' and
accepts with probability min(1, P(T'|Z) q(T'->T) / (P(T|Z) q(T->T'))), in log
space. Only the sets a proposal changes are re-scored. With global terms
(odometry) and ``delayed_acceptance=True`` a proposal is first screened with
the cheap terms (prior + appearance) and only survivors pay for the global
terms; the second stage accepts with min(1, exp(global(T') - global(T))),
which keeps the target exact (Christen & Fox 2005).

Several chains start from dispersed partitions (all distinct, all one place,
random), run from seeds spawned from one root, and are pooled; split R-hat
and effective sample sizes of log P and of the number of places are reported.
``init`` may be a previous PTM over fewer detections: the chains then start
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

from .diagnostics import effective_sample_size, split_rhat
from .moves import (GibbsReassign, SplitMerge, apply_proposal, initial_state, proposed_log_cheap,
                    proposed_partition)
from ._validation import count
from .partitions import Partition
from .result import PTM

__all__ = ["mcmc", "default_moves", "metropolis_step", "start_labels", "StepInfo", "MoveMixture", "SampleRecorder"]

_SMALLEST = 5e-324  # replaces a uniform draw of exactly 0 before taking its log


def default_moves():
    """The paper's split/merge, mixed with single-detection Gibbs reassignment."""
    return [(SplitMerge(), 0.5), (GibbsReassign(), 0.5)]


def mcmc(posterior, n_samples: int, burn_in: int = 0, thin: int = 1, seed=None, chains: int = 1,
         init=None, moves=None, delayed_acceptance: bool = False) -> PTM:
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
    delayed_acceptance : bool
        Screen proposals with the cheap terms before evaluating global ones.
    """
    n_samples = count("n_samples", n_samples, minimum=1)
    burn_in = count("burn_in", burn_in, minimum=0)
    thin = count("thin", thin, minimum=1)
    chains = count("chains", chains, minimum=1)
    mixture = MoveMixture(moves if moves is not None else default_moves())
    root = seed if isinstance(seed, np.random.SeedSequence) else np.random.SeedSequence(seed)
    recorder = SampleRecorder(chains, n_samples)
    started = time.perf_counter()
    for chain, chain_seed in enumerate(root.spawn(chains)):
        rng = np.random.default_rng(chain_seed)
        state = initial_state(posterior, start_labels(posterior, init, chain, rng))
        for step in range(burn_in + n_samples * thin):
            state, _ = mixture.step(posterior, state, rng, delayed_acceptance=delayed_acceptance)
            kept, remainder = divmod(step - burn_in + 1, thin)
            if step >= burn_in and remainder == 0:
                recorder.keep(chain, kept - 1, state)
        recorder.flush()
    wall = time.perf_counter() - started
    steps = chains * (burn_in + n_samples * thin)
    diagnostics = {"chains": chains, "steps": steps, "samples": chains * n_samples, "wall_s": wall,
                   "steps_per_s": steps / wall if wall > 0 else float("inf"), **mixture.diagnostics()}
    diagnostics.update(posterior.diagnostics())
    return recorder.result("mcmc", diagnostics)


@dataclass(frozen=True)
class StepInfo:
    """What one Metropolis-Hastings step did (kept apart from the chain state)."""

    proposed: bool          # the move proposed a different partition
    accepted: bool
    screened_out: bool      # rejected by the cheap first stage of delayed acceptance
    global_evaluated: bool  # the global (odometry) terms were evaluated


_NOTHING_PROPOSED = StepInfo(False, False, False, False)


def metropolis_step(posterior, state, rng, move, inverse_temperature: float = 1.0,
                    delayed_acceptance: bool = False):
    """One MH step targeting P(T|Z)^inverse_temperature; returns (state, StepInfo)."""
    proposal = move.propose(rng, state, posterior)
    if proposal is None:
        return state, _NOTHING_PROPOSED
    log_cheap, added_scores = proposed_log_cheap(posterior, state, proposal)
    log_ratio = inverse_temperature * (log_cheap - state.log_cheap) + proposal.log_q_ratio
    log_uniform = math.log(rng.random() or _SMALLEST)
    partition = None
    log_global = 0.0
    if posterior.has_global_terms:
        if delayed_acceptance:
            if log_uniform >= log_ratio:
                return state, StepInfo(True, False, True, False)
            log_ratio = 0.0  # stage two: min(1, exp(beta * (global(T') - global(T))))
            log_uniform = math.log(rng.random() or _SMALLEST)
        partition = proposed_partition(state, proposal)
        log_global = posterior.global_log_prob(partition)
        log_ratio += inverse_temperature * (log_global - state.log_global)
    evaluated = partition is not None
    if not log_uniform < log_ratio:
        return state, StepInfo(True, False, False, evaluated)
    if partition is None:
        partition = proposed_partition(state, proposal)
    return (apply_proposal(state, proposal, partition, added_scores, log_cheap, log_global),
            StepInfo(True, True, False, evaluated))


class MoveMixture:
    """Draws one move per step from a weighted list and tallies what each move did."""

    def __init__(self, moves):
        self.moves, weights = _weighted_moves(moves)
        self._cumulative = np.cumsum(weights) / np.sum(weights)
        self.proposed = np.zeros(len(self.moves), dtype=np.int64)
        self.accepted = np.zeros(len(self.moves), dtype=np.int64)
        self.screened_out = 0
        self.global_evaluations = 0

    def step(self, posterior, state, rng, inverse_temperature=1.0, delayed_acceptance=False):
        which = 0 if len(self.moves) == 1 else int(np.searchsorted(self._cumulative, rng.random(), side="right"))
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
        }


class SampleRecorder:
    """Pools kept samples into a histogram (run-length counted) and per-chain traces."""

    def __init__(self, chains: int, n_samples: int):
        self.counts: dict[Partition, int] = {}
        self.log_prob = np.empty((chains, n_samples))
        self.num_places = np.empty((chains, n_samples), dtype=np.int32)
        self._current = None
        self._run_length = 0

    def keep(self, chain: int, index: int, state) -> None:
        self.log_prob[chain, index] = state.log_prob
        self.num_places[chain, index] = len(state.blocks)
        if state.partition is not self._current:
            self.flush()
            self._current = state.partition
        self._run_length += 1

    def flush(self) -> None:
        if self._run_length:
            self.counts[self._current] = self.counts.get(self._current, 0) + self._run_length
        self._current, self._run_length = None, 0

    def result(self, method: str, diagnostics: dict) -> PTM:
        self.flush()
        chains, n_samples = self.log_prob.shape
        if chains > 1 and n_samples >= 4:
            for name, trace in (("log_prob", self.log_prob), ("num_places", self.num_places)):
                diagnostics[f"rhat_{name}"] = split_rhat(trace)
                diagnostics[f"ess_{name}"] = effective_sample_size(trace)
        diagnostics["n_distinct"] = len(self.counts)
        partitions = np.array([partition.labels for partition in self.counts], dtype=np.int32)
        frequencies = np.array(list(self.counts.values()), dtype=float)
        return PTM(partitions, frequencies, method, diagnostics,
                   traces={"log_prob": self.log_prob, "num_places": self.num_places})


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


def _draw_placement(posterior, labels: list[int], detection: int, rng) -> int:
    """Label for a new detection, drawn from its conditional under the cheap terms of the first
    ``detection + 1`` detections (existing places or a new one)."""
    blocks: dict[int, list[int]] = {}
    for index, label in enumerate(labels):
        blocks.setdefault(label, []).append(index)
    places = len(blocks)
    log_weights = []
    candidates = list(blocks) + [max(blocks, default=-1) + 1]
    for label in candidates:
        members = tuple(blocks.get(label, [])) + (detection,)
        gain = posterior.block_score(members) - (posterior.block_score(tuple(blocks[label])) if label in blocks else 0.0)
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
