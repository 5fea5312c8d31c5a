"""Sequentially-allocated split-merge (Dahl 2003; beyond the paper, docs/model.md §3.4).

Two anchors are drawn. If they share a set, it is split: the other members, in random order, each join the
part of the first or of the second anchor with probability proportional to exp(s(part + member) - s(part)),
and log q(T->T') is the sum of those choices' log probabilities. Otherwise their sets are merged, and the
reverse split's probability is found by replaying the allocation that gives the two sets.

    >>> import numpy as np
    >>> from ptm import Dataset, PoissonPrior, Posterior
    >>> from ptm.moves import initial_state, proposed_partition
    >>> posterior = Posterior(Dataset(labels=[0, 0, 1]), PoissonPrior(2.0))
    >>> state = initial_state(posterior, [0, 0, 1])
    >>> [proposed_partition(state, SequentialSplitMerge().propose(np.random.default_rng(seed), state, posterior)).labels
    ...  for seed in (0, 1)]                                        # a split of {0, 1}, a merge of both sets
    [(0, 1, 2), (0, 0, 0)]
"""

from __future__ import annotations

import math

import numpy as np

from ._common import distinct_pair, with_member
from .state import ChainState, Proposal

__all__ = ["SequentialSplitMerge", "split_or_merge", "allocate"]


class SequentialSplitMerge:
    """Sequentially-allocated merge-split (Dahl 2003) guided by the cheap terms.

    Two distinct detections are drawn uniformly. In different sets: propose
    the merge (its reverse, the split, is scored by replaying the allocation).
    In one set: split it, each other member (in random order) joining the part
    of the first or the second anchor with probability proportional to the
    exponentiated change of the cheap set scores.
    """

    name = "sequential_split_merge"

    def propose(self, rng, state: ChainState, posterior) -> Proposal | None:
        n = posterior.n
        if n == 1:
            return None
        first, second = distinct_pair(rng, n)
        return split_or_merge(rng, state, posterior.block_score, first, second)


def split_or_merge(rng, state: ChainState, score, first: int, second: int) -> Proposal:
    """Split the anchors' set, the other members allocated by ``score``, if they share one; else merge their
    sets. The Hastings term is the allocation's only (the anchors' own probabilities are the caller's)."""
    labels = state.partition.labels
    blocks = state.blocks
    if labels[first] == labels[second]:
        home = labels[first]
        others = [member for member in blocks[home] if member not in (first, second)]
        part_first, part_second, log_q = allocate(rng, score, first, second, others)
        return Proposal((home,), (part_first, part_second), -log_q)
    block_first, block_second = blocks[labels[first]], blocks[labels[second]]
    others = [member for member in block_first + block_second if member not in (first, second)]
    _, _, log_q = allocate(rng, score, first, second, others, forced=set(block_first))
    merged = tuple(sorted(block_first + block_second))
    return Proposal((labels[first], labels[second]), (merged,), log_q)


def allocate(rng, score, first, second, others, forced=None):
    """Allocate ``others`` to the parts of anchors ``first`` and ``second`` in random order, each member
    joining a part in proportion to exp(score(part + member) - score(part)); return the parts and log q.

    With ``forced`` (the members of the first anchor's actual set), replay
    that allocation and return the probability the procedure gives it.
    """
    part_first, part_second = (first,), (second,)
    log_q = 0.0
    for position in rng.permutation(len(others)):
        member = others[position]
        grown_first = with_member(part_first, member)
        grown_second = with_member(part_second, member)
        gain_first = score(grown_first) - score(part_first)
        gain_second = score(grown_second) - score(part_second)
        log_norm = float(np.logaddexp(gain_first, gain_second))
        if forced is not None:
            joins_first = member in forced
        else:
            joins_first = rng.random() < math.exp(gain_first - log_norm)
        if joins_first:
            part_first = grown_first
            log_q += gain_first - log_norm
        else:
            part_second = grown_second
            log_q += gain_second - log_norm
    return part_first, part_second, log_q
