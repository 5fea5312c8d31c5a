"""The chain state and a move's proposal (docs/model.md §3.4): what a Metropolis-Hastings step reads and writes.

A :class:`ChainState` is immutable: the partition T, each set's cheap score s(B) (prior-free sum of the terms
that decompose over sets), and the two parts of log P(T | Z), the cheap one (log P(T) + sum_B s(B)) and the
global one. A :class:`Proposal` names the sets a move removes and adds, so a step re-scores only those.

    >>> from ptm import Dataset, PoissonPrior, Posterior
    >>> state = initial_state(Posterior(Dataset(labels=[0, 0, 1]), PoissonPrior(2.0)), [0, 0, 1])
    >>> state.blocks, state.log_global
    (((0, 1), (2,)), 0.0)
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

from ..partitions import Block, Partition

__all__ = ["ChainState", "Proposal", "initial_state", "proposed_log_cheap", "proposed_partition", "apply_proposal"]


@dataclass(frozen=True)
class ChainState:
    """Where a chain is: the partition, each set's cheap score, and the two parts of log P(T|Z)."""

    partition: Partition
    block_scores: tuple[float, ...]
    log_cheap: float
    log_global: float

    @property
    def blocks(self) -> tuple[Block, ...]:
        return self.partition.blocks

    @property
    def log_prob(self) -> float:
        return self.log_cheap + self.log_global


@dataclass(frozen=True)
class Proposal:
    """Replace the sets at indices ``removed`` of the current state by the sets ``added``.

    ``log_q_ratio`` is log q(T'->T) - log q(T->T'), or, for a move whose reverse probability needs
    what only T' gives (its map estimate), -log q(T->T') with ``reverse_log_q(T')`` = log q(T'->T);
    the step then evaluates the proposal exactly, without a screening first stage.
    """

    removed: tuple[int, ...]
    added: tuple[Block, ...]
    log_q_ratio: float
    reverse_log_q: Callable[[Partition], float] | None = None


def initial_state(posterior, labels) -> ChainState:
    """The state of the partition ``labels`` under ``posterior`` (every set scored, the global terms evaluated)."""
    partition = posterior.partition(labels)
    scores = tuple(posterior.block_score(block) for block in partition.blocks)
    log_cheap = posterior.log_prior_by_size[partition.m] + sum(scores)
    return ChainState(partition, scores, log_cheap, posterior.global_log_prob(partition))


def proposed_log_cheap(posterior, state: ChainState, proposal: Proposal) -> tuple[float, tuple[float, ...]]:
    """Cheap log-probability of the proposed partition, from the change alone; also the new sets' scores."""
    added_scores = tuple(posterior.block_score(block) for block in proposal.added)
    m_new = len(state.blocks) - len(proposal.removed) + len(proposal.added)
    delta = sum(added_scores) - sum(state.block_scores[i] for i in proposal.removed)
    log_prior = posterior.log_prior_by_size
    log_cheap = state.log_cheap + delta + log_prior[m_new] - log_prior[len(state.blocks)]
    return log_cheap, added_scores


def proposed_partition(state: ChainState, proposal: Proposal) -> Partition:
    """The partition T' of ``proposal`` from ``state``."""
    blocks = [block for index, block in enumerate(state.blocks) if index not in proposal.removed]
    blocks.extend(proposal.added)
    blocks.sort()  # sets are disjoint, so tuples order by their smallest member
    return Partition(tuple(blocks))


def apply_proposal(state: ChainState, proposal: Proposal, partition: Partition,
                   added_scores, log_cheap: float, log_global: float) -> ChainState:
    """The accepted state, with each set's score carried over or taken from the proposal."""
    known = {block: score for index, (block, score) in enumerate(zip(state.blocks, state.block_scores))
             if index not in proposal.removed}
    known.update(zip(proposal.added, added_scores))
    scores = tuple(known[block] for block in partition.blocks)
    return ChainState(partition, scores, log_cheap, log_global)
