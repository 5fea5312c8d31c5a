"""The ``worlds`` and ``show`` sub-commands: list the floors, draw a generated dataset (SPEC §5).

``show`` draws the true detection poses and the odometry dead-reckoned from the
first true pose (composing the dataset's odometry rows, SPEC §2.2), numbers
each detection with its index and true place id, marks the world's places,
and appends the panorama strip when the file holds panoramas.

    $ ptm-bench worlds
    $ ptm-bench generate --world office --aliasing 0.2 --noise 1 --seed 0 --out office.npz
    $ ptm-bench show office.npz --out office.png
"""

from __future__ import annotations

import io
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

import ptm  # noqa: E402
from ptm.dataset import atomic_write  # noqa: E402

from .detector import detect  # noqa: E402
from .floorplan import list_worlds, load_world  # noqa: E402
from .odometry_noise import compose  # noqa: E402

__all__ = ["dead_reckoning", "draw_dataset", "register"]


def register(subparsers) -> None:
    worlds = subparsers.add_parser("worlds", help="list the preset floors", description="List the floors in worlds/.")
    worlds.set_defaults(handler=_run_worlds)
    show = subparsers.add_parser(
        "show",
        help="draw a dataset's trajectories, detections and panoramas",
        description="Draw the true and odometry trajectories with detection ids, and the panorama strip.",
    )
    show.add_argument("path", type=Path, help="a dataset .npz written by `ptm-bench generate`")
    show.add_argument("--out", type=Path, required=True, help="output figure (.png)")
    show.set_defaults(handler=_run_show)


def _run_worlds(args) -> int:
    print(f"{'world':<14} {'places':>6} {'route [m]':>9} {'detections':>10}  description")
    for name in list_worlds():
        floor = load_world(name)
        visits = len(detect(_densified(floor.route_points()), floor.places, floor.detection_radius,
                            np.random.default_rng(0)))
        print(f"{name:<14} {len(floor.places):>6} {floor.route_length():>9.1f} {visits:>10}  {floor.description}")
    print("(procedural grids: ptm_bench.floorplan.corridor_grid(rows, cols, loops, place_density, seed))")
    return 0


def _densified(points: np.ndarray, spacing: float = 0.05) -> np.ndarray:
    """The polyline through ``points`` sampled every ``spacing`` metres (the un-jittered route)."""
    pieces = [points[:1]]
    for start, stop in zip(points[:-1], points[1:]):
        count = max(1, int(np.ceil(np.linalg.norm(stop - start) / spacing)))
        pieces.append(start + (stop - start) * (np.arange(1, count + 1) / count)[:, None])
    return np.concatenate(pieces)


def dead_reckoning(dataset: ptm.Dataset) -> np.ndarray:
    """(N, 3) poses from composing the odometry rows onto the first true pose (or the origin)."""
    start = dataset.true_poses[0] if dataset.true_poses is not None else np.zeros(3)
    poses = [np.asarray(start, dtype=float)]
    for row in dataset.odometry if dataset.odometry is not None else []:
        poses.append(compose(poses[-1], row))
    return np.array(poses)


def draw_dataset(dataset: ptm.Dataset):
    """A matplotlib figure of the dataset (trajectories on top, panoramas below when present)."""
    has_panoramas = dataset.panoramas is not None
    figure = plt.figure(figsize=(10, 9 if has_panoramas else 6), constrained_layout=True)
    grid = figure.add_gridspec(2 if has_panoramas else 1, 1, height_ratios=[3, 2] if has_panoramas else [1])
    axes = figure.add_subplot(grid[0])
    places = dataset.meta.get("places", {})
    for place_id, (x, y) in places.items():
        axes.add_patch(plt.Circle((x, y), dataset.meta.get("detection_radius", 1.0), color="0.85", zorder=0))
        axes.annotate(f"place {place_id}", (x, y), textcoords="offset points", xytext=(0, -14), ha="center",
                      fontsize=7, color="0.4")
    labels = dataset.labels if dataset.labels is not None else np.arange(dataset.n)
    if dataset.true_poses is not None:
        truth = dataset.true_poses
        axes.plot(truth[:, 0], truth[:, 1], "-o", color="tab:green", label="true poses", markersize=4)
        for index, (x, y, _) in enumerate(truth):
            axes.annotate(f"{index}:{labels[index]}", (x, y), textcoords="offset points", xytext=(4, 4),
                          fontsize=8, color="tab:green")
    if dataset.odometry is not None:
        odometry = dead_reckoning(dataset)
        axes.plot(odometry[:, 0], odometry[:, 1], "--s", color="tab:red", label="odometry", markersize=4)
        for index, (x, y, _) in enumerate(odometry):
            axes.annotate(f"{index}", (x, y), textcoords="offset points", xytext=(4, -10), fontsize=8, color="tab:red")
    meta = dataset.meta
    axes.set_title(f"{meta.get('world', 'dataset')}: {dataset.n} detections, aliasing {meta.get('aliasing', '?')}, "
                   f"noise {meta.get('noise', '?')}, seed {meta.get('seed', '?')}  (labels: index:place)")
    axes.set_aspect("equal", adjustable="datalim")
    axes.set_xlabel("x [m]")
    axes.set_ylabel("y [m]")
    axes.legend(loc="best", fontsize=8)
    if has_panoramas:
        strip = figure.add_subplot(grid[1])
        strip.imshow(np.concatenate(list(dataset.panoramas), axis=0), aspect="auto", interpolation="nearest")
        height = dataset.panoramas.shape[1]
        strip.set_yticks((np.arange(dataset.n) + 0.5) * height, [f"{i}:{labels[i]}" for i in range(dataset.n)],
                         fontsize=7)
        strip.set_xticks([])
        strip.set_title("panoramas (row = detection index:place)")
    return figure


def _run_show(args) -> int:
    if args.out.suffix.lower() != ".png":
        raise ValueError(f"out: the figure is written as PNG; give a .png path, got {args.out}")
    dataset = ptm.Dataset.load(args.path)
    figure = draw_dataset(dataset)
    buffer = io.BytesIO()
    figure.savefig(buffer, format="png", dpi=110)
    plt.close(figure)
    atomic_write(args.out, lambda handle: handle.write(buffer.getvalue()))
    print(f"wrote {args.out}")
    return 0
