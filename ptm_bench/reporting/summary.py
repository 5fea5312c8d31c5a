"""The report of an experiment: ``summary.md`` with its tables and figures (docs/model.md §6).

From the sweep table (``cells.csv``) this module first keeps exactly the
cells of the current config (:func:`current_rows`: rows of cells no longer in
the config, or computed under an edited one, are left out and counted), then
aggregates, per world, aliasing, noise and variant, the scores over seeds —
mean ground-truth mass with its range, median rank, how often the MAP is the
truth, ARI, loop-closure F1 and average precision, expected vs true number of
places, wall time, and the measured aliasing of the datasets (``aliasing_auc``,
the AUC of signature distance for same- vs different-place pairs) beside the
aliasing knob. Per variant it pools the calibration of the probabilities over
every cell (:func:`calibration_by_variant`): the expected calibration error
ECE = sum_b (n_b / n) |mean p_b - mean y_b| of the pairwise co-assignment
probabilities over 10 bins, exact from the per-cell ``reliability`` tables
(:func:`ptm_bench.evaluation.scoring.pooled_reliability`); the Brier score, the mean of
the cells' ``brier`` weighted by ``n_pairs``; the mean log score of the truth,
log max(gt_mass, 1e-6); and the share of confidently wrong runs (MAP
probability >= 0.9, MAP not the truth). It sets every method side by side per condition (:func:`side_by_side`: each
posterior variant, each threshold baseline and each peer, with AP, ARI, F1, ECE
and the mean wall time per cell), puts the paper's reported figures
(the config's ``[paper]`` table) beside ours, lists where each variant's
parameters came from (the ``source_*`` columns), lists failed cells with their
errors, and draws the figures of :mod:`ptm_bench.reporting.plots`: those of the first
scored seed (each top topology on its own optimised map, the Laplace mode of its pose
graph, where the variant has an odometry model; the trajectory figure with the MAP
topology's map beside the reference and dead reckoning), the ground-truth-mass heat
map, the reliability diagram, each method's mean ARI and AP against its mean wall time
(``cost_accuracy.png``), and, for a sweep over several worlds, accuracy, chain
agreement and wall time against the number of detections.

    $ ptm-bench run experiments/exp3_nested.toml      # runs the cells, then writes the summary
    $ cat results/exp3_nested/summary.md
"""

from __future__ import annotations

import json
import math
import re
from dataclasses import replace
from pathlib import Path

import numpy as np
import pandas as pd

from ptm.dataset import atomic_write
from ptm.recorder import RENORMALISE_COVERAGE, STRAY_CHAIN_MASS
from ptm.se2 import dead_reckoning

from ptm_bench.evaluation import scoring
from ptm_bench.evaluation.calibration import floors_in
from ptm_bench.evaluation.datacache import dataset_for, is_recorded
from ptm_bench.evaluation.experiment import PEER_NAMES, Experiment, expand_cells
from ptm_bench.evaluation.models import build_models
from ptm_bench.reporting import plots

__all__ = ["aggregate", "calibration_by_variant", "current_rows", "markdown_table", "method_kinds", "side_by_side",
           "write_summary"]

CONDITION = ["world", "aliasing", "noise"]
#: The measured aliasing of a cell's dataset, shown beside the aliasing knob when the table has it.
MEASURED_ALIASING = "aliasing_auc"
#: Below this mean effective sample size of its importance weights a condition's odometry values are flagged.
LOW_ODOMETRY_ESS = 5.0
#: Columns that say where a parameter of a cell came from: ``source_<parameter>``.
SOURCE_PREFIX = "source_"


def current_rows(experiment: Experiment, table: pd.DataFrame, results_dir: Path) -> tuple[pd.DataFrame, dict]:
    """The rows of ``table`` that are cells of the current config, and counts of what was left out.

    A row is left out when its ``cell_id`` is not among the config's cells
    (``stale``: a seed, level or variant since removed) or when it records a
    ``definition`` digest other than its cell's (``edited``: computed under an
    edited config). Rows without a recorded definition (tables from before
    definitions existed) are kept, as the sweep reuses them. ``missing``
    counts the config's cells that have no row.
    """
    cells = expand_cells(experiment, Path(results_dir))
    definitions = {str(cell["cell_id"]): cell.get("definition") for cell in cells}
    if not len(table):
        return table, {"stale": 0, "edited": 0, "missing": len(cells)}
    if "cell_id" not in table.columns:
        raise ValueError("the table has no cell_id column: not a sweep table")
    cell_ids = table["cell_id"].astype(str)
    known = cell_ids.isin(definitions)
    recorded = table["definition"] if "definition" in table.columns else pd.Series(None, index=table.index)
    edited = pd.Series([_edited(digest, definitions.get(cell_id)) for cell_id, digest in zip(cell_ids, recorded)],
                       index=table.index, dtype=bool)
    kept = table[known & ~edited]
    counts = {"stale": int((~known).sum()), "edited": int(edited.sum()),
              "missing": len(set(definitions) - set(kept["cell_id"].astype(str)))}
    return kept, counts


def _edited(recorded, current) -> bool:
    """Whether a row was computed under another config than its cell's; unknown (no digest) counts as not."""
    return isinstance(recorded, str) and isinstance(current, str) and recorded != current


def aggregate(table: pd.DataFrame) -> pd.DataFrame:
    """One row per world x aliasing x noise x variant: scores summarised over the finished seeds (none when no cell
    finished)."""
    ok = _finished(table)
    rows = []
    for key, group in (ok.groupby(CONDITION + ["variant"], sort=False) if len(ok) else []):
        rank = group["gt_rank"]
        rows.append({
            **dict(zip(CONDITION + ["variant"], key)),
            MEASURED_ALIASING: _mean(group, MEASURED_ALIASING),
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
            "chains_agree": _chains_agree(group),
            "odometry_ess": _mean(group, "diag_odometry_ess_mean"),
            "noise_scale": _mean(group, "noise_scale_posterior_mean"),
            "noise_scale_in_prior_tail": _mean(group, "noise_scale_in_prior_tail"),
            "detections": _mean(group, "n_measurements"),
            "wall_s": group["wall_s"].mean(),
            **_pooled_calibration(group),
        })
    return pd.DataFrame(rows)


def calibration_by_variant(table: pd.DataFrame) -> pd.DataFrame:
    """One row per variant, pooled over every finished cell: the accuracy means beside the calibration scores.

    ``ece`` and ``brier`` pool every pair i < j of every cell (``n_pairs`` of
    them, from the cells that carry a ``reliability`` table); ``log_score`` is
    the mean over cells of log max(gt_mass, 1e-6); ``confidently_wrong`` the
    share of cells whose MAP has probability >= 0.9 and is not the truth.
    """
    ok = _finished(table)
    rows = []
    for variant, group in (ok.groupby("variant", sort=False) if len(ok) else []):
        rows.append({
            "variant": variant,
            "method": group["method"].iloc[0],
            "cells": len(group),
            "gt_mass": group["gt_mass"].mean(),
            "map_correct": group["map_correct"].astype(bool).mean(),
            "ari": group["ari"].mean(),
            "lc_ap": group["lc_ap"].mean(),
            **_pooled_calibration(group),
        })
    return pd.DataFrame(rows)


def method_kinds(experiment: Experiment) -> dict[str, str]:
    """Every method of the experiment, in the config's order, and its kind: ``posterior`` (a model variant),
    ``baseline`` (a threshold baseline) or ``peer`` (a robust back end, ``ptm_bench.evaluation.peers``)."""
    kinds = {variant.name: "posterior" for variant in experiment.variants}
    for baseline in experiment.baselines:
        kinds[baseline] = "peer" if baseline in PEER_NAMES else "baseline"
    return kinds


#: The scores of the side-by-side table, each a mean over a method's finished cells of a condition (``ece``
#: pooled over their pairs).
SIDE_BY_SIDE_SCORES = ("lc_ap", "ari", "lc_f1", "ece", "wall_s")


def side_by_side(experiment: Experiment, table: pd.DataFrame) -> pd.DataFrame:
    """One row per condition (world x aliasing x noise) and method: its kind (:func:`method_kinds`), its finished
    and failed cells, and :data:`SIDE_BY_SIDE_SCORES` over the finished ones (NaN where none finished).

    Conditions keep the table's order, methods the config's: each posterior variant, then the baselines and
    peers as the config lists them.
    """
    if not len(table):
        return pd.DataFrame()
    kinds = method_kinds(experiment)
    order = {name: index for index, name in enumerate(kinds)}
    summary = aggregate(table)
    means = summary.set_index(CONDITION + ["variant"]) if len(summary) else None
    conditions, rows, rank = {}, [], []
    for key, group in table.groupby(CONDITION + ["variant"], sort=False):
        finished = means.loc[key] if means is not None and key in means.index else None
        rows.append({**dict(zip(CONDITION + ["variant"], key)), "kind": kinds.get(key[-1], ""),
                     "cells": int((group["status"] == "ok").sum()), "failed": int((group["status"] != "ok").sum()),
                     **{score: math.nan if finished is None else finished[score] for score in SIDE_BY_SIDE_SCORES}})
        rank.append((conditions.setdefault(key[:-1], len(conditions)), order.get(key[-1], len(order))))
    frame = pd.DataFrame(rows)
    return frame.iloc[sorted(range(len(frame)), key=rank.__getitem__)].reset_index(drop=True)


def _finished(table: pd.DataFrame) -> pd.DataFrame:
    """The rows of finished cells, with their calibration columns (:func:`_with_calibration`); an empty frame when
    none finished (a table of failed cells alone has no score columns)."""
    ok = table[table["status"] == "ok"] if len(table) else table
    return _with_calibration(ok) if len(ok) else ok


def _with_calibration(ok: pd.DataFrame) -> pd.DataFrame:
    """``ok`` with ``log_score`` and ``confidently_wrong`` filled in, from ``gt_mass`` and ``top5``, where absent.

    Rows of tables written before these columns existed lack them; both follow
    from columns every row has (``top5`` lists the most probable topology first).
    """
    ok = ok.copy()
    derived_log = np.log(np.maximum(ok["gt_mass"].astype(float), scoring.LOG_SCORE_FLOOR))
    ok["log_score"] = ok["log_score"].astype(float).fillna(derived_log) if "log_score" in ok else derived_log
    derived_wrong = pd.Series([_confidently_wrong(top5, truth) for top5, truth in
                               zip(ok.get("top5", pd.Series(None, index=ok.index)),
                                   ok.get("true_labels", pd.Series(None, index=ok.index)))],
                              index=ok.index, dtype=object)
    if "confidently_wrong" in ok:
        recorded = ok["confidently_wrong"].astype(object)
        ok["confidently_wrong"] = recorded.where(recorded.notna(), derived_wrong)
    else:
        ok["confidently_wrong"] = derived_wrong
    return ok


def _confidently_wrong(top5, truth):
    if not isinstance(top5, str) or not isinstance(truth, str):
        return None
    topologies = json.loads(top5)
    if not topologies:
        return None
    labels, probability = topologies[0]
    return bool(probability >= scoring.CONFIDENT and tuple(labels) != tuple(json.loads(truth)))


def _pooled_calibration(group: pd.DataFrame) -> dict:
    """ECE and Brier pooled over the pairs of every row that has them; mean log score; confidently-wrong share."""
    has_pairs = group[group["reliability"].apply(lambda value: isinstance(value, str))] if "reliability" in group \
        else group.iloc[:0]
    n_pairs = float(has_pairs["n_pairs"].sum()) if len(has_pairs) else 0.0
    ece = brier = math.nan
    if n_pairs:
        ece = scoring.expected_calibration_error(scoring.pooled_reliability(has_pairs["reliability"]))
        weighted = has_pairs[has_pairs["n_pairs"] > 0]
        brier = float((weighted["brier"] * weighted["n_pairs"]).sum() / weighted["n_pairs"].sum())
    wrong = group["confidently_wrong"].dropna() if "confidently_wrong" in group else pd.Series(dtype=object)
    return {
        "n_pairs": int(n_pairs),
        "ece": ece,
        "brier": brier,
        "log_score": _mean(group, "log_score"),
        "confidently_wrong": float(wrong.astype(bool).mean()) if len(wrong) else math.nan,
    }


def _mean(group: pd.DataFrame, column: str) -> float:
    """The mean of ``column`` over the rows that have it; NaN when the column is absent or empty."""
    if column not in group:
        return math.nan
    values = pd.to_numeric(group[column], errors="coerce").dropna()
    return float(values.mean()) if len(values) else math.nan


def _chains_agree(group: pd.DataFrame) -> float:
    """Fraction of the sampled cells (those with a co-assignment difference between chains) that carry no
    disagreement ``warning`` (:func:`ptm_bench.evaluation.cell.disagreement`); NaN when none was sampled."""
    column = "diag_coassignment_max_difference"
    sampled = group[group[column].notna()] if column in group else group.iloc[:0]
    if not len(sampled):
        return math.nan
    warnings = sampled["warning"] if "warning" in sampled else pd.Series("", index=sampled.index)
    return float((warnings.astype("string").fillna("") == "").mean())


def _odometry_ess_note(summary: pd.DataFrame) -> list[str]:
    """A warning naming the conditions whose odometry estimates rest on fewer than ``LOW_ODOMETRY_ESS``
    effective importance samples; nothing when there are none."""
    low = summary[summary["odometry_ess"] < LOW_ODOMETRY_ESS]
    if not len(low):
        return []
    names = ", ".join(f"{row.world} a={row.aliasing:g} noise={row.noise:g} {row.variant}: {row.odometry_ess:.1f}"
                      for row in low.itertuples())
    return [f"**Odometry estimates unreliable** in {len(low)} of {summary['odometry_ess'].notna().sum()} "
            f"conditions with odometry: their importance weights have a mean effective sample size below "
            f"{LOW_ODOMETRY_ESS:g} ({names}), so log P(O | T) is dominated by single samples and its errors "
            "exceed the reported standard errors (docs/model.md §3.3, erratum E12).", ""]


def _noise_scale_note(summary: pd.DataFrame) -> list[str]:
    """A warning naming the conditions where the odometry noise scale's posterior lies in its prior's tail
    (``ptm.noise_scale_posterior``, docs/model.md §3.3): the covariances do not fit those runs, by far more than
    the prior allows; nothing when there are none."""
    if "noise_scale_in_prior_tail" not in summary:
        return []
    flagged = summary[summary["noise_scale_in_prior_tail"] > 0]
    if not len(flagged):
        return []
    names = ", ".join(f"{row.world} a={row.aliasing:g} noise={row.noise:g} {row.variant}: mean scale "
                      f"{row.noise_scale:.3g}, {row.noise_scale_in_prior_tail:.0%} of seeds"
                      for row in flagged.itertuples())
    return [f"**Odometry noise scale at the prior's edge** in {len(flagged)} of "
            f"{summary['noise_scale_in_prior_tail'].notna().sum()} conditions with odometry ({names}): the "
            "posterior asks for covariances the wide prior all but excludes, so the odometry model does not fit "
            "these runs (a calibration from elsewhere, or a penalty radius that forces merges).", ""]


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


def _condition_columns(frame: pd.DataFrame) -> list[str]:
    """The condition columns, with the measured aliasing beside the knob when any value of it is known."""
    if _has_measured_aliasing(frame):
        return ["world", "aliasing", MEASURED_ALIASING, "noise"]
    return list(CONDITION)


def _provenance(experiment: Experiment) -> str:
    """Which seeds were scored and what the calibration came from, for simulated and for recorded worlds."""
    recorded = [world for world in experiment.sweep.worlds if is_recorded(world)]
    simulated = len(experiment.sweep.worlds) - len(recorded)
    parts = []
    if simulated:
        parts.append(f"Scored seeds {list(experiment.sweep.seeds)}; held-out calibration seeds "
                     f"{list(experiment.sweep.calibration_seeds)}.")
    if recorded:
        calibrations = "; ".join(f"{world['name']} on {' + '.join(Path(path).stem for path in world['calibration'])}"
                                 for world in recorded)
        parts.append(f"Recorded runs, each calibrated on other runs ({calibrations}); on a recorded run the seeds "
                     f"{list(experiment.sweep.seeds)} are the inference's.")
    return " ".join(parts)


def write_summary(experiment: Experiment, table: pd.DataFrame, results_dir: Path, figures: bool = True) -> Path:
    """Write ``summary.md`` (and, with ``figures``, the PNG figures) into ``results_dir``.

    Only the rows of the current config's cells are summarised (:func:`current_rows`);
    the summary says how many rows of ``table`` it left out.
    """
    results_dir = Path(results_dir)
    results_dir.mkdir(parents=True, exist_ok=True)
    table, left_out = current_rows(experiment, table, results_dir)
    summary = aggregate(table)
    failed = table[table["status"] != "ok"] if len(table) else table
    lines = [f"# {experiment.name}", ""]
    if experiment.description:
        lines += [experiment.description, ""]
    lines += [
        f"{len(table)} cells: {len(table) - len(failed)} finished, {len(failed)} failed. "
        f"{_provenance(experiment)} Rows are means over seeds unless named otherwise; "
        "`gt_mass` is the posterior probability of the ground-truth topology, `gt_rank_median` its median rank "
        "(1 = most probable), `map_correct` the fraction of seeds whose MAP is the truth, `lc_*` loop-closure "
        "scores of the co-assignment matrix, `rhat_over_1.1` the fraction of seeds whose chains disagree "
        "(split R-hat of log P > 1.1: the masses of those runs are not converged), `chains_agree` the fraction of "
        "sampled seeds whose independent chains agree (split R-hat of log P and of the number of places <= 1.05, "
        "co-assignments within 0.05; `–` for exact posteriors and baselines), `odometry_ess` the mean effective "
        "sample size of the odometry term's importance weights over its evaluations (out of `n_importance`; near 1 "
        "its values are Monte-Carlo artefacts, docs/model.md §3.3)"
        + (f", `{MEASURED_ALIASING}` the measured aliasing of the datasets (AUC of signature distance separating "
           "same-place from different-place pairs: 1 = appearance tells places apart, 0.5 = it cannot)"
           if MEASURED_ALIASING in _condition_columns(summary) else "") + ".",
        "",
    ]
    lines += _left_out_note(left_out)
    if len(table) and len(failed) == len(table):
        lines += [f"**Every cell failed** ({len(failed)} of {len(table)}): there are no scores to summarise; the "
                  "errors are listed under Failed cells.", ""]
    if experiment.paper and len(summary):
        lines += ["## The paper's figures and ours", "", markdown_table(_paper_comparison(experiment, summary)), ""]
    if len(table):
        lines += _side_by_side_section(experiment, table)
    if len(summary):
        columns = _condition_columns(summary) + [
            "variant", "seeds", "detections", "gt_mass", "gt_mass_min", "gt_mass_max", "gt_rank_median", "map_correct",
            "ari", "lc_f1", "lc_ap", "expected_places", "map_places", "true_places", "rhat_over_1.1", "chains_agree",
            "odometry_ess", "wall_s"]
        lines += ["## Scores", "", markdown_table(summary[columns]), ""]
        lines += _odometry_ess_note(summary)
        lines += _noise_scale_note(summary)
        lines += _calibration_section(table, summary)
    lines += _held_out_floors_section(experiment, table)
    lines += _provenance_section(table)
    if len(failed):
        # a cell id joins its parts with '|', which would end a cell of the markdown table
        listed = failed[["cell_id", "error"]].apply(lambda column: column.map(
            lambda value: value.replace("|", r"\|") if isinstance(value, str) else value))
        lines += ["## Failed cells", "", markdown_table(listed), ""]
    if figures and len(summary):
        lines += ["## Figures", ""]
        drawn = _draw_figures(experiment, table, results_dir)
        for caption, path in drawn:
            lines += [f"![{caption}]({path.relative_to(results_dir).as_posix()})", f"*{caption}*", ""]
        _remove_undrawn_figures(results_dir, {path for _, path in drawn})
    path = results_dir / "summary.md"
    text = "\n".join(lines)
    atomic_write(path, lambda handle: handle.write(text.encode()))
    return path


#: The files :func:`_draw_figures` may write; those of a variant, world or axis no longer drawn are removed.
FIGURE_PATTERNS = ("trajectory.png", "top5_*.png", "traces_*.png", "gt_mass_heatmap.png", "reliability.png",
                   "scaling.png", "cost_accuracy.png")


def _remove_undrawn_figures(results_dir: Path, drawn: set) -> None:
    """Delete the summary's figures that this summary did not draw (e.g. of a variant since removed from the config)."""
    for pattern in FIGURE_PATTERNS:
        for path in results_dir.glob(pattern):
            if path not in drawn:
                path.unlink()


def _left_out_note(left_out: dict) -> list[str]:
    notes = []
    if left_out["stale"]:
        notes.append(f"{left_out['stale']} stale rows of the table were left out: their cells are not in the current "
                     "config (a world, level, seed or variant since removed).")
    if left_out["edited"]:
        notes.append(f"{left_out['edited']} rows of the table were left out: they were computed under an edited "
                     "config (their `definition` differs); rerun the sweep to recompute them.")
    if left_out["missing"]:
        notes.append(f"{left_out['missing']} cells of the config have no row yet.")
    return [" ".join(notes), ""] if notes else []


def _side_by_side_section(experiment: Experiment, table: pd.DataFrame) -> list[str]:
    return [
        "## Side by side",
        "",
        "Every method on the same runs, per condition: each posterior variant (`ari` of its MAP topology, `lc_f1` "
        "of the pairs with co-assignment > 0.5, `lc_ap` and `ece` of its co-assignment probabilities), the "
        "threshold baselines and the peers, the robust pose-graph back ends roboticists run instead (GNC, DCS, "
        "PCM, dead-reckoned distance: their accepted closures' partition for `ari` and `lc_f1`, a point mass for "
        "`ece`, and their pair scores for `lc_ap`). Baselines and peers choose their settings on the same "
        "held-out runs as the posterior's parameters. `cells` finished (their means are shown; `ece` pooled "
        "over their pairs), `failed` ended in an error (listed under Failed cells), `wall_s` is the mean wall "
        "time per cell, calibration included. The figure `cost_accuracy.png` draws ARI and AP against it.",
        "",
        markdown_table(side_by_side(experiment, table)[[*CONDITION, "variant", "kind", "cells", "failed",
                                                        *SIDE_BY_SIDE_SCORES]]),
        "",
    ]


def _cost_points(experiment: Experiment, table: pd.DataFrame) -> tuple[pd.DataFrame, str]:
    """The points of ``cost_accuracy.png`` and how they are taken: per method and condition where the conditions
    are few (at most ``len(plots.CONDITION_MARKERS)``), else per method over every finished cell."""
    kinds = method_kinds(experiment)
    side = side_by_side(experiment, table)
    side = side[side["cells"] > 0]
    conditions = side[CONDITION].drop_duplicates()
    if len(conditions) == 1:
        points, taken = side, "one point per method"
    elif len(conditions) <= len(plots.CONDITION_MARKERS):
        varying = [column for column in CONDITION if conditions[column].nunique() > 1]
        labels = [", ".join(f"{row[column]}" if column == "world" else f"{column} {row[column]:g}"
                            for column in varying) for _, row in side.iterrows()]
        points, taken = side.assign(condition=labels), "one point per method and condition"
    else:
        ok = table[table["status"] == "ok"]
        points = ok.groupby("variant", sort=False)[["ari", "lc_ap", "wall_s"]].mean().reset_index()
        order = {name: index for index, name in enumerate(kinds)}
        points = points.sort_values("variant", key=lambda names: names.map(lambda name: order.get(name, len(order))),
                                    kind="stable")
        taken = f"one point per method, the mean over its cells of {len(conditions)} conditions"
    named = [f"{name} ({kinds[name]})" if name in kinds else name for name in points["variant"]]
    return points.assign(variant=named), taken


def _calibration_section(table: pd.DataFrame, summary: pd.DataFrame) -> list[str]:
    by_variant = calibration_by_variant(table)
    floor = f"{scoring.LOG_SCORE_FLOOR:.0e}".replace("e-0", "e-")
    lines = [
        "## Calibration",
        "",
        "Pooled per variant over every finished cell (all conditions and seeds). `n_pairs` detection pairs i < j "
        "with co-assignment probability p (\"i and j are the same place\") and outcome y (1 if the truth puts them at "
        f"one place); `ece` = sum_b (n_b / n) |mean p_b - mean y_b| over {scoring.RELIABILITY_BINS} equal-width bins "
        "of p (0 = calibrated); `brier` = mean (p - y)^2 over the pairs; `log_score` = mean over cells of "
        f"log max(gt_mass, {floor}) (0 = all mass on the truth; {math.log(scoring.LOG_SCORE_FLOOR):.1f} "
        "= truth never visited); `confidently_wrong` = share of cells whose most probable topology has probability "
        f">= {scoring.CONFIDENT:g} and is not the truth. The threshold baselines are point masses: every p is 0 or 1. "
        "The reliability diagram under Figures draws mean p against the observed frequency of y per bin.",
        "",
        markdown_table(by_variant[["variant", "method", "cells", "gt_mass", "map_correct", "ari", "lc_ap", "n_pairs",
                                   "ece", "brier", "log_score", "confidently_wrong"]]),
        "",
    ]
    conditions = summary[CONDITION].drop_duplicates()
    if len(conditions) > 1:
        columns = _condition_columns(summary) + ["variant", "seeds", "n_pairs", "ece", "brier", "log_score",
                                                 "confidently_wrong"]
        lines += ["### Calibration per condition", "", markdown_table(summary[columns]), ""]
    return lines


def _held_out_floors_section(experiment: Experiment, table: pd.DataFrame) -> list[str]:
    """Per scored world, the floors or logs each calibrated parameter's held-out runs drove (read from the
    ``source_*`` columns by :func:`ptm_bench.evaluation.calibration.floors_in`); nothing when none names any."""
    ok = table[table["status"] == "ok"] if len(table) else table
    sources = [column for column in ok.columns if column.startswith(SOURCE_PREFIX)]
    calibrated_on = {}  # (world, floors) -> parameters
    for world, group in (ok.groupby("world", sort=False) if len(ok) else []):
        for column in sources:
            floors = dict.fromkeys(name for source in group[column].dropna() for name in floors_in(source))
            if floors:
                calibrated_on.setdefault((world, ", ".join(floors)), []).append(column[len(SOURCE_PREFIX):])
    if not calibrated_on:
        return []
    rows = pd.DataFrame([{"world": world, "parameters": ", ".join(parameters), "calibrated on": floors}
                         for (world, floors), parameters in calibrated_on.items()])
    protocol = {"other_floors": "floors other than the scored one", "same_floor": "the scored floor itself, the "
                "old protocol: these parameters saw its layout"}[experiment.sweep.calibration]
    return ["## Calibration floors and logs", "",
            f"The floors or logs of the held-out runs each parameter was calibrated on (`sweep.calibration = "
            f"\"{experiment.sweep.calibration}\"`: a simulated world on {protocol}; a recorded log on other logs).",
            "", markdown_table(rows), ""]


def _provenance_section(table: pd.DataFrame) -> list[str]:
    """Per variant, the distinct values of every ``source_*`` column; nothing when the table has none."""
    sources = [column for column in table.columns if column.startswith(SOURCE_PREFIX)] if len(table) else []
    ok = table[table["status"] == "ok"] if sources else table
    lines = []
    for variant, group in (ok.groupby("variant", sort=False) if sources and len(ok) else []):
        entries = []
        for column in sources:
            values = [str(value) for value in dict.fromkeys(group[column].dropna()) if str(value).strip()]
            if values:
                entries.append(f"  - `{column[len(SOURCE_PREFIX):]}`: " + "; ".join(values))
        estimate = _estimate_entry(group)
        entries += [estimate] if estimate else []
        if entries:
            lines += [f"- **{variant}**", *entries]
    if not lines:
        return []
    return ["## Where the parameters came from", "", *lines, ""]


def _estimate_entry(group: pd.DataFrame) -> str:
    """How a sampled variant's cells turned chains into probabilities (``diag_estimate``: the sampler's choice,
    :mod:`ptm.recorder`), with the lowest chain coverage where some renormalised; "" for exact rows."""
    if "diag_estimate" not in group:
        return ""
    used = group["diag_estimate"].dropna()
    if used.empty:
        return ""
    names = {"renormalised": "posterior values renormalised over the visited topologies",
             "frequency": "visit frequencies"}
    parts = [f"{names.get(name, name)} in {count} of {len(used)} cells" for name, count in used.value_counts().items()]
    coverage = group.loc[used.index, "diag_chain_coverage_min"] if "diag_chain_coverage_min" in group else None
    detail = ""
    if coverage is not None and coverage.notna().any():
        low, high = f"{coverage.min():.3g}", f"{coverage.max():.3g}"
        detail = (f" (the worst chain's share of the visited topologies' renormalised mass: "
                  f"{low if low == high else f'{low} to {high}'}; the sampler renormalises from "
                  f"{RENORMALISE_COVERAGE:g}, stray chains below {STRAY_CHAIN_MASS:g} set aside)")
    return "  - `estimate`: " + "; ".join(parts) + detail


def _paper_comparison(experiment: Experiment, summary: pd.DataFrame) -> pd.DataFrame:
    rows = []
    for variant, reported in experiment.paper.items():
        ours = summary[summary["variant"] == variant]
        for _, row in ours.iterrows():
            rows.append({
                **{column: row[column] for column in _condition_columns(summary)},
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
    world_spec = experiment.sweep.worlds[experiment.sweep.world_names().index(first["world"])]
    dataset = dataset_for(world_spec, float(first["aliasing"]), float(first["noise"]), int(first["seed"]),
                          experiment.sweep.generator_options, results_dir / "datasets",
                          experiment.settings.appearance.components)
    where = f"{first['world']}, aliasing {first['aliasing']:g}, noise {first['noise']:g}, seed {first['seed']}"
    figures = []
    truth = tuple(json.loads(first["true_labels"]))
    dead_reckoned = dead_reckoning(dataset.odometry) if dataset.odometry is not None else np.zeros((dataset.n, 3))
    trajectory_map = None  # (models, name, poses): the MAP map of the variant with the most models and odometry
    for _, row in condition.iterrows():
        slug = re.sub(r"[^A-Za-z0-9]+", "_", row["variant"]).strip("_")
        topologies = [(tuple(labels), probability) for labels, probability in json.loads(row["top5"])]
        modes = _modes(experiment, row, dataset, [labels for labels, _ in topologies])
        if modes is None:  # drawn where odometry puts the detections, as the paper draws them
            maps, drawn_on = [dead_reckoned] * len(topologies), "at dead-reckoned positions (no odometry model)"
        else:
            maps = [dead_reckoned if mode is None else mode for mode in modes]
            failed = [str(rank) for rank, mode in enumerate(modes, start=1) if mode is None]
            drawn_on = "each on its optimised map" + (
                f" (no converged mode for rank {', '.join(failed)}: at dead-reckoned positions)" if failed else "")
            models = len(row["models"].split("+"))
            if modes and modes[0] is not None and (trajectory_map is None or models > trajectory_map[0]):
                trajectory_map = (models, f"MAP topology's optimised map ({row['variant']})", modes[0])
        caption = f"Top topologies, {row['variant']} ({where}), {drawn_on}"
        figures.append((caption, plots.top_topologies(maps, topologies, truth, results_dir / f"top5_{slug}.png",
                                                      title=caption)))
        traces = {name[len("trace_"):]: json.loads(row[name]) for name in row.index
                  if name.startswith("trace_") and isinstance(row[name], str)}
        if traces:
            caption = f"Sampler traces, {row['variant']} ({where})"
            figures.append((caption, plots.sampler_traces(traces, results_dir / f"traces_{slug}.png", title=caption)))
    optimised = trajectory_map[1:] if trajectory_map is not None else None
    figures.insert(0, (f"Detections: reference, dead reckoning{' and the MAP map' if optimised else ''}: {where}",
                       plots.trajectories(dataset, results_dir / "trajectory.png", title=where, optimised=optimised)))
    if ok["aliasing"].nunique() > 1 or ok["noise"].nunique() > 1:
        caption = "Ground-truth mass over aliasing x noise" + (
            " (aliasing labelled with the measured AUC of signature distance)" if _has_measured_aliasing(ok) else "")
        figures.append((caption, plots.mass_heatmap(ok, results_dir / "gt_mass_heatmap.png")))
    if ok["world"].nunique() > 1:
        caption = "Accuracy, agreement between independent chains and wall time against the number of detections"
        figures.append((caption, plots.scaling(ok, results_dir / "scaling.png")))
    points, taken = _cost_points(experiment, table)
    caption = (f"Mean ARI and loop-closure AP against mean wall time per cell (log scale) of every posterior variant, "
               f"baseline and peer: {taken}")
    figures.append((caption, plots.cost_accuracy(points, results_dir / "cost_accuracy.png",
                                                     title=f"{experiment.name}: accuracy against cost")))
    reliability = {variant: scoring.pooled_reliability(group["reliability"])
                   for variant, group in ok.groupby("variant", sort=False)
                   if "reliability" in group and group["reliability"].apply(lambda value: isinstance(value, str)).any()}
    if reliability:
        caption = "Reliability of the pairwise co-assignment probabilities, pooled per variant over all cells"
        figures.append((caption, plots.reliability_diagram(reliability, results_dir / "reliability.png")))
    return figures


def _modes(experiment: Experiment, row, dataset, topologies) -> list | None:
    """The optimised map of each topology: the (N, 3) Laplace mode P* of its pose graph under the odometry model
    the row used (:meth:`ptm.odometry.OdometryTerm.mode_poses`; None for a fit that did not converge), or None
    for a variant without an odometry model (a baseline, appearance alone) or a dataset without odometry.

    The model is the variant's, from the builder that made the row's posterior
    (:func:`ptm_bench.evaluation.models.build_models`), without held-out runs: the mode does not depend on the
    prior or the landmark-density penalty (docs/model.md §3.3).
    """
    variant = next((variant for variant in experiment.variants if variant.name == row["variant"]), None)
    if variant is None or "odometry" not in variant.models or dataset.odometry is None:
        return None
    built = build_models(replace(variant, models=("odometry",)), dataset, held_out=None)
    term = built.models[0].bind(dataset)
    modes = []
    for labels in topologies:
        try:
            modes.append(term.mode_poses(labels))
        except ValueError:  # the fit did not converge: no mode to draw
            modes.append(None)
    return modes


def _has_measured_aliasing(ok: pd.DataFrame) -> bool:
    return MEASURED_ALIASING in ok and pd.to_numeric(ok[MEASURED_ALIASING], errors="coerce").notna().any()
