"""TieNormaliser: the normaliser of the odometry model's ties for landmarks spread over an area."""

import math

import numpy as np
import pytest
from scipy import integrate

import ptm
from helpers import appearance_posterior


def _tie_energy(positions, sigma):
    positions = np.asarray(positions, dtype=float)
    return sum(np.sum((positions[i] - positions[j]) ** 2) for i in range(len(positions))
               for j in range(i + 1, len(positions))) / (2.0 * sigma ** 2)


@pytest.mark.parametrize("size", [2, 3])
def test_the_normaliser_is_the_integral_of_the_tie_density(size):
    # In one dimension, with the set's mean held fixed (its integral is the area, A), the tie integrates to
    # sqrt(n) (2 pi sigma^2 / n)^((n - 1) / 2); in two dimensions to the square of that, n (2 pi sigma^2 / n)^(n - 1).
    sigma = 0.7

    def density(*offsets):  # positions = mean + offsets, the last offset fixed by a zero mean
        positions = np.append(offsets, -sum(offsets))[:, None]
        return math.exp(-_tie_energy(positions, sigma))

    numeric, _ = integrate.nquad(density, [(-8.0, 8.0)] * (size - 1))
    one_dimension = numeric * size  # the Jacobian of (t_1 .. t_n) -> (mean, n - 1 offsets) is n
    assert one_dimension == pytest.approx(math.sqrt(size) * (2 * math.pi * sigma ** 2 / size) ** ((size - 1) / 2),
                                          rel=1e-7)
    area = 50.0
    normaliser = ptm.TieNormaliser(area, sigma)
    expected = (size - 1) * math.log(area) - math.log(one_dimension ** 2)
    assert normaliser.block_log_likelihood(tuple(range(size))) == pytest.approx(expected, rel=1e-7)
    assert normaliser.block_log_likelihood((4,)) == 0.0


def test_with_odometry_alone_it_moves_mass_from_all_distinct_to_the_revisits():
    rng = np.random.default_rng(0)
    labels = np.arange(7) % 4
    corners = np.array([[0.0, 0.0], [5.0, 0.0], [5.0, 5.0], [0.0, 5.0]])
    poses = np.column_stack([corners[labels], ptm.se2.wrap_angle(labels * np.pi / 2)])
    odometry = ptm.se2.relative_pose(poses[:-1], poses[1:]) + rng.normal(0.0, [0.1, 0.1, 0.03], size=(6, 3))
    dataset = ptm.Dataset(odometry=odometry, labels=labels)
    model = ptm.OdometryModel(0.1, 0.03, sigma_topology=0.5, penalty_radius=2.0, max_penalty=0.0, seed=1)
    paper = ptm.exact_posterior(ptm.Posterior(dataset, ptm.PoissonPrior(4.0), [model]))
    normalised = ptm.exact_posterior(ptm.Posterior(
        dataset, ptm.PoissonPrior(4.0), [model, ptm.TieNormaliser.from_dead_reckoning(dataset, 0.5, margin=1.0)]))
    # without a penalty the paper's model can only prefer all-distinct; the normalised ties find the loop
    assert paper.map() == tuple(range(7))
    assert normalised.map() == tuple(labels)
    assert normalised.probability(labels) > 0.5 > paper.probability(labels)


def test_bad_areas_and_margins_are_refused():
    with pytest.raises(ValueError, match="area"):
        ptm.TieNormaliser(0.0, 1.0)
    with pytest.raises(ValueError, match="margin"):
        ptm.TieNormaliser.from_dead_reckoning(ptm.Dataset(odometry=np.ones((2, 3))), 1.0, margin=-1.0)
    with pytest.raises(ValueError, match="no area"):
        ptm.TieNormaliser.from_dead_reckoning(ptm.Dataset(odometry=np.zeros((2, 3))), 1.0, margin=0.0)
    with pytest.raises(ValueError, match="odometry"):
        ptm.TieNormaliser.from_dead_reckoning(ptm.Dataset(signatures=np.ones((2, 2))), 1.0, margin=1.0)
    with pytest.raises(ValueError, match="margin"):
        ptm.DeadReckonedTieNormaliser(1.0, margin=math.nan)


@pytest.mark.parametrize("route, margin, area", [
    ([[0.0, 0.0], [10.0, 0.0]], 1.0, 2 * 10.0 + math.pi),                   # a capsule
    ([[0.0, 0.0], [7.0, 7.0], [14.0, 0.0]], 0.5, 2 * 0.5 * 2 * math.hypot(7.0, 7.0) + math.pi * 0.25
     - 0.25 * (1 - math.pi / 4)),                                          # two capsules, the knee's corner
    ([[20.0 * math.cos(t), 20.0 * math.sin(t)] for t in np.linspace(0, 2 * math.pi, 721)], 1.5,
     math.pi * (21.5 ** 2 - 18.5 ** 2)),                                   # a ring
    ([[0.0, 0.0]], 2.0, 4.0 * math.pi),                                    # a point: a disc
])
def test_the_route_area_is_the_area_within_the_margin_of_the_route(route, margin, area):
    assert ptm.tie_normaliser.route_area(route, margin) == pytest.approx(area, rel=0.04)


def test_a_retraced_corridor_counts_once_and_a_box_counts_what_the_route_never_reaches():
    """Back and forth along one corridor is its area once; an L-shaped route fills a fraction of its box."""
    there_and_back = [[0.0, 0.0], [20.0, 0.0], [0.0, 0.0], [20.0, 0.0]]
    assert ptm.tie_normaliser.route_area(there_and_back, 1.0) == pytest.approx(
        ptm.tie_normaliser.route_area(there_and_back[:2], 1.0), rel=1e-9)
    steps = [[20.0, 0.0, math.pi / 2], [20.0, 0.0, 0.0]]  # 20 m east, then 20 m north: an L
    dataset = ptm.Dataset(odometry=steps)
    route = ptm.TieNormaliser.from_dead_reckoning(dataset, 1.0, margin=1.0)
    box = ptm.TieNormaliser(22.0 * 22.0, 1.0)  # the box around the dead-reckoned detections, margin added
    assert route.area == pytest.approx(2 * 2 * 20.0 + math.pi - (1 - math.pi / 4), rel=0.04)
    assert route.area < 0.2 * box.area
    bound = ptm.DeadReckonedTieNormaliser(1.0, margin=1.0).bind(dataset)
    assert bound.area == route.area and bound.block_log_likelihood((0, 2)) < box.block_log_likelihood((0, 2))


def test_standalone_scores_leave_out_the_terms_that_complete_a_global_one():
    # The normaliser's merge reward only an odometry term's ties take back: what scores the cheap terms alone
    # (Posterior.standalone_block_score) leaves it out, the full block score keeps it.
    appearance = appearance_posterior(8)
    normaliser = ptm.TieNormaliser(area=1600.0, sigma_topology=0.53)
    with_normaliser = ptm.Posterior(appearance.dataset, appearance.prior, appearance.terms + [normaliser])
    for block in [(0,), (0, 1), (2, 5, 7)]:
        assert with_normaliser.standalone_block_score(block) == pytest.approx(appearance.block_score(block), abs=1e-12)
        assert with_normaliser.block_score(block) == pytest.approx(
            appearance.block_score(block) + normaliser.block_log_likelihood(block), abs=1e-12)
    assert normaliser.block_log_likelihood((0, 1)) > 5.0  # the check has teeth: the reward is several nats a pair
    assert appearance.standalone_block_score((0, 1)) == appearance.block_score((0, 1))
