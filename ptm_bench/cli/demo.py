"""``ptm-bench demo``: the README's main job — the whole pipeline on an embedded default.

A small world is simulated (``nested_loops`` by default: a large loop around a
smaller one, twelve detections), the posterior over topologies (paper eq. 2:
prior eq. 8-9, odometry eq. 11-14, appearance eq. 15-19 corrected) is
sampled with odometry alone and with odometry plus appearance, the two
threshold baselines are run, every answer is scored against the ground truth
(docs/model.md §6), and the scores, the parameters' sources, the top topologies and
the figures are written to ``results/demo/``. Each cell is a sweep cell
(:func:`ptm_bench.evaluation.cell.run_cell`), so the demo follows the same rules: every
parameter is configured, a sensor specification, or calibrated on the two
held-out runs, never read from the scored run's ground truth. It is the
experiment machinery of ``ptm-bench run`` on the embedded config
:data:`DEMO_CONFIG`, and takes well under two minutes on two cores.

    $ ptm-bench demo
    $ ptm-bench demo --world office --seed 3 --aliasing 0.5
    $ ptm-bench demo --out /tmp/demo
"""

from __future__ import annotations

import argparse
import copy
import json
import time
from pathlib import Path

from ptm_bench.cli.options import RESUME_HINT, output_folder, positive_int
from ptm_bench.evaluation.cell import run_cell
from ptm_bench.evaluation.experiment import DEMO_CONFIG, expand_cells, parse_experiment
from ptm_bench.evaluation.sweep import run_sweep
from ptm_bench.reporting.plots import topology_string
from ptm_bench.reporting.summary import write_summary


DESCRIPTION = """\
The whole pipeline on a small simulated world: simulate one run, calibrate on two
held-out runs, sample the posterior over topologies with odometry alone and with
odometry + appearance, run the two threshold baselines, score everything against
the ground truth and print it.

Output goes to OUT (default results/demo):
  cells.csv        one row per method (scores, parameters and their sources)
  summary.md       the scores as a table, with the calibration section
  *.png            figures: trajectory, top-5 topologies, ground-truth mass
  datasets/        the simulated runs (cached)
The demo recomputes every time; it refuses an OUT that holds another experiment's
table (e.g. results/exp1_penalty), and writes nothing there.

It is `ptm-bench run` on the embedded config ptm_bench.evaluation.experiment.DEMO_CONFIG;
config keys and their defaults: docs/model.md section 6 and
ptm_bench.evaluation.experiment.DEFAULTS."""


def register(subparsers) -> None:
    parser = subparsers.add_parser("demo", help="the whole pipeline on a small simulated world (about a minute)",
                                   description=DESCRIPTION, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--world", default="nested_loops", help="world preset (default: nested_loops)")
    parser.add_argument("--seed", type=int, default=0, help="seed of the simulated run (default: 0)")
    parser.add_argument("--aliasing", type=float, default=0.0, help="0: all places look different; 1: all alike")
    parser.add_argument("--noise", type=float, default=1.0, help="odometry noise level (default: 1.0)")
    parser.add_argument("--workers", type=positive_int, default=2, help="local processes (default: 2)")
    parser.add_argument("--out", type=Path, default=Path("results/demo"), help="output folder (default: results/demo)")
    parser.set_defaults(handler=run)


def run(args) -> int:
    config = copy.deepcopy(DEMO_CONFIG)
    config["sweep"].update(worlds=[args.world], aliasing=[args.aliasing], noise=[args.noise], seeds=[args.seed])
    experiment = parse_experiment(config, source="ptm-bench demo")
    output_folder(args.out, "--out")
    if (args.out / "summary.md").exists() and not (args.out / "cells.csv").exists():  # another command's report
        raise ValueError(f"--out {args.out} holds a summary.md that is not the demo's (no cells.csv beside it); "
                         "refusing to replace it: choose another folder")
    cells = expand_cells(experiment, args.out)
    print(f"Simulating {args.world} (aliasing {args.aliasing:g}, noise {args.noise:g}, seed {args.seed}), "
          f"calibrating on held-out seeds {list(experiment.sweep.calibration_seeds)}, "
          f"and running {len(cells)} inferences on {args.workers} processes...")
    started = time.perf_counter()
    # A fresh table each time: the demo always recomputes (a sweep would resume instead). The sweep refuses
    # a table of another experiment before it drops a row.
    setattr(args, RESUME_HINT, "the demo starts afresh when rerun")
    table = run_sweep(cells, run_cell, args.out / "cells.csv", workers=args.workers, fresh=True, progress=True)
    failed = table[table["status"] != "ok"]
    for _, row in failed.iterrows():
        print(f"  {row['variant']} failed: {row['error']}")
    finished = table[table["status"] == "ok"]
    if finished.empty:
        return 1

    truth = tuple(json.loads(finished.iloc[0]["true_labels"]))
    print(f"\n{len(truth)} detections of {max(truth) + 1} places; true topology {topology_string(truth)} "
          "(character i is the place of detection i)\n")
    print(f"{'method':<22}{'P(truth)':>9}{'rank':>6}{'MAP=truth':>10}{'ARI':>6}{'loop F1':>8}{'E[places]':>10}"
          f"{'time':>8}")
    for _, row in finished.iterrows():
        rank = "-" if row["gt_rank"] != row["gt_rank"] else f"{int(row['gt_rank'])}"
        f1 = "-" if row["lc_f1"] != row["lc_f1"] else f"{row['lc_f1']:.2f}"
        print(f"{row['variant']:<22}{row['gt_mass']:>9.3f}{rank:>6}{'yes' if row['map_correct'] else 'no':>10}"
              f"{row['ari']:>6.2f}{f1:>8}{row['expected_places']:>10.2f}{row['wall_s']:>7.1f}s")
    full = finished[finished["variant"] == "odometry+appearance"]
    if not full.empty:
        # Where each parameter came from: the config, a sensor specification, or the held-out runs -- never the truth.
        print("\nparameters of odometry + appearance:")
        for column in sorted(c for c in full.columns if c.startswith("source_") and isinstance(full.iloc[0][c], str)):
            name = column.removeprefix("source_")
            value = full.iloc[0].get(name)
            shown = f"{value:.3g} " if isinstance(value, float) and value == value else (
                f"{value} " if isinstance(value, str) else "")
            print(f"  {name:<18}{shown}({full.iloc[0][column]})")
        print(f"  learnt from this run: prior rate {full.iloc[0]['prior_rate_posterior_mean']:.3g} "
              f"± {full.iloc[0]['prior_rate_posterior_sd']:.2g}, odometry noise scale "
              f"{full.iloc[0]['noise_scale_posterior_mean']:.3g} (posterior means)")
        print("\nmost probable topologies with odometry + appearance:")
        for labels, probability in json.loads(full.iloc[0]["top5"]):
            marker = "  <- ground truth" if tuple(labels) == truth else ""
            print(f"  {topology_string(labels)}  {probability:.3f}{marker}")

    summary = write_summary(experiment, table, args.out)
    print(f"\nwrote {summary} and its figures ({', '.join(sorted(p.name for p in args.out.glob('*.png')))}) "
          f"in {time.perf_counter() - started:.0f} s")
    return 0 if failed.empty else 1
