"""The ``scale`` section of ``ptm-bench speed``: the online mapper's latency per detection (docs/model.md §3.8).

One run of a generated corridor grid (10 x 10 nodes, 4 extra loops, 60 % of the nodes places, world and
run seed 0: 116 detections) at aliasing 0 and odometry noise 1, replayed detection by detection
through :class:`ptm.OnlineMapper` with its default settings, odometry + appearance. The parameters are
calibrated as a sweep calibrates them (:mod:`ptm_bench.evaluation.calibration`), on one held-out run of a
5 x 5 grid (seed 1000): the appearance model by empirical Bayes with one prior mean for every run (an
online run does not know its own mean signature before it ends), the penalty radius from the held-out
places, the tie from the detector's radius, and the prior rate, given to the mapper as a function of n,
from the held-out places per detection. ``--scale`` shrinks the grid's side by sqrt(scale) (n is in the
rows).

Rows (``section, metric, n, value, unit``), n = the run's detections:

* ``online_latency_median_s``, ``online_latency_p90_s``, ``online_latency_max_s`` -- wall seconds of one
  ``OnlineMapper.add``, over the run's detections;
* ``online_latency_last_quarter_median_s`` -- the same over the last quarter of the run (the largest n);
* ``online_map_ari`` -- adjusted Rand index of the final MAP against the truth; ``online_resamplings``.

    $ ptm-bench speed --section scale
    $ ptm-bench speed --section scale --scale 0.1   # a 3 x 3 grid: quick, for checking the section runs
"""

from __future__ import annotations

import math

import numpy as np

import ptm

from ptm_bench.evaluation.online import calibrated_mapper, replay
from ptm_bench.evaluation.scoring import adjusted_rand_index
from ptm_bench.simulation.generate import generate_dataset
from ptm_bench.world.floorplan import corridor_grid

__all__ = ["scale_rows"]

GRID_SIDE = 10
HELD_OUT_SIDE = 5
HELD_OUT_SEED = 1000


def _grid_run(side: int, seed: int) -> ptm.Dataset:
    floor = corridor_grid(side, side, min(4, (side - 1) ** 2), 0.6, seed)
    return generate_dataset(floor, aliasing=0.0, noise=1.0, seed=seed, images=False)


def _dataset_and_mapper(side: int = GRID_SIDE, seed: int = 0) -> tuple[ptm.Dataset, ptm.OnlineMapper]:
    """The grid run of the section and a fresh mapper for it, calibrated on the held-out run."""
    dataset = _grid_run(side, seed)
    mapper, _ = calibrated_mapper(dataset, [_grid_run(HELD_OUT_SIDE, HELD_OUT_SEED)], seed=seed)
    return dataset, mapper


def scale_rows(args) -> list[dict]:
    side = max(3, round(GRID_SIDE * math.sqrt(args.scale)))
    dataset, mapper = _dataset_and_mapper(side)
    result = replay(dataset, mapper)
    latency = np.array(result.diagnostics["latency_s"])
    n = dataset.n
    values = [
        ("online_latency_median_s", float(np.median(latency)), "s"),
        ("online_latency_p90_s", float(np.quantile(latency, 0.9)), "s"),
        ("online_latency_max_s", float(latency.max()), "s"),
        ("online_latency_last_quarter_median_s", float(np.median(latency[-max(1, n // 4):])), "s"),
        ("online_map_ari", adjusted_rand_index(result.map(), dataset.labels), "ARI"),
        ("online_resamplings", float(result.diagnostics["resamplings"]), f"of {n - 1} detections"),
    ]
    return [{"section": "scale", "metric": metric, "n": n, "value": value, "unit": unit}
            for metric, value, unit in values]
