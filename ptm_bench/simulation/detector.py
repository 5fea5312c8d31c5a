"""The landmark detector: fires at the robot's closest approach to a place (docs/model.md §5).

A *visit* is a maximal run of control steps during which the robot is within
``radius`` of one place; the detection is the step of that run nearest to the
place, labelled with the place id. Optionally each visit is missed with
probability ``miss_rate``, and false detections fire with ``false_rate`` per
metre driven away from every place (farther than twice the radius), at most
one per pose; a false detection is its own place and gets a fresh negative
label -1, -2, ... A rate the path cannot meet -- it never leaves the places'
surroundings, or the rate asks for more than one detection in a step -- is a
``ValueError``, never silently fewer false detections.

    >>> import numpy as np
    >>> path = np.column_stack([np.linspace(0.0, 10.0, 101), np.zeros(101)])   # drive 10 m along x
    >>> detections = detect(path, {0: (2.0, 0.5), 1: (8.0, -0.3)}, radius=1.0, rng=np.random.default_rng(0))
    >>> [(d.step, d.place_id) for d in detections]
    [(20, 0), (80, 1)]
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["Detection", "detect"]


@dataclass(frozen=True)
class Detection:
    """One firing of the detector: the control step and the true place id (negative for a false detection)."""

    step: int
    place_id: int
    distance: float  # [m] from the place (0 for a false detection)


def detect(poses, places: dict[int, tuple[float, float]], radius: float, rng: np.random.Generator,
           miss_rate: float = 0.0, false_rate: float = 0.0) -> list[Detection]:
    """Detections along a trajectory of (T+1, >=2) poses, in time order."""
    if not radius > 0:
        raise ValueError(f"detection radius must be positive, got {radius!r}")
    if not 0.0 <= miss_rate < 1.0:
        raise ValueError(f"miss_rate must be in [0, 1), got {miss_rate!r}")
    if not false_rate >= 0.0:
        raise ValueError(f"false_rate must be >= 0 per metre, got {false_rate!r}")
    positions = np.asarray(poses, dtype=float)[:, :2]
    place_ids = sorted(places)
    centres = np.array([places[place_id] for place_id in place_ids], dtype=float).reshape(-1, 2)
    distances = np.linalg.norm(positions[:, None, :] - centres[None, :, :], axis=2)  # (T+1, P)
    detections = []
    for column, place_id in enumerate(place_ids):
        inside = distances[:, column] <= radius
        edges = np.flatnonzero(np.diff(np.concatenate([[0], inside.astype(np.int8), [0]])))
        for start, stop in zip(edges[::2], edges[1::2]):
            step = start + int(np.argmin(distances[start:stop, column]))
            detections.append(Detection(int(step), place_id, float(distances[step, column])))
    detections.sort(key=lambda detection: detection.step)
    kept = [detection for detection in detections if rng.random() >= miss_rate]
    if false_rate > 0.0:
        travelled = np.concatenate([[0.0], np.linalg.norm(np.diff(positions, axis=0), axis=1)])
        far = distances.min(axis=1) > 2 * radius
        _check_false_rate(false_rate, travelled[far], radius)
        fires = far & (rng.random(len(positions)) < false_rate * travelled)
        false_steps = np.flatnonzero(fires)
        kept.extend(Detection(int(step), -(index + 1), 0.0) for index, step in enumerate(false_steps))
        kept.sort(key=lambda detection: detection.step)
    return kept


def _check_false_rate(false_rate: float, far_steps: np.ndarray, radius: float) -> None:
    """Refuse a false-detection rate the path cannot meet, given the lengths of its steps away from the places."""
    if not far_steps.sum() > 0:
        raise ValueError(f"false_rate: {false_rate:g} per metre cannot be met: the path never runs farther than "
                         f"twice the detection radius ({2 * radius:g} m) from a place, where false detections fire")
    longest = float(far_steps.max())
    if false_rate * longest > 1.0:
        raise ValueError(f"false_rate: {false_rate:g} per metre cannot be met: at most one false detection fires per "
                         f"step, and the path covers up to {longest:.3g} m in one, so the rate is at most "
                         f"{1 / longest:.3g} per metre")
