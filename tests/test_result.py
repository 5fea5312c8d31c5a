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


@pytest.mark.parametrize("weights, expected", [
    ([1e308, 1e308, 1e308], [1 / 3, 1 / 3, 1 / 3]),  # the sum overflowed: all were normalised to 0
    ([1.7e308, 1e-300, 1.7e308], [0.5, 0.5, 0.0]),
    ([1e308, 5e-324, 1e307], [1 / 1.1, 0.1 / 1.1, 0.0]),
    ([5e-324, 1e-323, 1.5e-323], [1 / 2, 1 / 3, 1 / 6]),  # subnormal: the smallest positive floats
    ([5e-324, 5e-324, 5e-324], [1 / 3, 1 / 3, 1 / 3]),
])
def test_huge_and_subnormal_weights_normalise(weights, expected):
    result = ptm.PTM([[0, 0, 0], [0, 0, 1], [0, 1, 2]], weights, "test")  # most probable first
    assert result.probabilities == pytest.approx(expected, rel=1e-12, abs=0)
    assert result.probabilities.sum() == pytest.approx(1.0, rel=1e-15)


def test_ordinary_weights_normalise_to_the_same_bits_as_before():
    weights = np.array([3.0, 1.0, 2.5])
    result = ptm.PTM([[0, 0, 0], [0, 0, 1], [0, 1, 2]], weights, "test")
    np.testing.assert_array_equal(result.probabilities, np.sort(weights)[::-1] / weights.sum())


def test_complex_probabilities_are_refused(tmp_path):
    with pytest.raises(ValueError, match="PTM probabilities must be real numbers"):
        ptm.PTM([[0, 0], [0, 1]], [0.5 + 0.5j, 0.5], "test")  # the imaginary part was dropped with a ComplexWarning
    path = ptm.PTM([[0, 0], [0, 1]], [0.5, 0.5], "exact").save(tmp_path / "result.npz")
    with np.load(path) as archive:
        contents = dict(archive)
    np.savez(path, **{**contents, "probabilities": contents["probabilities"] * (1 + 1j)})
    with pytest.raises(ValueError, match=rf"{path}: PTM probabilities must be real numbers"):
        ptm.PTM.load(path)
