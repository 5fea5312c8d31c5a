"""Independent runs that disagree are run on, and reported (issue 11, item 4; docs/model.md §3.4).

Chains disagree when the split R-hat of log P or of the number of places is
above 1.05, or two chains' co-assignment matrices are more than 0.05 apart
(``ptm.diagnostics.chains_agree``); where the estimate is renormalised the
co-assignments alone decide. The samplers then double the chains'
length, up to ``max_doublings`` times, and an extended run keeps exactly the
samples of a run started at the final length. A cell's row carries a
``warning`` when its chains still disagree, with the values reached, and the
sweep (``ptm-bench run``) prints each such warning as its cell finishes and
counts them at the end.
"""

import math

import numpy as np
import pytest

import ptm
import ptm.recorder
from ptm_bench.evaluation.cell import disagreement
from ptm_bench.evaluation.experiment import parse_experiment
from ptm_bench.evaluation.sweep import run_sweep

AGREE = {"rhat_log_prob": 1.01, "rhat_num_places": 1.0, "coassignment_max_difference": 0.02}


def test_chains_that_agree_give_no_warning():
    assert disagreement(AGREE) == ""


def test_a_result_without_several_chains_gives_no_warning():
    assert disagreement({"partitions": 203, "log_normaliser": 1.5}) == ""  # the exact posterior


@pytest.mark.parametrize("name, value, shown", [
    ("rhat_log_prob", 1.52, "split R-hat of log P 1.52"),
    ("rhat_num_places", float("inf"), "of the number of places inf"),
    ("coassignment_max_difference", 0.3, "largest co-assignment difference 0.3 "),
    ("coassignment_max_difference", 0.0504, "largest co-assignment difference 0.0504 "),  # not "0.05 (<= 0.05)"
])
def test_each_disagreement_is_reported_with_every_value_reached(name, value, shown):
    message = disagreement({**AGREE, name: value})
    assert message.startswith("independent chains disagree") and shown in message
    assert "(want <= 1.05)" in message and "(<= 0.05)" in message


def test_renormalised_estimates_are_judged_by_their_co_assignments_alone():
    """The renormalised probabilities do not count visits, so R-hats of the traces (which measure whether visit
    frequencies settled) do not decide; the chains' own estimates must still agree."""
    settled = {"rhat_log_prob": 1.6, "rhat_num_places": 2.1, "coassignment_max_difference": 1e-40,
               "estimate": "renormalised"}
    assert ptm.diagnostics.chains_agree(settled) is True and disagreement(settled) == ""
    assert ptm.diagnostics.chains_agree({**settled, "estimate": "frequency"}) is False  # the negative control
    apart = {**settled, "coassignment_max_difference": 0.3}
    message = disagreement(apart)
    assert ptm.diagnostics.chains_agree(apart) is False
    assert "difference 0.3 (<= 0.05) between the chains' renormalised estimates" in message
    assert "split R-hat of log P 1.6, of the number of places 2.1: not judged" in message


def test_a_stray_chain_is_named_with_how_far_below_it_stayed():
    stranded = {"rhat_log_prob": 5.19, "rhat_num_places": 5.19, "coassignment_max_difference": 1.0,
                "estimate": "renormalised", "chains": 4, "stray_chains": 1, "stray_log_prob_gap": 90.01,
                "stray_mass_max": 8.1e-40}
    message = disagreement(stranded)
    assert ptm.diagnostics.chains_agree(stranded) is False  # the chains did not mix, and the warning says so
    assert ("1 of 4 chains stayed in topologies at least 90 nats below the best found (at most 8.1e-40 of the "
            "renormalised mass each): the renormalised estimate gives their topologies next to nothing") in message
    assert "stayed in topologies" not in disagreement({**stranded, "stray_chains": 0})


def test_a_renormalising_run_stops_where_its_estimates_agree():
    """A run whose estimate renormalises records the estimate its agreement was judged by, and is not run on
    once its chains' estimates agree."""
    clear = ptm.Posterior(ptm.Dataset(signatures=np.array([[0.30, 0.10], [0.40, 0.05], [0.31, 0.11], [0.41, 0.04]])),
                          ptm.PoissonPrior(2.0), [ptm.AppearanceModel(0.3, 0.05, 3.0, 2e-4)])
    result = ptm.mcmc(clear, 200, burn_in=0, seed=1, chains=4, max_doublings=3, start="dispersed")
    assert result.diagnostics["estimate"] == "renormalised"
    assert result.diagnostics["coassignment_max_difference"] <= 0.05 and result.diagnostics["doublings"] == 0
    assert result.diagnostics["rhat_log_prob"] > 1.05  # the R-hats would have run it on
    assert ptm.diagnostics.chains_agree({**result.diagnostics, "estimate": "frequency"}) is False


def test_the_sweep_reports_the_cells_that_warn(tmp_path, capsys):
    cells = [{"cell_id": "a", "experiment": "agreement", "warning": ""},
             {"cell_id": "b", "experiment": "agreement", "warning": "independent chains disagree: ..."}]
    table = run_sweep(cells, dict, tmp_path / "cells.csv", workers=1, progress=False)  # dict: the cell is its row
    assert table.attrs["warned"] == 1
    reported = capsys.readouterr().err
    assert "warning: b: independent chains disagree: ..." in reported and "1 of 2 cells warn" in reported


def _two_cluster_posterior():
    signatures = np.array([[0.30, 0.10], [0.40, 0.05], [0.31, 0.11], [0.41, 0.04], [0.35, 0.08], [0.30, 0.09]])
    return ptm.Posterior(ptm.Dataset(signatures=signatures), ptm.PoissonPrior(2.0),
                         [ptm.AppearanceModel(0.3, 0.05, 3.0, 2e-4)])


def _histogram(result):
    return {tuple(labels): probability
            for labels, probability in zip(map(tuple, result.partitions), result.probabilities)}


class _NeverMoves:
    """A move that proposes nothing: every chain stays where it started (the negative control)."""

    def propose(self, rng, state, posterior):
        return None


@pytest.mark.parametrize("sampler, options", [(ptm.mcmc, {}), (ptm.tempered_mcmc, {"temperatures": (1.0, 0.5)})])
def test_an_extended_run_keeps_exactly_the_samples_of_a_run_of_its_final_length(sampler, options):
    posterior = _two_cluster_posterior()
    extended = sampler(posterior, 8, burn_in=5, seed=3, chains=3, max_doublings=4, start="dispersed", **options)
    doublings = extended.diagnostics["doublings"]
    assert doublings >= 1  # eight samples per chain are too few to agree: the test exercises the extension
    fresh = sampler(_two_cluster_posterior(), 8 * 2**doublings, burn_in=5, seed=3, chains=3, max_doublings=0,
                    start="dispersed", **options)
    assert extended.diagnostics["samples"] == fresh.diagnostics["samples"] == 3 * 8 * 2**doublings
    assert _histogram(extended) == pytest.approx(_histogram(fresh), abs=1e-15)
    for name, trace in fresh.traces.items():
        np.testing.assert_array_equal(extended.traces[name], trace)
    assert extended.diagnostics["rhat_log_prob"] == fresh.diagnostics["rhat_log_prob"]


def test_chains_are_extended_until_they_agree_and_no_further(monkeypatch):
    monkeypatch.setattr(ptm.recorder, "RENORMALISE_COVERAGE", math.inf)  # judged by the visit frequencies
    clear = ptm.Posterior(ptm.Dataset(signatures=np.array([[0.30, 0.10], [0.40, 0.05], [0.31, 0.11], [0.41, 0.04]])),
                          ptm.PoissonPrior(2.0), [ptm.AppearanceModel(0.3, 0.05, 3.0, 2e-4)])
    result = ptm.mcmc(clear, 2_000, burn_in=200, seed=1, chains=4, max_doublings=3, start="dispersed")
    assert ptm.diagnostics.chains_agree(result.diagnostics) is True
    assert result.diagnostics["doublings"] == 0 and result.diagnostics["samples"] == 4 * 2_000
    # Six detections between two clusters mix slowly: 3 000 samples per chain leave co-assignments 0.28 apart.
    slow = ptm.mcmc(_two_cluster_posterior(), 3_000, burn_in=300, seed=1, chains=4, max_doublings=3, start="dispersed")
    doublings = slow.diagnostics["doublings"]
    assert 1 <= doublings and ptm.diagnostics.chains_agree(slow.diagnostics) is True
    shorter = ptm.mcmc(_two_cluster_posterior(), 3_000 * 2 ** (doublings - 1), burn_in=300, seed=1, chains=4,
                       max_doublings=0, start="dispersed")
    assert ptm.diagnostics.chains_agree(shorter.diagnostics) is False


def test_chains_that_cannot_agree_stop_at_the_cap_and_the_cell_says_so():
    # Without moves the chain that starts at all-distinct and the one at all-one-place never meet.
    result = ptm.mcmc(_two_cluster_posterior(), 50, seed=0, chains=2, moves=[_NeverMoves()], max_doublings=2,
                      start="dispersed")
    assert result.diagnostics["doublings"] == 2 and result.diagnostics["samples"] == 2 * 50 * 4
    assert ptm.diagnostics.chains_agree(result.diagnostics) is False
    assert "after doubling the chains 2 times" in disagreement(result.diagnostics)


def test_one_chain_is_never_extended():
    result = ptm.mcmc(_two_cluster_posterior(), 20, seed=0, chains=1, max_doublings=3)
    assert result.diagnostics["doublings"] == 0 and ptm.diagnostics.chains_agree(result.diagnostics) is None


@pytest.mark.parametrize("value", [-1, 1.5, "2"])
def test_a_config_refuses_a_bad_max_doublings(value):
    with pytest.raises(ValueError, match="inference.max_doublings must be a non-negative integer"):
        parse_experiment({"sweep": {"worlds": ["short_loop"], "seeds": [0]}, "inference": {"max_doublings": value}})
