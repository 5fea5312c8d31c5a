"""Reassignment by the current map (beyond the paper; docs/model.md §3.4, "Data-driven moves").

As :class:`ptm.moves.GibbsReassign`, with each candidate set's log weight raised by the posterior's screen
(:meth:`ptm.Posterior.screen`): its ``screening_change`` predicts how the global terms (odometry) change if the
detection goes there, under the map of the current partition T. The detection then goes preferably where the
map puts it. The reverse probability q(T'->T) needs the map of T' (``Proposal.reverse_log_q``), so the step
evaluates such a proposal exactly instead of screening it; the weights make it likely to be accepted. Without a
screen (no global term offers one) the weights are the cheap conditional's and the move is a Gibbs step.

    >>> import numpy as np
    >>> from ptm import Dataset, PoissonPrior, Posterior
    >>> from ptm.moves import initial_state, proposed_partition
    >>> posterior = Posterior(Dataset(labels=[0, 0, 1]), PoissonPrior(2.0))      # no global term: no screen
    >>> state = initial_state(posterior, [0, 0, 1])
    >>> proposal = MapReassign(posterior.screen()).propose(np.random.default_rng(1), state, posterior)
    >>> proposed_partition(state, proposal).labels, proposal.reverse_log_q is not None
    ((0, 1, 2), True)
"""

from __future__ import annotations

import numpy as np

from ..partitions import Partition
from ._common import draw, uniform_index
from .gibbs import destinations, reassigned
from .state import ChainState, Proposal

__all__ = ["MapReassign"]


class MapReassign:
    """Move one detection to a set drawn from a prediction of its full conditional, the global terms included.

    ``screen``: the posterior's screen (:meth:`ptm.Posterior.screen`), or None for the cheap conditional alone.
    """

    name = "map_reassign"

    def __init__(self, screen):
        self.screen = screen

    def propose(self, rng, state: ChainState, posterior) -> Proposal | None:
        n = posterior.n
        if n == 1:
            return None
        detection = uniform_index(rng, n)
        home, rest, targets, weights = self._weights(posterior, state.partition, state.block_scores, detection)
        pick = draw(rng, weights)
        target = targets[pick]
        if target == (home if rest else -1):
            return None
        removed, added = reassigned(state.blocks, home, rest, detection, target)
        forward = weights[pick] - float(np.logaddexp.reduce(weights))

        def reverse_log_q(after: Partition) -> float:
            """log q(T' -> T): ``detection`` drawn again and sent back to ``rest`` (or alone), under T's map."""
            scores = [posterior.block_score(block) for block in after.blocks]
            _, _, targets_after, weights_after = self._weights(posterior, after, scores, detection)
            back = after.blocks.index(rest) if rest else -1
            return weights_after[targets_after.index(back)] - float(np.logaddexp.reduce(weights_after))

        return Proposal(removed, added, -forward, reverse_log_q)

    def _weights(self, posterior, partition: Partition, block_scores, detection: int):
        """:func:`ptm.moves.gibbs.destinations` with each weight raised by the screen's change of the global terms."""
        blocks = partition.blocks
        home, rest, targets, weights = destinations(posterior, partition, block_scores, detection)
        if self.screen is None:
            return home, rest, targets, weights
        current = home if rest else -1
        for position, target in enumerate(targets):
            if target != current:
                removed, added = reassigned(blocks, home, rest, detection, target)
                weights[position] += self.screen.screening_change(partition, [blocks[k] for k in removed], added)
        return home, rest, targets, weights
