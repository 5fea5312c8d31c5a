"""Scores of a posterior over topologies against the ground truth (SPEC §6).

A result to score is a *distribution*: a mapping from canonical partitions
(restricted growth strings, SPEC §2.1) to probabilities. A PTM gives its
histogram (:func:`distribution_of`); a baseline's single answer is a point mass
on one partition. From the distribution and the true labels this module
computes

* the posterior mass on the ground-truth partition and its rank (1 = most
  probable; ties share the better rank; NaN when the truth was never visited);
* whether the MAP partition is the ground truth, and the adjusted Rand index
  of the MAP (Hubert and Arabie, 1985);
* loop-closure precision, recall and F1 at a co-assignment threshold, and the
  average precision of the pairs ranked by their co-assignment probability
  ("i and j are the same place", SPEC §3.6);
* the expected and the true number of places.

    >>> row = score({(0, 1, 0): 0.75, (0, 1, 2): 0.25}, truth=[0, 1, 0])
    >>> row["gt_mass"], row["gt_rank"], row["map_correct"]
    (0.75, 1, True)
"""

from __future__ import annotations

from collections.abc import Mapping
from math import comb, isclose, nan

import numpy as np

from ptm.partitions import canonical

__all__ = [
    "adjusted_rand_index",
    "coassignment_matrix",
    "distribution_of",
    "ground_truth_rank",
    "loop_closure_scores",
    "point_mass",
    "score",
]

_PROBABILITY_TOLERANCE = 1e-6


def point_mass(labels) -> dict[tuple[int, ...], float]:
    """The distribution that puts all its mass on one partition (a baseline's answer)."""
    return {canonical(labels): 1.0}


def distribution_of(result) -> dict[tuple[int, ...], float]:
    """The histogram of a ``ptm.PTM`` as a ``{canonical labels: probability}`` dict."""
    return dict(result.top(len(result)))


def _validated(distribution: Mapping, n: int | None = None) -> dict[tuple[int, ...], float]:
    if not distribution:
        raise ValueError("distribution is empty: nothing to score")
    out: dict[tuple[int, ...], float] = {}
    for labels, probability in distribution.items():
        key = canonical(labels)
        if n is not None and len(key) != n:
            raise ValueError(f"distribution has a partition of {len(key)} detections, the ground truth has {n}")
        probability = float(probability)
        if not np.isfinite(probability) or probability < 0.0:
            raise ValueError(f"distribution has an invalid probability {probability!r} for {key}")
        out[key] = out.get(key, 0.0) + probability
    total = sum(out.values())
    if not isclose(total, 1.0, abs_tol=_PROBABILITY_TOLERANCE):
        raise ValueError(f"distribution probabilities sum to {total!r}, not 1")
    return out


def ground_truth_rank(distribution: Mapping, truth) -> float:
    """1 + the number of partitions strictly more probable than ``truth``; NaN if its mass is 0."""
    probabilities = _validated(distribution)
    truth_mass = probabilities.get(canonical(truth), 0.0)
    if truth_mass == 0.0:
        return nan
    return 1 + sum(1 for probability in probabilities.values() if probability > truth_mass)


def adjusted_rand_index(labels_a, labels_b) -> float:
    """The adjusted Rand index of two partitions of the same N detections.

    ARI = (I - E[I]) / (max I - E[I]) with I = sum_ij C(n_ij, 2) over the
    contingency table, E[I] = sum_i C(a_i, 2) sum_j C(b_j, 2) / C(N, 2) and
    max I = (sum_i C(a_i, 2) + sum_j C(b_j, 2)) / 2. When the denominator is 0
    (both partitions all singletons, or both one block) the index is 1 for
    equal partitions and 0 otherwise.
    """
    a, b = canonical(labels_a), canonical(labels_b)
    if len(a) != len(b):
        raise ValueError(f"labels_a has {len(a)} detections, labels_b has {len(b)}")
    if not a:
        raise ValueError("adjusted_rand_index needs at least one detection")
    table = np.zeros((max(a) + 1, max(b) + 1), dtype=np.int64)
    np.add.at(table, (np.array(a), np.array(b)), 1)
    pairs = np.vectorize(lambda count: comb(int(count), 2), otypes=[float])
    index = pairs(table).sum()
    rows, columns = pairs(table.sum(axis=1)).sum(), pairs(table.sum(axis=0)).sum()
    expected = rows * columns / comb(len(a), 2) if len(a) > 1 else 0.0
    maximum = (rows + columns) / 2.0
    if maximum == expected:
        return 1.0 if a == b else 0.0
    return float((index - expected) / (maximum - expected))


def coassignment_matrix(distribution: Mapping) -> np.ndarray:
    """The N x N matrix of P(i and j are the same place) under the distribution."""
    probabilities = _validated(distribution)
    n = len(next(iter(probabilities)))
    matrix = np.zeros((n, n))
    for labels, probability in probabilities.items():
        array = np.asarray(labels)
        matrix += probability * (array[:, None] == array[None, :])
    return matrix


def loop_closure_scores(coassignment, truth, threshold: float = 0.5) -> dict[str, float]:
    """Precision, recall, F1 and average precision of loop closures from a co-assignment matrix.

    Every unordered pair i < j is a candidate loop closure; it is a true one
    when the ground truth puts i and j at the same place, and it is predicted
    when its co-assignment probability exceeds ``threshold``. Precision is NaN
    when nothing is predicted, recall and average precision are NaN when the
    ground truth has no loop closure. Average precision ranks the pairs by
    probability and sums (R_t - R_{t-1}) P_t over the distinct probability
    levels t, so tied pairs enter together and the order of ties does not matter.
    """
    truth = np.asarray(canonical(truth))
    matrix = np.asarray(coassignment, dtype=float)
    n = truth.shape[0]
    if matrix.shape != (n, n):
        raise ValueError(f"coassignment must have shape ({n}, {n}), got {matrix.shape}")
    if not 0.0 <= threshold < 1.0:
        raise ValueError(f"threshold must be in [0, 1), got {threshold!r}")
    upper = np.triu_indices(n, k=1)
    scores = matrix[upper]
    positives = (truth[:, None] == truth[None, :])[upper]
    predicted = scores > threshold
    true_positives = int(np.sum(predicted & positives))
    n_predicted, n_positive = int(predicted.sum()), int(positives.sum())
    precision = true_positives / n_predicted if n_predicted else nan
    recall = true_positives / n_positive if n_positive else nan
    if np.isnan(precision) or np.isnan(recall):
        f1 = nan
    elif precision + recall == 0.0:
        f1 = 0.0
    else:
        f1 = 2.0 * precision * recall / (precision + recall)
    return {
        "lc_precision": precision,
        "lc_recall": recall,
        "lc_f1": f1,
        "lc_ap": _average_precision(scores, positives) if n_positive else nan,
    }


def _average_precision(scores: np.ndarray, positives: np.ndarray) -> float:
    levels, inverse = np.unique(-scores, return_inverse=True)  # distinct levels, most probable first
    hits_per_level = np.bincount(inverse, weights=positives, minlength=len(levels))
    pairs_per_level = np.bincount(inverse, minlength=len(levels))
    hits, pairs = np.cumsum(hits_per_level), np.cumsum(pairs_per_level)
    recall_gain = hits_per_level / positives.sum()
    return float(np.sum(recall_gain * hits / pairs))


def score(distribution: Mapping, truth, threshold: float = 0.5, coassignment=None) -> dict:
    """Every accuracy score of one distribution over partitions against the true labels.

    ``coassignment`` may pass the distribution's co-assignment matrix when it is
    already known (``PTM.coassignment()``), instead of recomputing it here.
    """
    truth = canonical(truth)
    probabilities = _validated(distribution, n=len(truth))
    # The most probable partition; ties go to the lexicographically smallest labels, for determinism.
    map_labels = max(probabilities.items(), key=lambda item: (item[1], [-label for label in item[0]]))[0]
    row = {
        "gt_mass": probabilities.get(truth, 0.0),
        "gt_rank": ground_truth_rank(probabilities, truth),
        "map_correct": map_labels == truth,
        "ari": adjusted_rand_index(map_labels, truth),
        "n_measurements": len(truth),
        "expected_places": sum(probability * (max(labels) + 1) for labels, probability in probabilities.items()),
        "true_places": max(truth) + 1,
        "map_places": max(map_labels) + 1,
        "n_topologies": len(probabilities),
    }
    if coassignment is None:
        coassignment = coassignment_matrix(probabilities)
    row.update(loop_closure_scores(coassignment, truth, threshold))
    return row
