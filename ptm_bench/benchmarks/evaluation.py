"""``ptm-bench speed --section evaluation``: the cost of the evaluation harness itself (docs/model.md §6).

* ``sweep_overhead_per_cell`` — wall time per cell of a sweep whose cells do
  nothing (forking a process, collecting the row, rewriting ``cells.csv``),
  with two local workers;
* ``score_time`` — :func:`ptm_bench.evaluation.scoring.score` of a histogram over
  ``n_topologies`` random partitions of N = 12 detections;
* ``demo_cell_wall`` — one ``nested_loops`` cell of the demo config
  (odometry + appearance, datasets cached), end to end.

    $ ptm-bench speed --section evaluation
"""

from __future__ import annotations

import tempfile
import time
from pathlib import Path

import numpy as np

from ptm.partitions import canonical

from ptm_bench.evaluation import scoring
from ptm_bench.evaluation.cell import run_cell
from ptm_bench.evaluation.experiment import DEMO_CONFIG, expand_cells, parse_experiment
from ptm_bench.evaluation.sweep import run_sweep

__all__ = ["evaluation_rows"]


def _empty_cell(cell: dict) -> dict:
    return {"value": cell["seed"]}


def evaluation_rows(args) -> list[dict]:
    rows = []
    cell_count = max(8, int(40 * args.scale))
    with tempfile.TemporaryDirectory() as folder:
        cells = [{"cell_id": str(seed), "seed": seed} for seed in range(cell_count)]
        started = time.perf_counter()
        run_sweep(cells, _empty_cell, Path(folder) / "cells.csv", workers=2, progress=False)
        rows.append({"section": "evaluation", "metric": "sweep_overhead_per_cell", "n": cell_count,
                     "value": (time.perf_counter() - started) / cell_count, "unit": "s"})

        rng = np.random.default_rng(0)
        count = 10_000
        partitions = rng.integers(0, 6, size=(count, 12))
        distribution = {}
        for row, weight in zip(partitions, rng.random(count)):
            key = canonical(row)
            distribution[key] = distribution.get(key, 0.0) + weight
        total = sum(distribution.values())
        distribution = {key: weight / total for key, weight in distribution.items()}
        started = time.perf_counter()
        scoring.score(distribution, partitions[0])
        rows.append({"section": "evaluation", "metric": "score_time", "n": len(distribution),
                     "value": time.perf_counter() - started, "unit": "s"})

        experiment = parse_experiment(DEMO_CONFIG, source="demo")
        cell = next(cell for cell in expand_cells(experiment, Path(folder)) if cell["variant"] == "odometry+appearance")
        run_cell(cell)  # generates and caches the datasets
        started = time.perf_counter()
        row = run_cell(cell)
        rows.append({"section": "evaluation", "metric": "demo_cell_wall", "n": row["n_measurements"],
                     "value": time.perf_counter() - started, "unit": "s"})
    return rows
