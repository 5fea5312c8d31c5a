"""The ``scale`` section of ``ptm-bench speed``: batch sampling's time to agreement against N, and the online
mapper's latency per detection (docs/model.md §3.4, §3.8).

*Time to agreement.* Generated corridor grids of 5 x 5 and 8 x 8 nodes (world and run seed 0, aliasing 0,
noise 1; about 30 and 60 detections), odometry + appearance calibrated on held-out runs exactly as a sweep
cell is (:func:`ptm_bench.evaluation.cell.run_cell`), sampled with the harness's default sampler
(four chains, ``inference.moves = "auto"``) from 2 500 samples per chain (burn-in 250), doubled until the
chains agree (:func:`ptm.diagnostics.chains_agree`, the sampler's own ``max_doublings``) or 40 000 (twice
the default n_samples, 20 000) did not. Rows, n = the run's detections: ``agreement_samples_per_chain`` (NaN
when 40 000 did not agree), ``agreement_wall_s`` (the sampler's wall time, every doubling included),
``agreement_rhat_log_prob`` and
``agreement_coassignment_max_difference`` reached, ``agreement_map_ari``, and
``odometry_evaluations_per_s`` (one over the mean time of a cache-missing evaluation of the odometry term
in that run).

*Online mapper.* One run of a generated corridor grid (10 x 10 nodes, 4 extra loops, 60 % of the nodes places, world and
run seed 0: 116 detections), one of a 14 x 14 grid (208 detections of 113 places) and one of a 16 x 16 grid (301
detections of 154 places: how far past 200 the latency holds), at aliasing 0 and odometry noise 1, each replayed
detection by detection through :class:`ptm.OnlineMapper` with its default settings, odometry + appearance. The
models are the harness's defaults, built as a sweep's (:func:`ptm_bench.evaluation.online.calibrated_mapper`,
the online differences named there) and calibrated on one held-out run of a 5 x 5 grid (seed 1000). ``--scale``
scales every grid's side by sqrt(scale) (n is in the rows).

Its rows (``section, metric, n, value, unit``), for each run, n = the run's detections:

* ``online_latency_median_s``, ``online_latency_p90_s``, ``online_latency_max_s`` -- wall seconds of one
  ``OnlineMapper.add``, over the run's detections;
* ``online_latency_last_quarter_median_s`` -- the same over the last quarter of the run (the largest n);
* ``online_map_ari`` -- adjusted Rand index of the final MAP against the truth; ``online_resamplings``;

and ``online_window_median_s`` with n = 20, 40, ...: the median over updates n - 19 ... n of that run, the
latency as the run grows (unit ``s (run of N)`` names the run: every run has windows at n = 20 ... 100).

    $ ptm-bench speed --section scale
    $ ptm-bench speed --section scale --scale 0.1   # 3 x 3 to 5 x 5 grids: quick, for checking the section runs
"""

from __future__ import annotations

import math
import tempfile
from pathlib import Path

import numpy as np

import ptm

from ptm_bench.evaluation.cell import run_cell
from ptm_bench.evaluation.experiment import expand_cells, parse_experiment
from ptm_bench.evaluation.online import calibrated_mapper, replay
from ptm_bench.evaluation.scoring import adjusted_rand_index
from ptm_bench.simulation.generate import generate_dataset
from ptm_bench.world.floorplan import corridor_grid

__all__ = ["scale_rows"]

ONLINE_SIDES = (10, 14, 16)  # the online runs' grids: 116, 208 and 301 detections
LATENCY_WINDOW = 20  # updates per online_window_median_s row
HELD_OUT_SIDE = 5
HELD_OUT_SEED = 1000
AGREEMENT_SIDES = (5, 8)
AGREEMENT_FIRST_SAMPLES, AGREEMENT_BURN_IN, AGREEMENT_DOUBLINGS = 2_500, 250, 4  # up to 40 000 samples


def _grid_run(side: int, seed: int) -> ptm.Dataset:
    floor = corridor_grid(side, side, min(4, (side - 1) ** 2), 0.6, seed)
    return generate_dataset(floor, aliasing=0.0, noise=1.0, seed=seed, images=False)


def _dataset_and_mapper(side: int, seed: int = 0) -> tuple[ptm.Dataset, ptm.OnlineMapper]:
    """The grid run of the section and a fresh mapper for it, calibrated on the held-out run."""
    dataset = _grid_run(side, seed)
    mapper, _ = calibrated_mapper(dataset, [_grid_run(HELD_OUT_SIDE, HELD_OUT_SEED)], seed=seed)
    return dataset, mapper


def scale_rows(args) -> list[dict]:
    return ([row for side in _scaled(AGREEMENT_SIDES, args.scale) for row in _agreement_rows(side)]
            + [row for side in _scaled(ONLINE_SIDES, args.scale) for row in _online_rows(side)])


def _scaled(sides, scale: float) -> list[int]:
    """The grid sides for ``--scale``: each times sqrt(scale) (at least 3), without repeats."""
    return sorted({max(3, round(side * math.sqrt(scale))) for side in sides})


def _agreement_rows(side: int) -> list[dict]:
    """Time to agreement of the default sampler on one grid run: the run's sweep cell, its chains doubled in
    length until they agree."""
    config = {"name": "speed_scale",
              "sweep": {"worlds": [{"generator": "corridor_grid", "name": f"grid{side}x{side}", "rows": side,
                                    "cols": side, "loops": min(4, (side - 1) ** 2), "place_density": 0.6}],
                        "seeds": [0], "calibration_seeds": [HELD_OUT_SEED]},
              "inference": {"n_samples": AGREEMENT_FIRST_SAMPLES, "burn_in": AGREEMENT_BURN_IN,
                            "max_doublings": AGREEMENT_DOUBLINGS},
              "variants": [{"name": "odometry+appearance", "models": ["odometry", "appearance"]}]}
    with tempfile.TemporaryDirectory() as folder:
        (cell,) = expand_cells(parse_experiment(config), Path(folder))
        row = run_cell(cell)
    samples = AGREEMENT_FIRST_SAMPLES * 2 ** row["diag_doublings"]
    values = [
        ("agreement_samples_per_chain", math.nan if row["warning"] else float(samples), "samples"),
        ("agreement_wall_s", row["diag_wall_s"], "s"),
        ("agreement_rhat_log_prob", row["diag_rhat_log_prob"], "R-hat"),
        ("agreement_coassignment_max_difference", row["diag_coassignment_max_difference"], "max abs"),
        ("agreement_map_ari", row["ari"], "ARI"),
        ("odometry_evaluations_per_s", 1e3 / row["diag_odometry_evaluation_ms_mean"], "1/s"),
    ]
    return [{"section": "scale", "metric": metric, "n": row["n_measurements"], "value": value, "unit": unit}
            for metric, value, unit in values]


def _online_rows(side: int) -> list[dict]:
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
    windows = [{"section": "scale", "metric": "online_window_median_s", "n": end,
                "value": float(np.median(latency[end - LATENCY_WINDOW:end])), "unit": f"s (run of {n})"}
               for end in range(LATENCY_WINDOW, n + 1, LATENCY_WINDOW)]
    return [{"section": "scale", "metric": metric, "n": n, "value": value, "unit": unit}
            for metric, value, unit in values] + windows
