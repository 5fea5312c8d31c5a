"""The summary draws each top topology on its own optimised map, and the MAP map beside the reference.

A variant with the odometry model gets, per topology, the Laplace mode of its
pose graph (ptm.odometry.OdometryTerm.mode_poses) under the model the row
used; a variant or baseline without it gets dead reckoning, and the caption
says which. The table is hand-made and the dataset a tiny synthetic loop, so
nothing is simulated or sampled.
"""

import json

import numpy as np
import pandas as pd
import pytest

import ptm
from ptm.se2 import dead_reckoning
from ptm_bench.evaluation import scoring
from ptm_bench.evaluation.experiment import expand_cells, parse_experiment
from ptm_bench.reporting import plots, summary

TRUTH = (0, 1, 2, 3, 0)
TOP = [[list(TRUTH), 0.7], [[0, 1, 2, 3, 4], 0.3]]
SIGMA_TOPOLOGY = 0.4
CONFIG = {
    "name": "maps",
    "baselines": ["greedy_odometry"],
    "sweep": {"worlds": ["short_loop"], "aliasing": [0.0], "seeds": [0], "calibration_seeds": [10]},
    "variants": [{"name": "odometry", "models": ["odometry"]},
                 {"name": "appearance", "models": ["appearance"]}],
}


def _loop(*args, **kwargs):
    square = np.tile([2.0, 0.0, np.pi / 2], (4, 1))
    steps = square + np.array([0.1, 0.05, 0.04])  # odometry of a square that does not close
    # the detector's radius r gives the variant's tie sigma r / sqrt 2 (the builder's rule)
    return ptm.Dataset(odometry=steps, labels=np.array(TRUTH), true_poses=dead_reckoning(square),
                       meta={"detection_radius": SIGMA_TOPOLOGY * np.sqrt(2.0)})


def _table(experiment, folder):
    rows = []
    for cell in expand_cells(experiment, folder):
        top = [[list(TRUTH), 1.0]] if cell["method"] == "baseline" else TOP
        row = {key: value for key, value in cell.items() if isinstance(value, (str, int, float, bool))}
        row.update(scoring.score({tuple(labels): p for labels, p in top}, TRUTH), top5=json.dumps(top),
                   true_labels=json.dumps(list(TRUTH)), wall_s=1.0, status="ok", error="")
        if cell["variant"] == "odometry":
            row["sigma_topology"] = SIGMA_TOPOLOGY
        rows.append(row)
    return pd.DataFrame(rows)


@pytest.fixture
def drawn(tmp_path, monkeypatch):
    """Write the summary; return the experiment, the summary text and the arguments of the map figures."""
    monkeypatch.setattr(summary, "dataset_for", _loop)
    calls = {"top": {}, "trajectory": []}
    top_topologies, trajectories = plots.top_topologies, plots.trajectories

    def recording_top(maps, topologies, truth, path, title=""):
        calls["top"][path.name] = (maps, topologies, title)
        return top_topologies(maps, topologies, truth, path, title)

    def recording_trajectories(dataset, path, title="", optimised=None):
        calls["trajectory"].append(optimised)
        return trajectories(dataset, path, title, optimised)

    monkeypatch.setattr(plots, "top_topologies", recording_top)
    monkeypatch.setattr(plots, "trajectories", recording_trajectories)
    experiment = parse_experiment(json.loads(json.dumps(CONFIG)), source="test")
    text = summary.write_summary(experiment, _table(experiment, tmp_path), tmp_path).read_text()
    return experiment, text, calls


def _expected_modes(experiment):
    settings = next(variant for variant in experiment.variants if variant.name == "odometry").odometry
    term = ptm.OdometryModel(sigma_xy=settings.sigma_xy, sigma_theta=settings.sigma_theta,
                             sigma_topology=SIGMA_TOPOLOGY).bind(_loop())
    return [term.mode_poses(labels) for labels, _ in TOP]


def test_an_odometry_variant_draws_each_topology_on_its_own_mode(drawn):
    experiment, text, calls = drawn
    maps, topologies, title = calls["top"]["top5_odometry.png"]
    assert [list(labels) for labels, _ in topologies] == [labels for labels, _ in TOP]
    expected = _expected_modes(experiment)
    assert all(np.array_equal(drawn_map, mode) for drawn_map, mode in zip(maps, expected))
    assert not np.allclose(expected[0], expected[1])  # the loop closure moves the map
    assert title.endswith("each on its optimised map") and title in text


@pytest.mark.parametrize("figure", ["top5_appearance.png", "top5_greedy_odometry.png"])
def test_a_variant_without_odometry_draws_dead_reckoning_and_says_so(drawn, figure):
    _, _, calls = drawn
    maps, _, title = calls["top"][figure]
    assert all(np.array_equal(drawn_map, dead_reckoning(_loop().odometry)) for drawn_map in maps)
    assert title.endswith("at dead-reckoned positions (no odometry model)")


def test_the_trajectory_figure_overlays_the_map_topologys_optimised_map(drawn):
    experiment, text, calls = drawn
    (optimised,) = calls["trajectory"]
    name, poses = optimised
    assert name == "MAP topology's optimised map (odometry)"
    assert np.array_equal(poses, _expected_modes(experiment)[0])
    assert "Detections: reference, dead reckoning and the MAP map" in text


def test_top_topologies_refuses_maps_that_do_not_match_the_topologies(tmp_path):
    with pytest.raises(ValueError, match="1 maps for 2 topologies"):
        plots.top_topologies([np.zeros((3, 2))], [((0, 1, 0), 0.9), ((0, 1, 2), 0.1)], (0, 1, 0), tmp_path / "x.png")
