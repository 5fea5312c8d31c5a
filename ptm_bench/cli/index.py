"""``ptm-bench index``: write ``docs/results.md``, the index of the committed results.

One line and one figure per experiment, computed from its committed table
(:mod:`ptm_bench.reporting.results_index` does the work). Run it from the
repository root after a sweep's table changes.

    $ ptm-bench index
    $ ptm-bench index --results results --experiments experiments --out docs/results.md
"""

from __future__ import annotations

from pathlib import Path

from ptm_bench.reporting.results_index import write_index

__all__ = ["register"]


def register(subparsers) -> None:
    parser = subparsers.add_parser(
        "index",
        help="write docs/results.md: one line and one figure per experiment, from the committed tables",
        description="Read every experiments/*.toml with its table results/NAME/cells.csv and write the index "
                    "of the results (what each experiment measures, its headline figures per variant, a figure, "
                    "where the table was produced) atomically to --out.",
    )
    parser.add_argument("--results", type=Path, default=Path("results"), help="results folder (default: results)")
    parser.add_argument("--experiments", type=Path, default=Path("experiments"),
                        help="experiment configs (default: experiments)")
    parser.add_argument("--out", type=Path, default=Path("docs/results.md"),
                        help="the index to write (default: docs/results.md)")
    parser.set_defaults(handler=_run_index)


def _run_index(args) -> int:
    print(f"wrote {write_index(args.results, args.experiments, args.out)}")
    return 0
