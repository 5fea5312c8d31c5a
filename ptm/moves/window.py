"""Joint reallocation of a window of consecutive detections: block sampling (Doucet, Briers & Senecal 2006;
beyond the paper, docs/model.md §3.4, "Data-driven moves").

A window of detections leaves its sets and is allocated again one by one, in order, each to a set so far or a
new one in proportion to the cheap terms; the reverse probability replays the allocation of T, which leaves the
same sets behind. It realigns a retraced corridor that a run of single moves cannot (each step alone is worse).
:class:`TrailingReallocation` is the window of the last detections, for the online mapper.

    >>> import numpy as np
    >>> from ptm import Dataset, PoissonPrior, Posterior
    >>> from ptm.moves import initial_state, proposed_partition
    >>> posterior = Posterior(Dataset(labels=[0, 1, 0, 1]), PoissonPrior(2.0))
    >>> state = initial_state(posterior, [0, 1, 0, 1])
    >>> proposal = TrailingReallocation(window=2).propose(np.random.default_rng(0), state, posterior)
    >>> proposed_partition(state, proposal).labels[:2]                  # detections 0 and 1 stay apart
    (0, 1)
"""

from __future__ import annotations

import numpy as np

from .._cache import BoundedCache
from .._validation import count
from ._common import draw, uniform_index, with_member
from .state import ChainState, Proposal

__all__ = ["WindowReallocation", "TrailingReallocation", "OPTIONS_KEPT", "allocate_in_order"]

#: Steps of the block reallocation whose options a :class:`WindowReallocation` remembers (a few kB each).
OPTIONS_KEPT = 10_000


class WindowReallocation:
    """Allocate a window of ``window`` consecutive detections again, jointly (block sampling).

    The window W = [s, s + window) has its start s drawn uniformly from the
    N - window + 1 possible ones, whatever the partition, so the sets the
    other detections form, T0 (T without W), are the same before and after the
    move, and each start is a move in detailed balance on its own. The members
    of W join, in index order, one of the sets so far (those of T0 and the
    ones earlier members of W opened) with weight exp(s(B + i) - s(B)), or a
    new one with weight exp(s({i}) + log P_prior(N, k + 1) - log P_prior(N, k)),
    k >= 1 the number of sets so far (with none, a new set is the only
    option). log q(T -> T') is the sum of the chosen options' log
    probabilities; log q(T' -> T) replays T's own allocation from the same T0.
    Proposing T again is ``None``.

    A stretch of corridor driven twice, or out and back (a U-turn: i + k
    revisits j - k), closes only when all of its detections join their
    places together; each single join can be worse than none, because the
    first one bends the map against the others. Appearance allocates the
    window's members one by one, and the odometry then judges the joint move.
    """

    name = "window_reallocation"

    def __init__(self, window: int = 8):
        self.window = count("window", window, minimum=1)
        self._options = BoundedCache(OPTIONS_KEPT)

    def propose(self, rng, state: ChainState, posterior) -> Proposal | None:
        n = posterior.n
        if n == 1:
            return None
        window = self._window(rng, n)
        labels = state.partition.labels
        kept = [tuple(member for member in block if member not in window) for block in state.blocks]
        left_behind = tuple(block for block in kept if block)
        old = (state.blocks, {detection: labels[detection] for detection in window})
        forward, log_q_forward = allocate_in_order(rng, posterior, left_behind, window, self._options,
                                                   steer=self._steer(left_behind, window))
        before = set(state.blocks)
        added = tuple(sorted(block for block in forward if block not in before))
        if not added:
            return None
        _, log_q_reverse = allocate_in_order(rng, posterior, left_behind, window, self._options, old,
                                             self._steer(left_behind, window))
        after = set(forward)
        removed = tuple(index for index, block in enumerate(state.blocks) if block not in after)
        return Proposal(removed, added, log_q_reverse - log_q_forward)

    def _steer(self, left_behind, window):
        """A fresh steering of one allocation (see :func:`allocate_in_order`), a function of the sets left
        behind and the window only, which T and T' share; None: the cheap terms alone."""
        return None

    def _window(self, rng, n: int) -> range:
        """The detections allocated again: ``window`` consecutive ones from a uniform start."""
        size = min(self.window, n)
        start = uniform_index(rng, n - size + 1)
        return range(start, start + size)


class TrailingReallocation(WindowReallocation):
    """:class:`WindowReallocation` of the last ``window`` detections (for :class:`ptm.OnlineMapper`, where
    the newest detections are the ones still undecided). The window is fixed by N alone."""

    name = "trailing_reallocation"

    def _window(self, rng, n: int) -> range:
        return range(max(0, n - self.window), n)


def allocate_in_order(rng, posterior, left_behind, detections, options: BoundedCache, old=None, steer=None):
    """The sets after ``detections`` join ``left_behind`` one by one (:class:`WindowReallocation`), and the
    log probability of that allocation; with ``old`` = (the blocks of T, each detection's block index in T),
    replay T's allocation instead of drawing one. ``options`` memoises each step's options by posterior, sets
    so far and detection: copies of one particle, and a chain that proposes from the same state again, meet
    the same steps. ``steer``, if given, adds ``steer.weights(detection, sets)`` to the options of joining
    ``sets``, and hears of each join made (``steer.joined(detection, set_index)``;
    :meth:`WindowReallocation._steer`)."""
    score = posterior.block_score
    sets = list(left_behind)
    set_scores = [score(block) for block in sets]  # kept in step with sets: each set is scored once per change
    home_of = {member: position for position, block in enumerate(sets) for member in block}
    log_q = 0.0
    for detection in detections:
        key = (posterior, detection, tuple(sets))
        step = options.get(key)
        if step is None:
            step = _allocation_options(posterior, sets, set_scores, detection)
            options.put(key, step)
        grown, log_weights, log_norm = step
        if steer is not None and sets:
            log_weights = log_weights.copy()
            log_weights[:-1] += steer.weights(detection, sets)
            log_norm = float(np.logaddexp.reduce(log_weights))
        if old is None:
            pick = draw(rng, log_weights)
        else:
            blocks, home = old
            placed = [member for member in blocks[home[detection]] if member in home_of]
            pick = home_of[placed[0]] if placed else len(sets)
        log_q += float(log_weights[pick]) - log_norm
        if steer is not None and pick < len(sets):
            steer.joined(detection, pick)
        if pick == len(sets):
            sets.append((detection,))
            set_scores.append(grown[pick])
        else:
            sets[pick] = with_member(sets[pick], detection)
            set_scores[pick] = grown[pick]
        home_of[detection] = pick
    return tuple(sorted(sets)), log_q


def _allocation_options(posterior, sets, set_scores, detection):
    """One step of :func:`allocate_in_order`: the scores of each set with ``detection`` and of it alone
    (last), the options' log weights and their log normaliser."""
    score, log_prior = posterior.block_score, posterior.log_prior_by_size
    grown = [score(with_member(block, detection)) for block in sets]
    weights = [with_detection - without for with_detection, without in zip(grown, set_scores)]
    opening = log_prior[len(sets) + 1] - log_prior[len(sets)] if sets else 0.0  # the first set: no choice
    alone = score((detection,))
    grown.append(alone)
    weights.append(alone + opening)
    log_weights = np.asarray(weights)
    return grown, log_weights, float(np.logaddexp.reduce(log_weights))
