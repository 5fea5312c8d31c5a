"""Importance sampling of the odometry integral in the increments' coordinates (docs/model.md §3.3, erratum E12).

A Gaussian in the poses cannot follow a route whose heading is uncertain: a turn of the heading early on
swings every later pose on an arc. Drawn in the relative poses between consecutive detections (which the
odometry constrains directly) and composed, the same Laplace Gaussian fits the integrand. These tests
check the exact case (a route without ties or penalty, whose integral is known in closed form), with the
poses' coordinates as the negative control, and that both coordinates estimate the same integral where
ties and the penalty act.

    python -m pytest tests/test_odometry_increments.py -q
"""

import numpy as np
import pytest

import ptm
from ptm.odometry import compose_linearised_increments
from ptm.pose_graph import poses_from_vector
from ptm.se2 import relative_pose
from test_odometry import square_loop_dataset
from test_odometry_proposal import issue_loop


def odometry(coordinates, n_importance=100, max_penalty=0.0, seed=0):
    return ptm.OdometryModel(0.2, 0.05, 0.3, 3.0, max_penalty, n_importance=n_importance, seed=seed,
                             sampling_coordinates=coordinates)


def test_a_route_without_ties_is_integrated_exactly_in_the_increments():
    # Every detection its own place and no penalty: E is a sum of independent Gaussian steps in the
    # increments, so the integral is sum_k 1/2 log det(2 pi Sigma_k) and every importance weight is equal.
    dataset = square_loop_dataset(60, side=5.0, sigma_xy=0.1, sigma_theta=0.05, seed=0)
    distinct = list(range(dataset.n))
    term = odometry("increments").bind(dataset)
    evaluation = term.evaluate(distinct)
    assert evaluation.log_likelihood == pytest.approx(term.log_likelihood_upper_bound(), abs=1e-9)
    assert evaluation.ess == pytest.approx(100.0)
    # negative control: the same Gaussian drawn in the poses (measured: 6.1 nats low, ESS 4 of 100)
    poses = odometry("poses").bind(dataset).evaluate(distinct)
    assert poses.log_likelihood < term.log_likelihood_upper_bound() - 1.0 and poses.ess < 20


@pytest.mark.parametrize("labels, max_penalty", [
    ([0, 1, 2, 3, 0, 1, 2], 0.0),     # the truth: ties only
    ([0, 1, 2, 3, 4, 1, 2], 10.0),    # detection 4 back at place 0 but called new: the penalty acts
    ([0, 1, 2, 3, 0, 1, 2], 30.0),
], ids=["truth", "penalised", "truth_with_penalty"])
def test_both_coordinates_estimate_the_same_integral(labels, max_penalty):
    dataset = issue_loop()
    estimates = [odometry(coordinates, 4000, max_penalty).bind(dataset).evaluate(labels)
                 for coordinates in ("poses", "increments")]
    combined = np.hypot(*[evaluation.standard_error for evaluation in estimates])
    assert abs(estimates[0].log_likelihood - estimates[1].log_likelihood) <= 4 * combined + 1e-3, estimates
    assert estimates[0].laplace == pytest.approx(estimates[1].laplace, abs=1e-12)  # one Laplace fit


def test_the_composition_is_exact_in_the_increments_and_first_order_in_the_poses():
    rng = np.random.default_rng(0)
    centre = rng.normal(size=15)
    tiny = rng.normal(size=(15, 1)) * 1e-7
    np.testing.assert_allclose(compose_linearised_increments(centre, tiny)[0], centre + tiny[:, 0], atol=1e-12)
    offsets = rng.normal(size=(15, 1)) * 0.3
    placed = poses_from_vector(compose_linearised_increments(centre, offsets)[0])
    before = poses_from_vector(centre)
    step = 1e-7  # u* + K delta: K by a finite difference of the relative poses
    moved = poses_from_vector(centre + step * offsets[:, 0])
    linearised = (relative_pose(before[:-1], before[1:])
                  + (relative_pose(moved[:-1], moved[1:]) - relative_pose(before[:-1], before[1:])) / step)
    np.testing.assert_allclose(relative_pose(placed[:-1], placed[1:]), linearised, atol=1e-6)


def test_unknown_coordinates_are_refused_and_configs_know_the_same_ones():
    with pytest.raises(ValueError, match="sampling_coordinates must be one of"):
        ptm.OdometryModel(sampling_coordinates="world")
    from ptm_bench.evaluation import experiment  # it lists them itself: parsing a config imports no inference

    assert set(experiment.SAMPLING_COORDINATES) == set(ptm.odometry.SAMPLING_COORDINATES)
    assert experiment.DEFAULTS["odometry"]["sampling_coordinates"] == ptm.OdometryModel().sampling_coordinates
    with pytest.raises(ValueError, match="penalty_proposal must be one of"):
        ptm.OdometryModel(penalty_proposal="tails")
    assert set(experiment.PENALTY_PROPOSALS) == set(ptm.odometry.PENALTY_PROPOSALS)
    assert experiment.DEFAULTS["odometry"]["penalty_proposal"] == ptm.OdometryModel().penalty_proposal
