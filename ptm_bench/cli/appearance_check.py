"""``ptm-bench appearance-check``: the appearance models' predictive check on held-out runs (docs/model.md §3.2).

Writes ``checks.csv``, ``pit.csv``, ``pit.png`` and ``summary.md`` to the
output folder (``results/appearance_check`` by default).

    $ ptm-bench appearance-check --worlds office --runs 30
"""

from __future__ import annotations

from pathlib import Path

from ptm_bench.cli.options import output_folder
from ptm_bench.evaluation.appearance_check import DEFAULT_WORLDS, predictive_check
from ptm_bench.reporting.appearance_check import write_report


def register(subparsers) -> None:
    parser = subparsers.add_parser(
        "appearance-check",
        help="predictive check of the appearance models on held-out simulated runs",
        description="Fit the appearance models (with outlier visits, the joint model, the paper's "
                    "independent one) on calibration runs and report how "
                    "often they are fooled on held-out runs (Bayes factors of pairs, PIT of revisits).",
    )
    parser.add_argument("--worlds", nargs="+", default=list(DEFAULT_WORLDS), choices=list(DEFAULT_WORLDS),
                        help="worlds to check (default: all)")
    parser.add_argument("--runs", type=int, default=30, help="held-out runs per world (default 30)")
    parser.add_argument("--calibration-runs", type=int, default=10, help="calibration runs per world (default 10)")
    parser.add_argument("--out", type=Path, default=Path("results/appearance_check"), help="output folder")
    parser.set_defaults(handler=_run)


def _run(args) -> int:
    output_folder(args.out, "--out")
    if (args.out / "cells.csv").exists():  # its summary.md and figures are an experiment's, not ours to replace
        raise ValueError(f"--out {args.out} holds an experiment's table (cells.csv); refusing to write the check's "
                         "summary.md there: choose another folder")
    worlds = {name: DEFAULT_WORLDS[name] for name in args.worlds}
    table, pit = predictive_check(worlds, args.runs, args.calibration_runs, cache_dir=args.out / "datasets")
    summary = write_report(table, pit, args.out)
    columns = ["world", "model", "revisits_favouring_split", "different_favouring_merge", "extreme_share_max"]
    print(table[columns].to_string(index=False, float_format=lambda v: f"{v:.3f}"))
    print(f"wrote {summary}")
    return 0
