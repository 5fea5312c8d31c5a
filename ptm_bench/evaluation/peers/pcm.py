"""Peer ``pcm``: pairwise consistency maximisation of the candidates under dead reckoning (Mangelson et al., 2018).

Two loop closures a~b and c~d (a < b, c < d) are consistent when the cycle
they form with the odometry closes: a -> b through the first closure, b -> d
along the odometry, d -> c through the second, c -> a along the odometry. With
position ties (headings free, docs/model.md §3.3) the cycle's residual is

    e = (p_c - p_a) - (p_d - p_b),     p the dead-reckoned positions,

zero-mean with covariance J Sigma J^T + 2 sigma_T^2 I, J the Jacobian of e
with respect to every odometry row (linearised at dead reckoning; a row's
heading error turns every later position about its own) and Sigma the rows'
covariances. The pair is consistent when e^T C^-1 e <= chi2_2^-1(p), p the
setting ``consistency_probability``. A candidate's own cycle (a -> b through
the closure, b -> a along the odometry: e = p_b - p_a, covariance
J Sigma J^T + sigma_T^2 I) must pass the same bound to enter the consistency
graph at all. The largest set of mutually consistent closures, the maximum
clique of that graph, is accepted: found by the greedy heuristic of PMC
(Rossi et al. 2015; Mangelson et al.'s PCM offers it beside the exact
search), :func:`greedy_max_clique`. Exact search is exponential: on a loop of
50 places driven four times (N = 200, 500 candidates, a clique of about 250)
``networkx.max_weight_clique`` ran for over a minute.

A candidate's score ranks clique members first, then by the share of the
other candidates it is consistent with: (accepted + degree / (P - 1)) / 2.

The covariances of all pairs of candidates are gathered from one covariance
of the dead-reckoned positions (:func:`position_covariance`, 2N x 2N), so the
P (P - 1) / 2 tests cost O(P^2) after an O(N^3) start.

    >>> import numpy as np, ptm
    >>> from ptm_bench.evaluation.peers.noise import PeerNoise
    >>> square = np.tile([2.0, 0.0, np.pi / 2], (8, 1))          # a 2 m square driven twice
    >>> signatures = [[0.0], [1.0], [2.0], [3.0]] * 2 + [[0.0]]
    >>> dataset = ptm.Dataset(odometry=square, signatures=signatures)
    >>> run(dataset, PeerNoise(0.05, 0.02, 0.3), PcmSettings(k=2)).labels
    (0, 1, 2, 3, 0, 1, 2, 3, 0)
"""

from __future__ import annotations

import time
from dataclasses import asdict, dataclass, replace

import numpy as np
from scipy.stats import chi2

from ptm.se2 import dead_reckoning

from ptm_bench.evaluation.peers.candidates import DEFAULT_K, CandidateSettings, candidate_grid, candidate_pairs
from ptm_bench.evaluation.peers.result import PeerResult

__all__ = ["PcmSettings", "consistency", "core_numbers", "greedy_max_clique", "grid", "position_covariance", "run"]


@dataclass(frozen=True)
class PcmSettings:
    """Candidates (``k``, ``gate`` in tie sigmas) and the consistency bound as a chi-square probability."""

    k: int = DEFAULT_K
    gate: float | None = None
    consistency_probability: float = 0.99

    def __post_init__(self):
        CandidateSettings(self.k, self.gate)
        if not 0.0 < self.consistency_probability < 1.0:
            raise ValueError(f"pcm setting consistency_probability must be in (0, 1), got "
                             f"{self.consistency_probability!r}")


def grid(with_signatures: bool) -> tuple[PcmSettings, ...]:
    """The settings calibration tries: every candidate setting (``candidate_grid``) x consistency probability
    0.99 (the default), 0.9, 0.999."""
    return tuple(PcmSettings(c.k, c.gate, p) for c in candidate_grid(with_signatures) for p in (0.99, 0.9, 0.999))


def position_covariance(poses: np.ndarray, covariances: np.ndarray) -> np.ndarray:
    """(N, 2, N, 2) covariance of the dead-reckoned positions, J Sigma J^T linearised at ``poses``.

    Row m (m = 1..N-1) moves pose m-1 to pose m and enters every pose k >= m:
    d p_k / d (dx_m, dy_m) = R(theta_{m-1}), d p_k / d dtheta_m = S (p_k - p_m), S the
    rotation by 90 degrees (a heading error turns the rest of the route about p_m).
    """
    n = len(poses)
    cos, sin = np.cos(poses[:-1, 2]), np.sin(poses[:-1, 2])
    jacobian = np.zeros((n, 2, n - 1, 3))
    jacobian[:, 0, :, 0], jacobian[:, 0, :, 1] = cos, -sin
    jacobian[:, 1, :, 0], jacobian[:, 1, :, 1] = sin, cos
    lever = poses[:, None, :2] - poses[None, 1:, :2]  # p_k - p_m
    jacobian[:, 0, :, 2], jacobian[:, 1, :, 2] = -lever[..., 1], lever[..., 0]
    jacobian *= (np.arange(n)[:, None] >= np.arange(1, n)[None, :])[:, None, :, None]
    flat = jacobian.reshape(2 * n, n - 1, 3)
    weighted = np.einsum("amj,mjl->aml", flat, covariances).reshape(2 * n, -1)
    return (weighted @ flat.reshape(2 * n, -1).T).reshape(n, 2, n, 2)


def _mahalanobis(residual: np.ndarray, covariance: np.ndarray) -> np.ndarray:
    """e^T C^-1 e for (..., 2) residuals and (..., 2, 2) symmetric positive definite covariances (closed form)."""
    a, b, d = covariance[..., 0, 0], covariance[..., 0, 1], covariance[..., 1, 1]
    x, y = residual[..., 0], residual[..., 1]
    return (d * x * x - 2.0 * b * x * y + a * y * y) / (a * d - b * b)


def consistency(dataset, noise, pairs: np.ndarray, bound: float):
    """(self-consistent (P,) bool, pairwise-consistent (P, P) bool) of candidate pairs at chi-square ``bound``.

    With w_x = p_b - p_a the dead-reckoned offset of candidate x = (a, b), a
    candidate's own cycle is w_x and a pair's cycle is w_x - w_y (module
    docstring); their covariances come from the offsets' joint covariance
    Cov(w_x, w_y), gathered from :func:`position_covariance`. Only pairs of
    self-consistent candidates can be consistent.
    """
    poses = dead_reckoning(dataset.odometry)
    covariance = position_covariance(poses, noise.step_covariances(dataset))
    first, second = pairs[:, 0], pairs[:, 1]
    offsets = poses[second, :2] - poses[first, :2]
    joint = (covariance[second][:, :, second] - covariance[second][:, :, first]
             - covariance[first][:, :, second] + covariance[first][:, :, first]).transpose(0, 2, 1, 3)
    own = joint[np.arange(len(pairs)), np.arange(len(pairs))]  # (P, 2, 2)
    tie = noise.sigma_tie ** 2 * np.eye(2)
    alone = _mahalanobis(offsets, own + tie) <= bound
    kept = np.flatnonzero(alone)
    between = joint[np.ix_(kept, kept)]  # Cov(w_x, w_y), (K, K, 2, 2)
    cycle = own[kept][:, None] + own[kept][None, :] - between - np.swapaxes(between, 2, 3) + 2.0 * tie
    residual = offsets[kept][:, None, :] - offsets[kept][None, :, :]
    together = np.zeros((len(pairs), len(pairs)), dtype=bool)
    together[np.ix_(kept, kept)] = _mahalanobis(residual, cycle) <= bound
    np.fill_diagonal(together, False)
    return alone, together


def core_numbers(adjacent: np.ndarray) -> np.ndarray:
    """The core number of every vertex (the largest k of a k-core holding it): peel the least-connected vertex."""
    count = len(adjacent)
    degree = adjacent.sum(axis=1).astype(np.int64)
    removed = np.zeros(count, dtype=bool)
    core = np.zeros(count, dtype=np.int64)
    level = 0
    for _ in range(count):
        vertex = int(np.argmin(np.where(removed, count + 1, degree)))
        level = max(level, int(degree[vertex]))
        core[vertex] = level
        removed[vertex] = True
        degree -= adjacent[vertex]
    return core


def greedy_max_clique(adjacent: np.ndarray) -> np.ndarray:
    """Indices of a large clique of the graph with boolean adjacency ``adjacent`` (PMC's heuristic, sorted).

    Vertices are ranked by core number (:func:`core_numbers`), then degree, then index. From every vertex
    whose core number leaves room for a larger clique than the first greedy pass found, the clique grows by
    the best-ranked vertex adjacent to all its members until none is left; the largest wins (ties: the
    start ranked first). All starts advance together, one vectorised step per added vertex.
    """
    count = len(adjacent)
    if count == 0:
        return np.zeros(0, dtype=np.int64)
    adjacent = np.asarray(adjacent, dtype=bool) & ~np.eye(count, dtype=bool)
    core = core_numbers(adjacent)
    order = np.lexsort((np.arange(count), -adjacent.sum(axis=1), -core))  # best-ranked vertex first
    preference = np.empty(count, dtype=np.int64)
    preference[order] = np.arange(count, 0, -1)

    def grow(starts):
        members = np.zeros((len(starts), count), dtype=bool)
        members[np.arange(len(starts)), starts] = True
        candidates = adjacent[starts].copy()
        rows = np.flatnonzero(candidates.any(axis=1))
        while len(rows):
            chosen = np.where(candidates[rows], preference, 0).argmax(axis=1)
            members[rows, chosen] = True
            candidates[rows] &= adjacent[chosen]
            rows = rows[candidates[rows].any(axis=1)]
        return members

    first = grow(order[:1])[0]
    starts = order[core[order] + 1 > first.sum()]
    if len(starts) == 0:
        return np.flatnonzero(first)
    grown = grow(starts)
    sizes = grown.sum(axis=1)
    best = grown[int(np.argmax(sizes))] if sizes.max() > first.sum() else first
    return np.flatnonzero(best)


def run(dataset, noise, settings: PcmSettings = PcmSettings()) -> PeerResult:
    """Candidates, their consistency graph, its (greedy) maximum clique accepted."""
    started = time.perf_counter()
    pairs = candidate_pairs(dataset, CandidateSettings(settings.k, settings.gate), noise.sigma_tie)
    bound = chi2.ppf(settings.consistency_probability, 2)
    alone, together = consistency(dataset, noise, pairs, bound)
    kept = np.flatnonzero(alone)  # a candidate that fails its own cycle is in no clique, not even one of its own
    accepted = np.zeros(len(pairs), dtype=bool)
    accepted[kept[greedy_max_clique(together[np.ix_(kept, kept)])]] = True
    degree = together.sum(axis=1) / max(len(pairs) - 1, 1)
    scores = (accepted + degree) / 2.0
    result = PeerResult.from_candidates("pcm", asdict(settings), dataset.n, pairs, scores, accepted)
    return replace(result, wall_s=time.perf_counter() - started)
