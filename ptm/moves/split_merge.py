"""The paper's split/merge proposal (paper eq. 10, Algorithm 2; docs/model.md §3.4) with its exact Hastings ratio.

Merge (probability 1/2): a pair of sets uniformly among C(M, 2); the reverse split has probability
1/2 * 1/N_S(T') * 1/S(n, 2). Split (probability 1/2): a non-singleton set uniformly among N_S(T), then one of
its S(n, 2) = 2^(n-1) - 1 two-way splits uniformly; the reverse merge has probability 1/2 * 1/C(M+1, 2).

    >>> import math
    >>> import numpy as np
    >>> from ptm import Dataset, PoissonPrior, Posterior
    >>> from ptm.moves import initial_state
    >>> posterior = Posterior(Dataset(labels=[0, 0, 0, 0]), PoissonPrior(2.0))
    >>> state = initial_state(posterior, [0, 0, 0, 0])
    >>> proposal = SplitMerge().propose(np.random.default_rng(0), state, posterior)   # a split, here
    >>> proposal.added, math.isclose(proposal.log_q_ratio, math.log(7))              # S(4, 2) = 7
    (((0, 3), (1, 2)), True)
"""

from __future__ import annotations

import math

from ..partitions import log_stirling2_two
from ._common import distinct_pair, uniform_index
from .state import ChainState, Proposal

__all__ = ["SplitMerge", "merge_log_q_ratio", "split_log_q_ratio"]


def merge_log_q_ratio(num_sets: int, num_nonsingleton_after: int, merged_size: int) -> float:
    """log q(T'->T) - log q(T->T') for merging two of ``num_sets`` sets into one of ``merged_size``.

    q(T->T') = 1/2 * 1/C(M, 2);  q(T'->T) = 1/2 * 1/N_S(T') * 1/S(n, 2).
    """
    return (math.log(num_sets * (num_sets - 1) / 2.0) - math.log(num_nonsingleton_after)
            - log_stirling2_two(merged_size))


def split_log_q_ratio(num_sets: int, num_nonsingleton: int, split_size: int) -> float:
    """log q(T'->T) - log q(T->T') for splitting a set of ``split_size`` of a partition with ``num_sets`` sets.

    q(T->T') = 1/2 * 1/N_S(T) * 1/S(n, 2);  q(T'->T) = 1/2 * 1/C(M+1, 2).
    """
    return (math.log(num_nonsingleton) + log_stirling2_two(split_size)
            - math.log((num_sets + 1) * num_sets / 2.0))


class SplitMerge:
    """The paper's split/merge proposal (Algorithm 2) with its exact Hastings ratio."""

    name = "split_merge"

    def propose(self, rng, state: ChainState, posterior) -> Proposal | None:
        blocks = state.blocks
        num_sets = len(blocks)
        if rng.random() < 0.5:
            if num_sets == 1:
                return None
            first, second = distinct_pair(rng, num_sets)
            merged = tuple(sorted(blocks[first] + blocks[second]))
            nonsingleton_after = sum(1 for block in blocks if len(block) > 1) + 1
            nonsingleton_after -= (len(blocks[first]) > 1) + (len(blocks[second]) > 1)
            return Proposal((first, second), (merged,),
                            merge_log_q_ratio(num_sets, nonsingleton_after, len(merged)))
        splittable = [index for index, block in enumerate(blocks) if len(block) > 1]
        if not splittable:
            return None
        chosen = splittable[uniform_index(rng, len(splittable))]
        members = blocks[chosen]
        while True:  # fair coins for all but the first member; redraw if part B is empty
            to_b = rng.random(len(members) - 1) < 0.5
            if to_b.any():
                break
        part_a = (members[0],) + tuple(member for member, flag in zip(members[1:], to_b) if not flag)
        part_b = tuple(member for member, flag in zip(members[1:], to_b) if flag)
        return Proposal((chosen,), (part_a, part_b),
                        split_log_q_ratio(num_sets, len(splittable), len(members)))
