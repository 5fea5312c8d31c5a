"""Recorded values of the odometry likelihood log P(O | T) (docs/model.md §3.3): the evaluation may get
faster, never different.

Every change to ``ptm.odometry`` and ``ptm.pose_graph`` must leave these values alone to 1e-9 relative (or
1e-9 nats); a change that is meant to move them records the new ones here, and the results it affects are
rerun. The literals are ``term.log_likelihood(labels)`` as the estimator computes them (fits from the chordal
and the dead-reckoning starts, draws in the increments, the penalised mode where the penalty acts), with
OPENBLAS_NUM_THREADS=1, for the truth, all distinct, all one place and random partitions
(``numpy.random.default_rng(len(name)).integers(0, 4, size=n)``) of three cases, which use the penalty
mixture (60-90 % of these partitions), the banded + low-rank and the sparse factor, and per-step
covariances with correlations.

    python -m pytest tests/test_odometry_values.py -q
"""

import numpy as np
import pytest

import ptm
from test_odometry import mixed_dataset, square_loop_dataset

LOOP = dict(sigma_xy=0.5, sigma_theta=0.15, sigma_topology=0.5, penalty_radius=3.0, max_penalty=5.0,
            n_importance=50, seed=0)

LOOP_VALUES = [
    ([0, 1, 2, 3, 0, 1, 2, 3], -12.089750282844953),
    ([0, 1, 2, 3, 4, 5, 6, 7], -5.613610168229108),
    ([0, 0, 0, 0, 0, 0, 0, 0], -215.22147661427817),
    ([0, 1, 1, 0, 1, 1, 1, 2], -118.49467606963404),
    ([0, 1, 0, 0, 1, 2, 1, 3], -79.53186743462312),
    ([0, 1, 2, 0, 3, 1, 2, 3], -33.051642098410774),
    ([0, 1, 2, 0, 0, 0, 0, 1], -124.50012999834817),
    ([0, 1, 0, 1, 0, 2, 3, 0], -103.67087183457572),
    ([0, 1, 0, 2, 3, 1, 3, 3], -78.0989682765679),
    ([0, 1, 1, 1, 2, 0, 1, 2], -90.55003721816854),
]

LOOP_SPARSE_VALUES = [
    ([0, 1, 2, 3, 0, 1, 2, 3], -11.985104761437254),
    ([0, 1, 2, 3, 4, 5, 6, 7], -5.546898347288411),
    ([0, 0, 0, 0, 0, 0, 0, 0], -215.32283597520757),
    ([0, 0, 1, 2, 3, 3, 3, 0], -79.10612140143193),
    ([0, 1, 0, 2, 3, 1, 3, 1], -89.1312299194324),
]

CORRELATED = dict(sigma_topology=0.5, penalty_radius=6.0, max_penalty=100.0, n_importance=100, seed=3)

CORRELATED_VALUES = [
    ([0, 1, 2, 3, 0, 1, 2, 3, 0, 1, 2], -76.09705610455478),
    ([0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10], -342.80585482342576),
    ([0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0], -2193.2055795823067),
    ([0, 0, 1, 2, 0, 0, 3, 2, 0, 3, 2], -545.1563154089683),
    ([0, 1, 2, 1, 3, 0, 1, 2, 3, 0, 3], -684.1750481156608),
    ([0, 1, 2, 2, 3, 3, 3, 3, 0, 3, 3], -856.7617642929349),
    ([0, 1, 2, 3, 0, 3, 1, 1, 0, 3, 1], -632.4830705510175),
    ([0, 1, 2, 3, 2, 0, 0, 1, 0, 1, 3], -876.9440011351406),
    ([0, 1, 2, 0, 0, 2, 1, 1, 1, 3, 3], -770.708332382968),
    ([0, 1, 0, 0, 1, 2, 0, 2, 2, 2, 2], -1073.9683343806207),
]


def correlated_dataset(n=11):
    """A square driven repeatedly, with per-step covariances that correlate the three components."""
    dataset = square_loop_dataset(n, side=5.0, seed=2)
    rng = np.random.default_rng(5)
    factors = np.diag([0.1, 0.06, 0.03]) + np.tril(rng.normal(0.0, 0.02, size=(n - 1, 3, 3)), -1)
    return ptm.Dataset(odometry=dataset.odometry, odometry_cov=factors @ np.swapaxes(factors, 1, 2),
                       labels=dataset.labels)


@pytest.mark.parametrize("dataset, settings, recorded", [
    (mixed_dataset(8), LOOP, LOOP_VALUES),
    (mixed_dataset(8), dict(LOOP, sparse_above=6), LOOP_SPARSE_VALUES),
    (correlated_dataset(), CORRELATED, CORRELATED_VALUES),
], ids=["loop", "loop_sparse", "correlated"])
def test_the_values_are_those_recorded(dataset, settings, recorded):
    term = ptm.OdometryModel(**settings).bind(dataset)
    for labels, value in recorded:
        assert term.log_likelihood(labels) == pytest.approx(value, rel=1e-9, abs=1e-9), labels
