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
