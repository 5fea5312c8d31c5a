"""The ``simulator`` section of ``ptm-bench speed``: panorama throughput and end-to-end generation time.

Rows (``section, metric, n, value, unit``):

* ``panoramas_per_s`` -- eight camera views rendered offscreen at the default
  rig resolution and stitched into a panorama, per second (n = panoramas timed);
  ``render_ms_per_view`` and ``stitch_ms_per_panorama`` split that time.
* ``generate_wall_s_<world>`` -- ``generate_dataset(world, 0.3, 1.0, seed 0)``
  end to end for each preset (n = detections); the target for nested_loops is
  30 s on two CPU cores.

    $ ptm-bench speed --section simulator
    $ ptm-bench speed --section simulator --scale 0.5
"""

from __future__ import annotations

import time

import numpy as np

from ptm_bench.simulation.generate import build_world, generate_dataset
from ptm_bench.simulation.panorama import CylindricalStitcher
from ptm_bench.simulation.robot import CAMERA_COUNT, Rig, RigConfig
from ptm_bench.world.floorplan import list_worlds, load_world

__all__ = ["simulator_rows"]


def _row(metric: str, n: int, value: float, unit: str) -> dict:
    return {"section": "simulator", "metric": metric, "n": n, "value": value, "unit": unit}


def simulator_rows(args) -> list[dict]:
    rig_config = RigConfig()
    floor = load_world("nested_loops")
    model, _, _ = build_world(floor, 0.3, np.random.default_rng(0), rig_config)
    rig = Rig(model, rig_config)
    stitcher = CylindricalStitcher(rig_config)
    count = max(4, int(round(20 * getattr(args, "scale", 1.0))))
    qpos = np.zeros(model.nq)
    qpos[:2] = floor.places[1]
    rig.views(qpos)  # warm-up: the first render compiles shaders and uploads the scene
    render_s = stitch_s = 0.0
    try:
        for heading in np.linspace(0.0, 2 * np.pi, count, endpoint=False):
            qpos[2] = heading
            started = time.perf_counter()
            views = rig.views(qpos)
            rendered = time.perf_counter()
            stitcher.stitch(views)
            render_s += rendered - started
            stitch_s += time.perf_counter() - rendered
    finally:
        rig.close()
    rows = [
        _row("panoramas_per_s", count, count / (render_s + stitch_s), "panoramas/s"),
        _row("render_ms_per_view", count * CAMERA_COUNT, 1000 * render_s / (count * CAMERA_COUNT), "ms"),
        _row("stitch_ms_per_panorama", count, 1000 * stitch_s / count, "ms"),
    ]
    for world in list_worlds():
        started = time.perf_counter()
        dataset = generate_dataset(world, 0.3, 1.0, 0, images=True)
        rows.append(_row(f"generate_wall_s_{world}", dataset.n, time.perf_counter() - started, "s"))
    return rows
