"""Detector: closest approach within the radius, misses and false detections at their configured rates."""

import numpy as np
import pytest

from ptm_bench.simulation.detector import detect

PLACES = {3: (2.0, 0.3), 7: (5.0, -0.6), 9: (8.0, 2.5)}


def _line(x0=0.0, x1=10.0, count=1001):
    xs = np.linspace(x0, x1, count)
    return np.column_stack([xs, np.zeros_like(xs), np.zeros_like(xs)])


def test_fires_once_per_pass_at_the_closest_approach_within_the_radius():
    poses = _line()
    detections = detect(poses, PLACES, radius=1.0, rng=np.random.default_rng(0))
    assert [d.place_id for d in detections] == [3, 7]  # place 9 is 2.5 m off the line
    for detection in detections:
        distances = np.linalg.norm(poses[:, :2] - PLACES[detection.place_id], axis=1)
        assert detection.step == int(np.argmin(distances))
        assert detection.distance == pytest.approx(distances.min()) and detection.distance <= 1.0


def test_a_return_pass_is_a_second_detection():
    there, back = _line(), _line(10.0, 0.0)
    detections = detect(np.concatenate([there, back[1:]]), PLACES, 1.0, np.random.default_rng(0))
    assert [d.place_id for d in detections] == [3, 7, 7, 3]
    assert all(a.step < b.step for a, b in zip(detections, detections[1:]))


def test_miss_rate_is_honoured_statistically():
    # 2000 passes back and forth by place 3
    one_way = _line(0.0, 4.0, 81)
    poses = np.concatenate([one_way if i % 2 == 0 else one_way[::-1] for i in range(2000)])
    kept = detect(poses, {3: (2.0, 0.3)}, 1.0, np.random.default_rng(5), miss_rate=0.3)
    expected, sd = 2000 * 0.7, np.sqrt(2000 * 0.3 * 0.7)
    assert abs(len(kept) - expected) < 4 * sd


def test_false_detections_have_fresh_negative_labels_at_the_configured_rate():
    poses = _line(0.0, 1000.0, 100_001)  # 1 km, far from the single place
    detections = detect(poses, {0: (0.0, 50.0)}, 1.0, np.random.default_rng(2), false_rate=0.05)
    labels = [d.place_id for d in detections]
    assert labels == list(range(-1, -len(labels) - 1, -1))
    assert abs(len(labels) - 50) < 4 * np.sqrt(50)


@pytest.mark.parametrize("kwargs, field", [({"radius": 0.0}, "radius"), ({"miss_rate": 1.0}, "miss_rate"),
                                           ({"false_rate": -1.0}, "false_rate")])
def test_bad_detector_settings_are_rejected(kwargs, field):
    arguments = {"radius": 1.0, **kwargs}
    with pytest.raises(ValueError, match=field):
        detect(_line(), PLACES, rng=np.random.default_rng(0), **arguments)
