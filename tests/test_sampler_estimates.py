"""How the samplers turn their chains into probabilities (docs/model.md §3.4, :mod:`ptm.recorder`): the
posterior renormalised over the visited topologies where every chain visited nearly all of the topologies any
chain found (a chain stranded in a mode of next to no mass apart), the visit frequencies otherwise.

The renormalised estimate is exact on what was visited: its total variation from the exact posterior is the
exact mass of the topologies no chain visited. On a flat posterior, where chains keep finding new topologies,
it is biased towards the best of them (the negative control), and the recorder keeps the frequencies there.
"""

import dataclasses

import numpy as np
import pytest

import ptm
import ptm.recorder
from ptm.moves import initial_state


def _peaked_posterior():
    signatures = np.array([[0.30, 0.10], [0.40, 0.05], [0.31, 0.11], [0.41, 0.04], [0.35, 0.20], [0.30, 0.09],
                           [0.20, 0.30]])
    return ptm.Posterior(ptm.Dataset(signatures=signatures), ptm.PoissonPrior(3.0),
                         [ptm.AppearanceModel(0.3, 0.05, 3.0, 2e-4)])


def _flat_posterior():
    """Ten detections that all look alike to a model whose places differ a lot: about e^5.8 topologies count."""
    signatures = np.random.default_rng(0).normal(0.3, 0.01, size=(10, 2))
    return ptm.Posterior(ptm.Dataset(signatures=signatures), ptm.PoissonPrior(5.0),
                         [ptm.AppearanceModel(0.3, 0.1, 3.0, 2e-4)])


def _unvisited_mass(result, exact) -> float:
    visited = {tuple(row) for row in result.partitions}
    return float(sum(p for row, p in zip(exact.partitions, exact.probabilities) if tuple(row) not in visited))


def _renormalised(result, posterior) -> ptm.PTM:
    """``result``'s topologies with their posterior probabilities renormalised over them."""
    log_probs = np.array([posterior.log_prob(labels) for labels in result.partitions])
    return ptm.PTM(result.partitions, np.exp(log_probs - log_probs.max()), "renormalised")


def test_a_peaked_posterior_is_renormalised_off_by_exactly_the_mass_never_visited():
    posterior = _peaked_posterior()
    exact = ptm.exact_posterior(posterior)
    result = ptm.mcmc(posterior, 3_000, burn_in=300, seed=2, chains=4)
    assert result.diagnostics["estimate"] == "renormalised" and result.diagnostics["chain_coverage_min"] >= 0.99
    missed = _unvisited_mass(result, exact)
    assert 0 < missed < 0.01  # some mass unvisited, so the identity below is not 0 == 0
    assert ptm.total_variation(result, exact) == pytest.approx(missed, abs=1e-9)


def test_a_flat_posterior_keeps_the_frequencies():
    flat = _flat_posterior()
    exact = ptm.exact_posterior(flat)
    assert exact.entropy() > 5
    result = ptm.mcmc(flat, 2_000, burn_in=200, seed=2, chains=4, start="dispersed", max_doublings=0)
    assert result.diagnostics["estimate"] == "frequency" and result.diagnostics["chain_coverage_min"] < 0.9

    def coassignment_error(estimate):
        return float(np.abs(estimate.coassignment() - exact.coassignment()).max())

    # The negative control: renormalising the visited few of many topologies favours the best found.
    assert coassignment_error(result) < 0.05 < 0.1 < coassignment_error(_renormalised(result, flat))


def _recorded(stray_log_prob: float, strays: int = 1) -> ptm.recorder.SampleRecorder:
    """Four chains of 100 samples: the first 4 - ``strays`` alternate between topologies A (log P 0) and B
    (log P -1), the others never leave C (log P ``stray_log_prob``)."""
    posterior = _peaked_posterior()
    recorder = ptm.recorder.SampleRecorder(4, 100)
    states = {}
    for name, labels, log_prob in (("A", (0, 1, 0, 1, 2, 0, 3), 0.0), ("B", (0, 1, 0, 1, 2, 3, 4), -1.0),
                                   ("C", (0, 0, 1, 1, 2, 3, 4), stray_log_prob)):
        state = initial_state(posterior, labels)
        states[name] = dataclasses.replace(state, log_cheap=log_prob, log_global=0.0)
    for chain in range(4):
        for index in range(100):
            recorder.keep(chain, index, states["C"] if chain >= 4 - strays else states["AB"[index % 2]])
    return recorder


def test_auto_renormalises_past_a_chain_stranded_far_below_the_others():
    """A chain that stays in a mode 50 nats below what the others keep visiting (a retraced corridor aligned
    one place off, on the scale grids) holds e^-50 of the renormalised mass; its frequency would be a quarter."""
    recorder = _recorded(stray_log_prob=-50.0)
    result = recorder.result("mcmc", {})
    probabilities = dict(zip(map(tuple, result.partitions), result.probabilities))
    assert result.diagnostics["estimate"] == "renormalised"
    assert probabilities[(0, 0, 1, 1, 2, 3, 4)] < 1e-20
    assert probabilities[(0, 1, 0, 1, 2, 0, 3)] / probabilities[(0, 1, 0, 1, 2, 3, 4)] == pytest.approx(np.e)
    assert result.diagnostics["stray_chains"] == 1
    assert result.diagnostics["stray_log_prob_gap"] == pytest.approx(50.0)
    assert result.diagnostics["chain_coverage_min"] < 1e-20  # the stray's own coverage is still reported


def test_a_chain_in_a_mode_that_matters_keeps_the_frequencies():
    """The negative control: 3 nats below, the lone chain's mode holds 3.5 % of the renormalised mass, so it
    is no stray, the other chains cover only 96 % and the frequencies stand (a quarter for its mode)."""
    recorder = _recorded(stray_log_prob=-3.0)
    result = recorder.result("mcmc", {})
    probabilities = dict(zip(map(tuple, result.partitions), result.probabilities))
    assert result.diagnostics["estimate"] == "frequency" and result.diagnostics["stray_chains"] == 0
    assert probabilities[(0, 0, 1, 1, 2, 3, 4)] == pytest.approx(0.25)


def test_one_chain_above_three_strays_is_no_evidence():
    """Where three chains of four are strays, the one left covers the mass trivially: no second chain found the
    same topologies, so the frequencies stand (as on a real log, FHW with odometry alone, where three chains
    stayed at least 10 nats below the fourth)."""
    result = _recorded(stray_log_prob=-50.0, strays=3).result("mcmc", {})
    assert result.diagnostics["estimate"] == "frequency" and result.diagnostics["stray_chains"] == 3
    assert _recorded(stray_log_prob=-50.0, strays=2).result("mcmc", {}).diagnostics["estimate"] == "renormalised"
