"""Exports of a topology's optimised map for robotics tools: g2o, TUM trajectories and a networkx graph.

The map of a topology T is the Laplace mode P* of its pose graph, the
minimiser of the energy E_T of docs/model.md §3.3 (paper eq. 13; step 1 of
the evaluation of eq. 3), :meth:`ptm.odometry.OdometryTerm.mode_poses`: the
detection poses in the frame of detection 0, which sits at the origin.

* **g2o** (:func:`g2o_text`). g2o scores an ``EDGE_SE2 i j z Omega`` with
  e = toVector(z^-1 o (p_i^-1 o p_j)) and chi^2 = e^T Omega e; the file is
  written so that 1/2 sum chi^2 is E_T itself, and P* its optimum:

  - ``VERTEX_SE2 i x y theta`` for every detection pose of the mode, and,
    last, ``FIX 0`` (pose 0 is the gauge);
  - ``EDGE_SE2 k-1 k dx dy dtheta I11 I12 I13 I22 I23 I33`` for odometry row k,
    the upper triangle of Omega_k = B_k^T Sigma_k^-1 B_k, B_k = blockdiag(R(dtheta_k), 1):
    the row's information (the inverse of its ``odometry_cov``, or of the
    model's diag(sigma_xy^2, sigma_xy^2, sigma_theta^2)) turned from the frame of
    detection k-1, where the model takes the difference r_k = (p_{k-1}^-1 o p_k) - o_k,
    to the frame of the measured pose, where g2o does (B_k is a rotation, so a
    covariance that is isotropic in x and y is unchanged);
  - ``EDGE_SE2 i j 0 0 0 w 0 0 w 0 0``, w = 1/sigma_T^2, for every pair i < j of
    detections of one place: the model ties all pairs of a set, positions
    only (1/2 |t_i - t_j|^2 / sigma_T^2; the heading is free, hence the zero
    angular information). A place seen n times gives n(n-1)/2 such edges.
    g2o reads this as it is; GTSAM's ``readG2o`` refuses a zero angular
    information ("not G2O matrix order"): give I33 a negligible value there.

* **TUM** (:func:`tum_text`): one line ``timestamp tx ty tz qx qy qz qw`` per
  detection (tz = qx = qy = 0, qz = sin(theta/2), qw = cos(theta/2)), which
  ``evo`` reads (``evo_ape tum reference.tum map.tum --align``: the
  estimates are in the frame of detection 0, the reference in its own).
* **networkx** (:func:`topology_graph`): places as nodes (``detections``, the
  indices as "0,4,9"; ``visits``; ``x`` and ``y``, the mean optimised
  position), traversals as edges (consecutive detections in different places;
  ``count``, in either direction). Only strings and numbers, so GraphML keeps it.
  networkx is imported when first needed (``pip install 'ptm[export]'``).

:func:`export_map` writes all of them for a dataset and a topology, each file
atomically (``ptm-bench export`` is its command line):

    >>> import tempfile, numpy as np, ptm
    >>> steps = np.tile([2.0, 0.0, np.pi / 2], (4, 1))                  # a 2 m square, back at the start
    >>> written = export_map(tempfile.mkdtemp(), ptm.Dataset(odometry=steps), [0, 1, 2, 3, 0], ptm.OdometryModel())
    >>> sorted(written.files), written.loop_closures, written.timestamps
    (['dead_reckoning.tum', 'map.g2o', 'map.tum', 'topology.graphml'], 1, 'detection index')
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ._validation import finite_array, positive
from .dataset import atomic_write
from .partitions import canonical
from .se2 import dead_reckoning, wrap_angle

__all__ = ["MapExport", "detection_timestamps", "export_map", "g2o_text", "topology_graph", "tum_text"]


@dataclass(frozen=True)
class MapExport:
    """What :func:`export_map` wrote: the files by name, where the TUM timestamps came from, and the number of
    loop-closure edges (same-place pairs) in the g2o file."""

    files: dict
    timestamps: str
    loop_closures: int


def export_map(folder, dataset, labels, model) -> MapExport:
    """Write the optimised map of the topology ``labels`` of ``dataset`` into ``folder`` (which must exist).

    ``model`` is the :class:`ptm.OdometryModel` whose energy defines the map
    (its ``sigma_topology``, and ``sigma_xy``/``sigma_theta`` where the dataset
    has no ``odometry_cov``). Files: ``map.g2o``, ``map.tum`` (the mode),
    ``dead_reckoning.tum``, ``reference.tum`` (the true poses, when the dataset
    has them) and ``topology.graphml``. Everything is computed before the
    first file is written, each file is written atomically, and files of an
    earlier export are replaced.
    """
    if dataset.odometry is None:
        raise ValueError("a map needs odometry: the dataset has none (dataset.odometry is None)")
    term = model.bind(dataset)
    poses = term.mode_poses(labels)  # validates the number of labels
    timestamps, timestamp_source = detection_timestamps(dataset)
    texts = {
        "map.g2o": g2o_text(poses, term.graph.odometry, term.graph.information, labels, model.sigma_topology),
        "map.tum": tum_text(poses, timestamps),
        "dead_reckoning.tum": tum_text(dead_reckoning(dataset.odometry), timestamps),
        "topology.graphml": "\n".join(_networkx().generate_graphml(topology_graph(labels, poses))) + "\n",
    }
    if dataset.true_poses is not None:
        texts["reference.tum"] = tum_text(dataset.true_poses, timestamps)
    folder = Path(folder)
    files = {}
    for name, text in texts.items():
        atomic_write(folder / name, lambda handle, text=text: handle.write(text.encode()))
        files[name] = folder / name
    first, _ = _same_place_pairs(np.asarray(canonical(labels)))
    return MapExport(files, timestamp_source, len(first))


def detection_timestamps(dataset) -> tuple[np.ndarray, str]:
    """The time of each detection for the TUM files, and where it came from: the dataset's
    ``meta["timestamps"]`` (an imported log's, in seconds) when it has one strictly increasing finite
    value per detection, else the detection index 0, 1, ..., N-1."""
    recorded = dataset.meta.get("timestamps")
    if recorded is not None:
        times = np.asarray(recorded, dtype=float)
        if times.shape == (dataset.n,) and np.all(np.isfinite(times)) and np.all(np.diff(times) > 0.0):
            return times, 'the dataset\'s meta["timestamps"]'
        return np.arange(dataset.n, dtype=float), ('detection index (the dataset\'s meta["timestamps"] are not '
                                                   'one strictly increasing time per detection)')
    return np.arange(dataset.n, dtype=float), "detection index"


def g2o_text(poses, odometry, odometry_information, labels, sigma_topology: float) -> str:
    """The pose graph of a topology in g2o's text format (see the module docstring for the convention).

    ``poses`` (N, 3): the vertices (the mode, :meth:`ptm.odometry.OdometryTerm.mode_poses`);
    ``odometry`` (N-1, 3): the measured rows; ``odometry_information`` (N-1, 3, 3): the inverse of each
    row's covariance in the model's convention; ``labels`` (N,): the topology; ``sigma_topology``: the
    tie's standard deviation [m].
    """
    poses = _poses(poses)
    n = len(poses)
    labels = _labels(labels, n)
    odometry = finite_array("odometry", odometry, ndim=2)
    if odometry.shape != (n - 1, 3):
        raise ValueError(f"odometry must have shape ({n - 1}, 3) for {n} poses, got {odometry.shape}")
    information = finite_array("odometry_information", odometry_information, ndim=3)
    if information.shape != (n - 1, 3, 3):
        raise ValueError(f"odometry_information must have shape ({n - 1}, 3, 3) for {n} poses, "
                         f"got {information.shape}")
    weight = 1.0 / positive("sigma_topology", sigma_topology) ** 2
    cos, sin = np.cos(odometry[:, 2]), np.sin(odometry[:, 2])
    rotations = np.zeros((n - 1, 3, 3))
    rotations[:, 0, 0], rotations[:, 0, 1], rotations[:, 1, 0], rotations[:, 1, 1] = cos, -sin, sin, cos
    rotations[:, 2, 2] = 1.0
    g2o_information = np.swapaxes(rotations, 1, 2) @ information @ rotations
    upper = np.triu_indices(3)
    lines = [f"VERTEX_SE2 {i} {_numbers([x, y, wrap_angle(theta)])}" for i, (x, y, theta) in enumerate(poses)]
    lines += [f"EDGE_SE2 {k} {k + 1} {_numbers(row)} {_numbers(matrix[upper])}"
              for k, (row, matrix) in enumerate(zip(odometry, g2o_information))]
    tie = _numbers([0.0, 0.0, 0.0, weight, 0.0, 0.0, weight, 0.0, 0.0])
    lines += [f"EDGE_SE2 {i} {j} {tie}" for i, j in zip(*_same_place_pairs(labels))]
    lines.append("FIX 0")  # last: GTSAM's reader stops at the first tag it does not know
    return "\n".join(lines) + "\n"


def tum_text(poses, timestamps) -> str:
    """A trajectory in the TUM format: ``timestamp tx ty tz qx qy qz qw`` per pose, for (N, 3) planar poses."""
    poses = _poses(poses)
    timestamps = finite_array("timestamps", timestamps, ndim=1)
    if timestamps.shape != (len(poses),):
        raise ValueError(f"timestamps must have one value per pose ({len(poses)}), got {timestamps.shape[0]}")
    half = poses[:, 2] / 2.0
    zeros = np.zeros(len(poses))
    columns = np.column_stack([timestamps, poses[:, 0], poses[:, 1], zeros, zeros, zeros, np.sin(half), np.cos(half)])
    return "".join(_numbers(row) + "\n" for row in columns)


def topology_graph(labels, poses):
    """The topology as a ``networkx.Graph``: places as nodes, traversals between places as edges.

    Node ``m`` (the canonical place label) has ``detections`` (its detection
    indices, "0,4,9"), ``visits`` and ``x``, ``y``, the mean of its detections'
    positions in ``poses`` (N, 3); edge (a, b) has ``count``, the number of
    consecutive detections k-1, k in places a and b, in either order.
    """
    networkx = _networkx()
    poses = _poses(poses)
    labels = _labels(labels, len(poses))
    graph = networkx.Graph()
    for place in range(int(labels.max()) + 1):
        members = np.flatnonzero(labels == place)
        x, y = poses[members, :2].mean(axis=0)
        graph.add_node(place, detections=",".join(str(index) for index in members), visits=len(members),
                       x=float(x), y=float(y))
    for before, after in zip(labels[:-1].tolist(), labels[1:].tolist()):
        if before != after:
            count = graph.edges[before, after]["count"] if graph.has_edge(before, after) else 0
            graph.add_edge(before, after, count=count + 1)
    return graph


def _same_place_pairs(labels: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Every pair i < j of detections with the same label (the topology's ties), ordered by (i, j)."""
    first, second = np.triu_indices(len(labels), k=1)
    same = labels[first] == labels[second]
    return first[same], second[same]


def _poses(poses) -> np.ndarray:
    poses = finite_array("poses", poses, ndim=2)
    if poses.shape[1] != 3 or len(poses) == 0:
        raise ValueError(f"poses must have shape (N, 3) with N >= 1, got {poses.shape}")
    return poses


def _labels(labels, n: int) -> np.ndarray:
    labels = np.asarray(canonical(labels))
    if labels.shape != (n,):
        raise ValueError(f"labels must hold one label per pose ({n}), got {len(labels)}")
    return labels


def _numbers(values) -> str:
    """Numbers as the shortest text that reads back to the same float."""
    return " ".join(repr(float(value)) for value in values)


def _networkx():
    try:
        import networkx
    except ImportError:
        raise ImportError("the topology graph needs networkx: pip install 'ptm[export]' (or pip install networkx)")\
            from None
    return networkx
