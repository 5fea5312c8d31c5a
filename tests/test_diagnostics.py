"""Convergence diagnostics (ptm.diagnostics): split R-hat and effective sample size on known traces."""

import numpy as np
import pytest

from ptm.diagnostics import effective_sample_size, split_rhat


def autoregressive(rho, chains, length, rng):
    traces = np.empty((chains, length))
    traces[:, 0] = rng.normal(size=chains) / np.sqrt(1 - rho**2)
    for t in range(1, length):
        traces[:, t] = rho * traces[:, t - 1] + rng.normal(size=chains)
    return traces


def test_independent_chains_agree_and_every_draw_counts():
    traces = np.random.default_rng(0).normal(size=(4, 2000))
    assert split_rhat(traces) < 1.01
    assert effective_sample_size(traces) == pytest.approx(8000, rel=0.15)


def test_chains_stuck_in_different_places_are_flagged():
    traces = np.random.default_rng(1).normal(size=(4, 2000)) + np.array([[0.0], [0.0], [3.0], [3.0]])
    assert split_rhat(traces) > 1.5


def test_autocorrelated_chains_have_the_textbook_effective_size():
    rho = 0.9  # ESS = n (1 - rho) / (1 + rho)
    traces = autoregressive(rho, 4, 20_000, np.random.default_rng(2))
    assert effective_sample_size(traces) == pytest.approx(80_000 * (1 - rho) / (1 + rho), rel=0.25)
    assert split_rhat(traces) < 1.02


def test_a_trace_that_moves_only_by_rounding_is_constant():
    # a chain that never leaves one topology: its incrementally updated log P drifts in the last digits
    traces = np.full((2, 1000), -1234.5678)
    traces[0, 500:] += 2.3e-13  # one rounding step half-way
    traces[1] += 4.5e-13
    assert split_rhat(traces) == 1.0
    assert effective_sample_size(traces) == 2000.0
    # constant halves at different values never mix
    assert split_rhat(np.repeat([[0.0], [1.0]], 100, axis=1)) == np.inf


def test_diagnostics_are_arviz_on_the_same_traces():
    from ptm.diagnostics import import_arviz

    arviz = import_arviz()
    traces = np.random.default_rng(3).normal(size=(3, 500)).cumsum(axis=1)  # random walks: R-hat well above 1
    assert split_rhat(traces) == pytest.approx(float(arviz.rhat(traces, method="rank")), rel=1e-12)
    assert effective_sample_size(traces) == pytest.approx(float(arviz.ess(traces, method="bulk")), rel=1e-12)
    assert split_rhat(traces) > 1.1


def test_a_missing_arviz_is_named(monkeypatch):
    import builtins

    from ptm.diagnostics import import_arviz

    real_import = builtins.__import__

    def without_arviz(name, *args, **kwargs):
        if name == "arviz":
            raise ImportError("No module named 'arviz'")
        return real_import(name, *args, **kwargs)

    monkeypatch.setattr(builtins, "__import__", without_arviz)
    with pytest.raises(ImportError, match="need the arviz package"):
        import_arviz()
