"""The PTM result's ArviZ export (docs/model.md §3.6): sampler traces as an InferenceData."""

import numpy as np
import pytest

import ptm
from helpers import appearance_posterior
from ptm.diagnostics import import_arviz


@pytest.fixture(scope="module")
def sampled():
    return ptm.mcmc(appearance_posterior(), 1_000, seed=3, chains=3, max_doublings=0)


def test_traces_become_an_inference_data_that_arviz_summarises(sampled):
    arviz = import_arviz()
    data = sampled.to_inference_data()
    assert set(data.groups()) == {"posterior", "sample_stats"}
    assert dict(data.posterior.sizes) == {"chain": 3, "draw": 1_000}
    np.testing.assert_array_equal(data.posterior["log_prob"].values, sampled.traces["log_prob"])
    np.testing.assert_array_equal(data.posterior["num_places"].values, sampled.traces["num_places"])
    np.testing.assert_array_equal(data.sample_stats["lp"].values, sampled.traces["log_prob"])
    assert data.posterior.attrs["ptm_method"] == "mcmc"
    summary = arviz.summary(data)
    assert list(summary.index) == ["log_prob", "num_places"]
    # the sampler's own diagnostics are ArviZ's, on the same traces
    assert float(arviz.rhat(data)["log_prob"]) == pytest.approx(sampled.diagnostics["rhat_log_prob"], rel=1e-12)
    assert float(arviz.ess(data)["num_places"]) == pytest.approx(sampled.diagnostics["ess_num_places"], rel=1e-12)


def test_arviz_draws_the_traces(sampled):
    pytest.importorskip("matplotlib")
    import matplotlib.pyplot as plt

    axes = import_arviz().plot_trace(sampled.to_inference_data())
    assert np.shape(axes) == (2, 2)  # one row per trace: density and trace
    plt.close("all")


def test_tempered_and_loaded_ptms_convert_too(tmp_path):
    tempered = ptm.tempered_mcmc(appearance_posterior(n=5), 200, temperatures=(1.0, 0.5), seed=1, chains=2,
                                 max_doublings=0)
    assert dict(tempered.to_inference_data().posterior.sizes) == {"chain": 2, "draw": 200}
    loaded = ptm.PTM.load(tempered.save(tmp_path / "tempered.npz"))
    np.testing.assert_array_equal(loaded.to_inference_data().posterior["log_prob"].values,
                                  tempered.traces["log_prob"])


def test_a_ptm_without_traces_is_refused_by_name():
    exact = ptm.exact_posterior(appearance_posterior(n=4))
    with pytest.raises(ValueError, match="method 'exact'.*no sampler traces"):
        exact.to_inference_data()
