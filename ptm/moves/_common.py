"""Small pieces the moves share: uniform draws, a draw from log weights, a set with one member more."""

from __future__ import annotations

from bisect import bisect_left

import numpy as np

from ..partitions import Block


def uniform_index(rng: np.random.Generator, count: int) -> int:
    """A uniform integer in [0, count) — cheaper than ``rng.integers`` for one draw."""
    return min(int(rng.random() * count), count - 1)


def distinct_pair(rng: np.random.Generator, count: int) -> tuple[int, int]:
    """An ordered pair of distinct indices, uniform among the count * (count - 1) pairs."""
    first = uniform_index(rng, count)
    second = uniform_index(rng, count - 1)
    return first, second + (second >= first)


def draw(rng: np.random.Generator, log_weights) -> int:
    """An index drawn with probability proportional to exp(log_weights)."""
    log_weights = np.asarray(log_weights)
    cumulative = np.cumsum(np.exp(log_weights - log_weights.max()))
    pick = int(np.searchsorted(cumulative, rng.random() * cumulative[-1], side="right"))
    return min(pick, len(log_weights) - 1)


def with_member(block: Block, member: int) -> Block:
    """The sorted set ``block`` with ``member`` added."""
    position = bisect_left(block, member)
    return block[:position] + (member,) + block[position:]
