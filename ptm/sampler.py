"""Metropolis-Hastings over topologies (paper eq. 10, Algorithm 1; docs/model.md §3.4).

Several chains, each from its own start (:mod:`ptm.starts`) and its own random stream spawned from one root
seed, run a mixture of moves (:mod:`ptm.moves`); each step is one Metropolis-Hastings step, with delayed
acceptance where there are global terms (a first stage on the cheap terms, joined by the posterior's screen for
the guided moves; :func:`ptm.moves.metropolis_step`). The kept samples are pooled into a PTM
(:mod:`ptm.recorder`), with split R-hat and effective sample sizes of log P and of the number of places and the
largest difference between two chains' co-assignment matrices. Chains that disagree by those measures
(:func:`ptm.diagnostics.chains_agree`) are run on, twice as long each time, at most ``max_doublings`` times
(:func:`run_chains`). :class:`SamplerOptions` holds the settings that :func:`mcmc` and
:func:`ptm.tempered_mcmc` share, validated once.

    >>> import numpy as np
    >>> from ptm import AppearanceModel, Dataset, PoissonPrior, Posterior
    >>> dataset = Dataset(signatures=np.array([[0.30, 0.10], [0.40, 0.05], [0.31, 0.11], [0.41, 0.04]]))
    >>> posterior = Posterior(dataset, PoissonPrior(2.0), [AppearanceModel(0.3, 0.05, 3.0, 2e-4)])
    >>> result = mcmc(posterior, n_samples=2_000, seed=1, chains=2)
    >>> result.map(), result.traces["log_prob"].shape, "rhat_log_prob" in result.diagnostics
    ((0, 1, 0, 1), (2, 2000), True)
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from ._validation import count, flag, instance, seed_sequence, share
from .diagnostics import chains_agree
from .moves import MoveMixture, initial_state, move_set
from .moves.sets import checked_moves
from .posterior import Posterior
from .recorder import SampleRecorder
from .starts import chain_start, checked_start

__all__ = ["MAX_CHAIN_STEPS", "MAX_KEPT_SAMPLES", "SamplerOptions", "checked_run", "mcmc", "run_chains",
           "sampler_diagnostics"]

#: The most samples one run may keep, over all its chains and doublings: the traces hold 12 bytes a sample,
#: so this is 12 GB (a larger request fails with ``ValueError`` before sampling, not with a MemoryError).
MAX_KEPT_SAMPLES = 10**9
#: The most steps one chain may take, burn-in, thinning and doublings included: even at a microsecond a step,
#: more would run for weeks.
MAX_CHAIN_STEPS = 10**12


@dataclass(frozen=True)
class SamplerOptions:
    """The settings of :func:`mcmc` and :func:`ptm.tempered_mcmc`, validated once (``ValueError`` or
    ``TypeError`` naming the field).

    Parameters
    ----------
    burn_in : int or None
        Steps each chain discards first; None: half of ``n_samples``.
    thin : int
        Keep one step in ``thin`` after the burn-in.
    chains : int
        Independent chains (ladders of :func:`ptm.tempered_mcmc`), pooled in the result.
    start : "smc", "dispersed", a PTM or a label sequence
        Where each chain starts (:mod:`ptm.starts`).
    moves : "auto", "default", "paper", "guided", or a list of moves or (move, weight) pairs
        The move set (:mod:`ptm.moves.sets`).
    delayed_acceptance : bool
        With global terms, screen each proposal first (with the cheap terms, and the posterior's screen for
        the guided moves) and evaluate the global terms for the survivors only.
    unscreened_share : float in [0, 1]
        With delayed acceptance, the share of steps that skip the screening and accept on the exact ratio
        (:class:`ptm.moves.MoveMixture`).
    max_doublings : int
        While several chains disagree, double the samples kept per chain, at most this many times.
    """

    burn_in: int | None = None
    thin: int = 1
    chains: int = 4
    start: object = "smc"
    moves: object = "auto"
    delayed_acceptance: bool = True
    unscreened_share: float = 0.05
    max_doublings: int = 2

    def __post_init__(self):
        fields = {
            "burn_in": None if self.burn_in is None else count("burn_in", self.burn_in, 0),
            "thin": count("thin", self.thin, 1),
            "chains": count("chains", self.chains, 1),
            "start": checked_start(self.start),
            "moves": checked_moves(self.moves),
            "unscreened_share": share("unscreened_share", self.unscreened_share),
            "max_doublings": count("max_doublings", self.max_doublings, 0),
            "delayed_acceptance": flag("delayed_acceptance", self.delayed_acceptance),
        }
        for name, value in fields.items():
            object.__setattr__(self, name, value)

    def burn_in_for(self, n_samples: int) -> int:
        """The steps each chain discards for ``n_samples`` kept: ``burn_in``, or half of ``n_samples``."""
        return n_samples // 2 if self.burn_in is None else self.burn_in


def mcmc(posterior, n_samples: int, *, seed=None, **options):
    """Sample the posterior over topologies; return the pooled histogram as a PTM.

    ``n_samples``: samples kept per chain (after the burn-in, every ``thin``-th step). ``seed``: an int,
    SeedSequence or None, the root from which each chain's stream is spawned. ``options``: the fields of
    :class:`SamplerOptions`. ``diagnostics`` holds, beside the convergence diagnostics, the move set run
    (``moves``), the burn-in, the acceptance rates and the screening's tallies.
    """
    options = SamplerOptions(**options)
    n_samples = checked_run(posterior, n_samples, options)
    root = seed_sequence("seed", seed)
    burn_in = options.burn_in_for(n_samples)
    moves = move_set(options.moves, posterior)
    mixture = MoveMixture(moves.moves, options.delayed_acceptance, moves.screen, options.unscreened_share)
    started = time.perf_counter()
    runners = []
    for chain, chain_seed in enumerate(root.spawn(options.chains)):
        rng = np.random.default_rng(chain_seed)
        labels = chain_start(posterior, options.start, chain, rng)
        runners.append(_Chain(posterior, initial_state(posterior, labels), rng, mixture))
    recorder, doublings = run_chains(runners, n_samples, burn_in, options.thin, options.max_doublings)
    wall = time.perf_counter() - started
    steps = options.chains * (burn_in + recorder.n_samples * options.thin)
    diagnostics = {"chains": options.chains, "steps": steps, "samples": options.chains * recorder.n_samples,
                   "doublings": doublings, "wall_s": wall, "steps_per_s": steps / wall if wall > 0 else float("inf"),
                   **mixture.diagnostics()}
    diagnostics.update(sampler_diagnostics(posterior, moves, options, burn_in))
    return recorder.result("mcmc", diagnostics)


def checked_run(posterior, n_samples, options: SamplerOptions) -> int:
    """``n_samples`` as an int, after checking the arguments of a run of :func:`mcmc` or
    :func:`ptm.tempered_mcmc`: ``TypeError`` unless ``posterior`` is a :class:`ptm.Posterior` and ``n_samples``
    a whole number, ``ValueError`` (naming the arguments) where the run would keep more than
    ``MAX_KEPT_SAMPLES`` samples or take more than ``MAX_CHAIN_STEPS`` steps a chain if every doubling
    were made."""
    instance("posterior", posterior, Posterior)
    n_samples = count("n_samples", n_samples, 1)
    doublings = min(options.max_doublings, 64)  # beyond 64, 2 ** doublings exceeds both limits anyway
    kept = options.chains * n_samples << doublings
    if kept > MAX_KEPT_SAMPLES:
        raise ValueError(f"n_samples={_amount(n_samples)} with chains={_amount(options.chains)} and max_doublings="
                         f"{_amount(options.max_doublings)} may keep {_amount(kept)} samples, more than "
                         f"MAX_KEPT_SAMPLES = {MAX_KEPT_SAMPLES:,} (12 bytes each)")
    burn_in = options.burn_in_for(n_samples)
    steps = burn_in + (n_samples << doublings) * options.thin
    if steps > MAX_CHAIN_STEPS:
        raise ValueError(f"n_samples={_amount(n_samples)} with burn_in={_amount(burn_in)}, thin="
                         f"{_amount(options.thin)} and max_doublings={_amount(options.max_doublings)} may take "
                         f"{_amount(steps)} steps a chain, more than MAX_CHAIN_STEPS = {MAX_CHAIN_STEPS:,}")
    return n_samples


def _amount(value: int) -> str:
    """A count for a message: in full, or its order of magnitude where it is huge (1e300 has 301 digits)."""
    return f"{value:,}" if value < 10**15 else f"about 1e{len(str(value)) - 1}"


class _Chain:
    """One Metropolis-Hastings chain of :func:`mcmc`: :meth:`step` advances it and returns its state."""

    def __init__(self, posterior, state, rng, mixture: MoveMixture):
        self.posterior, self.state, self.rng, self.mixture = posterior, state, rng, mixture

    def step(self):
        self.state, _ = self.mixture.step(self.posterior, self.state, self.rng)
        return self.state


def run_chains(chains, n_samples: int, burn_in: int, thin: int, max_doublings: int) -> tuple[SampleRecorder, int]:
    """Run ``chains`` (objects whose ``step()`` advances one chain and returns the state to record) for
    ``burn_in + n_samples * thin`` steps each, keeping every ``thin``-th state after the burn-in; then, while
    there are several chains and they disagree (:func:`ptm.diagnostics.chains_agree`), double ``n_samples``
    and continue every chain from where it stopped, at most ``max_doublings`` times.

    The burn-in stays as given. Each chain draws from its own stream and the target is a function of the
    partition alone, so an extended run keeps exactly the samples of a run started with the final
    ``n_samples``. Returns the recorder and the number of doublings made.
    """
    recorder = SampleRecorder(len(chains), n_samples)
    taken = [0] * len(chains)
    doublings = 0
    while True:
        steps = burn_in + recorder.n_samples * thin
        for index, chain in enumerate(chains):
            for step in range(taken[index], steps):
                state = chain.step()
                kept, remainder = divmod(step - burn_in + 1, thin)
                if step >= burn_in and remainder == 0:
                    recorder.keep(index, kept - 1, state)
            taken[index] = steps
            recorder.flush()
        if doublings == max_doublings or len(chains) < 2 or chains_agree(recorder.convergence()):
            return recorder, doublings
        doublings += 1
        recorder.extend(2 * recorder.n_samples)


def sampler_diagnostics(posterior, moves, options: SamplerOptions, burn_in: int) -> dict:
    """The move set run and the burn-in, the posterior's diagnostics, and the screen's under ``"screen"`` where
    it screened delayed acceptance."""
    diagnostics = {"moves": moves.name, "burn_in": burn_in, **posterior.diagnostics()}
    if options.delayed_acceptance and hasattr(moves.screen, "diagnostics"):
        diagnostics["screen"] = moves.screen.diagnostics()
    return diagnostics
