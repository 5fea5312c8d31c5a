"""The report of the appearance predictive check: tables, PIT histograms and ``summary.md`` (docs/model.md §3.2)."""

from __future__ import annotations

from pathlib import Path

import pandas as pd

from ptm.dataset import atomic_write

from ptm_bench.evaluation.appearance_check import CONFIDENCE, EXTREME_P, PIT_BINS
from ptm_bench.reporting import plots
from ptm_bench.reporting.summary import markdown_table

__all__ = ["write_report"]


def write_report(table: pd.DataFrame, pit: pd.DataFrame, out: Path) -> Path:
    """``checks.csv``, ``pit.csv``, ``pit.png`` and ``summary.md`` in ``out``."""
    out.mkdir(parents=True, exist_ok=True)
    for name, frame in (("checks.csv", table), ("pit.csv", pit)):
        atomic_write(out / name, lambda handle, frame=frame: handle.write(frame.to_csv(index=False).encode()))
    figure = plots.pit_histograms(pit, out / "pit.png", bins=PIT_BINS)
    shown = table[["world", "model", "runs", "calibration_runs", "aliasing_auc", "revisit_pairs"]].assign(
        revisits_favouring_split=_with_interval(table, "revisits_favouring_split"),
        different_pairs=table["different_pairs"],
        different_favouring_merge=_with_interval(table, "different_favouring_merge"),
        held_out_visits=table["held_out_visits"], extreme_share_max=table["extreme_share_max"])
    ks = table[["world", "model", *[c for c in table.columns if c.startswith("ks_p_")]]]
    lines = [
        "# Appearance predictive check",
        "",
        "Each model is fitted by empirical Bayes on the calibration runs (seeds 1000..) and checked on held-out "
        "runs (seeds 0..) at the same condition. `revisits_favouring_split`: share of same-place detection pairs "
        "whose appearance Bayes factor favours two places (target <= 0.02); `different_favouring_merge`: share of "
        "different-place pairs whose Bayes factor favours one place (target <= 0.02), each with its exact binomial "
        f"{CONFIDENCE:.0%} interval in brackets; `extreme_share_max`: the "
        f"largest share, over signature components, of held-out revisits whose two-sided predictive p-value is "
        f"below {EXTREME_P:g} (expected {EXTREME_P:g}); `aliasing_auc`: mean measured aliasing of the held-out runs.",
        "",
        markdown_table(shown),
        "",
        "Kolmogorov-Smirnov p-values of each component's PIT values against the uniform:",
        "",
        markdown_table(ks),
        "",
        f"![PIT histograms]({figure.name})",
        "",
        "*Probability integral transform of each held-out revisit under the posterior predictive given the other "
        "visits of its place, per component (flat = calibrated; U-shaped = overconfident).*",
        "",
    ]
    summary = out / "summary.md"
    atomic_write(summary, lambda handle: handle.write("\n".join(lines).encode()))
    return summary


def _with_interval(table: pd.DataFrame, share: str) -> pd.Series:
    """A share and its interval as the summary prints them, e.g. 0.0227 [0.0047, 0.065]."""
    return pd.Series([f"{value:.3g} [{low:.2g}, {high:.2g}]" for value, low, high
                      in zip(table[share], table[f"{share}_low"], table[f"{share}_high"])], index=table.index)
