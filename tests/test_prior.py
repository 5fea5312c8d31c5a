"""The Poisson occupancy prior (docs/model.md §3.1) is a proper distribution over partitions."""

import math

import numpy as np
import pytest
from scipy.special import gammaln

from ptm import PoissonPrior
from ptm.partitions import stirling2


@pytest.mark.parametrize("rate", [0.3, 2.0, 7.5, 40.0])
@pytest.mark.parametrize("n", [1, 4, 9])
def test_prior_sums_to_probability_of_at_least_one_landmark(rate, n):
    prior = PoissonPrior(rate)
    total = sum(stirling2(n, m) * math.exp(prior.log_prob(n, m)) for m in range(1, n + 1))
    assert total == pytest.approx(1.0 - math.exp(-rate), rel=1e-10)


def test_prior_matches_a_brute_force_sum_over_landmark_counts():
    rate, n, m = 3.0, 6, 2
    counts = np.arange(m, 400)
    brute = np.sum(np.exp(-rate + counts * math.log(rate) - gammaln(counts + 1)
                          + gammaln(counts + 1) - gammaln(counts - m + 1) - n * np.log(counts)))
    assert PoissonPrior(rate).log_prob(n, m) == pytest.approx(math.log(brute), rel=1e-12)


def test_prior_rejects_bad_input():
    with pytest.raises(ValueError, match="rate"):
        PoissonPrior(0.0)
    with pytest.raises(ValueError, match="rate"):
        PoissonPrior(float("nan"))
    with pytest.raises(ValueError, match="places"):
        PoissonPrior(1.0).log_prob(3, 4)


def brute_force(rate, n, m):
    """log P(T) summed term by term over every landmark count that matters (up to rate + 60 sd + 5000)."""
    counts = np.arange(m, int(rate + 60 * math.sqrt(rate) + 5000), dtype=float)
    return -rate + float(np.logaddexp.reduce(-n * np.log(counts) + counts * math.log(rate) - gammaln(counts - m + 1)))


@pytest.mark.parametrize("rate, n, m", [
    (math.exp(11), 3000, 5),  # the sum falls from L = M, then rises to a bump near L = rate: the old scan stopped early
    (1e4, 3000, 1), (1e4, 50, 3), (100.0, 3000, 1), (2.0, 200, 150), (1e5, 20, 20), (0.01, 7, 2),
])
def test_prior_is_right_where_its_terms_are_not_log_concave(rate, n, m):
    # abs: lgamma of counts near 1e5 carries ~1e-10 of rounding into the brute force (checked against mpmath at
    # 30 digits, which agrees with PoissonPrior to 2e-14)
    assert PoissonPrior(rate).log_prob(n, m) == pytest.approx(brute_force(rate, n, m), rel=1e-11, abs=1e-9)


@pytest.mark.parametrize("rate", [1e8, 1e12, 1e15])
def test_huge_rates_take_milliseconds_and_still_sum_to_one(rate):
    import time

    started = time.perf_counter()
    prior = PoissonPrior(rate)
    total = sum(stirling2(6, m) * math.exp(prior.log_prob(6, m)) for m in range(1, 7))
    assert time.perf_counter() - started < 2.0  # was 53 s and 5.7 GB at 1e8, more than 9 minutes at 1e12
    assert total == pytest.approx(1.0, rel=1e-9)
    # a Poisson count of landmarks that large puts every detection at a place of its own
    assert prior.log_prob(6, 6) == pytest.approx(0.0, abs=1e-6)


@pytest.mark.parametrize("rate, n", [(0.3, 5), (6.0, 9), (8.0, 12), (100.0, 30), (1e4, 9)])
def test_expected_places_is_the_prior_mean_of_the_number_of_sets(rate, n):
    prior = PoissonPrior(rate)
    mass = np.array([float(stirling2(n, m)) * math.exp(prior.log_prob(n, m)) for m in range(1, n + 1)])
    assert mass.sum() == pytest.approx(-math.expm1(-rate), rel=1e-10)
    assert prior.expected_places(n) == pytest.approx(float(np.arange(1, n + 1) @ mass / mass.sum()), rel=1e-10)
    assert 1.0 <= prior.expected_places(n) < min(n, rate + 1.0)


@pytest.mark.parametrize("n, places", [(9, 1.2), (9, 5.1), (12, 11.5), (150, 60.0)])
def test_the_rate_with_given_expected_places_reproduces_them(n, places):
    prior = PoissonPrior.with_expected_places(n, places)
    assert prior.expected_places(n) == pytest.approx(places, rel=1e-9)


@pytest.mark.parametrize("n, places", [(9, 1.0), (9, 9.0), (9, 0.5), (9, float("nan")), (0, 2.0), (2.5, 2.0)])
def test_expected_places_out_of_reach_are_refused(n, places):
    with pytest.raises(ValueError, match="expected places|n \\(the number of detections\\)"):
        PoissonPrior.with_expected_places(n, places)


@pytest.mark.parametrize("rate", [0.01, 3.0, 60.0, 1e3, 1e6])
@pytest.mark.parametrize("n", [1, 7, 116])
def test_the_table_of_every_m_matches_log_prob_one_m_at_a_time(rate, n):
    # the table sums all M on one grid (small rates) or falls back to log_prob (huge ones): the same numbers
    table = PoissonPrior(rate).table(n)
    reference = PoissonPrior(rate)
    assert table[0] == -math.inf and len(table) == n + 1
    np.testing.assert_allclose(table[1:], [reference.log_prob(n, m) for m in range(1, n + 1)], rtol=1e-13, atol=0)
