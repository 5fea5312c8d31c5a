"""Scores of a posterior over topologies against the ground truth (docs/model.md §6).

A result to score is a *distribution*: a mapping from canonical partitions
(restricted growth strings, docs/model.md §2.1) to probabilities. A PTM gives its
histogram (pass the PTM itself, :func:`as_ptm`); a baseline's single answer is a point mass
on one partition. From the distribution and the true labels this module
computes

* the posterior mass on the ground-truth partition and its rank (1 = most
  probable; ties share the better rank; NaN when the truth was never visited);
* whether the MAP partition is the ground truth, and the adjusted Rand index
  of the MAP (Hubert and Arabie, 1985);
* loop-closure precision, recall and F1 at a co-assignment threshold, and the
  average precision of the pairs ranked by their co-assignment probability
  ("i and j are the same place", docs/model.md §3.6);
* the expected and the true number of places;
* calibration (docs/model.md §6): the log score of the truth, log max(gt_mass, 1e-6)
  (:data:`LOG_SCORE_FLOOR`); whether the run is *confidently wrong* (its MAP
  has probability >= 0.9, :data:`CONFIDENT`, and is not the truth); and, for
  the N(N-1)/2 pairs i < j with probability p = P(i and j are the same place)
  and outcome y = 1 if the truth puts them at one place, else 0, the Brier
  score mean (p - y)^2, the ECE of the cell's own pairs, and a reliability
  table: per bin b of 10 equal-width bins of p, [n_b, sum of p, sum of y]
  (:func:`calibration_scores` lists the columns).

The reliability table makes the expected calibration error of a whole sweep
exact from per-cell rows: tables of cells add bin by bin
(:func:`pooled_reliability`), and the ECE of a table is
ECE = sum_b (n_b / n) |mean p_b - mean y_b| = sum_b |sum p_b - sum y_b| / n
(:func:`expected_calibration_error`); a sweep's Brier score is the mean of
the cells' ``brier`` weighted by their ``n_pairs``.

    >>> row = score({(0, 1, 0): 0.75, (0, 1, 2): 0.25}, truth=[0, 1, 0])
    >>> row["gt_mass"], row["gt_rank"], row["map_correct"], row["confidently_wrong"]
    (0.75, 1, True, False)
    >>> round(expected_calibration_error(reliability_table([0.95, 0.85, 0.05], [1, 1, 0])), 4)
    0.0833
"""

from __future__ import annotations

import json
from collections.abc import Iterable, Mapping
from math import isclose, log, nan

import numpy as np
from sklearn.metrics import adjusted_rand_score, average_precision_score, precision_recall_fscore_support

import ptm
from ptm.partitions import canonical

__all__ = [
    "CONFIDENT",
    "LOG_SCORE_FLOOR",
    "RELIABILITY_BINS",
    "adjusted_rand_index",
    "as_ptm",
    "calibration_scores",
    "coassignment_matrix",
    "expected_calibration_error",
    "ground_truth_rank",
    "loop_closure_scores",
    "point_mass",
    "pooled_reliability",
    "reliability_table",
    "score",
]

_PROBABILITY_TOLERANCE = 1e-6

#: Equal-width bins of the reliability diagram over [0, 1]; the last bin is closed (p = 1 falls in it).
RELIABILITY_BINS = 10
#: The smallest mass the log score counts: log(gt_mass) is floored at log(1e-6) = -13.8, so a truth the
#: sampler never visited (mass 0, or a baseline's wrong point mass) scores finitely. An MCMC histogram of
#: S samples cannot resolve masses below 1/S (the default config keeps 4 chains x 2e4 samples), so the floor
#: sits below every mass a sample can give and only ever acts on "never visited" (or an exact mass below 1e-6).
LOG_SCORE_FLOOR = 1e-6
#: A run is confidently wrong when its most probable topology has at least this probability and is not the truth.
CONFIDENT = 0.9


def point_mass(labels) -> dict[tuple[int, ...], float]:
    """The distribution that puts all its mass on one partition (a baseline's answer)."""
    return {canonical(labels): 1.0}


def as_ptm(distribution, n: int | None = None) -> ptm.PTM:
    """A distribution to score as a ``ptm.PTM``: a PTM passes through; a ``{labels: probability}`` dict is checked.

    The dict's labels are made canonical (equal partitions add up), every
    probability must be finite and non-negative and they must sum to 1 (within
    1e-6); ``n``, when given, is the number of detections every partition must have.
    The PTM then answers the questions the scores ask (probability and rank of
    the truth, MAP with its tie rule, co-assignment, expected number of places),
    so the harness and the library cannot disagree on them.
    """
    if isinstance(distribution, ptm.PTM):
        if n is not None and distribution.n != n:
            raise ValueError(f"the PTM is over {distribution.n} detections, the ground truth has {n}")
        return distribution
    probabilities = _validated(distribution, n)
    return ptm.PTM(list(probabilities), list(probabilities.values()), method="distribution")


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


def ground_truth_rank(distribution, truth) -> float:
    """1 + the number of partitions strictly more probable than ``truth``; NaN if its mass is 0 (``PTM.rank``)."""
    rank = as_ptm(distribution).rank(truth)
    return nan if rank is None else rank


def adjusted_rand_index(labels_a, labels_b) -> float:
    """The adjusted Rand index of two partitions of the same N detections (``sklearn.metrics.adjusted_rand_score``).

    1 for equal partitions, about 0 for unrelated ones (Hubert and Arabie,
    1985); also 1 when both are all singletons or both one block.
    """
    a, b = canonical(labels_a), canonical(labels_b)
    if len(a) != len(b):
        raise ValueError(f"labels_a has {len(a)} detections, labels_b has {len(b)}")
    if not a:
        raise ValueError("adjusted_rand_index needs at least one detection")
    return float(adjusted_rand_score(a, b))


def coassignment_matrix(distribution) -> np.ndarray:
    """The N x N matrix of P(i and j are the same place) under the distribution (``PTM.coassignment``)."""
    return as_ptm(distribution).coassignment()


def loop_closure_scores(coassignment, truth, threshold: float = 0.5) -> dict[str, float]:
    """Precision, recall, F1 and average precision of loop closures from a co-assignment matrix.

    Every unordered pair i < j is a candidate loop closure; it is a true one
    when the ground truth puts i and j at the same place, and it is predicted
    when its co-assignment probability exceeds ``threshold``. Precision is NaN
    when nothing is predicted, recall and average precision are NaN when the
    ground truth has no loop closure. Average precision ranks the pairs by
    probability and sums (R_t - R_{t-1}) P_t over the distinct probability
    levels t, so tied pairs enter together and the order of ties does not matter
    (``sklearn.metrics``: precision, recall, F1 and average precision).
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
    n_predicted, n_positive = int(predicted.sum()), int(positives.sum())
    precision, recall, f1, _ = precision_recall_fscore_support(positives, predicted, average="binary",
                                                               zero_division=np.nan)
    return {
        "lc_precision": float(precision) if n_predicted else nan,
        "lc_recall": float(recall) if n_positive else nan,
        "lc_f1": float(f1) if n_predicted and n_positive else nan,
        # sklearn's AP takes every distinct probability as a threshold, so tied pairs enter together.
        "lc_ap": float(average_precision_score(positives, scores)) if n_positive else nan,
    }


def reliability_table(probabilities, outcomes, bins: int = RELIABILITY_BINS) -> np.ndarray:
    """Per equal-width bin of ``probabilities`` over [0, 1]: [count, sum of probabilities, sum of outcomes].

    A ``(bins, 3)`` float array; tables of disjoint sets of pairs add. ``outcomes``
    are 0/1 (or booleans). Bin b holds edges[b] <= p < edges[b + 1] with
    ``edges = np.linspace(0, 1, bins + 1)``, the last bin closed (``numpy.histogram``'s
    convention). Probabilities within 1e-6 of [0, 1] (float round-off of a sum
    of sample weights) are clipped into it; others are an error.
    """
    probabilities = np.asarray(probabilities, dtype=float).ravel()
    outcomes = np.asarray(outcomes, dtype=float).ravel()
    if probabilities.shape != outcomes.shape:
        raise ValueError(f"reliability_table: {probabilities.size} probabilities but {outcomes.size} outcomes")
    if not np.all(np.isfinite(probabilities)) or np.any(probabilities < -_PROBABILITY_TOLERANCE) \
            or np.any(probabilities > 1.0 + _PROBABILITY_TOLERANCE):
        raise ValueError(f"reliability_table: probabilities must lie in [0, 1], got values from "
                         f"{np.min(probabilities)!r} to {np.max(probabilities)!r}")
    if not np.all((outcomes == 0.0) | (outcomes == 1.0)):
        raise ValueError("reliability_table: outcomes must be 0 or 1")
    if bins < 1:
        raise ValueError(f"reliability_table: bins must be >= 1, got {bins}")
    probabilities = np.clip(probabilities, 0.0, 1.0)
    edges = np.linspace(0.0, 1.0, bins + 1)
    return np.stack([
        np.histogram(probabilities, bins=edges)[0].astype(float),
        np.histogram(probabilities, bins=edges, weights=probabilities)[0],
        np.histogram(probabilities, bins=edges, weights=outcomes)[0],
    ], axis=1)


def pooled_reliability(tables: Iterable) -> np.ndarray:
    """The sum of reliability tables (arrays, or their JSON as in the ``reliability`` column); NaN entries skipped.

    Raises ``ValueError`` when there is no table to pool or the tables have different numbers of bins.
    """
    total = None
    for table in tables:
        if table is None or (isinstance(table, float) and np.isnan(table)):
            continue
        array = np.asarray(json.loads(table) if isinstance(table, str) else table, dtype=float)
        if array.ndim != 2 or array.shape[1] != 3:
            raise ValueError(f"a reliability table has shape (bins, 3), got {array.shape}")
        if total is not None and array.shape != total.shape:
            raise ValueError(f"reliability tables of {total.shape[0]} and {array.shape[0]} bins cannot be pooled")
        total = array if total is None else total + array
    if total is None:
        raise ValueError("pooled_reliability: no reliability table to pool")
    return total


def expected_calibration_error(table) -> float:
    """ECE = sum_b (n_b / n) |mean p_b - mean y_b| of a reliability table (array or JSON); NaN when n = 0."""
    table = np.asarray(json.loads(table) if isinstance(table, str) else table, dtype=float)
    total = table[:, 0].sum()
    if total == 0.0:
        return nan
    # (n_b / n) |s_b / n_b - o_b / n_b| = |s_b - o_b| / n, and empty bins add 0.
    return float(np.abs(table[:, 1] - table[:, 2]).sum() / total)


def calibration_scores(distribution, truth, coassignment=None) -> dict:
    """The calibration columns of a row: Brier score, pairs, reliability table (JSON), log score, confidently wrong.

    * ``n_pairs``: N (N - 1) / 2, the pairs i < j scored;
    * ``brier``: mean over the pairs of (p_ij - y_ij)^2 (NaN without pairs);
    * ``ece``: the expected calibration error of this cell's pairs alone (NaN without pairs);
    * ``reliability``: JSON ``[[n_b, sum p, sum y], ...]`` over :data:`RELIABILITY_BINS` bins;
    * ``log_score``: log max(P(truth), :data:`LOG_SCORE_FLOOR`);
    * ``map_mass``: the probability of the most probable topology;
    * ``confidently_wrong``: ``map_mass`` >= :data:`CONFIDENT` and the MAP is not the truth.
    """
    truth = canonical(truth)
    result = as_ptm(distribution, n=len(truth))
    return _calibration(result, truth, result.coassignment() if coassignment is None else coassignment)


def _calibration(result: ptm.PTM, truth: tuple[int, ...], coassignment) -> dict:
    matrix = np.asarray(coassignment, dtype=float)
    n = len(truth)
    if matrix.shape != (n, n):
        raise ValueError(f"coassignment must have shape ({n}, {n}), got {matrix.shape}")
    upper = np.triu_indices(n, k=1)
    labels = np.asarray(truth)
    predicted = matrix[upper]
    outcomes = (labels[:, None] == labels[None, :])[upper].astype(float)
    table = reliability_table(predicted, outcomes)
    clipped = np.clip(predicted, 0.0, 1.0)
    map_mass = float(result.probabilities[0])
    return {
        "n_pairs": int(predicted.size),
        "brier": float(np.mean((clipped - outcomes) ** 2)) if predicted.size else nan,
        "ece": expected_calibration_error(table),
        "reliability": json.dumps(table.tolist()),
        "log_score": log(max(result.probability(truth), LOG_SCORE_FLOOR)),
        "map_mass": map_mass,
        "confidently_wrong": bool(map_mass >= CONFIDENT and result.map() != truth),
    }


def score(distribution, truth, threshold: float = 0.5, coassignment=None) -> dict:
    """Every accuracy and calibration score of one distribution over partitions against the true labels.

    ``distribution`` is a ``ptm.PTM`` or a ``{labels: probability}`` dict (:func:`as_ptm`); the MAP is
    ``PTM.map()`` (of tied topologies, the lexicographically smallest labels). ``coassignment`` may pass
    the co-assignment matrix when it is already known, instead of recomputing it here. The calibration
    columns are those of :func:`calibration_scores`.
    """
    truth = canonical(truth)
    result = as_ptm(distribution, n=len(truth))
    map_labels = result.map()
    rank = result.rank(truth)
    row = {
        "gt_mass": result.probability(truth),
        "gt_rank": nan if rank is None else rank,
        "map_correct": map_labels == truth,
        "ari": adjusted_rand_index(map_labels, truth),
        "n_measurements": len(truth),
        "expected_places": result.expected_num_places(),
        "true_places": max(truth) + 1,
        "map_places": max(map_labels) + 1,
        "n_topologies": len(result),
    }
    if coassignment is None:
        coassignment = result.coassignment()
    row.update(loop_closure_scores(coassignment, truth, threshold))
    row.update(_calibration(result, truth, coassignment))
    return row
