"""The appearance predictive check's arithmetic (``ptm-bench appearance-check``, issue 9) on hand-made signatures."""

import numpy as np
import pytest
from scipy import stats

import ptm
from ptm_bench.evaluation.appearance_check import _check


def test_the_appearance_check_counts_pairs_and_bounds_their_shares():
    # Two places, far apart on one component; detection 2 is a revisit of place 0 that looks like place 1,
    # so two of the four revisit pairs favour "split" and both its different-place pairs favour "merge".
    signatures = np.array([[0.0], [0.01], [1.0], [1.0], [1.01]])
    dataset = ptm.Dataset(signatures=signatures, labels=np.array([0, 0, 0, 1, 1]))
    model = ptm.AppearanceModel(mu=0.5, kappa=0.1, alpha=3.0, beta=1e-3)
    row, pits = _check(lambda run: model, [dataset])
    factors = ptm.appearance.pairwise_log_bayes_factors(model.bind(dataset))
    assert factors[0, 1] > 0 and factors[0, 2] < 0 and factors[2, 3] > 0  # the construction does what it says
    assert row["revisit_pairs"] == 4 and row["different_pairs"] == 6
    assert row["revisits_favouring_split"] == pytest.approx(2 / 4)  # (0, 2) and (1, 2)
    assert row["different_favouring_merge"] == pytest.approx(2 / 6)  # (2, 3) and (2, 4)
    assert row["revisits_favouring_split_low"] < 0.5 < row["revisits_favouring_split_high"]
    expected = stats.binomtest(2, 6).proportion_ci(0.95, method="exact")
    assert (row["different_favouring_merge_low"], row["different_favouring_merge_high"]) == pytest.approx(
        (expected.low, expected.high))
    assert pits.shape == (5, 1) and np.all((pits > 0) & (pits < 1))
