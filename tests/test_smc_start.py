"""Chains started from their own SMC pass (``ptm.mcmc(smc_start=P)``, :func:`ptm.online.smc_start`;
docs/model.md §3.4, "Starts").

The start changes where a chain begins, not what it targets: the histogram of chains started this way
must match the exact posterior within the sampler tests' bound, while chains kept at their starts (a
move that never proposes) must not -- a sampler that only repeated its SMC draws would not pass.
"""

import numpy as np
import pytest

import ptm
import ptm.online
from helpers import appearance_posterior
from test_sampler import TOLERANCE
from ptm_bench.evaluation.cell import SMC_START_PARTICLES, _sampler_options
from ptm_bench.evaluation.experiment import DEFAULTS, parse_experiment


class StandStill:
    """A move that never proposes: the chain stays where it started."""

    name = "stand_still"

    def propose(self, rng, state, posterior):
        return None


@pytest.fixture(scope="module")
def target():
    posterior = appearance_posterior(8)
    return posterior, ptm.exact_posterior(posterior)


def test_chains_from_smc_starts_sample_the_exact_posterior(target):
    posterior, exact = target
    result = ptm.mcmc(posterior, 15_000, burn_in=1_000, seed=7, chains=2, smc_start=8)
    assert ptm.total_variation(result, exact) < TOLERANCE


def test_negative_control_chains_kept_at_their_smc_starts_miss_the_posterior(target):
    posterior, exact = target
    result = ptm.mcmc(posterior, 2_000, seed=7, chains=2, smc_start=8, moves=[(StandStill(), 1.0)])
    assert len(result) <= 2
    assert ptm.total_variation(result, exact) > 3 * TOLERANCE


def test_the_start_is_a_partition_of_the_run_and_its_seed_decides_it():
    signatures = np.array([[0.30, 0.10], [0.40, 0.05], [0.31, 0.11], [0.41, 0.04], [0.30, 0.10]])   # A B A B A
    posterior = ptm.Posterior(ptm.Dataset(signatures=signatures), ptm.PoissonPrior(2.0),
                              [ptm.AppearanceModel(0.3, 0.05, 3.0, 2e-4)])
    start = ptm.online.smc_start(posterior, 8, np.random.default_rng(0))
    assert start == (0, 1, 0, 1, 0)
    spread = appearance_posterior(8)
    draws = [ptm.online.smc_start(spread, 8, np.random.default_rng(seed)) for seed in (0, 0, 1, 2, 3)]
    assert draws[0] == draws[1] and all(len(draw) == 8 for draw in draws)
    assert len(set(draws)) > 1  # a spread posterior: other streams, other starts


def test_the_tempered_sampler_starts_its_replicas_the_same_way(target):
    posterior, exact = target
    result = ptm.tempered_mcmc(posterior, 2_000, temperatures=(1.0, 0.5), seed=7, smc_start=8,
                               moves=[(StandStill(), 1.0)])
    assert len(result) <= 2  # the beta = 1 replica holds one of the two replicas' SMC draws (swaps exchange them)
    assert all(exact.probability(labels) > 0 for labels, _ in result.top(2))


@pytest.mark.parametrize("options, message", [
    ({"smc_start": -1}, "smc_start must be an integer >= 0"),
    ({"smc_start": 8, "warm_up": 100}, "smc_start replaces init and warm_up"),
    ({"smc_start": 8, "init": [0] * 8}, "smc_start replaces init and warm_up"),
])
def test_bad_starts_are_refused_by_name(target, options, message):
    posterior, _ = target
    with pytest.raises(ValueError, match=message):
        ptm.mcmc(posterior, 10, seed=0, **options)


def test_a_run_with_neither_signatures_nor_odometry_is_refused():
    posterior = ptm.Posterior(ptm.Dataset(labels=[0, 1, 0]), ptm.PoissonPrior(2.0))
    with pytest.raises(ValueError, match="needs the detections' signatures or odometry"):
        ptm.mcmc(posterior, 10, seed=0, smc_start=4)


def test_the_harness_starts_every_chain_from_an_smc_pass_by_default(target):
    posterior, _ = target
    assert DEFAULTS["inference"]["warm_up"] == "smc"
    for moves in ("default", "guided", "paper"):
        options = _sampler_options(moves, {**DEFAULTS["inference"], "delayed_acceptance": False}, posterior)
        assert options["smc_start"] == SMC_START_PARTICLES and options["warm_up"] == 0
    old = _sampler_options("guided", {**DEFAULTS["inference"], "warm_up": "guided", "delayed_acceptance": False},
                           posterior)
    assert "smc_start" not in old and old["warm_up"] == ptm.sampler.WARM_UP_PER_DETECTION * posterior.n


def test_an_unknown_start_is_refused_by_the_config_parser():
    config = {"name": "bad", "sweep": {"worlds": ["short_loop"], "seeds": [0]}, "inference": {"warm_up": "sometimes"},
              "variants": [{"name": "a", "models": ["appearance"]}]}
    with pytest.raises(ValueError, match="inference.warm_up"):
        parse_experiment(config)
