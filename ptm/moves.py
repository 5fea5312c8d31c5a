"""Proposal moves over partitions (paper eq. 10, Algorithms 1-2; docs/model.md §3.4) and the chain state.

A move is any object with ``propose(rng, state, posterior) -> Proposal | None``
(``None`` means "propose the current partition again"). A proposal names the
sets it removes and the sets it adds, plus log q(T'->T) - log q(T->T'), so the
sampler re-scores only what changed.

* :class:`SplitMerge` — the paper's move. Merge (prob. 1/2): a pair of sets
  uniformly among C(M, 2); the reverse split has probability
  1/2 * 1/N_S(T') * 1/S(n, 2). Split (prob. 1/2): a non-singleton set
  uniformly among N_S(T), then one of its S(n, 2) = 2^(n-1) - 1 two-way splits
  uniformly; the reverse merge has probability 1/2 * 1/C(M+1, 2).
* :class:`GibbsReassign` — one detection moved to a set (or a new one) drawn
  from its conditional under the cheap terms (prior + decomposable models).
* :class:`MapReassign` — the same, the conditional raised by the odometry
  surrogate's prediction under the current map (:mod:`ptm.surrogate`); its
  reverse probability is computed from the map of T'.
* :class:`SequentialSplitMerge` — the sequentially-allocated merge-split of
  Dahl (2003): two anchors; if they share a set, split it by allocating the
  other members one by one in proportion to the cheap terms; else merge.
* :class:`GuidedSplitMerge` — the same with data-driven anchors: a merge
  partner drawn in proportion to the pair's Bayes factor exp(a_ij), a split
  anchor in proportion to exp(-a_ij) among its set; the Hastings ratio
  includes both anchor probabilities.
* :class:`WindowReallocation` — block sampling (Doucet, Briers & Senecal
  2006): a window of consecutive detections, its start uniform, leaves its
  sets and is allocated again one by one, in order, each to a set or a new
  one in proportion to the cheap terms; the reverse probability replays the
  allocation of T, which leaves the same sets behind. It realigns a retraced
  corridor that a run of single moves cannot (each step alone is worse).
  :class:`TrailingReallocation` is the window of the last detections, for
  the online mapper.
* :class:`MapWindowReallocation` — the same window, each member's options
  weighed by the odometry map of the sets left behind as well, conditioned on
  the joins made so far (:class:`ptm.surrogate.ConditionedMap`): it closes a
  loop with no appearance at all, where each single closure is worse than none.

    >>> import math
    >>> from ptm import Dataset, PoissonPrior, Posterior
    >>> posterior = Posterior(Dataset(labels=[0, 0, 0, 0]), PoissonPrior(2.0))
    >>> state = initial_state(posterior, [0, 0, 0, 0])
    >>> proposal = SplitMerge().propose(np.random.default_rng(0), state, posterior)   # a split, here
    >>> proposal.added, math.isclose(proposal.log_q_ratio, math.log(7))              # S(4, 2) = 7
    (((0, 3), (1, 2)), True)
"""

from __future__ import annotations

import math
from bisect import bisect_left
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from ._cache import BoundedCache
from ._validation import count, share
from .partitions import Block, Partition, log_stirling2_two

__all__ = [
    "ChainState", "Proposal", "SplitMerge", "GibbsReassign", "MapReassign", "SequentialSplitMerge", "GuidedSplitMerge",
    "WindowReallocation", "MapWindowReallocation", "TrailingReallocation",
    "merge_log_q_ratio", "split_log_q_ratio", "initial_state", "apply_proposal",
]


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
    the sampler then evaluates the proposal exactly, without a screening first stage.
    """

    removed: tuple[int, ...]
    added: tuple[Block, ...]
    log_q_ratio: float
    reverse_log_q: Callable[[Partition], float] | None = None


def initial_state(posterior, labels) -> ChainState:
    partition = posterior.partition(labels)
    scores = tuple(posterior.block_score(block) for block in partition.blocks)
    log_cheap = posterior.log_prior_by_size[partition.m] + sum(scores)
    return ChainState(partition, scores, log_cheap, posterior.global_log_prob(partition))


def proposed_log_cheap(posterior, state: ChainState, proposal: Proposal) -> tuple[float, tuple[float, ...]]:
    """Cheap log-probability of the proposed partition, from the change alone; also the new sets' scores."""
    added_scores = tuple(posterior.block_score(block) for block in proposal.added)
    m_new = len(state.blocks) - len(proposal.removed) + len(proposal.added)
    delta = sum(added_scores) - sum(state.block_scores[i] for i in proposal.removed)
    log_cheap = state.log_cheap + delta + posterior.log_prior_by_size[m_new] - posterior.log_prior_by_size[len(state.blocks)]
    return log_cheap, added_scores


def proposed_partition(state: ChainState, proposal: Proposal) -> Partition:
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


# -- the Hastings corrections of the paper's move -------------------------------------------------

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


def _uniform_index(rng: np.random.Generator, count: int) -> int:
    """A uniform integer in [0, count) — cheaper than ``rng.integers`` for one draw."""
    return min(int(rng.random() * count), count - 1)


def _distinct_pair(rng: np.random.Generator, count: int) -> tuple[int, int]:
    """An ordered pair of distinct indices, uniform among the count * (count - 1) pairs."""
    first = _uniform_index(rng, count)
    second = _uniform_index(rng, count - 1)
    return first, second + (second >= first)


def _with_member(block: Block, member: int) -> Block:
    position = bisect_left(block, member)
    return block[:position] + (member,) + block[position:]


class SplitMerge:
    """The paper's split/merge proposal (Algorithm 2) with its exact Hastings ratio."""

    name = "split_merge"

    def propose(self, rng, state: ChainState, posterior) -> Proposal | None:
        blocks = state.blocks
        num_sets = len(blocks)
        if rng.random() < 0.5:
            if num_sets == 1:
                return None
            first, second = _distinct_pair(rng, num_sets)
            merged = tuple(sorted(blocks[first] + blocks[second]))
            nonsingleton_after = sum(1 for block in blocks if len(block) > 1) + 1
            nonsingleton_after -= (len(blocks[first]) > 1) + (len(blocks[second]) > 1)
            return Proposal((first, second), (merged,),
                            merge_log_q_ratio(num_sets, nonsingleton_after, len(merged)))
        splittable = [index for index, block in enumerate(blocks) if len(block) > 1]
        if not splittable:
            return None
        chosen = splittable[_uniform_index(rng, len(splittable))]
        members = blocks[chosen]
        while True:  # fair coins for all but the first member; redraw if part B is empty
            to_b = rng.random(len(members) - 1) < 0.5
            if to_b.any():
                break
        part_a = (members[0],) + tuple(member for member, flag in zip(members[1:], to_b) if not flag)
        part_b = tuple(member for member, flag in zip(members[1:], to_b) if flag)
        return Proposal((chosen,), (part_a, part_b),
                        split_log_q_ratio(num_sets, len(splittable), len(members)))


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
        detection = _uniform_index(rng, n)
        home, rest, targets, weights = _destinations(posterior, state.partition, state.block_scores, detection)
        pick = _draw(rng, weights)
        target = targets[pick]
        current = home if rest else -1
        if target == current:
            return None
        removed, added = _reassigned(state.blocks, home, rest, detection, target)
        return Proposal(removed, added, weights[targets.index(current)] - weights[pick])


class MapReassign:
    """Move one detection to a set drawn from a prediction of its full conditional, odometry included.

    As :class:`GibbsReassign`, with each candidate's weight raised by the
    surrogate's prediction of the change of the global terms under the current
    map (``surrogate.screening_change``, :mod:`ptm.surrogate`): the detection
    goes preferably where the current map puts it. The reverse move's
    probability needs the map of T' (``Proposal.reverse_log_q``), so the
    sampler evaluates such a proposal exactly instead of screening it; the
    weights then make it likely to be accepted.
    """

    name = "map_reassign"

    def __init__(self, surrogate):
        self.surrogate = surrogate

    def propose(self, rng, state: ChainState, posterior) -> Proposal | None:
        n = posterior.n
        if n == 1:
            return None
        detection = _uniform_index(rng, n)
        home, rest, targets, weights = self._weights(posterior, state.partition, state.block_scores, detection)
        pick = _draw(rng, weights)
        target = targets[pick]
        if target == (home if rest else -1):
            return None
        removed, added = _reassigned(state.blocks, home, rest, detection, target)
        forward = weights[pick] - float(np.logaddexp.reduce(weights))

        def reverse_log_q(after: Partition) -> float:
            """log q(T' -> T): ``detection`` drawn again and sent back to ``rest`` (or alone), under T's map."""
            scores = [posterior.block_score(block) for block in after.blocks]
            _, _, targets_after, weights_after = self._weights(posterior, after, scores, detection)
            back = after.blocks.index(rest) if rest else -1
            return weights_after[targets_after.index(back)] - float(np.logaddexp.reduce(weights_after))

        return Proposal(removed, added, -forward, reverse_log_q)

    def _weights(self, posterior, partition: Partition, block_scores, detection: int):
        """:func:`_destinations` with each weight raised by the surrogate's screening change of the global terms."""
        blocks = partition.blocks
        home, rest, targets, weights = _destinations(posterior, partition, block_scores, detection)
        current = home if rest else -1
        for position, target in enumerate(targets):
            if target != current:
                removed, added = _reassigned(blocks, home, rest, detection, target)
                weights[position] += self.surrogate.screening_change(partition, [blocks[k] for k in removed], added)
        return home, rest, targets, weights


def _destinations(posterior, partition: Partition, block_scores, detection: int):
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
        weights.append(score(_with_member(block, detection)) - block_scores[index] + log_prior[sets_without])
    targets.append(-1)
    weights.append(score((detection,)) + log_prior[sets_without + 1])
    return home, rest, targets, weights


def _reassigned(blocks, home: int, rest: Block, detection: int, target: int):
    """The sets removed (indices) and added when ``detection`` leaves set ``home`` for ``target`` (-1: alone)."""
    if target == -1:
        return (home,), (rest, (detection,))
    joined = _with_member(blocks[target], detection)
    if rest:
        return (home, target), (rest, joined)
    return (home, target), (joined,)


def _draw(rng, log_weights) -> int:
    """An index drawn with probability proportional to exp(log_weights)."""
    log_weights = np.asarray(log_weights)
    cumulative = np.cumsum(np.exp(log_weights - log_weights.max()))
    pick = int(np.searchsorted(cumulative, rng.random() * cumulative[-1], side="right"))
    return min(pick, len(log_weights) - 1)


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
        first, second = _distinct_pair(rng, n)
        return _split_or_merge(rng, state, posterior.block_score, first, second)


class GuidedSplitMerge:
    """Sequentially-allocated split-merge whose anchors are drawn from the data: the pairs' Bayes factors.

    The pair affinity a_ij = s({i, j}) - s({i}) - s({j}) is the cheap terms'
    log Bayes factor of i and j being one place (appearance, paper eq. 15-19),
    a fixed matrix. The first anchor i is uniform. With probability 1/2 the
    move seeks a merge: the second anchor j is drawn among the detections
    outside i's set with probability p_T(j | i) proportional to exp(a_ij);
    otherwise it seeks a split: j is drawn among the other members of i's set
    in proportion to exp(-a_ij), the least alike first. Each draw mixes in
    ``exploration`` of a uniform one over the same candidates. Then, as in
    :class:`SequentialSplitMerge`, the anchors' sets are merged or their set is
    split with the other members allocated by the cheap scores. The reverse
    move draws the same ordered pair from the other side (a merge's reverse
    seeks a split, and vice versa), so for each pair the Hastings term is

        log p_T'(j | i) - log p_T(j | i)  +/-  log q_allocation.

    Which of these proposals the odometry allows is left to the surrogate's
    first stage of delayed acceptance.
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
        first = _uniform_index(rng, n)
        labels = np.asarray(state.partition.labels)
        seeks_merge = rng.random() < 0.5
        candidates = self._candidates(labels, first, seeks_merge)
        if not candidates.any():
            return None
        indices = np.flatnonzero(candidates)
        probabilities = self._anchor_probabilities(first, candidates, seeks_merge)[indices]
        pick = _draw(rng, np.log(probabilities))
        second = int(indices[pick])
        proposal = _split_or_merge(rng, state, posterior.block_score, first, second)
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
        forward, log_q_forward = _allocate_in_order(rng, posterior, left_behind, window, self._options,
                                                    steer=self._steer(left_behind, window))
        before = set(state.blocks)
        added = tuple(sorted(block for block in forward if block not in before))
        if not added:
            return None
        _, log_q_reverse = _allocate_in_order(rng, posterior, left_behind, window, self._options, old,
                                              self._steer(left_behind, window))
        after = set(forward)
        removed = tuple(index for index, block in enumerate(state.blocks) if block not in after)
        return Proposal(removed, added, log_q_reverse - log_q_forward)

    def _steer(self, left_behind, window):
        """A fresh steering of one allocation (see :func:`_allocate_in_order`), a function of the sets left
        behind and the window only, which T and T' share; None: the cheap terms alone."""
        return None

    def _window(self, rng, n: int) -> range:
        """The detections allocated again: ``window`` consecutive ones from a uniform start."""
        size = min(self.window, n)
        start = _uniform_index(rng, n - size + 1)
        return range(start, start + size)


class TrailingReallocation(WindowReallocation):
    """:class:`WindowReallocation` of the last ``window`` detections (for :class:`ptm.OnlineMapper`, where
    the newest detections are the ones still undecided). The window is fixed by N alone."""

    name = "trailing_reallocation"

    def _window(self, rng, n: int) -> range:
        return range(max(0, n - self.window), n)


class MapWindowReallocation(WindowReallocation):
    """:class:`WindowReallocation` steered by the map of the sets left behind.

    The map is that of T0 + the window's detections each alone (the window dead-reckoned from the detection
    before it), the same from T and from T', so the Hastings ratio stays a replay of T's allocation. Each
    member's option of joining a set is raised by ``trust`` times its estimated change of the odometry terms
    under that map, conditioned on the joins made so far in the window (:class:`ptm.surrogate.ConditionedMap`:
    the tie's Occam factor and misfit, and the landmark-density penalty it gives back); a new set by
    nothing. q then follows the window's conditional given the rest, and a retraced corridor closes in one
    move with no appearance at all, where each single closure is worse than none (the first one bends the
    map against the others, and leaves their neighbours side by side, apart).
    """

    name = "map_window_reallocation"

    def __init__(self, surrogate, window: int = 8, trust: float = 1.0):
        super().__init__(window)
        self.surrogate, self.trust = surrogate, share("trust", trust)

    def _steer(self, left_behind, window):
        open_window = Partition(tuple(sorted(left_behind + tuple((detection,) for detection in window))))
        return _MapSteering(self.surrogate.conditioned_map(open_window), self.trust)


class _MapSteering:
    """The steering of one :class:`MapWindowReallocation` allocation: weights from a conditioned map, which
    each join then conditions."""

    def __init__(self, conditioned, trust: float):
        self.conditioned, self.trust = conditioned, trust

    def weights(self, detection: int, sets) -> np.ndarray:
        return self.trust * self.conditioned.join_changes(detection, sets)

    def joined(self, detection: int, set_index: int) -> None:
        self.conditioned.tie(detection, set_index)


def _allocate_in_order(rng, posterior, left_behind, detections, options: BoundedCache, old=None, steer=None):
    """The sets after ``detections`` join ``left_behind`` one by one (:class:`WindowReallocation`), and the
    log probability of that allocation; with ``old`` = (the blocks of T, each detection's block index in T),
    replay T's allocation instead of drawing one. ``options`` memoises each step's options by posterior, sets
    so far and detection: copies of one particle, and a chain that proposes from the same state again, meet
    the same steps. ``steer``, if given, adds ``steer.weights(detection, sets)`` to the options of joining
    ``sets``, and hears of each join made (``steer.joined(detection, set_index)``; :meth:`WindowReallocation._steer`)."""
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
            pick = _draw(rng, log_weights)
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
            sets[pick] = _with_member(sets[pick], detection)
            set_scores[pick] = grown[pick]
        home_of[detection] = pick
    return tuple(sorted(sets)), log_q


def _allocation_options(posterior, sets, set_scores, detection):
    """One step of :func:`_allocate_in_order`: the scores of each set with ``detection`` and of it alone
    (last), the options' log weights and their log normaliser."""
    score, log_prior = posterior.block_score, posterior.log_prior_by_size
    grown = [score(_with_member(block, detection)) for block in sets]
    weights = [with_detection - without for with_detection, without in zip(grown, set_scores)]
    opening = log_prior[len(sets) + 1] - log_prior[len(sets)] if sets else 0.0  # the first set: no choice
    alone = score((detection,))
    grown.append(alone)
    weights.append(alone + opening)
    log_weights = np.asarray(weights)
    return grown, log_weights, float(np.logaddexp.reduce(log_weights))


def _split_or_merge(rng, state: ChainState, score, first: int, second: int) -> Proposal:
    """Split the anchors' set, the other members allocated by ``score``, if they share one; else merge their
    sets. The Hastings term is the allocation's only (the anchors' own probabilities are the caller's)."""
    labels = state.partition.labels
    blocks = state.blocks
    if labels[first] == labels[second]:
        home = labels[first]
        others = [member for member in blocks[home] if member not in (first, second)]
        part_first, part_second, log_q = _allocate(rng, score, first, second, others)
        return Proposal((home,), (part_first, part_second), -log_q)
    block_first, block_second = blocks[labels[first]], blocks[labels[second]]
    others = [member for member in block_first + block_second if member not in (first, second)]
    _, _, log_q = _allocate(rng, score, first, second, others, forced=set(block_first))
    merged = tuple(sorted(block_first + block_second))
    return Proposal((labels[first], labels[second]), (merged,), log_q)


def _allocate(rng, score, first, second, others, forced=None):
    """Allocate ``others`` to the parts of anchors ``first`` and ``second`` in random order, each member
    joining a part in proportion to exp(score(part + member) - score(part)); return the parts and log q.

    With ``forced`` (the members of the first anchor's actual set), replay
    that allocation and return the probability the procedure gives it.
    """
    part_first, part_second = (first,), (second,)
    log_q = 0.0
    for position in rng.permutation(len(others)):
        member = others[position]
        grown_first = _with_member(part_first, member)
        grown_second = _with_member(part_second, member)
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
