"""Partition canonicalisation and the counting numbers behind the proposal."""

import math

import numpy as np
import pytest

from ptm.partitions import Partition, bell, canonical, log_stirling2_two, stirling2

# OEIS A000110 and A008277 (rows of S(n, k)).
BELL = [1, 1, 2, 5, 15, 52, 203, 877, 4140, 21147, 115975, 678570, 4213597]
STIRLING_ROW_6 = [0, 1, 31, 90, 65, 15, 1]


def test_bell_numbers_match_known_values():
    assert [bell(n) for n in range(13)] == BELL


def test_stirling_second_kind_matches_known_values():
    assert [stirling2(6, k) for k in range(7)] == STIRLING_ROW_6
    assert sum(stirling2(9, k) for k in range(10)) == bell(9)


def test_stirling_second_kind_refuses_negative_arguments():
    with pytest.raises(ValueError, match="n, k >= 0"):
        stirling2(-1, 2)


def test_log_stirling_two_closed_form_agrees_with_scipy_exact():
    # the closed form log(2^(n-1) - 1) against the log of scipy's exact integer S(n, 2): measured 2.9e-14 at most
    closed = np.array([log_stirling2_two(n) for n in range(2, 301)])
    exact = np.array([math.log(stirling2(n, 2)) for n in range(2, 301)])
    np.testing.assert_allclose(closed, exact, rtol=1e-15, atol=1e-13)
    assert math.isfinite(log_stirling2_two(5000))  # where scipy's float S(n, 2) has overflowed


def test_canonical_form_is_the_restricted_growth_string():
    assert canonical((5, 2, 5, 7)) == (0, 1, 0, 2)
    assert canonical(np.array([5, 2, 5, 7], dtype=np.uint8)) == (0, 1, 0, 2)
    random_labels = np.random.default_rng(0).integers(-20, 20, size=200)
    assert canonical(random_labels) == canonical(random_labels.tolist())  # the array fast path
    assert canonical([3.0, 3.0, 1.0]) == (0, 0, 1)
    with pytest.raises(ValueError, match="integers"):
        canonical([0, 1.5])
    with pytest.raises(ValueError, match="integers"):
        canonical(["a", "b"])


def test_partition_views_agree():
    partition = Partition.from_labels([2, 2, 0, 1, 0])
    assert partition.labels == (0, 0, 1, 2, 1)
    assert partition.blocks == ((0, 1), (2, 4), (3,))
    assert (partition.n, partition.m) == (5, 3)
    assert Partition.from_blocks([(4, 2), (3,), (1, 0)]) == partition
    assert hash(Partition.from_blocks([(3,), (0, 1), (2, 4)])) == hash(partition)


def test_partition_rejects_bad_blocks():
    with pytest.raises(ValueError, match="disjoint"):
        Partition.from_blocks([(0, 1), (1, 2)])
    with pytest.raises(ValueError, match="at least one"):
        Partition.from_labels([])
