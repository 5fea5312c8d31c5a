"""Peer ``dcs``: dynamic covariance scaling on the candidates, Levenberg-Marquardt (GTSAM).

Agarwal et al. (2013): the Pose2 graph of :mod:`~ptm_bench.evaluation.peers.pose_graph`
with each candidate tie's noise wrapped in GTSAM's
``noiseModel.mEstimator.DCS(phi)``, solved from dead reckoning by
Levenberg-Marquardt (GTSAM's defaults). DCS scales a tie of squared
Mahalanobis distance chi^2 by s = min(1, 2 phi / (phi + chi^2)), so its
weight s^2 falls from 1 once chi^2 passes phi; the odometry and the prior
keep their Gaussian noise.

A candidate's score is its final weight s^2. It is accepted where the tie
closes within the chi-square bound at the solution, chi^2 <= chi2_2^-1(p),
p the setting ``accept_probability`` (as ``gnc`` and ``pcm`` bound theirs):
``phi`` says how hard the solver is pulled, ``accept_probability`` what
counts as a closure. A fixed weight threshold such as s^2 > 0.5 would tie the
two together (chi^2 < 1.83 phi) and reject 40 % of true ties at phi = 1.

    >>> import numpy as np, ptm
    >>> from ptm_bench.evaluation.peers.noise import PeerNoise
    >>> square = np.tile([2.0, 0.0, np.pi / 2], (4, 1))          # a 2 m square driven once, back at the start
    >>> dataset = ptm.Dataset(odometry=square, signatures=[[0.0], [1.0], [2.0], [3.0], [0.05]])
    >>> run(dataset, PeerNoise(0.05, 0.02, 0.3), DcsSettings(k=1)).labels
    (0, 1, 2, 3, 0)
"""

from __future__ import annotations

import time
from dataclasses import asdict, dataclass, replace

import numpy as np
from scipy.stats import chi2

from ptm_bench.evaluation.peers.candidates import DEFAULT_K, CandidateSettings, candidate_grid, candidate_pairs
from ptm_bench.evaluation.peers.pose_graph import import_gtsam, tie_chi2, tie_graph
from ptm_bench.evaluation.peers.result import PeerResult

__all__ = ["DcsSettings", "grid", "run"]

#: Levenberg-Marquardt iterations before a run is reported as not converged.
LM_MAX_ITERATIONS = 100


@dataclass(frozen=True)
class DcsSettings:
    """Candidates (``k``, ``gate`` in tie sigmas), the DCS constant ``phi`` (a squared Mahalanobis distance) and
    the acceptance bound as a chi-square probability."""

    k: int = DEFAULT_K
    gate: float | None = None
    phi: float = 1.0
    accept_probability: float = 0.99

    def __post_init__(self):
        CandidateSettings(self.k, self.gate)
        if not isinstance(self.phi, (int, float)) or not np.isfinite(self.phi) or self.phi <= 0:
            raise ValueError(f"dcs setting phi must be a positive number, got {self.phi!r}")
        if not 0.0 < self.accept_probability < 1.0:
            raise ValueError(f"dcs setting accept_probability must be in (0, 1), got {self.accept_probability!r}")


def grid(with_signatures: bool) -> tuple[DcsSettings, ...]:
    """The settings calibration tries: every candidate setting (``candidate_grid``) x phi 1 (the default,
    Agarwal et al.'s), 3, 10 x acceptance probability 0.99 (the default), 0.9, 0.999."""
    return tuple(DcsSettings(c.k, c.gate, phi, p) for c in candidate_grid(with_signatures)
                 for phi in (1.0, 3.0, 10.0) for p in (0.99, 0.9, 0.999))


def run(dataset, noise, settings: DcsSettings = DcsSettings()) -> PeerResult:
    """Candidates, then DCS-weighted Levenberg-Marquardt; a solver failure is a failed result with its message."""
    started = time.perf_counter()
    pairs = candidate_pairs(dataset, CandidateSettings(settings.k, settings.gate), noise.sigma_tie)
    if len(pairs) == 0:
        result = PeerResult.from_candidates("dcs", asdict(settings), dataset.n, pairs, [], [])
    else:
        gtsam = import_gtsam()
        estimator = gtsam.noiseModel.mEstimator.DCS.Create(settings.phi)
        graph = tie_graph(dataset, noise, pairs, robust=estimator)
        params = gtsam.LevenbergMarquardtParams()
        params.setMaxIterations(LM_MAX_ITERATIONS)
        try:
            optimizer = gtsam.LevenbergMarquardtOptimizer(graph.graph, graph.initial, params)
            values = optimizer.optimize()
        except RuntimeError as error:  # GTSAM's exceptions (an indeterminant linear system, ...)
            result = PeerResult.failure("dcs", asdict(settings), pairs, f"dcs: GTSAM failed: {error}")
        else:
            if optimizer.iterations() >= LM_MAX_ITERATIONS:
                result = PeerResult.failure("dcs", asdict(settings), pairs,
                                            f"dcs: Levenberg-Marquardt did not converge in {LM_MAX_ITERATIONS} "
                                            f"iterations (error {optimizer.error():.6g})")
            else:
                distances = tie_chi2(graph, values)
                weights = np.array([estimator.weight(np.sqrt(value)) for value in distances])
                result = PeerResult.from_candidates("dcs", asdict(settings), dataset.n, pairs, weights,
                                                    distances <= chi2.ppf(settings.accept_probability, 2))
    return replace(result, wall_s=time.perf_counter() - started)
