"""The ``worlds`` and ``show`` sub-commands: list the floors, draw a generated dataset (docs/model.md §5).

``show`` draws the true detection poses and the odometry dead-reckoned from the
first true pose (composing the dataset's odometry rows, docs/model.md §2.2), numbers
each detection with its index and true place id, marks the world's places,
and appends the panorama strip when the file holds panoramas.

    $ ptm-bench worlds
    $ ptm-bench generate --world office --aliasing 0.2 --noise 1 --seed 0 --out office.npz
    $ ptm-bench show office.npz --out office.png
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

import ptm

from ptm_bench.reporting.plots import dataset_overview
from ptm_bench.simulation.detector import detect
from ptm_bench.world.floorplan import list_worlds, load_world, resample_polyline

__all__ = ["register"]


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
        route, _ = resample_polyline(floor.route_points(), 0.05)  # the un-jittered route
        visits = len(detect(route, floor.places, floor.detection_radius,
                            np.random.default_rng(0)))
        print(f"{name:<14} {len(floor.places):>6} {floor.route_length():>9.1f} {visits:>10}  {floor.description}")
    print("(procedural grids: ptm_bench.world.floorplan.corridor_grid(rows, cols, loops, place_density, seed))")
    return 0


def _run_show(args) -> int:
    if args.out.suffix.lower() != ".png":
        raise ValueError(f"out: the figure is written as PNG; give a .png path, got {args.out}")
    print(f"wrote {dataset_overview(ptm.Dataset.load(args.path), args.out)}")
    return 0
