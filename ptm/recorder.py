"""Kept samples turned into a PTM: the pooled histogram, each topology's probability, and the chains'
convergence diagnostics (docs/model.md §3.4, "Several chains").

A topology's probability is one of two estimates, chosen by the chains themselves. The visit *frequency* is
its share of the kept samples. The *renormalised* estimate is P(T|Z) itself normalised over the distinct
topologies the chains visited, exp(log P(T|Z)) / sum over visited T' of exp(log P(T'|Z)): it has no Monte
Carlo error in the ratios between visited topologies and puts no mass where no chain went, so its total
variation from the posterior is exactly the posterior mass of the topologies never visited. It is the better
estimate where the chains found all of the posterior's bulk and revisit it (a peaked posterior, a sampler
that moves rarely), and a biased one where they keep finding new topologies (a flat posterior over very
many). So the recorder renormalises where each of at least two chains visited topologies holding at least
``RENORMALISE_COVERAGE`` of the renormalised mass of all of them, and counts visits otherwise. A *stray*
chain, whose topologies hold less than ``STRAY_CHAIN_MASS`` of that mass (a mode it never left, far below
the others'), is not asked to cover the others': its frequencies would give that mode a whole chain's share.

    >>> from ptm import Dataset, PoissonPrior, Posterior
    >>> from ptm.moves import initial_state
    >>> posterior = Posterior(Dataset(labels=[0, 0, 0]), PoissonPrior(2.0))
    >>> recorder = SampleRecorder(chains=2, n_samples=2)
    >>> for chain in range(2):
    ...     for index, labels in enumerate([(0, 0, 1), (0, 1, 2)]):
    ...         recorder.keep(chain, index, initial_state(posterior, labels))
    >>> result = recorder.result("mcmc", {})
    >>> result.diagnostics["estimate"], len(result)
    ('renormalised', 2)
"""

from __future__ import annotations

import math

import numpy as np

from .diagnostics import effective_sample_size, split_rhat
from .partitions import Partition
from .result import PTM

__all__ = ["SampleRecorder", "RENORMALISE_COVERAGE", "STRAY_CHAIN_MASS"]

#: The recorder renormalises when every chain visited topologies holding at least this share of the
#: renormalised mass of all chains' (:meth:`SampleRecorder.chain_coverage`), strays apart.
RENORMALISE_COVERAGE = 0.99
#: A chain whose visited topologies hold less than this share of that mass is a stray: it sits in a mode that the
#: renormalised estimate gives almost nothing (less than this share, so no co-assignment moves by more), and the
#: choice of estimate judges the coverage of the other chains alone.
STRAY_CHAIN_MASS = 0.01


class SampleRecorder:
    """Pools kept samples into a histogram (run-length counted, also per chain) and per-chain traces.

    ``keep(chain, index, state)`` records the state a chain holds at its ``index``-th kept sample;
    :meth:`result` turns the histogram into a PTM under the estimate the chains call for
    (:meth:`resolved_estimate`), with ``diagnostics["estimate"]`` saying which.
    """

    def __init__(self, chains: int, n_samples: int):
        self.n_samples = n_samples
        self.counts: dict[Partition, int] = {}
        self.chain_counts: list[dict[Partition, int]] = [{} for _ in range(chains)]
        self.log_prob = np.empty((chains, n_samples))
        self.num_places = np.empty((chains, n_samples), dtype=np.int32)
        # One recorded log P per partition (the first computed): chains update log P incrementally, so their
        # values of one partition differ in the last digits, which rank-based R-hat would count as disagreement.
        self._log_prob_of: dict[Partition, float] = {}
        self._current = None
        self._chain = 0
        self._run_length = 0
        self._convergence = (-1, {})  # (samples recorded, their convergence diagnostics)

    def keep(self, chain: int, index: int, state) -> None:
        self.log_prob[chain, index] = self._log_prob_of.setdefault(state.partition, state.log_prob)
        self.num_places[chain, index] = len(state.blocks)
        if state.partition is not self._current or chain != self._chain:
            self.flush()
            self._current, self._chain = state.partition, chain
        self._run_length += 1

    def flush(self) -> None:
        if self._run_length:
            self.counts[self._current] = self.counts.get(self._current, 0) + self._run_length
            per_chain = self.chain_counts[self._chain]
            per_chain[self._current] = per_chain.get(self._current, 0) + self._run_length
        self._current, self._run_length = None, 0

    def extend(self, n_samples: int) -> None:
        """Make room for ``n_samples`` per chain (more than now), keeping what was recorded."""
        grown = n_samples - self.n_samples
        self.log_prob = np.pad(self.log_prob, ((0, 0), (0, grown)))
        self.num_places = np.pad(self.num_places, ((0, 0), (0, grown)))
        self.n_samples = n_samples

    def chain_coverages(self) -> np.ndarray:
        """Each chain's share of the renormalised mass of every visited topology: the mass of the topologies it
        visited itself (1 for each when the chains visited the same topologies)."""
        self.flush()
        mass = dict(zip(self.counts, self._weights(self.counts, "renormalised")))
        total = sum(mass.values())
        return np.array([sum(mass[partition] for partition in counts) / total for counts in self.chain_counts])

    def chain_coverage(self) -> float:
        """The smallest of :meth:`chain_coverages` (NaN with one chain)."""
        return float(self.chain_coverages().min()) if len(self.chain_counts) > 1 else math.nan

    def strays(self) -> dict:
        """The stray chains (``STRAY_CHAIN_MASS``): ``stray_chains``, their number, and where there are some,
        ``stray_mass_max``, the largest share of the renormalised mass that one of them visited, and
        ``stray_log_prob_gap``, how far the best topology a stray visited lies below the best of all [nats]."""
        coverages = self.chain_coverages()
        stray = np.flatnonzero(coverages < STRAY_CHAIN_MASS)
        if not len(stray):
            return {"stray_chains": 0}
        best = max(self._log_prob_of[partition] for partition in self.counts)
        best_of_strays = max(self._log_prob_of[partition] for index in stray for partition in self.chain_counts[index])
        return {"stray_chains": len(stray), "stray_mass_max": float(coverages[stray].max()),
                "stray_log_prob_gap": float(best - best_of_strays)}

    def resolved_estimate(self) -> str:
        """``"renormalised"`` where at least two chains that are not strays each cover ``RENORMALISE_COVERAGE`` of
        the renormalised mass (:meth:`chain_coverages`; one chain alone is no evidence that the bulk was found),
        else ``"frequency"``."""
        if len(self.chain_counts) < 2:
            return "frequency"
        coverages = self.chain_coverages()
        judged = coverages[coverages >= STRAY_CHAIN_MASS]
        return "renormalised" if len(judged) >= 2 and judged.min() >= RENORMALISE_COVERAGE else "frequency"

    def convergence(self) -> dict:
        """Split R-hat and ESS of log P and of the number of places (with 4 or more samples per chain), and
        for several chains the largest difference between two chains' co-assignments, the chains'
        coverage of the visited topologies (:meth:`chain_coverage`), the stray chains (:meth:`strays`) and the
        estimate resolved (:meth:`resolved_estimate`); else {}."""
        self.flush()
        recorded = sum(self.counts.values())
        if self._convergence[0] == recorded:
            return dict(self._convergence[1])
        chains, n_samples = self.log_prob.shape
        diagnostics = {}
        if chains > 1 and n_samples >= 4:
            for name, trace in (("log_prob", self.log_prob), ("num_places", self.num_places)):
                diagnostics[f"rhat_{name}"] = split_rhat(trace)
                diagnostics[f"ess_{name}"] = effective_sample_size(trace)
        if chains > 1:
            diagnostics["coassignment_max_difference"] = self.coassignment_max_difference()
            diagnostics["chain_coverage_min"] = self.chain_coverage()
            diagnostics.update(self.strays())
            diagnostics["estimate"] = self.resolved_estimate()  # what ptm.diagnostics.chains_agree judges by
        self._convergence = (recorded, diagnostics)
        return dict(diagnostics)

    def result(self, method: str, diagnostics: dict) -> PTM:
        """The PTM of the kept samples, with ``diagnostics`` and the convergence diagnostics."""
        diagnostics.update(self.convergence())
        diagnostics["n_distinct"] = len(self.counts)
        estimate = self.resolved_estimate()
        diagnostics["estimate"] = estimate
        return PTM(np.array([partition.labels for partition in self.counts], dtype=np.int32),
                   self._weights(self.counts, estimate), method, diagnostics,
                   traces={"log_prob": self.log_prob, "num_places": self.num_places})

    def _weights(self, counts: dict, estimate: str) -> np.ndarray:
        """Unnormalised probabilities of the visited topologies ``counts`` (partition -> samples kept) under
        ``estimate``: their sample counts, or exp(log P) scaled by the largest."""
        if estimate == "frequency":
            return np.array(list(counts.values()), dtype=float)
        log_probs = np.array([self._log_prob_of[partition] for partition in counts])
        return np.exp(log_probs - log_probs.max())

    def coassignment_max_difference(self) -> float:
        """max over pairs of chains and detections (i, j) of |C_a(i, j) - C_b(i, j)|, C_c the co-assignment
        matrix of chain c's own estimate (its samples alone, under :meth:`resolved_estimate`): 0 when the chains
        agree on which detections share a place."""
        estimate = self.resolved_estimate()
        matrices = [PTM(np.array([partition.labels for partition in counts], dtype=np.int32),
                        self._weights(counts, estimate), "chain").coassignment() for counts in self.chain_counts]
        return float(max(np.abs(first - second).max()
                         for index, first in enumerate(matrices) for second in matrices[index + 1:]))
