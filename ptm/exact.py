"""Exact posterior by enumerating every partition (docs/model.md §3.5).

All Bell(N) partitions are visited depth-first as restricted growth strings
(iteratively, in lexicographic order): detection i joins one of the sets
opened so far or opens a new one. The
score of the decomposable terms is carried along the enumeration — adding i
to set j changes only that set's score — and each set's score is memoised by
its bitmask, so each of the 2^N - 1 possible sets is scored once. Global
terms (odometry) are evaluated at the leaves. Bell(10) = 115 975,
Bell(12) = 4 213 597; sizes above ``max_n`` are refused.

    >>> import numpy as np
    >>> from ptm import Dataset, PoissonPrior, Posterior
    >>> prior_only = Posterior(Dataset(labels=np.zeros(4, dtype=int)), PoissonPrior(2.0))   # N <= 12
    >>> exact = exact_posterior(prior_only)
    >>> len(exact), exact.map(), round(exact.expected_num_places(), 3)                      # Bell(4) = 15
    (15, (0, 0, 0, 0), 1.871)
"""

from __future__ import annotations

import time

import numpy as np
from scipy.special import logsumexp

from .partitions import Partition, bell
from .result import PTM

__all__ = ["exact_posterior"]


def exact_posterior(posterior, max_n: int = 12) -> PTM:
    """Enumerate and normalise the posterior over all partitions of N detections."""
    n = posterior.n
    if n > max_n:
        raise ValueError(
            f"exact enumeration of N={n} detections means {bell(n):,} partitions; "
            f"the limit is max_n={max_n} (raise it deliberately, or use ptm.mcmc)"
        )
    started = time.perf_counter()
    total = bell(n)
    partitions = np.empty((total, n), dtype=np.int8 if n < 128 else np.int16)
    log_probs = np.empty(total)
    log_prior = posterior.log_prior_by_size
    has_global = posterior.has_global_terms
    bits = [1 << i for i in range(n)]
    mask_scores: dict[int, float] = {0: 0.0}

    def score(mask: int) -> float:
        value = mask_scores.get(mask)
        if value is None:
            value = posterior.block_score(tuple(i for i in range(n) if mask & bits[i]))
            mask_scores[mask] = value
        return value

    # Depth-first over restricted growth strings without recursion: labels[d] is the set detection d
    # is in (-1 before its first choice), running[d] the score of the sets of detections 0..d-1,
    # replaced[d] the mask detection d's choice extended (None when it opened a new set).
    labels = [-1] * n
    running = [0.0] * (n + 1)
    replaced: list[int | None] = [None] * n
    sets_before = [0] * n
    masks: list[int] = []
    leaf = 0
    detection = 0
    while detection >= 0:
        choice = labels[detection]
        if choice >= 0:  # undo the previous choice of this detection
            if replaced[detection] is None:
                masks.pop()
            else:
                masks[choice] = replaced[detection]
        choice += 1
        if choice > sets_before[detection]:  # every choice tried: back up
            labels[detection] = -1
            detection -= 1
            continue
        labels[detection] = choice
        bit = bits[detection]
        if choice < sets_before[detection]:  # join set `choice`
            old = masks[choice]
            replaced[detection] = old
            masks[choice] = old | bit
            running[detection + 1] = running[detection] - score(old) + score(old | bit)
        else:  # open a new set
            replaced[detection] = None
            masks.append(bit)
            running[detection + 1] = running[detection] + score(bit)
        if detection + 1 < n:
            detection += 1
            sets_before[detection] = len(masks)
            continue
        partitions[leaf] = labels
        value = log_prior[len(masks)] + running[n]
        if has_global:
            value += posterior.global_log_prob(Partition.from_labels(labels))
        log_probs[leaf] = value
        leaf += 1

    log_normaliser = float(logsumexp(log_probs))
    if not np.isfinite(log_normaliser):
        raise ValueError("every partition has zero posterior probability")
    probabilities = np.exp(log_probs - log_normaliser)
    diagnostics = {"partitions": total, "log_normaliser": log_normaliser,
                   "wall_s": time.perf_counter() - started}
    diagnostics.update(posterior.diagnostics())
    return PTM(partitions, probabilities, "exact", diagnostics)
