"""Exact enumeration (docs/model.md §3.5) and the PTM result it returns (docs/model.md §3.6)."""

import math

import numpy as np
import pytest

import ptm
from helpers import appearance_posterior, prior_only_posterior
from ptm.partitions import stirling2


@pytest.mark.parametrize("n", [1, 2, 5, 8])
def test_enumeration_visits_every_partition_once(n):
    exact = ptm.exact_posterior(prior_only_posterior(n))
    assert len(exact) == ptm.bell(n)
    assert len({tuple(row) for row in exact.partitions}) == ptm.bell(n)
    assert all(ptm.canonical(row) == tuple(row) for row in exact.partitions)
    assert exact.probabilities.sum() == pytest.approx(1.0)


def test_enumeration_agrees_with_scoring_each_partition_from_scratch():
    posterior = appearance_posterior(n=6)
    exact = ptm.exact_posterior(posterior)
    log_probs = np.array([posterior.log_prob(row) for row in exact.partitions])
    expected = np.exp(log_probs - np.logaddexp.reduce(log_probs))
    assert np.allclose(exact.probabilities, expected, rtol=1e-9, atol=1e-15)


def test_prior_only_posterior_depends_on_the_number_of_places_only():
    exact = ptm.exact_posterior(prior_only_posterior(5, rate=2.0))
    prior = ptm.PoissonPrior(2.0)
    normaliser = 1.0 - math.exp(-2.0)
    for labels, probability in exact.top(52):
        assert probability == pytest.approx(math.exp(prior.log_prob(5, max(labels) + 1)) / normaliser)


def test_ptm_summaries_on_a_known_distribution():
    result = ptm.PTM(np.array([[0, 0, 1], [0, 1, 2], [0, 1, 0]]), np.array([0.5, 0.3, 0.2]), "test")
    assert result.top(2) == [((0, 0, 1), 0.5), ((0, 1, 2), 0.3)]
    assert result.map() == (0, 0, 1)
    assert result.probability([7, 7, 3]) == 0.5
    assert result.probability([0, 0, 0]) == 0.0
    assert result.rank([4, 5, 4]) == 3 and result.rank([1, 1, 1]) is None
    coassignment = result.coassignment()
    assert coassignment[0, 1] == pytest.approx(0.5) and coassignment[0, 2] == pytest.approx(0.2)
    assert np.allclose(np.diag(coassignment), 1.0)
    assert result.expected_num_places() == pytest.approx(0.5 * 2 + 0.3 * 3 + 0.2 * 2)
    assert result.entropy() == pytest.approx(-(0.5 * math.log(0.5) + 0.3 * math.log(0.3) + 0.2 * math.log(0.2)))
    frame = result.to_frame()
    assert list(frame.columns) == ["topology", "probability", "num_places"]
    assert frame["topology"].iloc[0] == "0,0,1"


def test_total_variation_of_disjoint_and_equal_ptms():
    first = ptm.PTM(np.array([[0, 0]]), np.array([1.0]), "test")
    second = ptm.PTM(np.array([[0, 1]]), np.array([1.0]), "test")
    assert ptm.total_variation(first, second) == pytest.approx(1.0)
    assert ptm.total_variation(first, first) == 0.0


def test_enumeration_refuses_beyond_the_limit():
    with pytest.raises(ValueError, match="max_n=12"):
        ptm.exact_posterior(prior_only_posterior(13))
    with pytest.raises(ValueError, match="max_n=4"):
        ptm.exact_posterior(prior_only_posterior(5), max_n=4)


def test_ptm_save_and_load_round_trip(tmp_path):
    result = ptm.mcmc(appearance_posterior(), 500, seed=0, chains=2)
    loaded = ptm.PTM.load(result.save(tmp_path / "ptm.npz"))
    assert loaded.top(10) == result.top(10)
    assert np.array_equal(loaded.traces["log_prob"], result.traces["log_prob"])
    assert loaded.diagnostics["acceptance_rate"] == result.diagnostics["acceptance_rate"]
    with pytest.raises(ValueError, match=".npz"):
        result.save(tmp_path / "ptm.json")


def test_enumeration_is_iterative_in_lexicographic_order(monkeypatch):
    def refuse(limit):
        raise AssertionError("exact_posterior must not change the recursion limit")

    monkeypatch.setattr("sys.setrecursionlimit", refuse)
    exact = ptm.exact_posterior(prior_only_posterior(7))
    assert len(exact) == ptm.bell(7)
    # with the prior alone all partitions with M places tie, and the PTM's stable sort keeps them in the
    # order they were enumerated: lexicographic in the restricted growth string
    rows, places = [tuple(row) for row in exact.partitions], exact.num_places()
    for m in range(1, 8):
        same_m = [row for row, count in zip(rows, places) if count == m]
        assert len(same_m) == stirling2(7, m) and same_m == sorted(same_m)


def _square_loop_with_appearance(n: int, seed: int = 0) -> ptm.Dataset:
    """A 5 m square driven repeatedly; each corner has its own appearance (so appearance is decisive)."""
    rng = np.random.default_rng(seed)
    labels = np.arange(n) % 4
    corners = np.array([[0.0, 0.0], [5.0, 0.0], [5.0, 5.0], [0.0, 5.0]])
    poses = np.column_stack([corners[labels], ptm.se2.wrap_angle(labels * np.pi / 2)])
    odometry = ptm.se2.relative_pose(poses[:-1], poses[1:]) + rng.normal(0.0, [0.1, 0.1, 0.03], size=(n - 1, 3))
    looks = np.array([[0.3, 0.1], [0.2, 0.3], [0.5, 0.1], [0.1, 0.5]])
    return ptm.Dataset(odometry=odometry, labels=labels, signatures=looks[labels] + rng.normal(0.0, 0.003, (n, 2)))


def _square_posterior(dataset, extra_terms=(), max_penalty: float = 0.0) -> ptm.Posterior:
    odometry = ptm.OdometryModel(0.1, 0.03, sigma_topology=0.5, penalty_radius=3.0, max_penalty=max_penalty, seed=2)
    appearance = ptm.AppearanceModel(mu=0.3, kappa=0.05, alpha=3.0, beta=2e-5)
    return ptm.Posterior(dataset, ptm.PoissonPrior(3.0), [odometry, appearance, *extra_terms])


def test_the_odometry_bound_holds_on_every_partition_and_is_the_penalty_free_all_distinct_value():
    dataset = _square_loop_with_appearance(5)
    term = _square_posterior(dataset, max_penalty=100.0).global_terms[0]
    bound = term.log_likelihood_upper_bound()
    values = [term.log_likelihood(labels) for labels in ptm.exact_posterior(prior_only_posterior(5)).partitions]
    assert max(values) <= bound
    free = _square_posterior(dataset).global_terms[0]
    assert free.evaluate(range(5)).laplace == pytest.approx(bound, abs=1e-9)
    # with covariances that couple position and heading (as real logs' do)
    rng = np.random.default_rng(0)
    factors = rng.normal(size=(4, 3, 3))
    coupled = ptm.Dataset(odometry=dataset.odometry, odometry_cov=0.01 * factors @ np.swapaxes(factors, 1, 2) + 1e-3 * np.eye(3))
    term = ptm.OdometryModel(max_penalty=0.0).bind(coupled)
    assert term.evaluate(range(5)).laplace == pytest.approx(term.log_likelihood_upper_bound(), abs=1e-9)


def test_skipping_partitions_below_the_bound_changes_no_probability_and_saves_most_evaluations():
    dataset = _square_loop_with_appearance(7)
    skipped = ptm.exact_posterior(_square_posterior(dataset))
    full = ptm.exact_posterior(_square_posterior(dataset), skip=False)
    assert full.diagnostics["global_evaluations"] == ptm.partitions.bell(7) == 877
    assert skipped.diagnostics["global_evaluations"] < 877 // 3
    assert skipped.diagnostics["skipped_mass_bound"] < math.exp(-40)
    assert ptm.total_variation(skipped, full) < 1e-12
    assert skipped.map() == full.map() == tuple(dataset.labels)


class _Overshoot:
    """A global term whose declared bound (0) is false on one partition, where it gives ``amount``."""

    name = "overshooting"

    def __init__(self, labels, amount: float):
        self.labels, self.amount = ptm.partitions.canonical(labels), amount

    def log_likelihood(self, partition) -> float:
        return self.amount if partition.labels == self.labels else 0.0

    def log_likelihood_upper_bound(self, num_places=None) -> float:
        return 0.0


def test_a_bound_found_false_turns_skipping_off_and_a_false_bound_never_met_shows_in_the_result():
    dataset = _square_loop_with_appearance(6)
    # false on the truth, the first partition evaluated: noticed, everything is evaluated
    noticed = ptm.exact_posterior(_square_posterior(dataset, [_Overshoot(dataset.labels, 5.0)]))
    full = ptm.exact_posterior(_square_posterior(dataset, [_Overshoot(dataset.labels, 5.0)]), skip=False)
    assert noticed.diagnostics["global_evaluations"] == 203
    assert ptm.total_variation(noticed, full) == 0.0
    # negative control: false only on the partition of lowest cheap score, which the skip never reaches and
    # where the false value would have dominated: the skipped result misses it, so the comparison above can fail
    cheap_only = ptm.exact_posterior(ptm.Posterior(dataset, ptm.PoissonPrior(3.0), _square_posterior(dataset).block_terms))
    lying = [_Overshoot(cheap_only.partitions[-1], 1e5)]
    missed = ptm.exact_posterior(_square_posterior(dataset, lying))
    assert missed.diagnostics["global_evaluations"] < 203
    assert ptm.total_variation(missed, ptm.exact_posterior(_square_posterior(dataset, lying), skip=False)) > 0.99


def test_a_budget_of_global_evaluations_refuses_at_once_what_the_skip_cannot_bring_under_it():
    dataset = _square_loop_with_appearance(6)
    within = ptm.exact_posterior(_square_posterior(dataset), max_global_evaluations=203)
    assert within.diagnostics["global_evaluations"] <= 203
    posterior = _square_posterior(dataset)
    with pytest.raises(ptm.exact.ExactBudgetExceeded, match="budget is 5"):
        ptm.exact_posterior(posterior, max_global_evaluations=5)
    assert posterior.diagnostics()["odometry"]["evaluations"] == 1  # refused after the first evaluation
    prior_only_odometry = ptm.Posterior(dataset, ptm.PoissonPrior(3.0), _square_posterior(dataset).global_terms)
    with pytest.raises(ptm.exact.ExactBudgetExceeded):
        ptm.exact_posterior(prior_only_odometry, max_global_evaluations=100)


def test_the_harness_method_auto_samples_where_exact_enumeration_would_exceed_its_budget(monkeypatch):
    from ptm_bench.evaluation import cell

    dataset = _square_loop_with_appearance(6)
    assert cell._affordable_exact_posterior(_square_posterior(dataset), 10).method == "exact"
    monkeypatch.setattr(cell, "AUTO_EXACT_GLOBAL_EVALUATIONS", 5)
    assert cell._affordable_exact_posterior(_square_posterior(dataset), 10) is None
    assert cell._affordable_exact_posterior(_square_posterior(dataset), 5) is None
