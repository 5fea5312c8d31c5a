"""The ``core`` section of ``ptm-bench speed``: sampler throughput and exact enumeration on appearance-only posteriors.

Metropolis-Hastings steps per second at N = 10, 50, 100 (K = 5) for the
paper's split/merge move alone (``moves="paper"``) and for the default move mix
(docs/model.md §3.4), one chain from a dispersed start, no burn-in; and the wall
time of exact enumeration at N = 10 (Bell(10) = 115 975 partitions, §3.5).
"""

from __future__ import annotations

import time

import numpy as np

import ptm

__all__ = ["core_rows", "synthetic_appearance_posterior"]

#: One chain of steps only: no start pass, burn-in or doublings in the timing.
_ONE_CHAIN = {"chains": 1, "start": "dispersed", "burn_in": 0, "max_doublings": 0}


def synthetic_appearance_posterior(n: int, k: int = 5, seed: int = 0) -> ptm.Posterior:
    """An appearance-only posterior over N detections of about N/3 places (K components)."""
    rng = np.random.default_rng(seed)
    places = max(1, n // 3)
    labels = rng.integers(0, places, size=n)
    centres = rng.uniform(0.05, 0.5, size=(places, k))
    signatures = np.abs(centres[labels] + rng.normal(0.0, 0.01, size=(n, k)))
    dataset = ptm.Dataset(signatures=signatures, labels=labels)
    model = ptm.AppearanceModel(mu=0.25, kappa=0.1, alpha=3.0, beta=2.0 * 0.01 ** 2)
    return ptm.Posterior(dataset, ptm.PoissonPrior(rate=float(places)), [model])


def core_rows(args) -> list[dict]:
    rows = []
    steps = max(1000, int(20_000 * args.scale))
    for n in (10, 50, 100):
        for label, moves in (("split_merge", "paper"), ("default_moves", "default")):
            posterior = synthetic_appearance_posterior(n)
            ptm.mcmc(posterior, 500, seed=0, **_ONE_CHAIN, moves=moves)  # warm the per-set memo
            started = time.perf_counter()
            ptm.mcmc(posterior, steps, seed=1, **_ONE_CHAIN, moves=moves)
            rate = steps / (time.perf_counter() - started)
            rows.append({"section": "core", "metric": f"mh_steps_per_s_appearance_{label}", "n": n,
                         "value": rate, "unit": "steps/s"})
    posterior = synthetic_appearance_posterior(10)
    started = time.perf_counter()
    ptm.exact_posterior(posterior)
    rows.append({"section": "core", "metric": "exact_enumeration_time", "n": 10,
                 "value": time.perf_counter() - started, "unit": "s"})
    return rows
