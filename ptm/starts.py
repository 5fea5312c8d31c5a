"""Where each chain of :func:`ptm.mcmc` and :func:`ptm.tempered_mcmc` starts (docs/model.md §3.4, "Starts";
§3.7 for a start from a shorter run's PTM).

* ``"smc"`` (the default): each chain from its own sequential Monte Carlo pass over the detections, of
  ``SMC_START_PARTICLES`` particles, drawn from the chain's own stream (:func:`ptm.online.smc_draw`). The pass
  builds the partition the way the run was walked, so a chain begins near the posterior's bulk instead of at
  an extreme that no single move leaves (a retraced corridor aligned one place off, all detections at one
  place).
* ``"dispersed"``: chain 0, 3, ... from all detections distinct, chain 1, 4, ... from all at one place, the
  others from random labels: starts far apart, for a posterior with neither signatures nor odometry (which an
  SMC pass cannot walk) or to see whether chains from the extremes agree.
* a :class:`ptm.PTM` over the first n <= N detections (incremental mapping): chain c from its (c + 1)-th most
  probable topology (cycling when it has fewer), each new detection placed by a draw from its conditional
  under the cheap terms.
* a label sequence of length N: every chain from that partition.

    >>> import numpy as np
    >>> from ptm import Dataset, PoissonPrior, Posterior
    >>> posterior = Posterior(Dataset(labels=[0, 0, 1, 1]), PoissonPrior(2.0))
    >>> [chain_start(posterior, "dispersed", chain, np.random.default_rng(0)) for chain in range(2)]
    [(0, 1, 2, 3), (0, 0, 0, 0)]
"""

from __future__ import annotations

import numpy as np

from .online import smc_draw
from .partitions import canonical
from .result import PTM

__all__ = ["SMC_START_PARTICLES", "STARTS", "checked_start", "chain_start"]

#: Particles of the SMC pass that starts each chain (``start="smc"``): a handful suffice, as the pass need only
#: bring the chain near the bulk, which the chain itself then samples.
SMC_START_PARTICLES = 16
#: The starts by name.
STARTS = ("smc", "dispersed")


def checked_start(start):
    """``start`` as a sampler keeps it: a name of :data:`STARTS`, a :class:`ptm.PTM`, or a label sequence (a
    tuple of canonical labels); else ``ValueError`` naming ``start``."""
    if isinstance(start, str):
        if start not in STARTS:
            raise ValueError(f"start must be one of {', '.join(STARTS)}, a PTM or a label sequence, got {start!r}")
        return start
    if isinstance(start, PTM):
        return start
    try:
        return canonical(list(start))
    except (TypeError, ValueError) as error:
        raise ValueError(f"start must be one of {', '.join(STARTS)}, a PTM or a label sequence, got {start!r} "
                         f"({error})") from None


def chain_start(posterior, start, chain: int, rng) -> tuple[int, ...]:
    """The partition chain number ``chain`` starts from under ``start`` (checked, :func:`checked_start`), drawn
    with ``rng`` where it is random."""
    n = posterior.n
    if isinstance(start, str):
        if start == "smc":
            return smc_draw(posterior, SMC_START_PARTICLES, rng)
        if chain % 3 == 0:
            return tuple(range(n))
        if chain % 3 == 1:
            return (0,) * n
        return tuple(int(x) for x in rng.integers(0, max(1, n // 2), size=n))
    if isinstance(start, PTM):
        if start.n > n:
            raise ValueError(f"start is a PTM over {start.n} detections, more than the posterior's {n}")
        tops = start.top(chain + 1)
        labels = list(tops[chain % len(tops)][0])
        for detection in range(start.n, n):
            labels.append(_draw_placement(posterior, labels, detection, rng))
        return tuple(labels)
    if len(start) != n:
        raise ValueError(f"start has {len(start)} labels, the posterior has N={n}")
    return start


def _draw_placement(posterior, labels: list[int], detection: int, rng) -> int:
    """Label for a new detection, drawn from its conditional under the cheap terms of the first
    ``detection + 1`` detections (existing places or a new one), less the terms that complete a global one."""
    score = posterior.standalone_block_score
    blocks: dict[int, list[int]] = {}
    for index, label in enumerate(labels):
        blocks.setdefault(label, []).append(index)
    places = len(blocks)
    log_weights = []
    candidates = list(blocks) + [max(blocks, default=-1) + 1]
    for label in candidates:
        members = tuple(blocks.get(label, [])) + (detection,)
        gain = score(members) - (score(tuple(blocks[label])) if label in blocks else 0.0)
        log_weights.append(gain + (0.0 if label in blocks else _new_place_log_odds(posterior, places)))
    log_weights = np.array(log_weights)
    probabilities = np.exp(log_weights - log_weights.max())
    probabilities /= probabilities.sum()
    return candidates[int(rng.choice(len(candidates), p=probabilities))]


def _new_place_log_odds(posterior, places: int) -> float:
    """Prior log-odds of opening place number ``places + 1`` versus joining one (full-N prior)."""
    table = posterior.log_prior_by_size
    return table[min(places + 1, len(table) - 1)] - table[max(places, 1)]
