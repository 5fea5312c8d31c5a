"""Scoring metrics on hand-made partitions with answers worked out by hand (ptm_bench.scoring)."""

import math

import numpy as np
import pytest

from ptm_bench import scoring


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


# -- baselines -------------------------------------------------------------------------------

from ptm import Dataset  # noqa: E402
from ptm_bench import baselines  # noqa: E402


def test_dead_reckoning_composes_increments_on_se2():
    # Forward 1 m, turn left 90 degrees, forward 1 m: ends at (1, 1) facing +y.
    poses = baselines.dead_reckoning([[1.0, 0.0, np.pi / 2], [1.0, 0.0, 0.0]])
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
