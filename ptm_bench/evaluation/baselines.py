"""Baselines that commit to one topology, scored like a PTM (docs/model.md §6).

Both baselines are the same greedy rule on different features: detections are
taken in time order, and each joins the nearest existing place (the running
mean of its detections' features) if that is closer than a threshold, or
opens a new place otherwise.

* ``greedy_odometry``: the features are the dead-reckoned positions, the
  odometry increments composed on SE(2) from the origin (paper eq. 3 without
  noise) — nearest-landmark data association on raw odometry.
* ``appearance_threshold``: the features are the appearance signatures.

The threshold is not tuned on the data being scored: :func:`fit_threshold`
picks the one with the best mean adjusted Rand index on labelled calibration
datasets (the held-out calibration seeds), from the candidate distances
those datasets offer.

    >>> import numpy as np, ptm
    >>> features = BASELINE_FEATURES["appearance_threshold"]
    >>> held_out = [ptm.Dataset(signatures=[[0.0], [5.0], [0.2], [5.1]], labels=[0, 1, 0, 1])]
    >>> threshold = fit_threshold(held_out, features)
    >>> greedy_threshold_labels(np.array([[0.1], [4.9], [9.8], [0.3]]), threshold)
    (0, 1, 2, 0)
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

import numpy as np

from ptm.partitions import canonical
from ptm.se2 import dead_reckoning

from ptm_bench.evaluation.scoring import adjusted_rand_index

__all__ = ["BASELINE_FEATURES", "fit_threshold", "greedy_threshold_labels"]

_MAX_CANDIDATES = 64


def _positions(dataset) -> np.ndarray:
    if dataset.odometry is None:
        raise ValueError("the greedy_odometry baseline needs a dataset with odometry")
    return dead_reckoning(dataset.odometry)[:, :2]


def _signatures(dataset) -> np.ndarray:
    if dataset.signatures is None:
        raise ValueError("the appearance_threshold baseline needs a dataset with signatures")
    return dataset.signatures


#: Baseline name -> the features it clusters, as a function of a ``ptm.Dataset``.
BASELINE_FEATURES: dict[str, Callable] = {
    "greedy_odometry": _positions,
    "appearance_threshold": _signatures,
}


def greedy_threshold_labels(features, threshold: float) -> tuple[int, ...]:
    """Assign each detection, in order, to the nearest place mean closer than ``threshold``, else a new place."""
    features = np.asarray(features, dtype=float)
    if features.ndim != 2 or len(features) == 0:
        raise ValueError(f"features must be a non-empty (N, D) array, got shape {features.shape}")
    if not np.isfinite(threshold) or threshold < 0:
        raise ValueError(f"threshold must be a finite non-negative distance, got {threshold!r}")
    sums, counts, labels = [], [], []
    for feature in features:
        if sums:
            distances = np.linalg.norm(np.array(sums) / np.array(counts)[:, None] - feature, axis=1)
            nearest = int(np.argmin(distances))
            if distances[nearest] < threshold:
                sums[nearest] = sums[nearest] + feature
                counts[nearest] += 1
                labels.append(nearest)
                continue
        sums.append(feature.copy())
        counts.append(1)
        labels.append(len(sums) - 1)
    return canonical(labels)


def fit_threshold(datasets: Sequence, features: Callable) -> float:
    """The threshold with the best mean ARI against the ground truth of labelled calibration datasets.

    Candidates are 0 and quantiles of the pairwise feature distances within
    each calibration dataset; ties go to the smallest threshold.
    """
    if not datasets:
        raise ValueError("fit_threshold needs at least one labelled calibration dataset")
    points = []
    for index, dataset in enumerate(datasets):
        if dataset.labels is None:
            raise ValueError(f"calibration dataset {index} has no labels")
        points.append(np.asarray(features(dataset), dtype=float))
    distances = np.concatenate([
        np.linalg.norm(block[:, None, :] - block[None, :, :], axis=2)[np.triu_indices(len(block), k=1)]
        for block in points
    ])
    # A threshold just above a distance admits that pair; nudging by a relative 1e-9 keeps the candidates distinct.
    quantiles = np.quantile(distances, np.linspace(0, 1, _MAX_CANDIDATES)) * (1 + 1e-9)
    candidates = np.unique(np.concatenate([[0.0], quantiles]))
    mean_ari = [
        np.mean([adjusted_rand_index(greedy_threshold_labels(block, threshold), dataset.labels)
                 for block, dataset in zip(points, datasets)])
        for threshold in candidates
    ]
    return float(candidates[int(np.argmax(mean_ari))])
