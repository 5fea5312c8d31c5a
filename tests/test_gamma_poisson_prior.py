"""The occupancy prior with a Gamma-distributed rate (docs/model.md §3.1, "Uncertain rate").

Its series against the integral over the rate that defines it, its normalisation, its limit, the rate's
posterior, and the posterior it gives against sampling (with a negative control: the plug-in rate's chains)."""

import math

import numpy as np
import pytest
from scipy import integrate, stats

import ptm
from helpers import appearance_posterior
from ptm.partitions import stirling2
from test_sampler import FIXED, TOLERANCE, visit_frequencies  # noqa: F401 (an autouse fixture)


def integrated(n, m, rate, shape, moment=0):
    """log of the integral over lambda ~ Gamma(shape, mean rate) of lambda^moment P(T | lambda), by quadrature."""
    gamma = stats.gamma(shape, scale=rate / shape)
    reference = ptm.PoissonPrior(rate).log_prob(n, m)

    def integrand(lam):
        return lam**moment * math.exp(ptm.PoissonPrior(lam).log_prob(n, m) - reference) * gamma.pdf(lam)

    value, _ = integrate.quad(integrand, 0.0, math.inf, epsabs=0.0, epsrel=1e-11, limit=400)
    return reference + math.log(value)


@pytest.mark.parametrize("n, m, rate, shape", [(9, 5, 6.0, 2.0), (9, 1, 6.0, 0.5), (9, 9, 3.0, 1.0),
                                               (1, 1, 2.0, 2.0), (30, 12, 20.0, 4.0)])
def test_the_series_is_the_integral_over_the_rate(n, m, rate, shape):
    assert ptm.GammaPoissonPrior(rate, shape).log_prob(n, m) == pytest.approx(integrated(n, m, rate, shape),
                                                                              abs=1e-9)


@pytest.mark.parametrize("rate, shape, n", [(6.0, 2.0, 9), (0.3, 0.5, 7), (40.0, 1.0, 10)])
def test_it_sums_over_all_partitions_to_the_chance_of_at_least_one_landmark(rate, shape, n):
    prior = ptm.GammaPoissonPrior(rate, shape)
    total = sum(stirling2(n, m) * math.exp(prior.log_prob(n, m)) for m in range(1, n + 1))
    no_landmark = (shape / (shape + rate)) ** shape  # the negative binomial at L = 0
    assert total == pytest.approx(1.0 - no_landmark, rel=1e-10)


def test_a_well_known_rate_gives_the_plug_in_prior():
    sharp, plug_in = ptm.GammaPoissonPrior(6.0, 1e5), ptm.PoissonPrior(6.0)
    assert np.allclose(sharp.table(9)[1:], plug_in.table(9)[1:], atol=2e-4)
    assert not np.allclose(ptm.GammaPoissonPrior(6.0, 2.0).table(9)[1:], plug_in.table(9)[1:], atol=0.1)


def test_the_rate_posterior_of_a_place_count_is_its_conditional_mean_and_sd():
    prior, n, m = ptm.GammaPoissonPrior(6.0, 2.0), 9, 7
    mean, sd = prior.rate_posterior(n, m)
    log_evidence = integrated(n, m, 6.0, 2.0)
    expected_mean = math.exp(integrated(n, m, 6.0, 2.0, moment=1) - log_evidence)
    expected_second = math.exp(integrated(n, m, 6.0, 2.0, moment=2) - log_evidence)
    assert mean == pytest.approx(expected_mean, rel=1e-8)
    assert sd == pytest.approx(math.sqrt(expected_second - expected_mean**2), rel=1e-7)


def test_more_places_raise_the_rate_posterior_and_a_ptm_mixes_them():
    prior = ptm.GammaPoissonPrior(6.0, 2.0)
    few, many = prior.rate_posterior(8, 2), prior.rate_posterior(8, 8)
    assert few[0] < 6.0 < many[0]
    result = ptm.PTM(partitions=[(0, 0, 0, 0, 1, 1, 1, 1), tuple(range(8))], probabilities=[0.25, 0.75], method="exact")
    mean, sd = prior.rate_posterior_of(result)
    assert mean == pytest.approx(0.25 * few[0] + 0.75 * many[0])
    assert sd > max(few[1], many[1])  # the spread of the mixture adds to each component's


def test_the_expected_places_and_the_rate_that_gives_them():
    prior = ptm.GammaPoissonPrior.with_expected_places(12, 7.0, shape=2.0)
    assert prior.expected_places(12) == pytest.approx(7.0, abs=1e-9)
    by_sum = sum(m * stirling2(12, m) * math.exp(prior.log_prob(12, m)) for m in range(1, 13))
    by_sum /= sum(stirling2(12, m) * math.exp(prior.log_prob(12, m)) for m in range(1, 13))
    assert prior.expected_places(12) == pytest.approx(by_sum, rel=1e-9)


@pytest.mark.parametrize("rate, shape", [(0.0, 1.0), (1.0, -1.0), (math.nan, 1.0), (1.0, math.inf), (1e6, 1.0),
                                         (10.0, 1e-5)])
def test_bad_rates_and_shapes_are_refused(rate, shape):
    with pytest.raises(ValueError, match="rate|shape"):
        ptm.GammaPoissonPrior(rate, shape)


def test_out_of_reach_expected_places_are_refused():
    with pytest.raises(ValueError, match="expected places"):
        ptm.GammaPoissonPrior.with_expected_places(9, 9.5, shape=2.0)


def test_sampling_finds_the_marginal_posterior_and_the_plug_in_rate_does_not():
    """Appearance, N = 8: the exact posterior under the uncertain rate (mean 8, shape 1) against 2 chains of
    30 000 steps. Measured TV, seeds 3-6: 0.039 0.037 0.044 0.028 (at 15 000 steps 0.067 0.052 0.039); the plug-in
    rate's chains 0.366 0.345 0.342 0.355 from it."""
    base = appearance_posterior(8)
    marginal = ptm.Posterior(base.dataset, ptm.GammaPoissonPrior(8.0, 1.0), base.terms)
    plug_in = ptm.Posterior(base.dataset, ptm.PoissonPrior(8.0), base.terms)
    exact = ptm.exact_posterior(marginal)
    settings = dict(burn_in=1_000, seed=3, chains=2, **FIXED)
    assert ptm.total_variation(ptm.mcmc(marginal, 30_000, **settings), exact) < TOLERANCE
    assert ptm.total_variation(ptm.mcmc(plug_in, 30_000, **settings), exact) > 3 * TOLERANCE


@pytest.mark.parametrize("rate, shape, n", [(6.0, 2.0, 9), (95.0, 2.0, 122), (3.0, 0.5, 40), (2.0, 1.0, 1)])
def test_the_table_of_every_m_matches_log_prob_one_m_at_a_time(rate, shape, n):
    prior = ptm.GammaPoissonPrior(rate, shape)
    table = prior.table(n)
    assert table[0] == -math.inf and len(table) == n + 1
    assert np.allclose(table[1:], [prior.log_prob(n, m) for m in range(1, n + 1)], rtol=0.0, atol=1e-10)
