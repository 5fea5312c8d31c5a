"""The standard deviations the odometry likelihood can compute with, relative to the odometry's own scale
(docs/model.md §3.3, "Parameters").

The pose graph holds positions and headings of the size of the odometry's dead-reckoned poses, their scale
c = max(1, largest |coordinate| [m or rad]), so each coordinate carries a rounding error of about 2^-52 c.
A step covariance or a tie whose standard deviation is not much larger than that weighs rounding noise: at
1e-100 x I the posterior of a 2 m square was flat over seven topologies, the truth not among them. One whose
standard deviation dwarfs the whole route carries no information the pose graph's Hessian can keep beside
the ties. Every standard deviation -- the square roots of each ``odometry_cov`` row's eigenvalues, else
``sigma_xy`` and ``sigma_theta``, and ``sigma_topology`` -- must therefore lie in ``STD_RANGE`` x c (and
below 1e150, so that its square is a float); :func:`step_covariances` refuses the rest with a
``ValueError`` naming the field and the row.

    >>> import numpy as np
    >>> from ptm import Dataset, OdometryModel
    >>> steps = np.tile([2.0, 0.0, np.pi / 2], (4, 1))
    >>> step_covariances(OdometryModel(), Dataset(odometry=steps)).shape
    (4, 3, 3)
    >>> step_covariances(OdometryModel(), Dataset(odometry=steps, odometry_cov=np.tile(1e-100 * np.eye(3), (4, 1, 1))))
    Traceback (most recent call last):
    ...
    ValueError: odometry_cov[0] has standard deviations from 1e-50 to 1e-50, outside [6.28e-12, 6.28e+06], ...
"""

from __future__ import annotations

import numpy as np

from ..se2 import dead_reckoning

__all__ = ["STD_RANGE", "step_covariances"]

#: Standard deviations allowed, as multiples of the odometry's scale c: at 1e-12 c the rounding of the poses
#: is 2e-4 standard deviations.
STD_RANGE = (1e-12, 1e6)
#: No standard deviation may exceed this, whatever the scale: its square must stay a float.
LARGEST_STD = 1e150


def step_covariances(model, dataset) -> np.ndarray:
    """The (N-1, 3, 3) covariances of ``dataset``'s odometry steps: its ``odometry_cov``, else
    diag(sigma_xy^2, sigma_xy^2, sigma_theta^2) of ``model``; ``ValueError`` naming the field (and the row)
    where a standard deviation of a step or ``model.sigma_topology`` lies outside ``STD_RANGE`` x the scale."""
    poses = dead_reckoning(dataset.odometry)
    scale = max(1.0, float(np.max(np.abs(poses))))
    if not np.isfinite(scale):
        raise ValueError("odometry: its dead-reckoned poses overflow (a step of about 1e308 m or more)")
    low, high = STD_RANGE[0] * scale, min(STD_RANGE[1] * scale, LARGEST_STD)
    where = (f"outside [{low:.3g}, {high:.3g}], STD_RANGE = ({STD_RANGE[0]:g}, {STD_RANGE[1]:g}) x the odometry's "
             f"scale {scale:.3g} (its largest dead-reckoned coordinate, at least 1): beyond, the likelihood is "
             "rounding noise")
    names = ("sigma_topology",) + (("sigma_xy", "sigma_theta") if dataset.odometry_cov is None else ())
    for name in names:
        value = getattr(model, name)
        if not low <= value <= high:
            raise ValueError(f"{name} = {value:.3g} is {where}")
    if dataset.odometry_cov is None:
        variances = [model.sigma_xy**2, model.sigma_xy**2, model.sigma_theta**2]
        return np.broadcast_to(np.diag(variances), (len(dataset.odometry), 3, 3))
    deviations = np.sqrt(np.maximum(np.linalg.eigvalsh(dataset.odometry_cov), 0.0))  # ascending per row
    outside = np.flatnonzero((deviations[:, 0] < low) | (deviations[:, -1] > high))
    if outside.size:
        row = int(outside[0])
        raise ValueError(f"odometry_cov[{row}] has standard deviations from {deviations[row, 0]:.3g} to "
                         f"{deviations[row, -1]:.3g}, {where}")
    return dataset.odometry_cov
