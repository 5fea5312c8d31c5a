"""Parallel tempering over topologies (beyond the paper; docs/model.md §3.4).

A ladder of chains targets P(T|Z)^beta for inverse temperatures
1 = beta_0 > beta_1 > ... ; hot chains cross between modes that a single
chain at beta = 1 leaves rarely (strong aliasing: several very different
topologies explain the data). Every ``swap_interval`` steps one adjacent pair
(i, i+1) is chosen uniformly and their states are exchanged with probability

    min(1, exp((beta_i - beta_{i+1}) * (log P(T_{i+1}|Z) - log P(T_i|Z))))

which keeps every chain's tempered target invariant. Only the beta = 1 chain
is recorded. Each replica runs the move set of :func:`ptm.mcmc` and starts from its own start
(:mod:`ptm.starts`); the ladders share the settings of :class:`ptm.SamplerOptions`.

    >>> import numpy as np
    >>> from ptm import AppearanceModel, Dataset, PoissonPrior, Posterior
    >>> dataset = Dataset(signatures=np.array([[0.30, 0.10], [0.40, 0.05], [0.31, 0.11], [0.41, 0.04]]))
    >>> posterior = Posterior(dataset, PoissonPrior(2.0), [AppearanceModel(0.3, 0.05, 3.0, 2e-4)])
    >>> result = tempered_mcmc(posterior, 2_000, temperatures=(1.0, 0.5, 0.25), seed=0, chains=1)
    >>> result.map(), len(result.diagnostics["swap_acceptance"])    # one rate per adjacent pair
    ((0, 1, 0, 1), 2)
"""

from __future__ import annotations

import math
import time

import numpy as np

from ._validation import count, finite_array, seed_sequence
from .moves import MoveMixture, initial_state, move_set
from .sampler import SamplerOptions, checked_run, run_chains, sampler_diagnostics
from .starts import chain_start

__all__ = ["tempered_mcmc"]


def tempered_mcmc(posterior, n_samples: int, *, seed=None, temperatures=(1.0, 0.5, 0.25, 0.12, 0.06, 0.03),
                  swap_interval: int = 10, **options):
    """Sample with ladders of tempered replicas; return the beta = 1 chains' pooled histogram as a PTM.

    ``temperatures`` are inverse temperatures, strictly decreasing from 1; every ``swap_interval`` steps one
    adjacent pair of each ladder is proposed a swap. ``n_samples``, ``seed`` and ``options`` (the fields of
    :class:`ptm.SamplerOptions`) are those of :func:`ptm.mcmc`, with ``chains`` independent ladders, whose
    beta = 1 replicas give the convergence diagnostics; one ladder draws from ``seed`` itself, several from its
    children. Every replica starts from its own start and runs the same move set.
    """
    options = SamplerOptions(**options)
    n_samples = checked_run(posterior, n_samples, options)
    swap_interval = count("swap_interval", swap_interval, 1)
    betas = finite_array("temperatures", temperatures)
    if betas.ndim != 1 or betas.size < 2 or betas[0] != 1.0 or np.any(np.diff(betas) >= 0) or betas[-1] <= 0:
        raise ValueError(f"temperatures must start at 1.0 and decrease strictly to a positive value, "
                         f"got {temperatures!r}")
    burn_in = options.burn_in_for(n_samples)
    moves = move_set(options.moves, posterior)
    mixtures = [MoveMixture(moves.moves, options.delayed_acceptance, moves.screen, options.unscreened_share)
                for _ in betas]
    root = seed_sequence("seed", seed)
    ladder_seeds = [root] if options.chains == 1 else root.spawn(options.chains)
    swaps = _SwapCounts(betas.size - 1)

    started = time.perf_counter()
    ladders = []
    for chain, ladder_seed in enumerate(ladder_seeds):
        replica_seeds = ladder_seed.spawn(betas.size + 1)
        rngs = [np.random.default_rng(s) for s in replica_seeds[:-1]]
        states = [initial_state(posterior, chain_start(posterior, options.start, chain + index, rng))
                  for index, rng in enumerate(rngs)]
        ladders.append(_Ladder(posterior, betas, states, rngs, np.random.default_rng(replica_seeds[-1]), mixtures,
                               swap_interval, swaps))
    recorder, doublings = run_chains(ladders, n_samples, burn_in, options.thin, options.max_doublings)
    wall = time.perf_counter() - started

    total = burn_in + recorder.n_samples * options.thin
    steps = options.chains * total * betas.size
    diagnostics = {
        "chains": options.chains, "replicas": int(betas.size), "inverse_temperatures": betas.tolist(),
        "steps": steps, "samples": options.chains * recorder.n_samples, "doublings": doublings, "wall_s": wall,
        "steps_per_s": steps / wall if wall > 0 else float("inf"),
        "swap_acceptance": (swaps.accepted / np.maximum(swaps.proposed, 1)).tolist(),
        **mixtures[0].diagnostics(),
    }
    diagnostics.update(sampler_diagnostics(posterior, moves, options, burn_in))
    return recorder.result("tempered_mcmc", diagnostics)


class _SwapCounts:
    """Proposed and accepted swaps per adjacent pair of inverse temperatures, over all ladders."""

    def __init__(self, pairs: int):
        self.proposed = np.zeros(pairs, dtype=np.int64)
        self.accepted = np.zeros(pairs, dtype=np.int64)


class _Ladder:
    """One ladder of tempered replicas: :meth:`step` advances every replica, proposes a swap every
    ``swap_interval`` steps, and returns the beta = 1 replica's state."""

    def __init__(self, posterior, betas, states, rngs, swap_rng, mixtures, swap_interval: int, swaps: _SwapCounts):
        self.posterior, self.betas, self.states, self.rngs, self.swap_rng = posterior, betas, states, rngs, swap_rng
        self.mixtures, self.swap_interval, self.swaps = mixtures, swap_interval, swaps
        self.steps = 0

    def step(self):
        states, betas = self.states, self.betas
        for index, beta in enumerate(betas):
            states[index], _ = self.mixtures[index].step(self.posterior, states[index], self.rngs[index], beta)
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
