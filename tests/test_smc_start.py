"""Chains started from their own SMC pass (``start="smc"``, the default; :func:`ptm.online.smc_draw`;
docs/model.md §3.4, "Starts"), and the other starts (:mod:`ptm.starts`).

The start changes where a chain begins, not what it targets: the histogram of chains started this way
must match the exact posterior within the sampler tests' bound, while chains kept at their starts (a
move that never proposes) must not -- a sampler that only repeated its SMC draws would not pass.
"""

import numpy as np
import pytest

import ptm
import ptm.online
from helpers import appearance_posterior
from ptm.starts import SMC_START_PARTICLES, chain_start
from test_sampler import TOLERANCE, visit_frequencies  # noqa: F401 (an autouse fixture)


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
    result = ptm.mcmc(posterior, 15_000, burn_in=1_000, seed=7, chains=2, max_doublings=0)
    assert ptm.SamplerOptions().start == "smc" and SMC_START_PARTICLES == 16  # the default start
    assert ptm.total_variation(result, exact) < TOLERANCE


def test_negative_control_chains_kept_at_their_smc_starts_miss_the_posterior(target):
    posterior, exact = target
    result = ptm.mcmc(posterior, 2_000, seed=7, chains=2, moves=[(StandStill(), 1.0)], max_doublings=0)
    assert len(result) <= 2
    assert ptm.total_variation(result, exact) > 3 * TOLERANCE


def test_the_start_is_a_partition_of_the_run_and_its_seed_decides_it():
    signatures = np.array([[0.30, 0.10], [0.40, 0.05], [0.31, 0.11], [0.41, 0.04], [0.30, 0.10]])   # A B A B A
    posterior = ptm.Posterior(ptm.Dataset(signatures=signatures), ptm.PoissonPrior(2.0),
                              [ptm.AppearanceModel(0.3, 0.05, 3.0, 2e-4)])
    start = ptm.online.smc_draw(posterior, 8, np.random.default_rng(0))
    assert start == (0, 1, 0, 1, 0)
    spread = appearance_posterior(8)
    draws = [ptm.online.smc_draw(spread, 8, np.random.default_rng(seed)) for seed in (0, 0, 1, 2, 3)]
    assert draws[0] == draws[1] and all(len(draw) == 8 for draw in draws)
    assert len(set(draws)) > 1  # a spread posterior: other streams, other starts


def test_the_tempered_sampler_starts_its_replicas_the_same_way(target):
    posterior, exact = target
    result = ptm.tempered_mcmc(posterior, 2_000, temperatures=(1.0, 0.5), seed=7, chains=1,
                               moves=[(StandStill(), 1.0)])
    assert len(result) <= 2  # the beta = 1 replica holds one of the two replicas' SMC draws (swaps exchange them)
    assert all(exact.probability(labels) > 0 for labels, _ in result.top(2))


def test_dispersed_starts_are_the_extremes_and_random_labels():
    posterior = appearance_posterior(6)
    starts = [chain_start(posterior, "dispersed", chain, np.random.default_rng(0)) for chain in range(4)]
    assert starts[0] == tuple(range(6)) and starts[1] == (0,) * 6 and starts[3] == starts[0]
    assert all(0 <= label < 3 for label in starts[2])


def test_a_label_sequence_starts_every_chain_there():
    posterior = appearance_posterior(6)
    result = ptm.mcmc(posterior, 50, seed=0, chains=2, start=[5, 5, 7, 5, 7, 9], moves=[StandStill()])
    assert result.top(2) == [((0, 0, 1, 0, 1, 2), 1.0)]


@pytest.mark.parametrize("start, message", [
    ("warm_up", "start must be one of smc, dispersed, a PTM or a label sequence"),
    (None, "start must be one of"),
    ([0, 1, 0.5, 0, 1, 2, 0, 1], "start must be one of"),
    ([0] * 7, "start has 7 labels, the posterior has N=8"),
])
def test_bad_starts_are_refused_by_name(target, start, message):
    posterior, _ = target
    with pytest.raises(ValueError, match=message):
        ptm.mcmc(posterior, 10, seed=0, start=start)


def test_a_start_from_a_ptm_over_more_detections_is_refused(target):
    posterior, _ = target
    longer = ptm.PTM([[0] * 9], [1.0], "exact")
    with pytest.raises(ValueError, match="start is a PTM over 9 detections, more than the posterior's 8"):
        ptm.mcmc(posterior, 10, seed=0, start=longer)


def test_a_run_with_neither_signatures_nor_odometry_is_refused_an_smc_start():
    posterior = ptm.Posterior(ptm.Dataset(labels=[0, 1, 0]), ptm.PoissonPrior(2.0))
    with pytest.raises(ValueError, match="needs the detections' signatures or odometry.*start=\"dispersed\""):
        ptm.mcmc(posterior, 10, seed=0)
    assert ptm.mcmc(posterior, 10, seed=0, start="dispersed").n == 3
