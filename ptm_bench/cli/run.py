"""``ptm-bench run``: run an experiment config as a resumable sweep, then write its summary and figures
(docs/model.md §6).

Cells already in ``results/NAME/cells.csv`` are skipped, so an interrupted run
resumes where it stopped; cells whose definition changed since (an edited config,
world or code) are recomputed. Cells run in local processes by default, or on a
Dask distributed cluster with ``--scheduler ADDRESS`` (``pip install 'ptm[dask]'``).

    $ ptm-bench run experiments/exp3_nested.toml
    $ ptm-bench run experiments/grid.toml --workers 2 --retry-failed
    $ ptm-bench run experiments/grid.toml --scheduler tcp://scheduler:8786
"""

from __future__ import annotations

import argparse
from pathlib import Path

from ptm_bench.cli.options import RESUME_HINT, output_folder, positive_int, report_file
from ptm_bench.evaluation.cell import run_cell
from ptm_bench.evaluation.experiment import describe, expand_cells, load_experiment
from ptm_bench.evaluation.sweep import run_sweep
from ptm.dataset import atomic_write
from ptm_bench.reporting.checks import check_table, evaluate_checks, junit_xml
from ptm_bench.reporting.summary import aggregate, current_rows, markdown_table, write_summary

SHOWN_COLUMNS = ["world", "aliasing", "noise", "variant", "seeds", "gt_mass", "gt_rank_median", "map_correct", "ari",
                 "wall_s"]


DESCRIPTION = """\
Run an experiment config as a resumable sweep: worlds x aliasing x noise x seeds x
(variants + baselines), one cell each, then write the summary and figures.

Output goes to OUT/NAME/ (NAME: the config's 'name', default its file name):
  cells.csv        one row per cell (scores, parameters and their sources, status, error)
  cells.csv.lock   while a run writes the table: its pid (a second run is refused)
  summary.md       the table per condition and variant, the paper's figures, calibration
  *.png            figures; datasets/ caches the simulated runs

Cells already in cells.csv are skipped, so an interrupted run (Ctrl-C, a kill)
resumes where it stopped; cells whose definition changed (config, world or code)
are recomputed.

With --check, the config's [checks] thresholds (e.g. "odometry+appearance".gt_mass
= ">= 0.9") are checked against the summary: a table of what held, a JUnit XML
report (OUT/NAME/checks.xml, or --junit PATH) and exit status 1 if one fell short.

Config sections ([sweep], [inference], [odometry], [appearance], [[variants]],
baselines, [paper], [checks]) and every key with its default: docs/model.md section 6,
the typed records of ptm_bench.evaluation.settings (an unknown or removed key is
refused, naming its path) and ptm_bench.evaluation.experiment.DEFAULTS
(python3 -c "import ptm_bench.evaluation.experiment as e; print(e.DEFAULTS)")."""


def register(subparsers) -> None:
    parser = subparsers.add_parser("run", help="run an experiment config (a resumable sweep) and write its summary",
                                   description=DESCRIPTION, formatter_class=argparse.RawDescriptionHelpFormatter,
                                   epilog="example: ptm-bench run experiments/exp3_nested.toml --workers 2")
    parser.add_argument("config", type=Path, help="an experiment config, e.g. experiments/exp3_nested.toml")
    parser.add_argument("--out", type=Path, default=Path("results"),
                        help="results folder; the experiment writes OUT/NAME/ (default: results)")
    parser.add_argument("--workers", type=positive_int, default=None, help="local processes (default: number of CPUs)")
    parser.add_argument("--scheduler", default=None,
                        help="Dask distributed scheduler address (tcp://host:8786), instead of local processes")
    parser.add_argument("--retry-failed", action="store_true", help="rerun cells that ended in an error")
    parser.add_argument("--check", action="store_true",
                        help="check the config's [checks] thresholds; exit 1 if one fails; write a JUnit XML report")
    parser.add_argument("--junit", type=Path, default=None,
                        help="the file where --check writes its report (default: OUT/NAME/checks.xml)")
    parser.add_argument("--no-figures", action="store_true", help="write summary.md without drawing figures")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")
    parser.set_defaults(handler=run)


def run(args) -> int:
    experiment = load_experiment(args.config)
    output_folder(args.out, "--out")
    if args.junit is not None:
        report_file(args.junit, "--junit")
    results_dir = output_folder(args.out / experiment.name, "--out")
    cells = expand_cells(experiment, results_dir)
    print(describe(experiment))
    setattr(args, RESUME_HINT, f"every finished cell is in {results_dir / 'cells.csv'}; "
                               f"rerun `ptm-bench run {args.config} --out {args.out}` to resume")
    table = run_sweep(cells, run_cell, results_dir / "cells.csv", workers=args.workers, scheduler=args.scheduler,
                      retry_failed=args.retry_failed, progress=not args.no_progress)
    if table.attrs.get("recomputed_changed"):
        print(f"{table.attrs['recomputed_changed']} cells were recomputed: their definition changed since the table "
              "was written")
    if table.attrs.get("reused_unverified"):
        print(f"{table.attrs['reused_unverified']} cells were reused from a table written before configs were "
              f"recorded; delete {results_dir / 'cells.csv'} to recompute them")
    summary_path = write_summary(experiment, table, results_dir, figures=not args.no_figures)
    current, left_out = current_rows(experiment, table, results_dir)
    summary = aggregate(current)
    if left_out["stale"]:
        print(f"{left_out['stale']} rows of cells no longer in the config are kept in the table but left out here")
    if len(summary):
        print(markdown_table(summary[SHOWN_COLUMNS]))
    failed = int((table["status"] != "ok").sum())
    print(f"\n{len(table) - failed} cells finished, {failed} failed; table {results_dir / 'cells.csv'}, "
          f"summary {summary_path}")
    if failed:
        print(failure_report(table, f"ptm-bench run {args.config} --out {args.out} --retry-failed"))
    checks_failed = 0
    if args.check:
        if not experiment.checks:
            raise ValueError(f"--check: {args.config} has no [checks] table")
        results = evaluate_checks(experiment.checks, summary)
        checks_failed = int((~results["held"]).sum())
        report = args.junit or results_dir / "checks.xml"
        atomic_write(report, lambda handle: handle.write(junit_xml(results, experiment.name).encode()))
        print(f"\nchecks of {args.config}:\n{check_table(results)}\n"
              f"{len(results) - checks_failed} held, {checks_failed} did not; JUnit report {report}")
    return 0 if failed == 0 and checks_failed == 0 else 1


def failure_report(table, retry_command: str, shown: int = 3) -> str:
    """The distinct errors of the failed cells (most frequent first), and how to rerun only those cells."""
    errors = table.loc[table["status"] != "ok", "error"].astype("string").fillna("").value_counts()
    lines = [f"  {count} cell{'s' if count > 1 else ''}: {error}" for error, count in errors.head(shown).items()]
    if len(errors) > shown:
        lines.append(f"  ... and {len(errors) - shown} other errors (column 'error' of the table)")
    return "\n".join(["failed cells:", *lines, f"fix the cause, then rerun only those cells: {retry_command}"])
