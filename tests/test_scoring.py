"""Scoring metrics on hand-made partitions with answers worked out by hand (ptm_bench.evaluation.scoring)."""

import json
import math

import numpy as np
import pytest

from ptm.partitions import canonical
from ptm_bench.evaluation import scoring


def test_adjusted_rand_index_matches_hand_computation():
    # truth blocks {0,1},{2,3},{4}; guess blocks {0,1},{2},{3,4}.
    # Contingency counts 2,1,1,1 -> index = C(2,2) = 1; row pairs = 2, column pairs = 2;
    # expected = 2 * 2 / C(5,2) = 0.4; max = 2 -> ARI = (1 - 0.4) / (2 - 0.4) = 0.375.
    assert scoring.adjusted_rand_index([0, 0, 1, 1, 2], [0, 0, 1, 2, 2]) == pytest.approx(0.375)


def test_adjusted_rand_index_is_one_for_equal_partitions_under_relabelling():
    assert scoring.adjusted_rand_index([3, 3, 7, 1], [0, 0, 1, 2]) == 1.0
    assert scoring.adjusted_rand_index([0, 1, 2], [5, 6, 7]) == 1.0  # degenerate: all singletons


def test_adjusted_rand_index_of_all_singletons_against_one_block_is_zero():
    assert scoring.adjusted_rand_index([0, 1, 2, 3], [0, 0, 0, 0]) == 0.0


def test_adjusted_rand_index_averages_zero_on_independent_random_partitions():
    rng = np.random.default_rng(20260101)
    values = [
        scoring.adjusted_rand_index(rng.integers(0, 4, 30), rng.integers(0, 4, 30)) for _ in range(400)
    ]
    # The index is corrected for chance: its mean over independent partitions is 0.
    # Its standard deviation here is about 0.02, so the mean of 400 is within 0.01 of 0.
    assert abs(np.mean(values)) < 0.01
    assert np.std(values) > 0.005  # not a constant


def test_adjusted_rand_index_rejects_mismatched_lengths():
    with pytest.raises(ValueError, match="labels_a has 3 detections"):
        scoring.adjusted_rand_index([0, 1, 0], [0, 1])


def _matrix(n, entries, background):
    matrix = np.full((n, n), background)
    np.fill_diagonal(matrix, 1.0)
    for (i, j), value in entries.items():
        matrix[i, j] = matrix[j, i] = value
    return matrix


def test_loop_closure_precision_recall_f1_and_average_precision_by_hand():
    # truth: pairs (0,1) and (2,3) are loop closures.
    matrix = _matrix(4, {(0, 1): 0.9, (0, 2): 0.6, (2, 3): 0.4}, background=0.1)
    scores = scoring.loop_closure_scores(matrix, [0, 0, 1, 1])
    # predicted (> 0.5): (0,1) true, (0,2) false -> precision 1/2; recall 1/2; F1 1/2.
    assert scores["lc_precision"] == pytest.approx(0.5)
    assert scores["lc_recall"] == pytest.approx(0.5)
    assert scores["lc_f1"] == pytest.approx(0.5)
    # ranked: 0.9 hit (P=1, R=1/2), 0.6 miss, 0.4 hit (P=2/3, R=1) -> AP = 1/2*1 + 1/2*2/3.
    assert scores["lc_ap"] == pytest.approx(0.5 + 1.0 / 3.0)


def test_average_precision_counts_ties_together():
    # Two pairs tied at the top, one true and one false, then the other true pair.
    matrix = _matrix(4, {(0, 1): 0.8, (0, 2): 0.8, (2, 3): 0.3}, background=0.0)
    scores = scoring.loop_closure_scores(matrix, [0, 0, 1, 1])
    # level 0.8: 1 hit of 2 pairs -> R=1/2, P=1/2; level 0.3: R=1, P=2/3.
    assert scores["lc_ap"] == pytest.approx(0.25 + 1.0 / 3.0)


def test_loop_closure_scores_are_nan_where_undefined():
    # No loop closure in the truth, none predicted.
    scores = scoring.loop_closure_scores(np.eye(3), [0, 1, 2])
    assert all(math.isnan(scores[name]) for name in ("lc_precision", "lc_recall", "lc_f1", "lc_ap"))


def test_loop_closure_scores_reject_a_matrix_of_the_wrong_size():
    with pytest.raises(ValueError, match="coassignment must have shape"):
        scoring.loop_closure_scores(np.eye(3), [0, 0, 1, 1])


def test_coassignment_matrix_of_a_two_partition_mixture():
    matrix = scoring.coassignment_matrix({(0, 0, 1): 0.25, (0, 1, 0): 0.75})
    expected = np.array([[1.0, 0.25, 0.75], [0.25, 1.0, 0.0], [0.75, 0.0, 1.0]])
    np.testing.assert_allclose(matrix, expected)


def test_score_of_a_posterior_with_the_truth_second():
    truth = [4, 4, 9, 4]  # canonical (0, 0, 1, 0)
    distribution = {(0, 1, 2, 0): 0.5, (0, 0, 1, 0): 0.3, (0, 1, 2, 3): 0.2}
    row = scoring.score(distribution, truth)
    assert row["gt_mass"] == pytest.approx(0.3)
    assert row["gt_rank"] == 2
    assert row["map_correct"] is False
    # MAP (0,1,2,0) against truth (0,0,1,0): contingency counts 2,1,1 -> index 1;
    # row pairs C(3,2)=3, column pairs C(2,2)=1; expected 3/6=0.5; max 2 -> ARI 0.5/1.5.
    assert row["ari"] == pytest.approx(1.0 / 3.0)
    assert row["expected_places"] == pytest.approx(0.5 * 3 + 0.3 * 2 + 0.2 * 4)
    assert row["true_places"] == 2
    assert row["n_measurements"] == 4


def test_score_of_an_unvisited_truth_has_zero_mass_and_no_rank():
    row = scoring.score(scoring.point_mass([0, 1, 2]), [0, 0, 1])
    assert row["gt_mass"] == 0.0
    assert math.isnan(row["gt_rank"])
    assert row["lc_recall"] == 0.0


def test_ties_share_the_better_rank():
    assert scoring.ground_truth_rank({(0, 0): 0.5, (0, 1): 0.5}, [0, 1]) == 1


def test_score_rejects_a_distribution_that_does_not_sum_to_one():
    with pytest.raises(ValueError, match="sum to 0.9"):
        scoring.score({(0, 1): 0.9}, [0, 1])


def test_score_rejects_partitions_of_the_wrong_size():
    with pytest.raises(ValueError, match="partition of 3 detections, the ground truth has 2"):
        scoring.score({(0, 1, 0): 1.0}, [0, 1])


# -- calibration -----------------------------------------------------------------------------


def test_expected_calibration_error_of_a_reliability_table_by_hand():
    # Bins of width 0.1: [0, .1) holds 0.05 (y 0); [.1, .2) holds 0.15 (y 1) and 0.12 (y 0);
    # [.8, .9) holds 0.85 (y 1); [.9, 1] holds 0.95 (y 1).
    table = scoring.reliability_table([0.05, 0.15, 0.12, 0.85, 0.95], [0, 1, 0, 1, 1])
    assert table.shape == (10, 3)
    np.testing.assert_allclose(table[[0, 1, 8, 9]], [[1, 0.05, 0], [2, 0.27, 1], [1, 0.85, 1], [1, 0.95, 1]])
    assert table[2:8].sum() == 0.0
    # ECE = 1/5 |0.05 - 0| + 2/5 |0.135 - 0.5| + 1/5 |0.85 - 1| + 1/5 |0.95 - 1| = 0.01 + 0.146 + 0.03 + 0.01.
    assert scoring.expected_calibration_error(table) == pytest.approx(0.196)
    # A perfectly calibrated table has ECE 0; the same table as JSON gives the same value.
    assert scoring.expected_calibration_error([[4, 1.0, 1.0], [2, 1.6, 1.6]]) == 0.0
    assert scoring.expected_calibration_error(json.dumps(table.tolist())) == pytest.approx(0.196)


def test_reliability_table_puts_certainty_in_the_last_bin_and_refuses_non_probabilities():
    table = scoring.reliability_table([0.0, 1.0, 1.0 + 1e-12], [0, 1, 1])  # round-off above 1 is clipped
    np.testing.assert_allclose(table[0], [1, 0.0, 0])
    np.testing.assert_allclose(table[-1], [2, 2.0, 2])
    with pytest.raises(ValueError, match="probabilities must lie in \\[0, 1\\]"):
        scoring.reliability_table([0.5, 1.2], [0, 1])
    with pytest.raises(ValueError, match="outcomes must be 0 or 1"):
        scoring.reliability_table([0.5], [0.5])
    with pytest.raises(ValueError, match="2 probabilities but 1 outcomes"):
        scoring.reliability_table([0.5, 0.5], [1])


def test_calibration_columns_of_a_two_topology_posterior_by_hand():
    # truth (0, 0, 1); P(0,0,1) = 0.65, P(0,1,2) = 0.35. Pairs: (0,1) p 0.65 y 1; (0,2), (1,2) p 0 y 0.
    row = scoring.score({(0, 0, 1): 0.65, (0, 1, 2): 0.35}, truth=[5, 5, 2])
    assert row["n_pairs"] == 3
    assert row["brier"] == pytest.approx(0.35 ** 2 / 3)
    assert row["ece"] == pytest.approx(0.35 / 3)  # bin [0, .1): 2 pairs, exact; bin [.6, .7): |0.65 - 1|
    table = np.array(json.loads(row["reliability"]))
    np.testing.assert_allclose(table[[0, 6]], [[2, 0.0, 0], [1, 0.65, 1]])
    assert row["log_score"] == pytest.approx(math.log(0.65))
    assert row["map_mass"] == pytest.approx(0.65) and row["confidently_wrong"] is False


def test_log_score_is_floored_so_an_unvisited_truth_is_finite():
    unvisited = scoring.score(scoring.point_mass([0, 1, 2]), [0, 0, 1])
    assert unvisited["log_score"] == pytest.approx(math.log(1e-6)) == pytest.approx(-13.815510557964274)
    tiny = scoring.score({(0, 0, 1): 1e-8, (0, 1, 2): 1.0 - 1e-8}, [0, 0, 1])
    assert tiny["log_score"] == pytest.approx(math.log(1e-6))
    assert scoring.score(scoring.point_mass([0, 0, 1]), [0, 0, 1])["log_score"] == 0.0


def test_confidently_wrong_needs_both_a_confident_map_and_a_wrong_one():
    truth = [0, 0, 1]
    assert scoring.score({(0, 1, 2): 0.92, (0, 0, 1): 0.08}, truth)["confidently_wrong"] is True
    assert scoring.score({(0, 1, 2): 0.9, (0, 0, 1): 0.1}, truth)["confidently_wrong"] is True  # >= 0.9
    assert scoring.score({(0, 1, 2): 0.88, (0, 0, 1): 0.12}, truth)["confidently_wrong"] is False  # not confident
    assert scoring.score({(0, 0, 1): 0.95, (0, 1, 2): 0.05}, truth)["confidently_wrong"] is False  # right
    wrong_baseline = scoring.score(scoring.point_mass([0, 1, 2]), truth)
    assert wrong_baseline["confidently_wrong"] is True
    # A point mass predicts 0 or 1 for every pair: the wrong pair (0, 1) costs (0 - 1)^2 of 3 pairs.
    assert wrong_baseline["brier"] == pytest.approx(1.0 / 3.0)
    assert wrong_baseline["ece"] == pytest.approx(1.0 / 3.0)


def _random_distribution(rng, n):
    partitions = {canonical(rng.integers(0, n, n)) for _ in range(int(rng.integers(1, 6)))}
    weights = rng.dirichlet(np.ones(len(partitions)))
    return dict(zip(partitions, weights))


def _concatenated_ece(probabilities, outcomes, bins=10):
    """ECE straight from its definition, bin by bin over the concatenated pairs (last bin closed)."""
    edges = np.linspace(0.0, 1.0, bins + 1)
    ece = 0.0
    for index in range(bins):
        upper = probabilities <= edges[index + 1] if index == bins - 1 else probabilities < edges[index + 1]
        members = (probabilities >= edges[index]) & upper
        if members.any():
            ece += members.sum() / len(probabilities) * abs(probabilities[members].mean() - outcomes[members].mean())
    return ece


def test_pooled_ece_and_brier_from_per_cell_columns_equal_those_of_the_concatenated_pairs():
    rng = np.random.default_rng(91)
    rows, probabilities, outcomes = [], [], []
    for _ in range(12):
        n = int(rng.integers(2, 8))  # cells of different sizes, so pooling must weight by pairs
        truth = canonical(rng.integers(0, 3, n))
        distribution = _random_distribution(rng, n)
        rows.append(scoring.score(distribution, truth))
        upper = np.triu_indices(n, k=1)
        probabilities.append(scoring.coassignment_matrix(distribution)[upper])
        outcomes.append((np.asarray(truth)[:, None] == np.asarray(truth)[None, :])[upper])
    probabilities, outcomes = np.concatenate(probabilities), np.concatenate(outcomes).astype(float)
    pooled = scoring.expected_calibration_error(scoring.pooled_reliability(row["reliability"] for row in rows))
    assert pooled == pytest.approx(_concatenated_ece(probabilities, outcomes), abs=1e-12)
    # The mean of the per-cell ECEs is not the pooled ECE: pooling has to go through the tables.
    assert abs(np.mean([row["ece"] for row in rows]) - pooled) > 0.01
    n_pairs = np.array([row["n_pairs"] for row in rows])
    assert n_pairs.sum() == len(probabilities)
    brier = np.sum([row["brier"] for row in rows] * n_pairs) / n_pairs.sum()
    assert brier == pytest.approx(np.mean((probabilities - outcomes) ** 2), abs=1e-12)


def test_pooled_reliability_skips_missing_tables_and_refuses_mismatched_ones():
    table = scoring.reliability_table([0.3], [1])
    np.testing.assert_allclose(scoring.pooled_reliability([json.dumps(table.tolist()), float("nan"), table]), 2 * table)
    with pytest.raises(ValueError, match="cannot be pooled"):
        scoring.pooled_reliability([table, scoring.reliability_table([0.3], [1], bins=5)])
    with pytest.raises(ValueError, match="no reliability table"):
        scoring.pooled_reliability([float("nan")])


# -- baselines -------------------------------------------------------------------------------

from ptm import Dataset  # noqa: E402
from ptm.se2 import dead_reckoning  # noqa: E402
from ptm_bench.evaluation import baselines  # noqa: E402


def test_dead_reckoning_composes_increments_on_se2():
    # Forward 1 m, turn left 90 degrees, forward 1 m: ends at (1, 1) facing +y.
    poses = dead_reckoning([[1.0, 0.0, np.pi / 2], [1.0, 0.0, 0.0]])
    np.testing.assert_allclose(poses[-1], [1.0, 1.0, np.pi / 2], atol=1e-12)


def test_greedy_threshold_joins_the_nearest_place_mean_closer_than_the_threshold():
    points = np.array([[0.0], [10.0], [0.4], [10.6], [0.9], [5.0]])
    # 0.4 joins place 0 (mean 0 -> 0.2); 10.6 joins place 1; 0.9 is 0.7 from mean 0.2 -> joins; 5.0 is new.
    assert baselines.greedy_threshold_labels(points, threshold=0.8) == (0, 1, 0, 1, 0, 2)
    assert baselines.greedy_threshold_labels(points, threshold=0.0) == (0, 1, 2, 3, 4, 5)


def test_fit_threshold_recovers_the_gap_between_within_and_between_place_distances():
    rng = np.random.default_rng(7)
    datasets = []
    for _ in range(3):
        labels = rng.permutation(np.repeat(np.arange(4), 3))
        signatures = np.array([[10.0 * label, 0.0] for label in labels]) + rng.normal(scale=0.3, size=(12, 2))
        datasets.append(Dataset(signatures=signatures, labels=labels))
    threshold = baselines.fit_threshold(datasets, baselines.BASELINE_FEATURES["appearance_threshold"])
    # Within-place spreads are ~1 at most, places are 10 apart: any threshold in between is perfect.
    assert 0.5 < threshold < 9.0
    for dataset in datasets:
        labels = baselines.greedy_threshold_labels(dataset.signatures, threshold)
        assert scoring.adjusted_rand_index(labels, dataset.labels) == 1.0


def test_baselines_name_the_missing_field():
    with pytest.raises(ValueError, match="needs a dataset with odometry"):
        baselines.BASELINE_FEATURES["greedy_odometry"](Dataset(signatures=np.ones((3, 2))))
