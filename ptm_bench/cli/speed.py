"""``ptm-bench speed``: throughput benchmarks, written to results/speed.csv.

Sections (run all by default, or pick with ``--section``):

* ``core`` — Metropolis-Hastings steps per second on appearance-only
  posteriors at N = 10, 50, 100 (K = 5), for the paper's split/merge move
  alone and for the default move mix, and the wall time of exact
  enumeration at N = 10 (Bell(10) = 115 975 partitions).
* further sections registered in ``SECTIONS`` by the odometry model, the
  simulator, the evaluation harness and the online mapper (``scale``).

Rows: ``section, metric, n, value, unit``. Timings are single-process; compare
ratios within one run, not absolute times across machines.

    $ ptm-bench speed
    $ ptm-bench speed --section core --out results
"""

from __future__ import annotations

import argparse
import importlib
import platform
from pathlib import Path

from ptm.dataset import atomic_write
from ptm_bench.cli.options import output_folder

# section name -> "module:function"; each function takes the parsed args and returns row dicts.
SECTIONS = {
    "core": "ptm_bench.benchmarks.core:core_rows",
    "simulator": "ptm_bench.benchmarks.simulator:simulator_rows",
    "odometry": "ptm_bench.benchmarks.odometry:odometry_rows",
    "evaluation": "ptm_bench.benchmarks.evaluation:evaluation_rows",
    "scale": "ptm_bench.benchmarks.scale:scale_rows",
}


def _section_function(name: str):
    module_name, function_name = SECTIONS[name].split(":")
    return getattr(importlib.import_module(module_name), function_name)


def run(args) -> int:
    import pandas as pd

    names = args.section or list(SECTIONS)
    unknown = [name for name in names if name not in SECTIONS]
    if unknown:
        raise ValueError(f"unknown section(s) {unknown}; known: {sorted(SECTIONS)}")
    out = output_folder(Path(args.out), "--out")
    path = out / "speed.csv"
    previous = _previous_rows(path)  # read before the (long) measurements: a foreign file is refused at once
    rows = []
    for name in names:
        print(f"[speed] running section {name} ...", flush=True)
        rows.extend(_section_function(name)(args))
    frame = pd.DataFrame(rows, columns=["section", "metric", "n", "value", "unit"])
    frame["machine"] = f"{platform.node()} {platform.processor() or platform.machine()}"
    if previous is not None:  # keep other sections' rows from earlier runs
        previous = previous[~previous["section"].isin(names)]
        frame = pd.concat([previous, frame], ignore_index=True)
    atomic_write(path, lambda handle: handle.write(frame.to_csv(index=False).encode()))
    with pd.option_context("display.width", 120, "display.max_rows", 200):
        print(frame.drop(columns="machine").to_string(index=False, float_format=lambda v: f"{v:,.4g}"))
    print(f"[speed] wrote {path}")
    return 0


def _previous_rows(path: Path):
    """The rows of an earlier speed.csv, None if there is none; ``ValueError`` for a file that is not one."""
    import pandas as pd

    if not path.exists():
        return None
    try:
        previous = pd.read_csv(path)
    except (pd.errors.ParserError, pd.errors.EmptyDataError, UnicodeDecodeError, IsADirectoryError) as error:
        raise ValueError(f"{path} is not a speed table ({type(error).__name__}); refusing to overwrite it") from None
    missing = {"section", "metric", "n", "value", "unit"} - set(previous.columns)
    if missing:
        raise ValueError(f"{path} is not a speed table (no column {', '.join(sorted(missing))}); refusing to "
                         "overwrite it")
    return previous


DESCRIPTION = """\
Throughput benchmarks. Output: OUT/speed.csv (default results/speed.csv), one row
per measurement: section, metric, n, value, unit, machine. Rows of the sections
run now replace their earlier rows; other sections' rows are kept.

Sections (all by default; pick with --section, repeatable):
  core        Metropolis-Hastings steps per second on appearance-only posteriors
              (N = 10, 50, 100; split/merge alone and the default move mix), and
              exact enumeration at N = 10 (Bell(10) = 115 975 partitions)
  simulator   panoramas rendered and stitched per second; generate_dataset end to
              end for each preset world
  odometry    one log P(O | T) evaluation on a cache miss at N = 10 ... 200; cache
              hit rate, weights' ESS and steps per second with and without
              delayed acceptance at N = 50
  evaluation  the sweep's overhead per cell, scoring time, one demo cell end to end
  scale       the default sampler's time to agreement on generated grids of about
              30 and 60 detections; the online mapper's latency per detection
              (median, 90th percentile, largest, median of the last quarter and
              of every 20 updates) replaying generated 10 x 10, 14 x 14 and
              16 x 16 corridor grids (116, 208 and 301 detections), odometry +
              appearance, and its final MAPs' ARI (about 11 minutes on 2 cores)

Timings are single-process; compare ratios within one run, not absolute times
across machines. Each section's workload and settings are fixed in its module,
ptm_bench.benchmarks.SECTION (--scale only scales the work); the settings an
experiment config may change are documented in docs/model.md section 6 and
ptm_bench.evaluation.experiment.DEFAULTS."""


def register(subparsers) -> None:
    parser = subparsers.add_parser("speed", help="throughput benchmarks -> results/speed.csv",
                                   description=DESCRIPTION, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--section", action="append", help="section to run (repeatable); default all")
    parser.add_argument("--out", default="results", help="folder for speed.csv (default: results)")
    parser.add_argument("--scale", type=float, default=1.0,
                        help="multiply the work per measurement (smaller = faster, noisier)")
    parser.set_defaults(handler=run)
