"""How well odometry rows' covariances describe their errors: the normalised error against a reference.

Each row's error r_k = (reference motion) - (odometry row), the angle wrapped
(the residual of the pose graph at the reference poses, docs/model.md §3.3,
eq. 3), whitened by its covariance: q_k = r_k^T Sigma_k^-1 r_k / 3. Its mean
is 1 where the covariances are right, above 1 where they are too tight and
below where they are too wide (the normalised estimation error squared per
dimension). The importer prints it for every log and uses it on a log's
calibration drive (:func:`ptm_bench.logs.noise_fit.calibrate_on_drive`).

    >>> import numpy as np
    >>> rows, reference = np.array([[1.0, 0.0, 0.0]]), np.array([[1.2, 0.0, 0.1]])
    >>> normalised_errors(rows, np.diag([0.04, 0.04, 0.01])[None], reference).round(6)  # (1 + 0 + 1) / 3
    array([0.666667])
"""

from __future__ import annotations

import numpy as np

from ptm.se2 import relative_pose, wrap_angle

__all__ = ["normalised_errors", "row_normalised_error"]


def normalised_errors(rows, covariances, reference_rows) -> np.ndarray:
    """(K,) r_k^T Sigma_k^-1 r_k / 3 of odometry ``rows`` (K, 3) with ``covariances`` (K, 3, 3) against the
    motion ``reference_rows`` (K, 3) of a reference over the same stretches."""
    error = np.asarray(reference_rows, dtype=float) - np.asarray(rows, dtype=float)
    error[:, 2] = wrap_angle(error[:, 2])
    whitened = np.linalg.solve(np.asarray(covariances, dtype=float), error[:, :, None])[:, :, 0]
    return np.einsum("ka,ka->k", error, whitened) / 3.0


def row_normalised_error(dataset) -> float:
    """The mean of :func:`normalised_errors` over a dataset's odometry rows against its true poses."""
    if dataset.odometry is None or dataset.odometry_cov is None or dataset.true_poses is None:
        raise ValueError("the normalised row error needs a dataset with odometry, odometry_cov and true_poses")
    if not len(dataset.odometry):
        raise ValueError("the normalised row error needs at least one odometry row")
    reference = relative_pose(dataset.true_poses[:-1], dataset.true_poses[1:])
    return float(np.mean(normalised_errors(dataset.odometry, dataset.odometry_cov, reference)))
