"""Exports of a topology's optimised map (ptm.export, ``ptm-bench export``): each file read back and compared.

The g2o file is parsed and its vertices, information matrices and same-place
edges compared with the mode and the model; g2o's own error convention applied
to the parsed file must give the pose-graph energy E_T of docs/model.md §3.3
at any configuration. The TUM files are read back with numpy, the GraphML file
with networkx. Bad inputs fail with a ValueError naming the field.
"""

from __future__ import annotations

import dataclasses
import sys

import numpy as np
import pytest

import ptm
from ptm.export import detection_timestamps, export_map, g2o_text, topology_graph, tum_text
from ptm.se2 import compose, dead_reckoning, relative_pose, wrap_angle
from ptm_bench.cli import main

networkx = pytest.importorskip("networkx")

LABELS = [0, 1, 2, 3, 0, 1, 2, 3, 0]  # a 2 m square driven twice
SIGMA_TOPOLOGY = 0.2


def _loop_dataset(**meta) -> ptm.Dataset:
    """The square with noisy odometry and correlated, anisotropic covariances (so that their frame matters)."""
    rng = np.random.default_rng(4)
    true_poses = dead_reckoning(np.tile([2.0, 0.0, np.pi / 2], (8, 1)), start=(1.0, -2.0, 0.3))
    steps = relative_pose(true_poses[:-1], true_poses[1:])
    factors = np.tril(rng.normal(0.0, 0.02, (8, 3, 3))) + np.diag([0.08, 0.03, 0.04])
    covariances = factors @ np.swapaxes(factors, 1, 2)
    noisy = steps + np.einsum("kij,kj->ki", np.linalg.cholesky(covariances), rng.standard_normal((8, 3)))
    return ptm.Dataset(odometry=noisy, odometry_cov=covariances, labels=LABELS, true_poses=true_poses, meta=meta)


def _model() -> ptm.OdometryModel:
    return ptm.OdometryModel(sigma_topology=SIGMA_TOPOLOGY)


def _read_g2o(text: str):
    """(vertices {id: pose}, edges [(i, j, measurement, information)], fixed ids) of a g2o file."""
    vertices, edges, fixed = {}, [], []
    for line in text.splitlines():
        tag, *fields = line.split()
        if tag == "VERTEX_SE2":
            vertices[int(fields[0])] = np.array(fields[1:], dtype=float)
        elif tag == "EDGE_SE2":
            values = np.array(fields[2:], dtype=float)
            information = np.zeros((3, 3))
            information[np.triu_indices(3)] = values[3:]
            edges.append((int(fields[0]), int(fields[1]), values[:3], information + np.triu(information, 1).T))
        elif tag == "FIX":
            fixed.append(int(fields[0]))
        else:
            raise AssertionError(f"unexpected g2o line {line!r}")
    return vertices, edges, fixed


def _g2o_energy(poses, edges) -> float:
    """1/2 sum e^T Omega e with g2o's EDGE_SE2 error e = toVector(z^-1 o (p_i^-1 o p_j))."""
    total = 0.0
    for i, j, measurement, information in edges:
        error = relative_pose(measurement, relative_pose(poses[i], poses[j]))
        total += 0.5 * error @ information @ error
    return total


def _rotation(angle: float) -> np.ndarray:
    return np.array([[np.cos(angle), -np.sin(angle), 0.0], [np.sin(angle), np.cos(angle), 0.0], [0.0, 0.0, 1.0]])


# -- the mode -------------------------------------------------------------------------------------------------

def test_mode_poses_is_the_fits_minimiser_with_pose_zero_at_the_origin():
    dataset = _loop_dataset()
    term = _model().bind(dataset)
    poses = term.mode_poses(LABELS)
    assert poses.shape == (9, 3) and np.array_equal(poses[0], np.zeros(3))
    fit = term.fit(np.array(LABELS))
    assert fit.converged and np.array_equal(poses[1:].ravel(), fit.x)
    assert np.abs(term.graph.linearise(fit.x, LABELS).gradient).max() < 1e-6
    # the ties pull the returns to the start together, which dead reckoning leaves apart
    drift = np.linalg.norm(dead_reckoning(dataset.odometry)[[4, 8], :2], axis=1)
    assert np.all(np.linalg.norm(poses[[4, 8], :2], axis=1) < 0.5 * drift)
    assert np.array_equal(term.mode_poses([5, 6, 7, 8, 5, 6, 7, 8, 5]), poses)  # any labels of the partition


def test_mode_poses_refuses_a_wrong_length_and_an_unconverged_fit(monkeypatch):
    term = _model().bind(_loop_dataset())
    with pytest.raises(ValueError, match="has 9 labels, got 8"):
        term.mode_poses(LABELS[:-1])
    fit = term.fit(np.array(LABELS))
    monkeypatch.setattr(term, "fit", lambda labels: dataclasses.replace(fit, converged=False, failure="iteration limit"))
    with pytest.raises(ValueError, match=r"no converged mode \(iteration limit\)"):
        term.mode_poses(LABELS)


# -- g2o ------------------------------------------------------------------------------------------------------

def test_g2o_round_trip_poses_information_and_same_place_edges(tmp_path):
    dataset = _loop_dataset()
    export_map(tmp_path, dataset, LABELS, _model())
    text = (tmp_path / "map.g2o").read_text()
    vertices, edges, fixed = _read_g2o(text)
    mode = _model().bind(dataset).mode_poses(LABELS)
    assert fixed == [0] and text.splitlines()[-1] == "FIX 0"  # last: GTSAM stops reading at a tag it does not know
    assert sorted(vertices) == list(range(9))
    parsed = np.array([vertices[i] for i in range(9)])
    assert np.array_equal(parsed[:, :2], mode[:, :2])
    assert np.allclose(parsed[:, 2], wrap_angle(mode[:, 2]), rtol=0, atol=1e-15)
    odometry_edges, tie_edges = edges[:8], edges[8:]
    for k, (i, j, measurement, information) in enumerate(odometry_edges):
        assert (i, j) == (k, k + 1) and np.array_equal(measurement, dataset.odometry[k])
        # g2o's error is in the frame of the measured pose: turned back, the information is the row's Sigma^-1
        turn = _rotation(dataset.odometry[k, 2])
        assert np.allclose(turn @ information @ turn.T, np.linalg.inv(dataset.odometry_cov[k]), rtol=1e-9, atol=1e-9)
    # every pair of detections of one place is tied (the model's clique), positions only
    expected_pairs = [(i, j) for i in range(9) for j in range(i + 1, 9) if LABELS[i] == LABELS[j]]
    assert [(i, j) for i, j, _, _ in tie_edges] == expected_pairs
    weight = 1.0 / SIGMA_TOPOLOGY**2
    for _, _, measurement, information in tie_edges:
        assert np.array_equal(measurement, np.zeros(3)) and np.array_equal(information, np.diag([weight, weight, 0.0]))


def test_the_g2o_files_energy_is_the_pose_graph_energy_everywhere(tmp_path):
    dataset = _loop_dataset()
    term = _model().bind(dataset)
    _, edges, _ = _read_g2o(g2o_text(term.mode_poses(LABELS), dataset.odometry, term.graph.information, LABELS,
                                     SIGMA_TOPOLOGY))
    rng = np.random.default_rng(1)
    mode = term.mode_poses(LABELS)
    for poses in (mode, compose(mode, rng.normal(0.0, [0.3, 0.3, 0.5], (9, 3)) * (np.arange(9) > 0)[:, None])):
        expected = float(term.graph.energy(poses[1:].ravel(), LABELS))
        assert _g2o_energy(poses, edges) == pytest.approx(expected, rel=1e-10)


# -- TUM ------------------------------------------------------------------------------------------------------

def test_tum_round_trip_of_the_map_dead_reckoning_and_the_reference(tmp_path):
    times = [10.0 + 0.5 * k for k in range(9)]
    dataset = _loop_dataset(timestamps=times)
    written = export_map(tmp_path, dataset, LABELS, _model())
    assert written.timestamps == 'the dataset\'s meta["timestamps"]'
    trajectories = {"map.tum": _model().bind(dataset).mode_poses(LABELS),
                    "dead_reckoning.tum": dead_reckoning(dataset.odometry), "reference.tum": dataset.true_poses}
    for name, poses in trajectories.items():
        table = np.loadtxt(tmp_path / name)
        assert table.shape == (9, 8), name
        assert np.array_equal(table[:, 0], times) and np.array_equal(table[:, 1:3], poses[:, :2])
        assert np.array_equal(table[:, 3:6], np.zeros((9, 3)))
        assert np.allclose(np.hypot(table[:, 6], table[:, 7]), 1.0, rtol=0, atol=1e-15)
        yaw = 2.0 * np.arctan2(table[:, 6], table[:, 7])
        assert np.allclose(wrap_angle(yaw - poses[:, 2]), 0.0, rtol=0, atol=1e-12), name


def test_timestamps_are_the_detection_index_unless_the_dataset_has_increasing_times():
    assert detection_timestamps(_loop_dataset())[1] == "detection index"
    times, source = detection_timestamps(_loop_dataset(timestamps=[0.0, 1.0, 1.0, 2, 3, 4, 5, 6, 7]))
    assert np.array_equal(times, np.arange(9.0)) and "not one strictly increasing time" in source
    assert tum_text(np.zeros((2, 3)), [0.0, 1.0]) == "0.0 0.0 0.0 0.0 0.0 0.0 0.0 1.0\n1.0 0.0 0.0 0.0 0.0 0.0 0.0 1.0\n"


def test_a_dataset_without_true_poses_gets_no_reference_file(tmp_path):
    dataset = _loop_dataset().replace(true_poses=None)
    assert sorted(export_map(tmp_path, dataset, LABELS, _model()).files) == [
        "dead_reckoning.tum", "map.g2o", "map.tum", "topology.graphml"]
    assert not (tmp_path / "reference.tum").exists()


# -- the topology graph ---------------------------------------------------------------------------------------

def test_topology_graph_by_hand():
    poses = np.array([[0.0, 0.0, 0.0], [2.0, 0.0, 1.0], [0.2, 0.4, 2.0], [5.0, 5.0, 0.0], [2.2, 0.2, 0.5]])
    graph = topology_graph([7, 3, 7, 9, 3], poses)  # canonical (0, 1, 0, 2, 1)
    assert dict(graph.nodes(data=True)) == {
        0: {"detections": "0,2", "visits": 2, "x": pytest.approx(0.1), "y": pytest.approx(0.2)},
        1: {"detections": "1,4", "visits": 2, "x": pytest.approx(2.1), "y": pytest.approx(0.1)},
        2: {"detections": "3", "visits": 1, "x": 5.0, "y": 5.0},
    }
    # traversals 0->1, 1->0, 0->2, 2->1
    assert {tuple(sorted(edge)): data["count"] for *edge, data in graph.edges(data=True)} == {
        (0, 1): 2, (0, 2): 1, (1, 2): 1}


def test_graphml_round_trip(tmp_path):
    dataset = _loop_dataset()
    export_map(tmp_path, dataset, LABELS, _model())
    read_back = networkx.read_graphml(tmp_path / "topology.graphml", node_type=int)
    expected = topology_graph(LABELS, _model().bind(dataset).mode_poses(LABELS))
    assert dict(read_back.nodes(data=True)) == dict(expected.nodes(data=True))  # floats exactly, types kept
    assert ({frozenset(edge): data for *edge, data in read_back.edges(data=True)}
            == {frozenset(edge): data for *edge, data in expected.edges(data=True)})
    assert read_back.nodes[0]["detections"] == "0,4,8" and type(read_back.nodes[0]["visits"]) is int
    assert read_back.edges[0, 1]["count"] == 2


def test_without_networkx_the_error_says_how_to_install_it(tmp_path, monkeypatch):
    monkeypatch.setitem(sys.modules, "networkx", None)  # import networkx now raises ImportError
    with pytest.raises(ImportError, match=r"pip install 'ptm\[export\]'"):
        export_map(tmp_path, _loop_dataset(), LABELS, _model())
    assert list(tmp_path.iterdir()) == []  # nothing written before the failure


# -- bad input ------------------------------------------------------------------------------------------------

def test_a_wrong_number_of_labels_is_refused_before_anything_is_written(tmp_path):
    with pytest.raises(ValueError, match="has 9 labels, got 8"):
        export_map(tmp_path, _loop_dataset(), LABELS[:-1], _model())
    assert list(tmp_path.iterdir()) == []
    with pytest.raises(ValueError, match=r"labels must hold one label per pose \(9\), got 10"):
        topology_graph(LABELS + [0], np.zeros((9, 3)))


def test_non_finite_inputs_are_named():
    dataset = _loop_dataset()
    information = np.broadcast_to(np.eye(3), (8, 3, 3))
    poses = np.zeros((9, 3))
    poses[3, 1] = np.nan
    with pytest.raises(ValueError, match=r"poses contains a non-finite value .*nan.* at index \(3, 1\)"):
        g2o_text(poses, dataset.odometry, information, LABELS, 0.3)
    with pytest.raises(ValueError, match="poses contains a non-finite"):
        tum_text(poses, np.arange(9.0))
    with pytest.raises(ValueError, match="timestamps contains a non-finite"):
        tum_text(np.zeros((2, 3)), [0.0, np.inf])
    with pytest.raises(ValueError, match=r"odometry_information must have shape \(8, 3, 3\)"):
        g2o_text(np.zeros((9, 3)), dataset.odometry, information[:7], LABELS, 0.3)
    with pytest.raises(ValueError, match="sigma_topology must be a finite positive number"):
        g2o_text(np.zeros((9, 3)), dataset.odometry, information, LABELS, 0.0)
    with pytest.raises(ValueError, match=r"poses must have shape \(N, 3\)"):
        tum_text(np.zeros((9, 2)), np.arange(9.0))


def test_a_dataset_without_odometry_has_no_map(tmp_path):
    with pytest.raises(ValueError, match="a map needs odometry"):
        export_map(tmp_path, ptm.Dataset(labels=LABELS), LABELS, _model())


def test_a_second_export_replaces_the_files_and_leaves_no_temporary(tmp_path):
    dataset = _loop_dataset()
    export_map(tmp_path, dataset, [0, 1, 2, 3, 4, 5, 6, 7, 8], _model())
    export_map(tmp_path, dataset, LABELS, _model())
    assert sorted(path.name for path in tmp_path.iterdir()) == [
        "dead_reckoning.tum", "map.g2o", "map.tum", "reference.tum", "topology.graphml"]
    assert (tmp_path / "map.g2o").read_text().count("EDGE_SE2") == 8 + 3 + 1 + 1 + 1


# -- the command line -----------------------------------------------------------------------------------------

def test_cli_exports_labels_and_a_saved_ptms_map(tmp_path, capsys):
    dataset_path = _loop_dataset(detection_radius=0.5).save(tmp_path / "loop.npz")
    by_labels = tmp_path / "by_labels"
    assert main(["export", str(dataset_path), "--labels", ",".join(map(str, LABELS)), "--out", str(by_labels),
                 "--sigma-topology", str(SIGMA_TOPOLOGY)]) == 0
    printed = capsys.readouterr().out
    assert "N = 9 detections, 4 places, 6 same-place edges (sigma_topology 0.2 m)" in printed
    result = ptm.PTM([LABELS, [0, 1, 2, 3, 4, 5, 6, 7, 8]], [0.8, 0.2], "exact").save(tmp_path / "result.npz")
    by_ptm = tmp_path / "by_ptm"
    assert main(["export", str(dataset_path), "--ptm", str(result), "--out", str(by_ptm),
                 "--sigma-topology", str(SIGMA_TOPOLOGY)]) == 0
    assert "the MAP topology of" in capsys.readouterr().out
    labels_file = tmp_path / "labels.txt"
    labels_file.write_text("\n".join(map(str, LABELS)) + "\n")
    by_file = tmp_path / "by_file"
    assert main(["export", str(dataset_path), "--labels", str(labels_file), "--out", str(by_file),
                 "--sigma-topology", str(SIGMA_TOPOLOGY)]) == 0
    for name in ("map.g2o", "map.tum", "dead_reckoning.tum", "reference.tum", "topology.graphml"):
        assert (by_ptm / name).read_bytes() == (by_labels / name).read_bytes() == (by_file / name).read_bytes()


@pytest.mark.parametrize("arguments, message", [
    (["--labels", "0,1,0"], "has 9 labels, got 3"),
    (["--labels", "0,one,0"], "--labels: expected integers"),
    (["--labels", "0,1,2,3,0,1,2,3,0", "--sigma-topology", "-1"], "sigma_topology must be a positive number, got -1"),
])
def test_cli_names_a_bad_topology(tmp_path, capsys, arguments, message):
    dataset_path = _loop_dataset(detection_radius=0.5).save(tmp_path / "loop.npz")
    assert main(["export", str(dataset_path), *arguments, "--out", str(tmp_path / "out")]) == 2
    assert message in capsys.readouterr().err


def test_cli_refuses_a_ptm_over_other_detections(tmp_path, capsys):
    dataset_path = _loop_dataset(detection_radius=0.5).save(tmp_path / "loop.npz")
    result = ptm.PTM([[0, 1, 0]], [1.0], "exact").save(tmp_path / "result.npz")
    assert main(["export", str(dataset_path), "--ptm", str(result), "--out", str(tmp_path / "out")]) == 2
    assert "is over 3 detections, the dataset" in capsys.readouterr().err


def test_cli_without_the_detectors_radius_asks_for_it(tmp_path, capsys):
    """The default tie is the detector's radius / sqrt 2, as in a sweep: a dataset without the radius is refused."""
    dataset_path = _loop_dataset().save(tmp_path / "loop.npz")
    assert main(["export", str(dataset_path), "--labels", "truth", "--out", str(tmp_path / "out")]) == 2
    assert "no 'detection_radius'" in capsys.readouterr().err
