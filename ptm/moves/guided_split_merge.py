"""Sequentially-allocated split-merge with data-driven anchors (beyond the paper; docs/model.md §3.4,
"Data-driven moves").

The pair affinity a_ij = s({i, j}) - s({i}) - s({j}) is the cheap terms' log Bayes factor of i and j being one
place (appearance, paper eq. 15-19), a fixed matrix. A merge partner is drawn in proportion to exp(a_ij), a
split anchor in proportion to exp(-a_ij) among its set; the Hastings ratio includes both anchors' probabilities.

    >>> import numpy as np
    >>> from ptm import AppearanceModel, Dataset, PoissonPrior, Posterior
    >>> signatures = np.array([[0.30, 0.10], [0.40, 0.05], [0.31, 0.11]])
    >>> model = AppearanceModel(0.3, 0.05, 3.0, 2e-4)
    >>> posterior = Posterior(Dataset(signatures=signatures), PoissonPrior(2.0), [model])
    >>> move = GuidedSplitMerge(posterior)
    >>> bool(move.pair_affinity[0, 2] > 0 > move.pair_affinity[0, 1])    # 0 and 2 look alike, 0 and 1 do not
    True
"""

from __future__ import annotations

import math

import numpy as np

from ._common import draw, uniform_index
from .sequential_split_merge import split_or_merge
from .state import ChainState, Proposal

__all__ = ["GuidedSplitMerge"]


class GuidedSplitMerge:
    """Sequentially-allocated split-merge whose anchors are drawn from the data: the pairs' Bayes factors.

    The first anchor i is uniform. With probability 1/2 the move seeks a
    merge: the second anchor j is drawn among the detections outside i's set
    with probability p_T(j | i) proportional to exp(a_ij); otherwise it seeks a
    split: j is drawn among the other members of i's set in proportion to
    exp(-a_ij), the least alike first. Each draw mixes in ``exploration`` of a
    uniform one over the same candidates. Then, as in
    :class:`ptm.moves.SequentialSplitMerge`, the anchors' sets are merged or
    their set is split with the other members allocated by the cheap scores.
    The reverse move draws the same ordered pair from the other side (a
    merge's reverse seeks a split, and vice versa), so for each pair the
    Hastings term is

        log p_T'(j | i) - log p_T(j | i)  +/-  log q_allocation.

    Which of these proposals the odometry allows is left to the screen in
    delayed acceptance's first stage.
    """

    name = "guided_split_merge"

    def __init__(self, posterior, exploration: float = 0.1):
        if not 0.0 < exploration <= 1.0:
            raise ValueError(f"exploration must lie in (0, 1], got {exploration!r}")
        self.exploration = float(exploration)
        score = posterior.block_score
        singles = np.array([score((i,)) for i in range(posterior.n)])
        self.pair_affinity = np.zeros((posterior.n, posterior.n))
        for i in range(posterior.n):
            for j in range(i + 1, posterior.n):
                self.pair_affinity[i, j] = self.pair_affinity[j, i] = score((i, j)) - singles[i] - singles[j]

    def propose(self, rng, state: ChainState, posterior) -> Proposal | None:
        n = posterior.n
        if n == 1:
            return None
        first = uniform_index(rng, n)
        labels = np.asarray(state.partition.labels)
        seeks_merge = rng.random() < 0.5
        candidates = self._candidates(labels, first, seeks_merge)
        if not candidates.any():
            return None
        indices = np.flatnonzero(candidates)
        probabilities = self._anchor_probabilities(first, candidates, seeks_merge)[indices]
        pick = draw(rng, np.log(probabilities))
        second = int(indices[pick])
        proposal = split_or_merge(rng, state, posterior.block_score, first, second)
        after = labels.copy()
        for index, block in enumerate(proposal.added):
            after[list(block)] = n + index
        return Proposal(proposal.removed, proposal.added,
                        proposal.log_q_ratio + self.anchors_log_ratio(after, first, second, seeks_merge,
                                                                      probabilities[pick]))

    def anchors_log_ratio(self, after: np.ndarray, first: int, second: int, seeks_merge: bool,
                          forward: float) -> float:
        """log p_T'(second | first) - log ``forward``: the reverse move draws the second anchor from T'
        (labels ``after``), seeking the opposite of this move (a split after a merge)."""
        reverse = self._anchor_probabilities(first, self._candidates(after, first, not seeks_merge), not seeks_merge)
        return math.log(reverse[second]) - math.log(forward)

    @staticmethod
    def _candidates(labels: np.ndarray, first: int, seeks_merge: bool) -> np.ndarray:
        """Where the second anchor may be: outside the first's set (a merge) or inside it (a split)."""
        same = labels == labels[first]
        if seeks_merge:
            return ~same
        same[first] = False
        return same

    def _anchor_probabilities(self, first: int, candidates: np.ndarray, seeks_merge: bool) -> np.ndarray:
        """p(j | first) over all j: (1 - exploration) softmax(+-a_first,j) + exploration uniform, on ``candidates``."""
        affinity = self.pair_affinity[first]
        log_weights = np.where(candidates, affinity if seeks_merge else -affinity, -np.inf)
        weights = np.exp(log_weights - log_weights.max())
        return ((1.0 - self.exploration) * weights / weights.sum()
                + self.exploration * candidates / np.count_nonzero(candidates))
