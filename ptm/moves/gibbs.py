"""Single-detection Gibbs reassignment (beyond the paper; docs/model.md §3.4).

One detection i, drawn uniformly, moves to a set drawn from its conditional under the cheap terms: with
T_-i the partition of the others (M_-i sets), a set B of T_-i has log weight s(B + i) - s(B) + log P(N, M_-i)
and a new set s({i}) + log P(N, M_-i + 1). The normaliser is the same seen from T and from T', so
log q(T'->T) - log q(T->T') = cheap(T) - cheap(T'): without global terms every such move is accepted, with
them the ratio of the global terms decides.

    >>> import numpy as np
    >>> from ptm import Dataset, PoissonPrior, Posterior
    >>> from ptm.moves import initial_state, proposed_partition
    >>> posterior = Posterior(Dataset(labels=[0, 0, 1]), PoissonPrior(2.0))
    >>> state = initial_state(posterior, [0, 0, 1])
    >>> proposed_partition(state, GibbsReassign().propose(np.random.default_rng(1), state, posterior)).labels
    (0, 1, 2)
"""

from __future__ import annotations

from ..partitions import Block, Partition
from ._common import draw, uniform_index, with_member
from .state import ChainState, Proposal

__all__ = ["GibbsReassign", "destinations", "reassigned"]


class GibbsReassign:
    """Move one detection to a set drawn from its conditional under the cheap terms.

    The candidates are every other set and a new singleton. Proposing from the
    cheap conditional gives log q ratio = cheap(T) - cheap(T'), so without
    global terms every such move is accepted (a Gibbs step), and with them the
    acceptance ratio is the ratio of the global terms alone.
    """

    name = "gibbs"

    def propose(self, rng, state: ChainState, posterior) -> Proposal | None:
        n = posterior.n
        if n == 1:
            return None
        detection = uniform_index(rng, n)
        home, rest, targets, weights = destinations(posterior, state.partition, state.block_scores, detection)
        pick = draw(rng, weights)
        target = targets[pick]
        current = home if rest else -1
        if target == current:
            return None
        removed, added = reassigned(state.blocks, home, rest, detection, target)
        return Proposal(removed, added, weights[targets.index(current)] - weights[pick])


def destinations(posterior, partition: Partition, block_scores, detection: int):
    """Where ``detection`` may go and the log weights of its cheap conditional there.

    Returns its set's index ``home``, the rest of that set ``rest``, the
    ``targets`` (set indices; -1 stands for a new singleton; ``home`` itself
    when ``rest`` is not empty) and their log weights: s(B + i) - s(B) +
    log P_prior(N, M_-i) for a set B, s({i}) + log P_prior(N, M_-i + 1) for a
    new one (relative to the partition without the detection, so the same from
    either side of a move).
    """
    blocks = partition.blocks
    home = partition.labels[detection]  # block j carries label j
    rest = tuple(member for member in blocks[home] if member != detection)
    sets_without = len(blocks) - (0 if rest else 1)
    log_prior = posterior.log_prior_by_size
    score = posterior.block_score
    targets: list[int] = []
    weights: list[float] = []
    for index, block in enumerate(blocks):
        if index == home:
            if rest:
                targets.append(index)
                weights.append(block_scores[home] - score(rest) + log_prior[sets_without])
            continue
        targets.append(index)
        weights.append(score(with_member(block, detection)) - block_scores[index] + log_prior[sets_without])
    targets.append(-1)
    weights.append(score((detection,)) + log_prior[sets_without + 1])
    return home, rest, targets, weights


def reassigned(blocks, home: int, rest: Block, detection: int, target: int):
    """The sets removed (indices) and added when ``detection`` leaves set ``home`` for ``target`` (-1: alone)."""
    if target == -1:
        return (home,), (rest, (detection,))
    joined = with_member(blocks[target], detection)
    if rest:
        return (home, target), (rest, joined)
    return (home, target), (joined,)
