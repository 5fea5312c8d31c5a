"""The move mixture: each step draws one move from a weighted list (as emcee mixes its moves) and runs a
Metropolis-Hastings step with it (:func:`ptm.moves.metropolis.metropolis_step`; docs/model.md §3.4).

    >>> import numpy as np
    >>> from ptm import Dataset, PoissonPrior, Posterior
    >>> from ptm.moves import GibbsReassign, SplitMerge, initial_state
    >>> posterior = Posterior(Dataset(labels=[0, 0, 1]), PoissonPrior(2.0))
    >>> mixture = MoveMixture([(SplitMerge(), 0.5), (GibbsReassign(), 0.5)])
    >>> state = initial_state(posterior, [0, 0, 1])
    >>> for _ in range(100):
    ...     state, _ = mixture.step(posterior, state, np.random.default_rng(0))
    >>> int(mixture.proposed.sum())
    100
"""

from __future__ import annotations

import math

import numpy as np

from .._validation import share
from .metropolis import metropolis_step

__all__ = ["MoveMixture", "weighted_moves"]


class MoveMixture:
    """Draws one move per step from a weighted list and tallies what each move did.

    ``moves``: moves or (move, weight) pairs (:func:`weighted_moves`). ``delayed_acceptance`` and ``screen``
    are those of :func:`ptm.moves.metropolis.metropolis_step`. With ``unscreened_share`` > 0 and global terms
    to screen, each step skips delayed acceptance's screening with that probability and accepts on the exact
    ratio: a mixture, chosen independently of the state, of two kernels that each keep the posterior, so it
    keeps it too. A screen that mispredicts where the chain sits (a map that a wrong merge distorts) makes the
    screened kernel reject the very move that repairs it; the unscreened steps let such a move through at its
    exact odds (docs/model.md §3.4, "Unscreened steps").
    """

    def __init__(self, moves, delayed_acceptance: bool = False, screen=None, unscreened_share: float = 0.0):
        self.moves, weights = weighted_moves(moves)
        self._cumulative = np.cumsum(weights) / np.sum(weights)
        self.delayed_acceptance, self.screen = bool(delayed_acceptance), screen
        self.unscreened_share = share("unscreened_share", unscreened_share)
        self.proposed = np.zeros(len(self.moves), dtype=np.int64)
        self.accepted = np.zeros(len(self.moves), dtype=np.int64)
        self.screened_out = 0
        self.global_evaluations = 0
        self.unscreened = 0

    def step(self, posterior, state, rng, inverse_temperature: float = 1.0):
        """One step from ``state`` targeting P(T|Z)^inverse_temperature; returns (state, StepInfo)."""
        which = 0 if len(self.moves) == 1 else int(np.searchsorted(self._cumulative, rng.random(), side="right"))
        delayed_acceptance = self.delayed_acceptance
        if (delayed_acceptance and posterior.has_global_terms and self.unscreened_share
                and rng.random() < self.unscreened_share):
            delayed_acceptance = False
            self.unscreened += 1
        state, info = metropolis_step(posterior, state, rng, self.moves[which], inverse_temperature,
                                      delayed_acceptance, self.screen)
        self.proposed[which] += 1
        self.accepted[which] += info.accepted
        self.screened_out += info.screened_out
        self.global_evaluations += info.global_evaluated
        return state, info

    def diagnostics(self) -> dict:
        """The acceptance rate, overall and by move, the global terms' evaluations, the proposals screened out
        and the steps that skipped the screening."""
        return {
            "acceptance_rate": float(self.accepted.sum() / max(self.proposed.sum(), 1)),
            "acceptance_by_move": {getattr(move, "name", type(move).__name__): float(a / max(p, 1))
                                   for move, a, p in zip(self.moves, self.accepted, self.proposed)},
            "global_evaluations": int(self.global_evaluations),
            "screened_out": int(self.screened_out),
            "unscreened_steps": int(self.unscreened),
        }


def weighted_moves(moves) -> tuple[list, np.ndarray]:
    """The moves of a list of moves or (move, weight) pairs (weight 1 where none is given) and their weights;
    ``ValueError`` for an object without ``propose``, a weight that is not a finite positive number, or no move."""
    move_list, weights = [], []
    for item in moves:
        move, weight = item if isinstance(item, tuple) else (item, 1.0)
        if not hasattr(move, "propose"):
            raise ValueError(f"moves: {move!r} is not a move, it has no propose(rng, state, posterior)")
        if not (isinstance(weight, (int, float)) and math.isfinite(weight) and weight > 0):
            raise ValueError(f"moves: move weights must be positive, got {weight!r}")
        move_list.append(move)
        weights.append(float(weight))
    if not move_list:
        raise ValueError("moves must hold at least one move")
    return move_list, np.array(weights)
