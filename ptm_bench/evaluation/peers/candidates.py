"""The candidate front end every peer shares: which pairs of detections a back end may close (docs/model.md §6).

A robust back end decides which of a few proposed loop closures are real; it
never sees every pair. As place recognition proposes them on a robot, the
candidates are

* with signatures: each detection's ``k`` nearest neighbours in appearance
  (Euclidean distance between signatures), among the detections whose
  dead-reckoned position lies within ``gate`` tie sigmas of its own when a
  gate is set (the search radius of a place recogniser that trusts the
  odometry that far), else among all detections. The union over detections,
  as unordered pairs: a pair is proposed when either end ranks the other
  among its ``k`` nearest;
* without signatures: every pair whose dead-reckoned positions lie within
  ``gate`` tie sigmas (a gate is then required).

A detection is never paired with itself. Consecutive detections are kept:
a robot can fire twice at one place (it turned back at a dead end, or a
detector fired on the way in and out; the real logs have such pairs), and
the odometry factor between them is what lets a back end reject the
candidate where they are not. Ties in distance go to the smaller index
(a stable sort), so the candidates are a deterministic function of the
dataset and the settings.

    >>> import numpy as np, ptm
    >>> dataset = ptm.Dataset(odometry=np.tile([1.0, 0.0, 0.0], (3, 1)), signatures=[[0.0], [5.0], [0.1], [5.2]])
    >>> candidate_pairs(dataset, CandidateSettings(k=1), sigma_tie=1.0).tolist()
    [[0, 2], [1, 3]]
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ptm.se2 import dead_reckoning

__all__ = ["DEFAULT_K", "CandidateSettings", "candidate_grid", "candidate_pairs", "dead_reckoned_distances"]

#: Nearest neighbours in appearance proposed per detection: a place revisited three to five times is then
#: proposed whole from any one of its visits, and the pairs stay linear in N (the back ends' cost).
DEFAULT_K = 4


@dataclass(frozen=True)
class CandidateSettings:
    """``k`` nearest neighbours in appearance per detection; ``gate``: the dead-reckoned distance gate in tie
    sigmas (None: no gate)."""

    k: int = DEFAULT_K
    gate: float | None = None

    def __post_init__(self):
        if isinstance(self.k, bool) or not isinstance(self.k, int) or self.k < 1:
            raise ValueError(f"candidate setting k must be a positive integer, got {self.k!r}")
        if self.gate is not None and (not isinstance(self.gate, (int, float)) or not math.isfinite(self.gate)
                                      or self.gate <= 0):
            raise ValueError(f"candidate setting gate must be None or a positive number of tie sigmas, "
                             f"got {self.gate!r}")


def candidate_grid(with_signatures: bool) -> tuple[CandidateSettings, ...]:
    """The front-end settings calibration tries, the default first.

    With signatures: k = 4, 2, 8 nearest neighbours, ungated or within 16 tie
    sigmas (a place recogniser that trusts the odometry to about 11 detection
    radii). Without: every pair within 4, 2 or 8 tie sigmas (two detections of
    one place lie within 2r = 2.8 tie sigmas of each other before any drift).
    """
    if with_signatures:
        return tuple(CandidateSettings(k, gate) for gate in (None, 16.0) for k in (DEFAULT_K, 2, 8))
    return tuple(CandidateSettings(DEFAULT_K, gate) for gate in (4.0, 2.0, 8.0))


def dead_reckoned_distances(dataset) -> np.ndarray:
    """(N, N) distances [m] between the detections' positions composed from the odometry alone (paper eq. 3)."""
    if dataset.odometry is None:
        raise ValueError("the peers need a dataset with odometry (dataset.odometry is None)")
    positions = dead_reckoning(dataset.odometry)[:, :2]
    return np.linalg.norm(positions[:, None, :] - positions[None, :, :], axis=2)


def candidate_pairs(dataset, settings: CandidateSettings, sigma_tie: float) -> np.ndarray:
    """(P, 2) int array of candidate pairs i < j, sorted; ``sigma_tie`` [m] scales the gate."""
    n = dataset.n
    within = None
    if settings.gate is not None or dataset.signatures is None:
        if settings.gate is None:
            raise ValueError("a dataset without signatures needs a candidate gate (all pairs within it are proposed)")
        within = dead_reckoned_distances(dataset) <= settings.gate * sigma_tie
    if dataset.signatures is None:
        first, second = np.nonzero(np.triu(within, k=1))
        return np.column_stack([first, second]).astype(np.int64)
    signatures = np.asarray(dataset.signatures, dtype=float)
    distances = np.linalg.norm(signatures[:, None, :] - signatures[None, :, :], axis=2)
    np.fill_diagonal(distances, np.inf)
    if within is not None:
        distances[~within] = np.inf
    k = min(settings.k, n - 1)
    order = np.argsort(distances, axis=1, kind="stable")[:, :k]  # stable: equal distances keep index order
    rows = np.repeat(np.arange(n), k)
    columns = order.ravel()
    keep = np.isfinite(distances[rows, columns])
    pairs = np.sort(np.column_stack([rows[keep], columns[keep]]), axis=1)
    return np.unique(pairs, axis=0).astype(np.int64).reshape(-1, 2)
