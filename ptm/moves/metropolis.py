"""One Metropolis-Hastings step over topologies (paper eq. 10, Algorithm 1; docs/model.md §3.4).

The step asks a move for a proposal T' and accepts with probability
min(1, P(T'|Z)^beta q(T'->T) / (P(T|Z)^beta q(T->T'))), in log space; only the sets the proposal changes are
re-scored. With global terms (odometry) and delayed acceptance a proposal is first screened with the cheap
terms (prior + decomposable terms), plus the screen's prediction s_T(T') of the change of the global terms
where a screen is given (:meth:`ptm.Posterior.screen`), and only survivors pay for the global terms. The second
stage corrects exactly (Christen & Fox 2005, :func:`second_stage_log_ratio`): with r the log of the first
stage's ratio,

    log alpha_2 = beta (global(T') - global(T) - s_T(T')) + min(r, beta (s_T(T') + s_T'(T))) - min(0, r),

which is beta (global(T') - global(T)) without a screen. What the step did is a :class:`StepInfo`, kept apart
from the chain state.

    >>> import numpy as np
    >>> from ptm import Dataset, PoissonPrior, Posterior
    >>> from ptm.moves import SplitMerge, initial_state
    >>> posterior = Posterior(Dataset(labels=[0, 0, 1]), PoissonPrior(2.0))
    >>> state, info = metropolis_step(posterior, initial_state(posterior, [0, 0, 1]), np.random.default_rng(0),
    ...                               SplitMerge())
    >>> info.proposed, state.partition.m in (1, 2, 3)
    (True, True)
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from .state import apply_proposal, proposed_log_cheap, proposed_partition

__all__ = ["StepInfo", "metropolis_step", "second_stage_log_ratio"]

_SMALLEST = 5e-324  # replaces a uniform draw of exactly 0 before taking its log


@dataclass(frozen=True)
class StepInfo:
    """What one Metropolis-Hastings step did (kept apart from the chain state)."""

    proposed: bool          # the move proposed a different partition
    accepted: bool
    screened_out: bool      # rejected by the cheap first stage of delayed acceptance
    global_evaluated: bool  # the global (odometry) terms were evaluated


_NOTHING_PROPOSED = StepInfo(False, False, False, False)


def metropolis_step(posterior, state, rng, move, inverse_temperature: float = 1.0, delayed_acceptance: bool = False,
                    screen=None):
    """One MH step targeting P(T|Z)^inverse_temperature; returns (state, StepInfo).

    ``delayed_acceptance``: screen the proposal in a first stage on the cheap terms, joined by ``screen``'s
    ``screening_change(partition, removed_sets, added_sets)`` where a screen is given (its optional
    ``screening_change_bound`` rejects early what the prediction would reject too).
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
        removed = [state.blocks[index] for index in proposal.removed]
        if hasattr(screen, "screening_change_bound") and log_uniform >= log_ratio + inverse_temperature * (
                screen.screening_change_bound(state.partition, removed, proposal.added)):
            return state, StepInfo(True, False, True, False)  # out at an upper bound: out at the prediction too
        predicted = 0.0 if screen is None else screen.screening_change(state.partition, removed, proposal.added)
        screening_ratio = log_ratio + inverse_temperature * predicted
        if log_uniform >= screening_ratio:
            return state, StepInfo(True, False, True, False)
        log_uniform = math.log(rng.random() or _SMALLEST)
        partition = proposed_partition(state, proposal)
        log_global = posterior.global_log_prob(partition)
        reverse_predicted = 0.0
        if screen is not None and math.isfinite(log_global) and math.isfinite(state.log_global):
            reverse_predicted = screen.screening_change(partition, proposal.added, removed)
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
    target whatever the screen. Without one (both predictions 0) it is exp(global_change).
    """
    return global_change - predicted + (min(screening_ratio, predicted + reverse_predicted) - min(0.0, screening_ratio))
