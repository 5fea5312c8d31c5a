"""Proposal moves over partitions, the Metropolis-Hastings step that uses them, and the move sets
(paper eq. 10, Algorithms 1-2; docs/model.md §3.4). One move per module:

* :class:`SplitMerge` (``split_merge``) — the paper's move, with its exact Hastings ratio.
* :class:`GibbsReassign` (``gibbs``) — one detection moved to a set drawn from its cheap conditional.
* :class:`MapReassign` (``map_reassign``) — the same, the conditional raised by the posterior's screen under the
  current map; its reverse probability is computed from the map of T'.
* :class:`SequentialSplitMerge` (``sequential_split_merge``) — Dahl's (2003) sequentially-allocated split-merge.
* :class:`GuidedSplitMerge` (``guided_split_merge``) — the same with anchors drawn by the pairs' Bayes factors.
* :class:`WindowReallocation`, :class:`TrailingReallocation` (``window``) — block sampling of consecutive
  detections (Doucet, Briers & Senecal 2006).
* :class:`MapWindowReallocation` (``map_window``) — the window steered by the map of the sets left behind.

A move is any object with ``propose(rng, state, posterior) -> Proposal | None`` (``state``: :mod:`.state`).
:func:`metropolis_step` (``metropolis``) accepts or rejects a proposal, :class:`MoveMixture` (``mixture``) draws
a move per step from a weighted list, and :func:`move_set` (``sets``) resolves the named sets.

    >>> import math
    >>> import numpy as np
    >>> from ptm import Dataset, PoissonPrior, Posterior
    >>> posterior = Posterior(Dataset(labels=[0, 0, 0, 0]), PoissonPrior(2.0))
    >>> state = initial_state(posterior, [0, 0, 0, 0])
    >>> proposal = SplitMerge().propose(np.random.default_rng(0), state, posterior)   # a split, here
    >>> proposal.added, math.isclose(proposal.log_q_ratio, math.log(7))              # S(4, 2) = 7
    (((0, 3), (1, 2)), True)
"""

from .gibbs import GibbsReassign
from .guided_split_merge import GuidedSplitMerge
from .map_reassign import MapReassign
from .map_window import MapWindowReallocation
from .metropolis import StepInfo, metropolis_step, second_stage_log_ratio
from .mixture import MoveMixture
from .sequential_split_merge import SequentialSplitMerge
from .sets import (GUIDED_FROM_N, MAP_WINDOW_SHARE, MOVE_SETS, MoveSet, default_moves, guided_moves, move_set,
                   paper_moves)
from .split_merge import SplitMerge, merge_log_q_ratio, split_log_q_ratio
from .state import ChainState, Proposal, apply_proposal, initial_state, proposed_log_cheap, proposed_partition
from .window import TrailingReallocation, WindowReallocation

__all__ = [
    "ChainState", "Proposal", "initial_state", "proposed_log_cheap", "proposed_partition", "apply_proposal",
    "SplitMerge", "GibbsReassign", "MapReassign", "SequentialSplitMerge", "GuidedSplitMerge",
    "WindowReallocation", "TrailingReallocation", "MapWindowReallocation", "merge_log_q_ratio", "split_log_q_ratio",
    "StepInfo", "metropolis_step", "second_stage_log_ratio", "MoveMixture",
    "GUIDED_FROM_N", "MAP_WINDOW_SHARE", "MOVE_SETS", "MoveSet", "default_moves", "guided_moves", "paper_moves",
    "move_set",
]
