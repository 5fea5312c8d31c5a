"""The report of an experiment: ``summary.md`` with its tables and figures (SPEC §6).

From the sweep table (``cells.csv``) this module aggregates, per world,
aliasing, noise and variant, the scores over seeds — mean ground-truth mass
with its range, median rank, how often the MAP is the truth, ARI, loop-closure
F1 and average precision, expected vs true number of places, wall time — puts
the paper's reported figures (the config's ``[paper]`` table) side by side
with ours, lists failed cells with their errors, and draws the figures of
:mod:`ptm_bench.plots` for the first scored seed.

    >>> table = read_table("results/exp3_nested/cells.csv")
    >>> write_summary(load_experiment("experiments/exp3_nested.toml"), table, Path("results/exp3_nested"))
    >>> print(Path("results/exp3_nested/summary.md").read_text())
"""

from __future__ import annotations

import json
import math
import re
from pathlib import Path

import numpy as np
import pandas as pd

from ptm.dataset import atomic_write

from . import plots
from .baselines import dead_reckoning
from .datacache import dataset_for
from .experiment import Experiment

__all__ = ["aggregate", "markdown_table", "write_summary"]

CONDITION = ["world", "aliasing", "noise"]


def aggregate(table: pd.DataFrame) -> pd.DataFrame:
    """One row per world x aliasing x noise x variant: scores summarised over the finished seeds."""
    ok = table[table["status"] == "ok"]
    rows = []
    for key, group in ok.groupby(CONDITION + ["variant"], sort=False):
        rank = group["gt_rank"]
        rows.append({
            **dict(zip(CONDITION + ["variant"], key)),
            "models": group["models"].iloc[0],
            "method": group["method"].iloc[0],
            "seeds": len(group),
            "gt_mass": group["gt_mass"].mean(),
            "gt_mass_min": group["gt_mass"].min(),
            "gt_mass_max": group["gt_mass"].max(),
            # An unvisited truth has no rank: count it as worse than every visited one.
            "gt_rank_median": rank.fillna(np.inf).median(),
            "map_correct": group["map_correct"].astype(bool).mean(),
            "ari": group["ari"].mean(),
            "lc_f1": group["lc_f1"].mean(),
            "lc_ap": group["lc_ap"].mean(),
            "expected_places": group["expected_places"].mean(),
            "map_places": group["map_places"].mean(),
            "true_places": group["true_places"].mean(),
            # Chains that disagree (split R-hat of log P above 1.1) make the masses above unreliable.
            "rhat_over_1.1": _fraction_above(group, "diag_rhat_log_prob", 1.1),
            "wall_s": group["wall_s"].mean(),
        })
    return pd.DataFrame(rows)


def _fraction_above(group: pd.DataFrame, column: str, limit: float) -> float:
    """Fraction of the rows where ``column`` exceeds ``limit``, among those that have it; NaN if none do."""
    values = group[column].dropna() if column in group else pd.Series(dtype=float)
    return float((values > limit).mean()) if len(values) else math.nan


def markdown_table(frame: pd.DataFrame) -> str:
    """A GitHub-flavoured markdown table; floats to 3 significant digits."""
    def cell(value):
        if isinstance(value, (float, np.floating)):
            if math.isnan(value):
                return "–"
            if math.isinf(value):
                return "not visited"
            return f"{value:.3g}"
        return str(value)

    header = "| " + " | ".join(frame.columns) + " |"
    rule = "|" + "|".join("---" for _ in frame.columns) + "|"
    body = ["| " + " | ".join(cell(value) for value in row) + " |" for row in frame.itertuples(index=False)]
    return "\n".join([header, rule, *body])


def write_summary(experiment: Experiment, table: pd.DataFrame, results_dir: Path, figures: bool = True) -> Path:
    """Write ``summary.md`` (and, with ``figures``, the PNG figures) into ``results_dir``."""
    results_dir = Path(results_dir)
    results_dir.mkdir(parents=True, exist_ok=True)
    summary = aggregate(table)
    failed = table[table["status"] != "ok"] if len(table) else table
    lines = [f"# {experiment.name}", ""]
    if experiment.description:
        lines += [experiment.description, ""]
    lines += [
        f"{len(table)} cells: {len(table) - len(failed)} finished, {len(failed)} failed. "
        f"Scored seeds {experiment.sweep['seeds']}; appearance calibrated on held-out seeds "
        f"{experiment.sweep['calibration_seeds']}. Rows are means over seeds unless named otherwise; "
        "`gt_mass` is the posterior probability of the ground-truth topology, `gt_rank_median` its median rank "
        "(1 = most probable), `map_correct` the fraction of seeds whose MAP is the truth, `lc_*` loop-closure "
        "scores of the co-assignment matrix, `rhat_over_1.1` the fraction of seeds whose chains disagree "
        "(split R-hat of log P > 1.1: the masses of those runs are not converged).",
        "",
    ]
    if experiment.paper and len(summary):
        lines += ["## The paper's figures and ours", "", markdown_table(_paper_comparison(experiment, summary)), ""]
    if len(summary):
        columns = CONDITION + ["variant", "seeds", "gt_mass", "gt_mass_min", "gt_mass_max", "gt_rank_median",
                               "map_correct", "ari", "lc_f1", "lc_ap", "expected_places", "map_places", "true_places", "rhat_over_1.1",
                   "wall_s"]
        lines += ["## Scores", "", markdown_table(summary[columns]), ""]
    if len(failed):
        lines += ["## Failed cells", "", markdown_table(failed[["cell_id", "error"]]), ""]
    if figures and len(summary):
        lines += ["## Figures", ""]
        for caption, path in _draw_figures(experiment, table, results_dir):
            lines += [f"![{caption}]({path.relative_to(results_dir).as_posix()})", f"*{caption}*", ""]
    path = results_dir / "summary.md"
    text = "\n".join(lines)
    atomic_write(path, lambda handle: handle.write(text.encode()))
    return path


def _paper_comparison(experiment: Experiment, summary: pd.DataFrame) -> pd.DataFrame:
    rows = []
    for variant, reported in experiment.paper.items():
        ours = summary[summary["variant"] == variant]
        for _, row in ours.iterrows():
            rows.append({
                **{column: row[column] for column in CONDITION},
                "variant": variant,
                "paper gt mass": reported.get("gt_mass", math.nan),
                "ours gt mass (mean)": row["gt_mass"],
                "ours range over seeds": f"{row['gt_mass_min']:.3f}–{row['gt_mass_max']:.3f}",
                "paper gt rank": reported.get("gt_rank", math.nan),
                "ours median rank": row["gt_rank_median"],
                "ours MAP = truth": row["map_correct"],
                "ours E[places] / true": f"{row['expected_places']:.2f} / {row['true_places']:g}",
                "paper note": reported.get("note", ""),
            })
    return pd.DataFrame(rows)


def _draw_figures(experiment: Experiment, table: pd.DataFrame, results_dir: Path):
    """Trajectories, top topologies and traces of the first seed of the first condition; the heat map."""
    ok = table[table["status"] == "ok"]
    first = ok.iloc[0]
    condition = ok[(ok["world"] == first["world"]) & (ok["aliasing"] == first["aliasing"])
                   & (ok["noise"] == first["noise"]) & (ok["seed"] == first["seed"])]
    world_spec = next(world for world in experiment.sweep["worlds"]
                      if (world if isinstance(world, str) else world["name"]) == first["world"])
    dataset = dataset_for(world_spec, float(first["aliasing"]), float(first["noise"]), int(first["seed"]),
                          experiment.sweep["generator_options"], results_dir / "datasets",
                          experiment.settings["appearance"]["components"])
    where = f"{first['world']}, aliasing {first['aliasing']:g}, noise {first['noise']:g}, seed {first['seed']}"
    figures = [(f"Detections and odometry: {where}",
                plots.trajectories(dataset, results_dir / "trajectory.png", title=where))]
    truth = tuple(json.loads(first["true_labels"]))
    # Drawn where odometry puts the detections, as the paper draws them: merged sets show as edges.
    positions = dead_reckoning(dataset.odometry) if dataset.odometry is not None else np.zeros((dataset.n, 2))
    for _, row in condition.iterrows():
        slug = re.sub(r"[^A-Za-z0-9]+", "_", row["variant"]).strip("_")
        topologies = [(tuple(labels), probability) for labels, probability in json.loads(row["top5"])]
        caption = f"Top topologies, {row['variant']} ({where})"
        figures.append((caption, plots.top_topologies(positions, topologies, truth, results_dir / f"top5_{slug}.png",
                                                      title=caption)))
        traces = {name[len("trace_"):]: json.loads(row[name]) for name in row.index
                  if name.startswith("trace_") and isinstance(row[name], str)}
        if traces:
            caption = f"Sampler traces, {row['variant']} ({where})"
            figures.append((caption, plots.sampler_traces(traces, results_dir / f"traces_{slug}.png", title=caption)))
    if ok["aliasing"].nunique() > 1 or ok["noise"].nunique() > 1:
        figures.append(("Ground-truth mass over aliasing x noise", plots.mass_heatmap(ok, results_dir / "gt_mass_heatmap.png")))
    return figures
