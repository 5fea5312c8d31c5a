"""Convergence diagnostics for several chains: rank-normalised split R-hat and effective sample size.

Both come from ArviZ (:func:`arviz.rhat`, :func:`arviz.ess`; Vehtari, Gelman,
Simpson, Carpenter and Bürkner, "Rank-normalization, folding, and
localization: an improved R-hat for assessing convergence of MCMC", Bayesian
Analysis 2021): R-hat compares the variance between half-chains with the
variance within them after rank-normalising the draws (and takes the larger of
the bulk and the folded-tail value); values near 1 (below ~1.01) mean the
chains agree. The ESS is the bulk effective sample size. ArviZ is imported
when a diagnostic is first computed, so ``import ptm`` stays light.

Two cases are settled here before ArviZ sees them, because rank
normalisation turns rounding noise into signal: a trace whose values differ
only by rounding (a chain that never left one topology: its log-probability is
updated incrementally, so it drifts in the last digits) counts as constant
(R-hat 1, every draw effective), and half-chains that are each constant at
different values never mixed (R-hat infinite, one effective draw per half-chain).

Independent chains *agree* (:func:`chains_agree`) when the split R-hat of
log P and of the number of places are at most ``AGREEMENT_RHAT`` and every two
chains' co-assignment matrices are within ``AGREEMENT_COASSIGNMENT`` of each
other (max abs): the samplers extend chains that do not (``max_doublings``)
and the harness warns about results that still do not. Where the probabilities
are the posterior values renormalised over the visited topologies
(``diagnostics["estimate"] == "renormalised"``), how often a chain visited a
topology does not enter them, so the R-hats, which measure whether visit
frequencies have settled, are not part of the verdict: chains agree when their
own renormalised estimates do (co-assignments within the bound). On
near-point-mass posteriors the R-hats otherwise flag chains whose estimates
agree to 1e-40 (a chain's rare, short excursions fall in one half of it).

    >>> traces = np.random.default_rng(0).normal(size=(4, 1000))
    >>> round(split_rhat(traces), 2), effective_sample_size(traces) > 3000
    (1.0, True)
"""

from __future__ import annotations

import warnings

import numpy as np

__all__ = ["split_rhat", "effective_sample_size", "chains_agree", "import_arviz", "AGREEMENT_RHAT",
           "AGREEMENT_COASSIGNMENT"]

#: The largest split R-hat (of log P and of the number of places) at which chains agree.
AGREEMENT_RHAT = 1.05
#: The largest difference (max abs) between two chains' co-assignment matrices at which they agree.
AGREEMENT_COASSIGNMENT = 0.05
#: The diagnostics :func:`chains_agree` reads.
AGREEMENT_DIAGNOSTICS = ("rhat_log_prob", "rhat_num_places", "coassignment_max_difference")


def _traces(traces) -> np.ndarray:
    traces = np.asarray(traces, dtype=float)
    if traces.ndim != 2:
        raise ValueError(f"traces must have shape (chains, samples), got {traces.shape}")
    if traces.shape[1] < 4:
        raise ValueError("each chain needs at least 4 samples for split diagnostics")
    return traces


def _split_halves(traces: np.ndarray) -> np.ndarray:
    half = traces.shape[1] // 2
    return np.concatenate([traces[:, :half], traces[:, -half:]], axis=0)


def _constant(values) -> bool:
    """True when the values differ by no more than rounding (relative 1e-9)."""
    return float(np.ptp(values)) <= 1e-9 * max(1.0, float(np.abs(values).max()))


def _never_mixed(halves) -> bool:
    """True when every half-chain is constant (to rounding) on its own."""
    return all(_constant(half) for half in halves)


def import_arviz():
    """The ``arviz`` module, imported on first use (``import ptm`` does not load it), without the
    FutureWarning that arviz 0.2x prints on import about its coming refactor."""
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", FutureWarning)
            import arviz
    except ImportError as error:
        raise ImportError("R-hat, ESS and PTM.to_inference_data need the arviz package "
                          "(python3 -m pip install arviz)") from error
    return arviz


def split_rhat(traces) -> float:
    """Rank-normalised split R-hat (:func:`arviz.rhat`) of a scalar trace, shape (chains, samples)."""
    traces = _traces(traces)
    if _constant(traces):
        return 1.0
    if _never_mixed(_split_halves(traces)):
        return float("inf")
    return float(import_arviz().rhat(traces, method="rank"))


def effective_sample_size(traces) -> float:
    """Bulk effective sample size (:func:`arviz.ess`) of a scalar trace, shape (chains, samples)."""
    traces = _traces(traces)
    halves = _split_halves(traces)
    if _constant(traces):
        return float(halves.size)
    if _never_mixed(halves):
        return float(halves.shape[0])
    return float(import_arviz().ess(traces, method="bulk"))


def chains_agree(diagnostics: dict) -> bool | None:
    """Whether a sampler's independent chains agree (module docstring), or None when ``diagnostics`` lack one
    of ``AGREEMENT_DIAGNOSTICS`` (one chain, the exact posterior).

        >>> chains_agree({"rhat_log_prob": 1.01, "rhat_num_places": 1.0, "coassignment_max_difference": 0.02})
        True
        >>> chains_agree({"rhat_log_prob": 1.01, "rhat_num_places": 1.0, "coassignment_max_difference": 0.3})
        False
        >>> chains_agree({"rhat_log_prob": 1.6, "rhat_num_places": 1.3, "coassignment_max_difference": 1e-40,
        ...               "estimate": "renormalised"})
        True
    """
    reached = [diagnostics.get(name) for name in AGREEMENT_DIAGNOSTICS]
    if any(value is None for value in reached):
        return None
    rhat_log_prob, rhat_num_places, coassignment = reached
    if diagnostics.get("estimate") == "renormalised":
        return bool(coassignment <= AGREEMENT_COASSIGNMENT)
    return bool(rhat_log_prob <= AGREEMENT_RHAT and rhat_num_places <= AGREEMENT_RHAT
                and coassignment <= AGREEMENT_COASSIGNMENT)
