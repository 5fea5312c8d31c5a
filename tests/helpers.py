"""Shared builders for the tests: small posteriors with exactly enumerable targets, and a small labelled run."""

import numpy as np

import ptm

TRUE_LABELS_8 = np.array([0, 1, 2, 0, 1, 2, 0, 1])
PLACE_SIGNATURES = np.array([[0.30, 0.10], [0.25, 0.15], [0.40, 0.05]])


def prior_only_posterior(n: int = 6, rate: float = 2.0) -> ptm.Posterior:
    return ptm.Posterior(ptm.Dataset(labels=np.zeros(n, dtype=int)), ptm.PoissonPrior(rate))


def appearance_posterior(n: int = 8, noise: float = 0.02, seed: int = 0) -> ptm.Posterior:
    """Three places with nearby signatures: a posterior spread over many partitions (entropy ~2 nats)."""
    rng = np.random.default_rng(seed)
    labels = TRUE_LABELS_8[:n]
    signatures = PLACE_SIGNATURES[labels] + rng.normal(0.0, noise, size=(n, 2))
    dataset = ptm.Dataset(signatures=signatures, labels=labels)
    model = ptm.AppearanceModel(mu=0.3, kappa=0.05, alpha=3.0, beta=2.0 * noise ** 2)
    return ptm.Posterior(dataset, ptm.PoissonPrior(3.0), [model])


CORNERS = np.array([[0.0, 0.0], [2.0, 0.0], [2.0, 2.0], [0.0, 2.0]])
LOOP_LABELS = np.array([0, 1, 2, 3, 0, 1, 2, 3, 0])


def square_loop_dataset(seed: int, labels=LOOP_LABELS, detection_radius: float = 0.5) -> ptm.Dataset:
    """A robot driving a 2 m square twice, detecting its four corners: true poses near the corners, noisy odometry
    with covariances, a signature per place, and the detector's radius in the meta (a sensor specification)."""
    from ptm.se2 import relative_pose

    rng = np.random.default_rng(seed)
    labels = np.asarray(labels)
    xy = CORNERS[labels % len(CORNERS)] + rng.normal(0.0, 0.05, size=(len(labels), 2))
    heading = np.arctan2(np.roll(xy, -1, axis=0)[:, 1] - xy[:, 1], np.roll(xy, -1, axis=0)[:, 0] - xy[:, 0])
    poses = np.column_stack([xy, heading])
    odometry = relative_pose(poses[:-1], poses[1:]) + rng.normal(0.0, [0.1, 0.1, 0.05], size=(len(labels) - 1, 3))
    covariance = np.tile(np.diag([0.01, 0.01, 0.0025]), (len(labels) - 1, 1, 1))
    place_looks = np.array([[0.3, 0.1], [0.5, 0.2], [0.2, 0.4], [0.6, 0.5]])
    signatures = place_looks[labels % len(CORNERS)] + rng.normal(0.0, 0.02, size=(len(labels), 2))
    return ptm.Dataset(odometry=odometry, odometry_cov=covariance, signatures=signatures, labels=labels,
                       true_poses=poses, meta={"detection_radius": detection_radius})
