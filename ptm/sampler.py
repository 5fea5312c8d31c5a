"""Metropolis-Hastings over topologies (paper Algorithm 1, SPEC §3.4).

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
its conditional under the cheap terms (incremental mapping, SPEC §3.7).

    >>> result = mcmc(posterior, n_samples=20_000, burn_in=2_000, seed=1, chains=4)
    >>> result.top(3), result.diagnostics["rhat_log_prob"]
"""

from __future__ import annotations

import math
import time

import numpy as np

from .diagnostics import effective_sample_size, split_rhat
from .moves import (GibbsReassign, SplitMerge, apply_proposal, initial_state, proposed_log_cheap,
                    proposed_partition)
from .partitions import Partition
from .result import PTM

__all__ = ["mcmc", "default_moves"]


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
    n_samples = _count("n_samples", n_samples, minimum=1)
    burn_in = _count("burn_in", burn_in, minimum=0)
    thin = _count("thin", thin, minimum=1)
    chains = _count("chains", chains, minimum=1)
    move_list, weights = _weighted_moves(moves if moves is not None else default_moves())
    root = seed if isinstance(seed, np.random.SeedSequence) else np.random.SeedSequence(seed)
    chain_seeds = root.spawn(chains)

    started = time.perf_counter()
    counts: dict[Partition, int] = {}
    log_prob_trace = np.empty((chains, n_samples))
    places_trace = np.empty((chains, n_samples), dtype=np.int32)
    proposed = np.zeros(len(move_list), dtype=np.int64)
    accepted = np.zeros(len(move_list), dtype=np.int64)
    screened_out = 0
    global_evaluations = 0
    for chain, chain_seed in enumerate(chain_seeds):
        rng = np.random.default_rng(chain_seed)
        start_labels = _start_labels(posterior, init, chain, rng)
        stats = _run_chain(posterior, initial_state(posterior, start_labels), rng, move_list, weights,
                           n_samples, burn_in, thin, delayed_acceptance, counts,
                           log_prob_trace[chain], places_trace[chain])
        proposed += stats["proposed"]
        accepted += stats["accepted"]
        screened_out += stats["screened_out"]
        global_evaluations += stats["global_evaluations"]
    wall = time.perf_counter() - started

    partitions = np.array([partition.labels for partition in counts], dtype=np.int32)
    frequencies = np.array(list(counts.values()), dtype=float)
    steps = chains * (burn_in + n_samples * thin)
    diagnostics = {
        "chains": chains,
        "steps": steps,
        "samples": chains * n_samples,
        "acceptance_rate": float(accepted.sum() / max(proposed.sum(), 1)),
        "acceptance_by_move": {getattr(move, "name", type(move).__name__): float(a / max(p, 1))
                               for move, a, p in zip(move_list, accepted, proposed)},
        "n_distinct": len(counts),
        "wall_s": wall,
        "steps_per_s": steps / wall if wall > 0 else float("inf"),
        "global_evaluations": global_evaluations,
        "screened_out": screened_out,
    }
    if chains > 1 and n_samples >= 4:
        for name, trace in (("log_prob", log_prob_trace), ("num_places", places_trace)):
            diagnostics[f"rhat_{name}"] = split_rhat(trace)
            diagnostics[f"ess_{name}"] = effective_sample_size(trace)
    diagnostics.update(posterior.diagnostics())
    return PTM(partitions, frequencies, "mcmc", diagnostics,
               traces={"log_prob": log_prob_trace, "num_places": places_trace})


def _run_chain(posterior, state, rng, move_list, weights, n_samples, burn_in, thin,
               delayed_acceptance, counts, log_prob_trace, places_trace) -> dict:
    """Advance one chain, adding its kept samples to ``counts`` and the traces."""
    cumulative = np.cumsum(weights)
    cumulative /= cumulative[-1]
    single_move = len(move_list) == 1
    has_global = posterior.has_global_terms
    two_stage = delayed_acceptance and has_global
    proposed = np.zeros(len(move_list), dtype=np.int64)
    accepted = np.zeros(len(move_list), dtype=np.int64)
    screened_out = 0
    global_evaluations = 0

    total_steps = burn_in + n_samples * thin
    run_length = 0  # consecutive kept samples at the current state, flushed on change
    kept = 0
    for step in range(total_steps):
        which = 0 if single_move else int(np.searchsorted(cumulative, rng.random(), side="right"))
        proposal = move_list[which].propose(rng, state, posterior)
        proposed[which] += 1
        if proposal is not None:
            log_cheap, added_scores = proposed_log_cheap(posterior, state, proposal)
            log_ratio = log_cheap - state.log_cheap + proposal.log_q_ratio
            log_uniform = math.log(rng.random() or 5e-324)
            partition = None
            log_global = 0.0
            if two_stage:
                if log_uniform >= log_ratio:
                    screened_out += 1
                    log_ratio = -math.inf
                else:
                    partition = proposed_partition(state, proposal)
                    log_global = posterior.global_log_prob(partition)
                    global_evaluations += 1
                    log_ratio = log_global - state.log_global
                    log_uniform = math.log(rng.random() or 5e-324)
            elif has_global:
                partition = proposed_partition(state, proposal)
                log_global = posterior.global_log_prob(partition)
                global_evaluations += 1
                log_ratio += log_global - state.log_global
            if log_uniform < log_ratio:
                if partition is None:
                    partition = proposed_partition(state, proposal)
                if run_length:
                    counts[state.partition] = counts.get(state.partition, 0) + run_length
                    run_length = 0
                state = apply_proposal(state, proposal, partition, added_scores, log_cheap, log_global)
                accepted[which] += 1
        if step >= burn_in and (step - burn_in) % thin == thin - 1:
            log_prob_trace[kept] = state.log_prob
            places_trace[kept] = len(state.blocks)
            kept += 1
            run_length += 1
    if run_length:
        counts[state.partition] = counts.get(state.partition, 0) + run_length
    return {"proposed": proposed, "accepted": accepted, "screened_out": screened_out,
            "global_evaluations": global_evaluations}


def _start_labels(posterior, init, chain: int, rng) -> tuple[int, ...]:
    """The partition chain number ``chain`` starts from."""
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
    count = len(blocks)
    log_weights = []
    candidates = list(blocks) + [max(blocks, default=-1) + 1]
    for label in candidates:
        members = tuple(blocks.get(label, [])) + (detection,)
        gain = posterior.block_score(members) - (posterior.block_score(tuple(blocks[label])) if label in blocks else 0.0)
        log_weights.append(gain + (0.0 if label in blocks else _new_place_log_odds(posterior, count)))
    log_weights = np.array(log_weights)
    probabilities = np.exp(log_weights - log_weights.max())
    probabilities /= probabilities.sum()
    return candidates[int(rng.choice(len(candidates), p=probabilities))]


def _new_place_log_odds(posterior, count: int) -> float:
    """Prior log-odds of opening place number ``count + 1`` versus joining one (full-N prior)."""
    table = posterior.log_prior_by_size
    return table[min(count + 1, len(table) - 1)] - table[max(count, 1)]


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


def _count(name: str, value, minimum: int) -> int:
    if isinstance(value, bool) or int(value) != value or value < minimum:
        raise ValueError(f"{name} must be an integer >= {minimum}, got {value!r}")
    return int(value)
