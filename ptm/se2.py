"""SE(2) algebra of planar poses (x, y, theta): the one place the library and the harness compose poses.

A pose ``world_T_a`` maps coordinates in frame ``a`` to the world frame. An
odometry row is the relative pose ``a_T_b`` = (world_T_a)^-1 o world_T_b of a
detection b in the frame of the detection a before it (docs/model.md §2.2),
so composing the rows from the first pose (dead reckoning) recovers the poses
the odometry alone implies. Every function accepts stacked poses of shape
(..., 3).

    >>> import numpy as np
    >>> step = np.array([1.0, 0.0, np.pi / 2])        # one metre forward, then turn left
    >>> dead_reckoning([step, step, step, step])[-1].round(12) + 0.0
    array([0.        , 0.        , 6.28318531])
    >>> relative_pose([2.0, 1.0, 0.3], compose([2.0, 1.0, 0.3], step)).round(12) + 0.0
    array([1.        , 0.        , 1.57079633])
"""

from __future__ import annotations

import numpy as np

__all__ = ["wrap_angle", "compose", "relative_pose", "dead_reckoning"]


def wrap_angle(angle):
    """Angles wrapped to (-pi, pi]."""
    wrapped = np.mod(np.asarray(angle, dtype=float) + np.pi, 2.0 * np.pi) - np.pi
    return np.where(wrapped == -np.pi, np.pi, wrapped)


def compose(world_T_a, a_T_b) -> np.ndarray:
    """``world_T_b`` = world_T_a o a_T_b for (..., 3) poses (the angle is summed, not wrapped)."""
    a, step = np.asarray(world_T_a, dtype=float), np.asarray(a_T_b, dtype=float)
    cos, sin = np.cos(a[..., 2]), np.sin(a[..., 2])
    return np.stack([a[..., 0] + cos * step[..., 0] - sin * step[..., 1],
                     a[..., 1] + sin * step[..., 0] + cos * step[..., 1],
                     a[..., 2] + step[..., 2]], axis=-1)


def relative_pose(world_T_a, world_T_b) -> np.ndarray:
    """``a_T_b`` = (world_T_a)^-1 o world_T_b for (..., 3) poses, the angle wrapped to (-pi, pi]."""
    a, b = np.asarray(world_T_a, dtype=float), np.asarray(world_T_b, dtype=float)
    dx, dy = b[..., 0] - a[..., 0], b[..., 1] - a[..., 1]
    cos, sin = np.cos(a[..., 2]), np.sin(a[..., 2])
    return np.stack([cos * dx + sin * dy, -sin * dx + cos * dy, wrap_angle(b[..., 2] - a[..., 2])], axis=-1)


def dead_reckoning(increments, start=(0.0, 0.0, 0.0)) -> np.ndarray:
    """(T+1, 3) poses from composing (T, 3) relative increments onto ``start`` (the origin by default).

    Vectorised: the heading before step k is the start heading plus the sum of
    the earlier turns, so every step is rotated into the world frame at once.
    Headings are accumulated without wrapping, so that they stay continuous
    along the path.
    """
    increments = np.asarray(increments, dtype=float).reshape(-1, 3)
    start = np.asarray(start, dtype=float)
    headings = start[2] + np.concatenate([[0.0], np.cumsum(increments[:, 2])])
    cos, sin = np.cos(headings[:-1]), np.sin(headings[:-1])
    world_steps = np.stack([cos * increments[:, 0] - sin * increments[:, 1],
                            sin * increments[:, 0] + cos * increments[:, 1]], axis=-1)
    positions = start[:2] + np.concatenate([np.zeros((1, 2)), np.cumsum(world_steps, axis=0)])
    return np.column_stack([positions, headings])
