"""Where the importance samples are placed: the Laplace Gaussian read in the increments (docs/model.md §3.3,
step 2, "Where the Gaussian is drawn"; erratum E12).

A draw delta ~ N(0, H^-1) of the Laplace proposal is read in the relative poses between consecutive
detections, which the odometry constrains directly, and composed from the origin:

    P(delta) = C(u* + K delta),

with u* the increments of P*, K = du/dP at P* and C the composition. K and C are triangular with rotation
(or unit) diagonal blocks, so both have determinant 1: the state has density N(delta; 0, H^-1) in the
increments' coordinates, where the integral of exp(-E - Pen) is the same as in the poses', and the
importance weights keep their form. A Gaussian in the poses cannot follow a long route: a heading error at
one detection swings every later pose on an arc, far from where a Gaussian in the poses puts it.
:func:`compose_linearised_increments` places draws; :func:`linearised_increment_offsets` inverts it, for
the density of a state under a proposal component centred elsewhere (:mod:`ptm.odometry.proposal`).

    >>> centre = np.array([1.0, 0.0, 0.5, 2.0, 0.5, 1.0])         # two poses after the origin
    >>> delta = np.random.default_rng(0).normal(0.0, 0.1, (6, 3))
    >>> np.allclose(linearised_increment_offsets(centre, compose_linearised_increments(centre, delta)), delta)
    True
"""

from __future__ import annotations

import numpy as np

from ..pose_graph import poses_from_vector
from ..se2 import relative_pose

__all__ = ["compose_linearised_increments", "linearised_increment_offsets"]


def compose_linearised_increments(centre, offsets) -> np.ndarray:
    """States (S, d) P(u) for u = u* + K delta: ``offsets`` delta (d, S) mapped to relative poses at
    P* = ``centre`` (d,) and composed from the fixed origin.

        >>> centre = np.array([1.0, 0.0, 0.5, 2.0, 0.5, 1.0])
        >>> np.allclose(compose_linearised_increments(centre, np.zeros((6, 1))), centre)
        True
    """
    centre = np.asarray(centre, dtype=float)
    samples = offsets.shape[1]
    poses = poses_from_vector(centre)  # (N, 3), the origin first
    moves = np.concatenate([np.zeros((1, 3, samples)), offsets.reshape(-1, 3, samples)])  # (N, 3, S)
    before, after = poses[:-1], poses[1:]
    cos, sin = np.cos(before[:, 2])[:, None], np.sin(before[:, 2])[:, None]
    dx, dy = (after[:, 0] - before[:, 0])[:, None], (after[:, 1] - before[:, 1])[:, None]
    forward, left = cos * dx + sin * dy, -sin * dx + cos * dy  # u*: the step in the frame of the pose before
    ddx, ddy = moves[1:, 0] - moves[:-1, 0], moves[1:, 1] - moves[:-1, 1]
    turn_before = moves[:-1, 2]
    step_forward = forward + cos * ddx + sin * ddy + left * turn_before
    step_left = left - sin * ddx + cos * ddy - forward * turn_before
    step_turn = (after[:, 2] - before[:, 2])[:, None] + moves[1:, 2] - moves[:-1, 2]
    headings = np.cumsum(step_turn, axis=0)  # heading of pose k (the origin's is 0)
    heading_before = np.concatenate([np.zeros((1, samples)), headings[:-1]])
    cos_h, sin_h = np.cos(heading_before), np.sin(heading_before)
    x = np.cumsum(cos_h * step_forward - sin_h * step_left, axis=0)
    y = np.cumsum(sin_h * step_forward + cos_h * step_left, axis=0)
    return np.stack([x, y, headings], axis=1).reshape(-1, samples).T


def linearised_increment_offsets(centre, states) -> np.ndarray:
    """The inverse of :func:`compose_linearised_increments`: the offsets delta (d, S) with
    ``compose_linearised_increments(centre, delta) == states`` for states (S, d), i.e.
    delta = K^-1 (u(states) - u*), K^-1 the linearised composition at P* = ``centre``."""
    centre, states = np.asarray(centre, dtype=float), np.asarray(states, dtype=float)
    samples = states.shape[0]

    centre_poses = poses_from_vector(centre)[:, :, None]  # (N, 3, 1)
    sampled_poses = poses_from_vector(states)  # (S, N, 3)
    # u(states) - u*: (N - 1, 3, S), the step in the frame of the pose before and the turn
    change = np.moveaxis(relative_pose(sampled_poses[:, :-1], sampled_poses[:, 1:])
                         - relative_pose(centre_poses[:-1, :, 0], centre_poses[1:, :, 0]), 0, -1)
    # the turn's offset from the headings as they are, not wrapped: a draw far from P* (a wide proposal) may
    # turn by more than pi more than P* does, and wrapping would map it to another offset and another density
    change[:, 2] = (np.diff(sampled_poses[:, :, 2], axis=1) - np.diff(centre_poses[:, 2, 0])).T
    turns = np.cumsum(change[:, 2], axis=0)  # the heading offset of poses 1..N-1
    turn_before = np.concatenate([np.zeros((1, samples)), turns[:-1]])
    before = centre_poses[:-1, :, 0]
    cos, sin = np.cos(before[:, 2])[:, None], np.sin(before[:, 2])[:, None]
    step_x = (centre_poses[1:, 0] - centre_poses[:-1, 0])  # (N - 1, 1)
    step_y = (centre_poses[1:, 1] - centre_poses[:-1, 1])
    # d t_k = d t_{k-1} + R(theta*_{k-1}) d s_k + d theta_{k-1} perp(t*_k - t*_{k-1}), perp(x, y) = (-y, x)
    x = np.cumsum(cos * change[:, 0] - sin * change[:, 1] - turn_before * step_y, axis=0)
    y = np.cumsum(sin * change[:, 0] + cos * change[:, 1] + turn_before * step_x, axis=0)
    return np.stack([x, y, turns], axis=1).reshape(-1, samples)
