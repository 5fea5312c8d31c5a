"""The noise every peer assumes: per-step odometry covariances and the tie sigma (docs/model.md §3.3, §6).

The peers read the same noise as the posterior, so that a difference in the
scores is a difference of method, not of knowledge: a step's covariance is the
dataset's ``odometry_cov`` where it has one, else diag(sigma_xy^2, sigma_xy^2,
sigma_theta^2) (the configured sigmas); two detections of one place differ by
the tie sigma sigma_T per axis, the posterior's rule for it
(:func:`ptm_bench.evaluation.calibration.topology_sigma`: configured, else the
detector's radius r / sqrt 2 from the sensor specification in the dataset's meta).

    >>> noise = PeerNoise.from_meta({"detection_radius": 1.5}, sigma_xy=0.1, sigma_theta=0.05)
    >>> round(noise.sigma_tie, 4)
    1.0607
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ptm_bench.evaluation.calibration import topology_sigma

__all__ = ["PeerNoise"]


@dataclass(frozen=True)
class PeerNoise:
    """Odometry sigmas [m, rad] for datasets without ``odometry_cov``, and the tie sigma sigma_T [m]."""

    sigma_xy: float
    sigma_theta: float
    sigma_tie: float

    def __post_init__(self):
        for name in ("sigma_xy", "sigma_theta", "sigma_tie"):
            value = getattr(self, name)
            if not isinstance(value, (int, float)) or not math.isfinite(value) or value <= 0:
                raise ValueError(f"PeerNoise.{name} must be a positive finite number, got {value!r}")

    @classmethod
    def from_meta(cls, meta: dict, sigma_xy: float, sigma_theta: float, sigma_tie: float | None = None) -> "PeerNoise":
        """The configured ``sigma_tie`` (``odometry.sigma_topology``), else the posterior's sensor-specification
        rule (:func:`~ptm_bench.evaluation.calibration.topology_sigma`: r / sqrt 2 from meta ``detection_radius``)."""
        return cls(float(sigma_xy), float(sigma_theta), topology_sigma(sigma_tie, meta)[0])

    def step_covariances(self, dataset) -> np.ndarray:
        """(N-1, 3, 3) covariances of the odometry rows: ``dataset.odometry_cov``, else the configured sigmas."""
        if dataset.odometry is None:
            raise ValueError("the peers need a dataset with odometry (dataset.odometry is None)")
        if dataset.odometry_cov is not None:
            return np.asarray(dataset.odometry_cov, dtype=float)
        variances = np.diag([self.sigma_xy ** 2, self.sigma_xy ** 2, self.sigma_theta ** 2])
        return np.broadcast_to(variances, (len(dataset.odometry), 3, 3)).copy()
