"""What a peer answers: accepted loop closures, the partition they imply, and a score per pair (docs/model.md §6).

A robust back end weighs each candidate pair; the accepted ones are the loop
closures, and the connected components of the accepted closures are its
partition (canonical labels, docs/model.md §2.1): closures are transitive, so
a detection joins every detection it is linked to through accepted closures.

The score for average precision ranks the pairs the way the partition is
built: a pair's score is the largest s such that the pair is linked through
candidates that each score at least s (the bottleneck of the best path, from
a maximum spanning forest), and 0 where no candidate path links it. Cutting
this ranking at any level gives the components of the candidates scoring
above it, so a pair the peer joins only through other closures is credited
with the closures that join it.
A peer that scores every pair directly (``distance_rank``) passes its own
ranking instead.

A run whose solver fails (an exception, no convergence, a singular system)
is a *failed* result that carries the solver's message, never an exception
out of a sweep.

    >>> result = PeerResult.from_candidates("example", {}, 3, [[0, 1], [1, 2]], [0.9, 0.2], [True, False])
    >>> result.labels, float(result.pair_scores[0, 2])
    ((0, 0, 1), 0.2)
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

from ptm.partitions import canonical

from ptm_bench.evaluation import scoring

__all__ = ["PeerResult", "bottleneck_scores", "closure_labels", "score_peer"]


@dataclass(frozen=True)
class PeerResult:
    """One peer's answer on one dataset, or its failure.

    Attributes
    ----------
    peer : str
        The peer's name (a key of ``ptm_bench.evaluation.peers.PEERS``).
    settings : dict
        The settings it ran with (``dataclasses.asdict`` of the peer's settings).
    labels : tuple of int or None
        The partition: connected components of the accepted closures (None when failed).
    pairs : (P, 2) int array
        The candidate pairs i < j.
    scores : (P,) float array
        Each candidate's score (its final weight, or the peer's own ranking).
    accepted : (P,) bool array
        The candidates accepted as loop closures.
    pair_scores : (N, N) float array or None
        The score of every pair for average precision (module docstring); None when failed.
    error : str or None
        The solver's message when the run failed.
    wall_s : float
        Seconds the run took (candidates included).
    """

    peer: str
    settings: dict
    labels: tuple[int, ...] | None
    pairs: np.ndarray
    scores: np.ndarray
    accepted: np.ndarray
    pair_scores: np.ndarray | None
    error: str | None = None
    wall_s: float = 0.0

    @property
    def failed(self) -> bool:
        """True when the solver failed; ``error`` then says why."""
        return self.error is not None

    @classmethod
    def from_candidates(cls, peer: str, settings: dict, n: int, pairs, scores, accepted) -> "PeerResult":
        """A result from the candidates' scores and acceptance: components and bottleneck scores built here."""
        pairs = np.asarray(pairs, dtype=np.int64).reshape(-1, 2)
        scores = np.asarray(scores, dtype=float).reshape(-1)
        accepted = np.asarray(accepted, dtype=bool).reshape(-1)
        if not (len(pairs) == len(scores) == len(accepted)):
            raise ValueError(f"{len(pairs)} candidate pairs, {len(scores)} scores and {len(accepted)} acceptances")
        if not np.all(np.isfinite(scores)):
            return cls.failure(peer, settings, pairs, f"{peer}: the solver returned a non-finite weight")
        return cls(peer, settings, closure_labels(n, pairs[accepted]), pairs, scores, accepted,
                   bottleneck_scores(n, pairs, scores))

    @classmethod
    def failure(cls, peer: str, settings: dict, pairs, message: str) -> "PeerResult":
        """A failed run: no partition, the solver's message on one line."""
        pairs = np.asarray(pairs, dtype=np.int64).reshape(-1, 2)
        empty = np.full(len(pairs), math.nan)
        return cls(peer, settings, None, pairs, empty, np.zeros(len(pairs), dtype=bool), None,
                   error=" ".join(str(message).split()))


def closure_labels(n: int, closures) -> tuple[int, ...]:
    """Canonical labels of the connected components of the closures (an (M, 2) array of pairs) over n detections."""
    closures = np.asarray(closures, dtype=np.int64).reshape(-1, 2)
    graph = coo_matrix((np.ones(len(closures)), (closures[:, 0], closures[:, 1])), shape=(n, n))
    _, components = connected_components(graph, directed=False)
    return canonical(components)


def bottleneck_scores(n: int, pairs, scores) -> np.ndarray:
    """(N, N) matrix: the best bottleneck score of a candidate path between i and j, 0 where there is none.

    Kruskal's maximum spanning forest: candidates in decreasing score (ties in
    pair order); when one joins two components A and B, every pair across them
    gets its score, which is the bottleneck of their best path.
    """
    pairs = np.asarray(pairs, dtype=np.int64).reshape(-1, 2)
    scores = np.asarray(scores, dtype=float).reshape(-1)
    matrix = np.zeros((n, n))
    members = [[index] for index in range(n)]
    owner = np.arange(n)
    for index in np.argsort(-scores, kind="stable"):
        first, second = owner[pairs[index]]
        if first == second:
            continue
        if len(members[first]) < len(members[second]):
            first, second = second, first
        a, b = members[first], members[second]
        matrix[np.ix_(a, b)] = scores[index]
        matrix[np.ix_(b, a)] = scores[index]
        owner[b] = first
        a.extend(b)
        members[second] = []
    return matrix


def score_peer(result: PeerResult, truth) -> dict:
    """The sweep's score columns of a peer's run (docs/model.md §6), or its failure.

    The partition is scored like the threshold baselines' answer, a point mass
    (ARI, loop-closure precision/recall/F1, Brier, ECE of the 0/1 co-assignment);
    ``lc_ap`` is the average precision of the peer's pair scores instead, its
    graded ranking. A failed run gives ``{"peer_error": message}`` and NaN scores.
    """
    if result.failed:
        return {"ari": math.nan, "lc_f1": math.nan, "lc_ap": math.nan, "peer_error": result.error}
    row = scoring.score(scoring.point_mass(result.labels), truth)
    row["lc_ap"] = scoring.loop_closure_scores(result.pair_scores, truth)["lc_ap"]
    row["peer_error"] = ""
    row["n_candidates"] = int(len(result.pairs))
    row["n_accepted"] = int(result.accepted.sum())
    return row
