"""Peer ``gnc``: graduated non-convexity with a truncated-least-squares loss over the candidates (GTSAM).

Yang et al. (2020), as roboticists run it for loop-closure outlier rejection:
GTSAM's ``GncLMOptimizer`` over the Pose2 graph of
:mod:`~ptm_bench.evaluation.peers.pose_graph`, the prior and the odometry rows
declared known inliers, every candidate tie subject to the TLS loss. A tie is
an inlier while its factor cost (half its squared Mahalanobis distance) stays
under c^2 = chi2_2^-1(p) / 2, p the setting ``inlier_probability`` (2 degrees
of freedom: the tie's two position axes; its heading is free). GNC starts
from the convex surrogate of the loss and tightens it step by step to the
TLS loss, each step a Levenberg-Marquardt solve, so the weights end at 0 or
1. A candidate's score is its final weight; it is accepted where the weight
exceeds 0.5.

    >>> import numpy as np, ptm
    >>> from ptm_bench.evaluation.peers.noise import PeerNoise
    >>> square = np.tile([2.0, 0.0, np.pi / 2], (4, 1))          # a 2 m square driven once, back at the start
    >>> dataset = ptm.Dataset(odometry=square, signatures=[[0.0], [1.0], [2.0], [3.0], [0.05]])
    >>> run(dataset, PeerNoise(0.05, 0.02, 0.3), GncSettings(k=1)).labels
    (0, 1, 2, 3, 0)
"""

from __future__ import annotations

import time
from dataclasses import asdict, dataclass, replace

from scipy.stats import chi2

from ptm_bench.evaluation.peers.candidates import DEFAULT_K, CandidateSettings, candidate_grid, candidate_pairs
from ptm_bench.evaluation.peers.pose_graph import import_gtsam, tie_graph
from ptm_bench.evaluation.peers.result import PeerResult

__all__ = ["GncSettings", "grid", "run"]

#: Weights of the TLS loss end at 0 or 1; a candidate is accepted above this.
ACCEPT_WEIGHT = 0.5


@dataclass(frozen=True)
class GncSettings:
    """Candidates (``k``, ``gate`` in tie sigmas) and the TLS inlier threshold as a chi-square probability."""

    k: int = DEFAULT_K
    gate: float | None = None
    inlier_probability: float = 0.99

    def __post_init__(self):
        CandidateSettings(self.k, self.gate)
        if not 0.0 < self.inlier_probability < 1.0:
            raise ValueError(f"gnc setting inlier_probability must be in (0, 1), got {self.inlier_probability!r}")


def grid(with_signatures: bool) -> tuple[GncSettings, ...]:
    """The settings calibration tries: every candidate setting (``candidate_grid``) x inlier probability 0.99
    (the default), 0.9, 0.999."""
    return tuple(GncSettings(c.k, c.gate, p) for c in candidate_grid(with_signatures) for p in (0.99, 0.9, 0.999))


def run(dataset, noise, settings: GncSettings = GncSettings()) -> PeerResult:
    """Candidates, then GNC-TLS over them; a solver failure is a failed result with its message."""
    started = time.perf_counter()
    pairs = candidate_pairs(dataset, CandidateSettings(settings.k, settings.gate), noise.sigma_tie)
    if len(pairs) == 0:
        result = PeerResult.from_candidates("gnc", asdict(settings), dataset.n, pairs, [], [])
    else:
        gtsam = import_gtsam()
        graph = tie_graph(dataset, noise, pairs)
        params = gtsam.GncLMParams(gtsam.LevenbergMarquardtParams())  # GTSAM's defaults, as a user runs it
        params.setLossType(gtsam.GncLossType.TLS)
        params.setKnownInliers(graph.known_inliers)
        try:
            optimizer = gtsam.GncLMOptimizer(graph.graph, graph.initial, params)
            optimizer.setInlierCostThresholds(0.5 * chi2.ppf(settings.inlier_probability, 2))
            optimizer.optimize()
            weights = optimizer.getWeights()[len(graph.known_inliers):]
        except RuntimeError as error:  # how GTSAM's exceptions (an indeterminant linear system, ...) reach Python
            result = PeerResult.failure("gnc", asdict(settings), pairs, f"gnc: GTSAM failed: {error}")
        else:
            result = PeerResult.from_candidates("gnc", asdict(settings), dataset.n, pairs, weights,
                                                weights > ACCEPT_WEIGHT)
    return replace(result, wall_s=time.perf_counter() - started)
