"""Measured aliasing: how well appearance alone tells places apart in one dataset (docs/model.md §5, §6).

The aliasing knob a in [0, 1] sets how many distinct decors the places get;
what inference meets is how alike the *signatures* are. The measured
aliasing of a dataset is the area under the ROC curve with which the
Euclidean distance between two detections' signatures separates pairs taken
at different places from pairs taken at the same place:

    AUC = P(d(i, j) > d(k, l) | i, j at different places, k, l at one place)
          (ties count one half; the Mann-Whitney U statistic over n_diff * n_same)

1 means every different-place pair is farther apart than every same-place
pair (perfectly separable), 0.5 means signature distance carries no
information about the place. False detections (negative labels) are left
out. NaN when the dataset has no revisit or only one place.

    >>> float(signature_auc([[0.0], [0.1], [1.0], [1.1]], [0, 0, 1, 1]))    # places apart: separable
    1.0
    >>> float(signature_auc([[0.5], [0.5], [0.5], [0.5]], [0, 0, 1, 1]))    # every place looks alike: chance
    0.5
"""

from __future__ import annotations

import math

import numpy as np
from scipy.spatial.distance import pdist
from scipy.stats import mannwhitneyu

__all__ = ["signature_auc"]


def signature_auc(signatures, labels) -> float:
    """AUC of signature distance for different-place vs same-place detection pairs (NaN if undefined)."""
    signatures = np.asarray(signatures, dtype=float)
    labels = np.asarray(labels)
    if signatures.ndim != 2 or labels.shape != (signatures.shape[0],):
        raise ValueError(f"signatures must be (N, K) and labels (N,), got {signatures.shape} and {labels.shape}")
    real = labels >= 0
    signatures, labels = signatures[real], labels[real]
    if labels.size < 2:
        return math.nan
    distances = pdist(signatures)
    same = pdist(labels[:, None], lambda u, v: float(u[0] == v[0])).astype(bool)
    if same.all() or not same.any():
        return math.nan
    statistic = mannwhitneyu(distances[~same], distances[same], alternative="two-sided").statistic
    return float(statistic) / (np.count_nonzero(~same) * np.count_nonzero(same))
