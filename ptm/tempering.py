"""Parallel tempering over topologies (beyond the paper; docs/model.md §3.4).

A ladder of chains targets P(T|Z)^beta for inverse temperatures
1 = beta_0 > beta_1 > ... ; hot chains cross between modes that a single
chain at beta = 1 leaves rarely (strong aliasing: several very different
topologies explain the data). Every ``swap_interval`` steps one adjacent pair
(i, i+1) is chosen uniformly and their states are exchanged with probability

    min(1, exp((beta_i - beta_{i+1}) * (log P(T_{i+1}|Z) - log P(T_i|Z))))

which keeps every chain's tempered target invariant. Only the beta = 1 chain
is recorded. Each replica runs the same move mixture as :func:`ptm.mcmc`.

    >>> import numpy as np
    >>> from ptm import AppearanceModel, Dataset, PoissonPrior, Posterior
    >>> dataset = Dataset(signatures=np.array([[0.30, 0.10], [0.40, 0.05], [0.31, 0.11], [0.41, 0.04]]))
    >>> posterior = Posterior(dataset, PoissonPrior(2.0), [AppearanceModel(0.3, 0.05, 3.0, 2e-4)])
    >>> result = tempered_mcmc(posterior, 2_000, temperatures=(1.0, 0.5, 0.25), seed=0)
    >>> result.map(), len(result.diagnostics["swap_acceptance"])    # one rate per adjacent pair
    ((0, 1, 0, 1), 2)
"""

from __future__ import annotations

import math
import time

import numpy as np

from ._validation import count
from .moves import initial_state
from .sampler import (MoveMixture, chain_start, checked_estimate, checked_smc_start, default_moves, run_chains,
                      screening_diagnostics)

__all__ = ["tempered_mcmc"]


def tempered_mcmc(posterior, n_samples: int, temperatures=(1.0, 0.6, 0.35, 0.2), burn_in: int = 0,
                  thin: int = 1, swap_interval: int = 10, seed=None, init=None, moves=None,
                  delayed_acceptance=False, chains: int = 1, warm_up: int = 0, max_doublings: int = 0,
                  estimate: str = "frequency", unscreened_share: float = 0.0, smc_start: int = 0):
    """Sample with a ladder of tempered replicas; return the beta = 1 chain's histogram as a PTM.

    ``temperatures`` are inverse temperatures, strictly decreasing from 1.
    ``chains`` independent ladders (their beta = 1 replicas starting from
    different topologies) are pooled, and the split R-hat and ESS of their
    beta = 1 traces are in the diagnostics, as for :func:`ptm.mcmc`; one
    ladder draws from ``seed`` itself, several from its children.
    ``moves``, ``delayed_acceptance`` (``True`` or a surrogate) and ``warm_up``
    (steps on approximations of the posterior from each replica's start) are
    those of :func:`ptm.mcmc`, so ``**ptm.sampler.guided_options(posterior)``
    applies to every replica. ``max_doublings`` runs ladders whose beta = 1
    chains disagree on, twice as long each time, ``estimate`` turns the beta = 1 chains into
    probabilities, and ``unscreened_share`` skips the screening in that share of each replica's steps, as in
    :func:`ptm.mcmc`; so does ``smc_start``, which starts every replica from its own SMC pass.
    """
    n_samples = count("n_samples", n_samples, minimum=1)
    burn_in = count("burn_in", burn_in, minimum=0)
    thin = count("thin", thin, minimum=1)
    swap_interval = count("swap_interval", swap_interval, minimum=1)
    chains = count("chains", chains, minimum=1)
    warm_up = count("warm_up", warm_up, minimum=0)
    max_doublings = count("max_doublings", max_doublings, minimum=0)
    estimate = checked_estimate(estimate)
    smc_start = checked_smc_start(smc_start, init, warm_up)
    betas = np.asarray(temperatures, dtype=float)
    if betas.ndim != 1 or betas.size < 2 or betas[0] != 1.0 or np.any(np.diff(betas) >= 0) or betas[-1] <= 0:
        raise ValueError(f"temperatures must start at 1.0 and decrease strictly to a positive value, got {temperatures!r}")

    root = seed if isinstance(seed, np.random.SeedSequence) else np.random.SeedSequence(seed)
    ladder_seeds = [root] if chains == 1 else root.spawn(chains)
    mixtures = [MoveMixture(moves if moves is not None else default_moves(), unscreened_share) for _ in betas]
    swaps = _SwapCounts(betas.size - 1)

    started = time.perf_counter()
    ladders = []
    for chain, ladder_seed in enumerate(ladder_seeds):
        replica_seeds = ladder_seed.spawn(betas.size + 1)
        rngs = [np.random.default_rng(s) for s in replica_seeds[:-1]]
        surrogate = None if isinstance(delayed_acceptance, bool) else delayed_acceptance
        states = []
        for index, rng in enumerate(rngs):
            labels = chain_start(posterior, init, chain + index, rng, warm_up, surrogate, smc_start)
            states.append(initial_state(posterior, labels))
        ladders.append(_Ladder(posterior, betas, states, rngs, np.random.default_rng(replica_seeds[-1]), mixtures,
                               delayed_acceptance, swap_interval, swaps))
    recorder, doublings = run_chains(ladders, n_samples, burn_in, thin, max_doublings, estimate)
    wall = time.perf_counter() - started

    total = burn_in + recorder.n_samples * thin
    steps = chains * total * betas.size
    diagnostics = {
        "chains": chains, "replicas": int(betas.size), "inverse_temperatures": betas.tolist(),
        "steps": steps, "samples": chains * recorder.n_samples, "doublings": doublings, "wall_s": wall,
        "steps_per_s": steps / wall if wall > 0 else float("inf"),
        "swap_acceptance": (swaps.accepted / np.maximum(swaps.proposed, 1)).tolist(),
        **mixtures[0].diagnostics(),
    }
    diagnostics.update(screening_diagnostics(posterior, delayed_acceptance))
    return recorder.result("tempered_mcmc", diagnostics)


class _SwapCounts:
    """Proposed and accepted swaps per adjacent pair of inverse temperatures, over all ladders."""

    def __init__(self, pairs: int):
        self.proposed = np.zeros(pairs, dtype=np.int64)
        self.accepted = np.zeros(pairs, dtype=np.int64)


class _Ladder:
    """One ladder of tempered replicas: :meth:`step` advances every replica, proposes a swap every
    ``swap_interval`` steps, and returns the beta = 1 replica's state."""

    def __init__(self, posterior, betas, states, rngs, swap_rng, mixtures, delayed_acceptance, swap_interval: int,
                 swaps: _SwapCounts):
        self.posterior, self.betas, self.states, self.rngs, self.swap_rng = posterior, betas, states, rngs, swap_rng
        self.mixtures, self.delayed_acceptance, self.swap_interval, self.swaps = (mixtures, delayed_acceptance,
                                                                                  swap_interval, swaps)
        self.steps = 0

    def step(self):
        states, betas = self.states, self.betas
        for index, beta in enumerate(betas):
            states[index], _ = self.mixtures[index].step(self.posterior, states[index], self.rngs[index], beta,
                                                         self.delayed_acceptance)
        self.steps += 1
        if self.steps % self.swap_interval == 0:
            lower = min(int(self.swap_rng.random() * (betas.size - 1)), betas.size - 2)
            upper = lower + 1
            log_ratio = (betas[lower] - betas[upper]) * (states[upper].log_prob - states[lower].log_prob)
            self.swaps.proposed[lower] += 1
            if math.log(self.swap_rng.random() or 5e-324) < log_ratio:
                states[lower], states[upper] = states[upper], states[lower]
                self.swaps.accepted[lower] += 1
        return states[0]
