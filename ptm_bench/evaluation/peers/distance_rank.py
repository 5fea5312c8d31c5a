"""Peer ``distance_rank``: pairs ranked by their dead-reckoned distance alone (docs/model.md §6).

The floor of what odometry says without any inference: every pair of
detections is scored by how close the odometry composed from the start
(paper eq. 3) puts them, nearer first, and average precision is taken over
all pairs. Its partition joins the pairs closer than ``threshold`` tie sigmas
(the connected components, single linkage), the threshold calibrated on
held-out runs like every peer's settings.

    >>> import numpy as np, ptm
    >>> from ptm_bench.evaluation.peers.noise import PeerNoise
    >>> square = np.tile([2.0, 0.0, np.pi / 2], (4, 1))          # a 2 m square driven once, back at the start
    >>> run(ptm.Dataset(odometry=square), PeerNoise(0.05, 0.02, 0.3), DistanceRankSettings(threshold=2.0)).labels
    (0, 1, 2, 3, 0)
"""

from __future__ import annotations

import math
import time
from dataclasses import asdict, dataclass, replace

import numpy as np

from ptm_bench.evaluation.peers.candidates import dead_reckoned_distances
from ptm_bench.evaluation.peers.result import PeerResult, closure_labels

__all__ = ["DistanceRankSettings", "grid", "run"]


@dataclass(frozen=True)
class DistanceRankSettings:
    """Pairs closer than ``threshold`` tie sigmas (dead-reckoned) are joined."""

    threshold: float = 2.0

    def __post_init__(self):
        if not isinstance(self.threshold, (int, float)) or not math.isfinite(self.threshold) or self.threshold <= 0:
            raise ValueError(f"distance_rank setting threshold must be a positive number of tie sigmas, "
                             f"got {self.threshold!r}")


def grid(with_signatures: bool) -> tuple[DistanceRankSettings, ...]:
    """The thresholds calibration tries: 2 tie sigmas (the default), then 0.5 to 16; signatures play no part."""
    return tuple(DistanceRankSettings(t) for t in (2.0, 0.5, 1.0, 1.5, 3.0, 4.0, 6.0, 8.0, 12.0, 16.0))


def run(dataset, noise, settings: DistanceRankSettings = DistanceRankSettings()) -> PeerResult:
    """Every pair scored by minus its dead-reckoned distance; the pairs under the threshold joined."""
    started = time.perf_counter()
    distances = dead_reckoned_distances(dataset)
    first, second = np.triu_indices(dataset.n, k=1)
    pairs = np.column_stack([first, second])
    close = distances[first, second] <= settings.threshold * noise.sigma_tie
    result = PeerResult(peer="distance_rank", settings=asdict(settings),
                        labels=closure_labels(dataset.n, pairs[close]), pairs=pairs,
                        scores=-distances[first, second], accepted=close, pair_scores=-distances)
    return replace(result, wall_s=time.perf_counter() - started)
