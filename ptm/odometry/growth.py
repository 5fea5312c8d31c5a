"""Online growth of the odometry term: the run one detection longer starts fits from the shorter run's modes
(docs/model.md §3.3, step 3, "Determinism"; §3.8).

The online mapper binds its models anew after every detection. For a partition whose last detection is a
place of its own, that detection is a leaf of the pose graph, held by its odometry row alone with zero
residual: the minima of E are those of the run one detection shorter with the leaf composed on, and both
starts of the fit (:mod:`ptm.odometry.laplace`) are the shorter run's starts with the leaf composed on. So a
term grown from the shorter one (:meth:`ptm.odometry.OdometryTerm.grown`) starts such a fit from the shorter
run's converged mode with the leaf composed on (:class:`ShorterRun`), and the Newton steps only polish it: a
few factorisations instead of two fits from the starts. The value then agrees with the fit from the starts
to the solver's tolerance, not to the bit.

    >>> from ptm import Dataset
    >>> shorter, longer = Dataset(odometry=[[1.0, 0.0, 0.5]]), Dataset(odometry=[[1.0, 0.0, 0.5], [2.0, 0.0, 0.0]])
    >>> extends_by_one(shorter, longer), extends_by_one(longer, shorter)
    (True, False)
    >>> run = ShorterRun({(0, 1): np.array([1.0, 0.0, 0.5])}, last_row=longer.odometry[-1])
    >>> run.start(np.array([0, 1, 2])).round(3)                         # the leaf composed onto the mode
    array([1.   , 0.   , 0.5  , 2.755, 0.959, 0.5  ])
    >>> run.start(np.array([0, 1, 0])) is None                          # the last detection joins a set
    True
"""

from __future__ import annotations

import numpy as np

from ..partitions import canonical
from ..se2 import compose

__all__ = ["ShorterRun", "extends_by_one"]


def extends_by_one(shorter, longer) -> bool:
    """Whether the dataset ``longer`` extends the run of ``shorter`` by one detection, with the same odometry
    rows and covariances."""
    rows = shorter.n - 1
    before, after = shorter.odometry_cov, longer.odometry_cov
    return bool(longer.odometry is not None and longer.n == shorter.n + 1
                and np.array_equal(longer.odometry[:rows], shorter.odometry)
                and (rows == 0 or (before is None) == (after is None))
                and (before is None or np.array_equal(after[:rows], before)))


class ShorterRun:
    """The converged Laplace modes of the run one detection shorter, by canonical partition (any mapping with
    ``get``, such as the shorter term's memo), and ``last_row``, the odometry row that reaches the new
    detection."""

    def __init__(self, modes, last_row):
        self.modes = modes
        self.last_row = np.asarray(last_row, dtype=float)

    def start(self, labels) -> np.ndarray | None:
        """The shorter run's converged mode of ``labels[:-1]`` with the last pose composed onto it by the last
        odometry row, where the last detection of ``labels`` (an (N,) array) is a place of its own and that
        mode is remembered; else None."""
        if labels[-1] in labels[:-1]:
            return None
        mode = self.modes.get(canonical(labels[:-1]))
        if mode is None:
            return None
        last_pose = mode[-3:] if len(mode) else np.zeros(3)
        return np.concatenate([mode, compose(last_pose, self.last_row)])
