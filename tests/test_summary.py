"""The summary of a sweep: only the current config's cells, pooled calibration, measured aliasing, provenance.

Tables here are built from hand-made distributions scored by :func:`ptm_bench.evaluation.scoring.score`
and the dataset of the per-seed figures is a tiny synthetic one, so no simulation runs.
"""

import json
import math

import numpy as np
import pandas as pd
import pytest

from ptm import Dataset
from ptm.partitions import canonical
from ptm_bench.reporting import plots
from ptm_bench.evaluation import scoring
from ptm_bench.reporting import summary
from ptm_bench.evaluation.experiment import expand_cells, parse_experiment

CONFIG = {
    "name": "tiny",
    "baselines": ["greedy_odometry"],
    "sweep": {"worlds": ["short_loop"], "aliasing": [0.0, 1.0], "seeds": [0, 1], "calibration_seeds": [10]},
    "variants": [{"name": "appearance", "models": ["appearance"]}],
}
TRUTH = (0, 1, 2, 0, 1)


def _outcome(cell, rng):
    """A scored row for a cell: the posterior puts 0.6 to 0.95 on the truth, the baseline is a point mass."""
    if cell["method"] == "baseline":
        distribution = scoring.point_mass(TRUTH if cell["seed"] == 0 else (0, 1, 2, 3, 1))
    else:
        mass = float(rng.uniform(0.6, 0.95))
        distribution = {TRUTH: mass, (0, 1, 2, 0, 3): 1.0 - mass}
    row = scoring.score(distribution, TRUTH)
    row.update(top5=json.dumps([[list(labels), p] for labels, p in sorted(distribution.items(), key=lambda x: -x[1])]),
               true_labels=json.dumps(list(TRUTH)), wall_s=1.0, status="ok", error="",
               aliasing_auc=0.9 - 0.3 * cell["aliasing"] + 0.01 * cell["seed"],
               source_prior_rate="calibrated: 0.6 places per detection on 1 held-out run")
    if cell["method"] == "baseline":
        row["source_threshold"] = "fitted on the held-out runs"
    return row


def _table(experiment, results_dir):
    rng = np.random.default_rng(3)
    cells = expand_cells(experiment, results_dir)
    plain = (str, int, float, bool)
    return pd.DataFrame([{**{key: value for key, value in cell.items() if isinstance(value, plain)},
                          **_outcome(cell, rng)} for cell in cells])


def _fake_dataset(*args, **kwargs):
    return Dataset(odometry=np.tile([1.0, 0.0, 1.2], (4, 1)), labels=np.array(TRUTH),
                   true_poses=np.c_[np.arange(5.0), np.zeros(5), np.zeros(5)])


@pytest.fixture
def experiment():
    return parse_experiment(json.loads(json.dumps(CONFIG)), source="test")


def test_the_summary_keeps_only_current_cells_and_reports_the_stale_ones(tmp_path, experiment, monkeypatch):
    monkeypatch.setattr(summary, "dataset_for", _fake_dataset)
    table = _table(experiment, tmp_path)
    assert len(table) == 8
    # A row of a seed no longer in the config; if it were kept, its failure would be listed and counted.
    stale = {**table.iloc[0].to_dict(), "cell_id": "short_loop|a=0|noise=1|seed=7|appearance", "seed": 7,
             "status": "error", "error": "StaleError: from an old config"}
    # A row of a current cell computed under an edited config: the same cell_id, another definition.
    edited = {**table.iloc[1].to_dict(), "definition": "0123456789abcdef", "status": "error",
              "error": "EditedError: from an edited config"}
    table = pd.concat([table.drop(index=1), pd.DataFrame([stale, edited])], ignore_index=True)
    text = summary.write_summary(experiment, table, tmp_path).read_text()
    assert "7 cells: 7 finished, 0 failed" in text
    assert "1 stale rows of the table were left out" in text
    assert "1 rows of the table were left out: they were computed under an edited config" in text
    assert "1 cells of the config have no row yet" in text
    assert "StaleError" not in text and "EditedError" not in text and "## Failed cells" not in text
    kept, counts = summary.current_rows(experiment, table, tmp_path)
    assert counts == {"stale": 1, "edited": 1, "missing": 1} and len(kept) == 7


def test_the_summary_shows_pooled_calibration_measured_aliasing_provenance_and_the_reliability_figure(
        tmp_path, experiment, monkeypatch):
    monkeypatch.setattr(summary, "dataset_for", _fake_dataset)
    table = _table(experiment, tmp_path)
    text = summary.write_summary(experiment, table, tmp_path).read_text()
    assert "left out" not in text and "no row yet" not in text
    assert "## Calibration" in text
    header = next(line for line in text.splitlines() if line.startswith("| variant | method | cells"))
    for column in ("gt_mass", "n_pairs", "ece", "brier", "log_score", "confidently_wrong"):
        assert f"| {column} |" in header
    assert "![Reliability of the pairwise" in text and "(reliability.png)" in text
    assert (tmp_path / "reliability.png").stat().st_size > 0
    assert (tmp_path / "gt_mass_heatmap.png").is_file()
    # The measured aliasing sits beside the knob: seeds 0 and 1 measure 0.90 and 0.91 at aliasing 0.
    scores = text.split("## Scores")[1]
    assert "| world | aliasing | aliasing_auc | noise |" in scores
    assert "| short_loop | 0 | 0.905 | 1 |" in scores
    assert "## Where the parameters came from" in text
    assert "  - `prior_rate`: calibrated: 0.6 places per detection on 1 held-out run" in text
    assert "  - `threshold`: fitted on the held-out runs" in text
    # The baseline is right on seed 0 and confidently wrong on seed 1, at both aliasing levels.
    pooled = summary.calibration_by_variant(table).set_index("variant")
    assert pooled.loc["greedy_odometry", "confidently_wrong"] == 0.5
    assert pooled.loc["appearance", "confidently_wrong"] == 0.0
    assert pooled.loc["greedy_odometry", "log_score"] == pytest.approx(0.5 * math.log(1e-6))


def test_per_variant_calibration_pools_the_pairs_of_all_cells(tmp_path, experiment):
    table = _table(experiment, tmp_path)
    pooled = summary.calibration_by_variant(table).set_index("variant").loc["appearance"]
    rows = table[table["variant"] == "appearance"]
    # Every appearance cell: truth mass m on TRUTH and 1 - m on (0,1,2,0,3), whose only difference is
    # detection 4. Pairs (1,4) have p = m, y = 1; pairs (0,3) have p = 1, y = 1; the 8 others p = 0 or 1 - m, y = 0.
    probabilities, outcomes = [], []
    for mass in rows["gt_mass"]:
        matrix = scoring.coassignment_matrix({TRUTH: mass, (0, 1, 2, 0, 3): 1.0 - mass})
        upper = np.triu_indices(5, k=1)
        probabilities.append(matrix[upper])
        outcomes.append((np.array(TRUTH)[:, None] == np.array(TRUTH)[None, :])[upper])
    p, y = np.concatenate(probabilities), np.concatenate(outcomes).astype(float)
    assert pooled["n_pairs"] == len(p) == 40
    assert pooled["brier"] == pytest.approx(np.mean((p - y) ** 2))
    assert pooled["ece"] == pytest.approx(scoring.expected_calibration_error(scoring.reliability_table(p, y)))
    assert pooled["log_score"] == pytest.approx(np.log(rows["gt_mass"]).mean())


def test_per_variant_ece_and_brier_weight_cells_by_their_pairs():
    rng = np.random.default_rng(5)
    rows, probabilities, outcomes = [], [], []
    for n in (2, 3, 9, 12):  # 1, 3, 36 and 66 pairs: an unweighted mean over cells would differ
        truth, other = canonical(rng.integers(0, 3, n)), canonical(rng.integers(0, n, n))
        mass = float(rng.uniform(0.2, 0.8))
        distribution = {truth: mass, other: 1.0 - mass} if other != truth else {truth: 1.0}
        rows.append({"variant": "v", "method": "mcmc", "status": "ok", **scoring.score(distribution, truth)})
        upper = np.triu_indices(n, k=1)
        probabilities.append(scoring.coassignment_matrix(distribution)[upper])
        outcomes.append((np.array(truth)[:, None] == np.array(truth)[None, :])[upper])
    p, y = np.concatenate(probabilities), np.concatenate(outcomes).astype(float)
    pooled = summary.calibration_by_variant(pd.DataFrame(rows)).iloc[0]
    assert pooled["n_pairs"] == len(p) == 106
    assert pooled["brier"] == pytest.approx(np.mean((p - y) ** 2), abs=1e-12)
    concatenated = scoring.expected_calibration_error(scoring.reliability_table(p, y))
    assert pooled["ece"] == pytest.approx(concatenated, abs=1e-12)
    assert abs(pooled["brier"] - np.mean([row["brier"] for row in rows])) > 1e-3


def test_old_tables_without_the_new_columns_are_summarised(tmp_path, experiment, monkeypatch):
    monkeypatch.setattr(summary, "dataset_for", _fake_dataset)
    table = _table(experiment, tmp_path)
    old = table.drop(columns=["n_pairs", "brier", "ece", "reliability", "log_score", "map_mass", "confidently_wrong",
                              "aliasing_auc", "source_prior_rate", "source_threshold", "definition"])
    text = summary.write_summary(experiment, old, tmp_path).read_text()
    assert "aliasing_auc" not in text and "Where the parameters came from" not in text
    assert "(reliability.png)" not in text
    # The log score and the confidently-wrong share follow from gt_mass and top5; ECE and Brier are unknown.
    pooled = summary.calibration_by_variant(old).set_index("variant")
    assert pooled.loc["greedy_odometry", "confidently_wrong"] == 0.5
    assert pooled.loc["greedy_odometry", "log_score"] == pytest.approx(0.5 * math.log(1e-6))
    assert math.isnan(pooled.loc["greedy_odometry", "ece"]) and pooled.loc["greedy_odometry", "n_pairs"] == 0


def test_heat_map_labels_aliasing_with_the_measured_auc_where_known():
    table = pd.DataFrame({"world": "w", "aliasing": [0.0, 0.0, 0.0, 0.5, 1.0], "noise": 1.0, "seed": [0, 0, 1, 0, 0],
                          "variant": ["a", "b", "a", "a", "a"], "aliasing_auc": [0.8, 0.8, 0.9, 0.6, np.nan],
                          "status": "ok"})
    # Level 0: datasets of seeds 0 and 1 (seed 0 counted once, though two variants ran on it).
    assert plots._aliasing_labels(table, [0.0, 0.5, 1.0]) == ["0 (AUC 0.85)", "0.5 (AUC 0.60)", "1"]
    assert plots._aliasing_labels(table.drop(columns="aliasing_auc"), [0.0, 0.5]) == ["0", "0.5"]


def test_reliability_diagram_refuses_a_malformed_table(tmp_path):
    with pytest.raises(ValueError, match="must have shape \\(bins, 3\\)"):
        plots.reliability_diagram({"v": np.ones((10, 2))}, tmp_path / "r.png")


def test_chains_agree_counts_sampled_cells_without_a_disagreement_warning():
    group = pd.DataFrame({"diag_coassignment_max_difference": [0.01, 0.3, 0.02, np.nan],
                          "warning": [np.nan, "independent chains disagree: ...", "", np.nan]})
    assert summary._chains_agree(group) == pytest.approx(2 / 3)  # the exact (NaN) cell is not counted
    assert math.isnan(summary._chains_agree(group.iloc[3:]))
    assert math.isnan(summary._chains_agree(pd.DataFrame({"gt_mass": [0.5]})))  # a table from before the column


def test_a_sweep_over_several_worlds_draws_accuracy_agreement_and_time_against_n(tmp_path, monkeypatch):
    monkeypatch.setattr(summary, "dataset_for", _fake_dataset)
    experiment = parse_experiment({**json.loads(json.dumps(CONFIG)), "sweep": {**CONFIG["sweep"], "aliasing": [0.0],
                                   "worlds": ["short_loop", "office"]}}, source="test")
    table = _table(experiment, tmp_path)
    table["n_measurements"] = np.where(table["world"] == "office", 9, 5)
    table["diag_coassignment_max_difference"] = np.where(table["method"] == "baseline", np.nan, 0.02)
    text = summary.write_summary(experiment, table, tmp_path).read_text()
    assert "(scaling.png)" in text and (tmp_path / "scaling.png").stat().st_size > 0
    scores = summary.aggregate(table).set_index(["world", "variant"])
    assert scores.loc[("office", "appearance"), "detections"] == 9
    assert scores.loc[("office", "appearance"), "chains_agree"] == 1.0
    assert math.isnan(scores.loc[("office", "greedy_odometry"), "chains_agree"])


def test_one_world_draws_no_scaling_figure_and_an_empty_table_is_refused(tmp_path, experiment, monkeypatch):
    monkeypatch.setattr(summary, "dataset_for", _fake_dataset)
    summary.write_summary(experiment, _table(experiment, tmp_path), tmp_path)
    assert not (tmp_path / "scaling.png").exists()
    with pytest.raises(ValueError, match="no finished cells"):
        plots.scaling(pd.DataFrame({"status": ["error"], "variant": ["v"]}), tmp_path / "s.png")


def test_figures_of_variants_no_longer_drawn_are_removed_and_others_kept(tmp_path, experiment, monkeypatch):
    monkeypatch.setattr(summary, "dataset_for", _fake_dataset)
    removed, unrelated = tmp_path / "top5_a_removed_variant.png", tmp_path / "notes.png"
    removed.write_bytes(b"old"), unrelated.write_bytes(b"mine")
    summary.write_summary(experiment, _table(experiment, tmp_path), tmp_path)
    assert not removed.exists() and unrelated.read_bytes() == b"mine"
    assert (tmp_path / "top5_appearance.png").is_file() and (tmp_path / "trajectory.png").is_file()


def test_the_odometry_ess_is_summarised_and_a_degenerate_one_is_flagged(tmp_path, experiment, monkeypatch):
    monkeypatch.setattr(summary, "dataset_for", _fake_dataset)
    table = _table(experiment, tmp_path)
    sampled = table["variant"] == "appearance"  # stands in for a variant with odometry: only the column matters
    table["diag_odometry_ess_mean"] = np.where(sampled, 40.0, np.nan)
    healthy = summary.write_summary(experiment, table, tmp_path, figures=False).read_text()
    scores = summary.aggregate(table).set_index("variant")
    assert (scores.loc["appearance", "odometry_ess"] == 40.0).all()
    assert scores.loc["greedy_odometry", "odometry_ess"].isna().all()
    assert "Odometry estimates unreliable" not in healthy
    table.loc[sampled & (table["aliasing"] == 1.0), "diag_odometry_ess_mean"] = 1.2
    degenerate = summary.write_summary(experiment, table, tmp_path, figures=False).read_text()
    assert "Odometry estimates unreliable** in 1 of 2 conditions" in degenerate
    assert "short_loop a=1 noise=1 appearance: 1.2" in degenerate


def test_a_noise_scale_in_its_priors_tail_is_flagged_by_condition(tmp_path, experiment):
    table = _table(experiment, tmp_path)
    sampled = table["variant"] == "appearance"  # stands in for a variant with odometry: only the columns matter
    table["noise_scale_posterior_mean"] = np.where(sampled, 1.3, np.nan)
    table["noise_scale_in_prior_tail"] = np.where(sampled, 0.0, np.nan)
    healthy = summary.write_summary(experiment, table, tmp_path, figures=False).read_text()
    assert "noise scale at the prior's edge" not in healthy
    table.loc[sampled & (table["aliasing"] == 1.0), ["noise_scale_posterior_mean", "noise_scale_in_prior_tail"]] = (
        57.0, 1.0)
    flagged = summary.write_summary(experiment, table, tmp_path, figures=False).read_text()
    assert "**Odometry noise scale at the prior's edge** in 1 of 2 conditions" in flagged
    assert "short_loop a=1 noise=1 appearance: mean scale 57, 100% of seeds" in flagged


def test_the_provenance_says_how_sampled_probabilities_were_estimated(tmp_path, experiment):
    table = _table(experiment, tmp_path)
    assert "`estimate`" not in "\n".join(summary._provenance_section(table))  # rows without the diagnostic
    appearance = table["variant"] == "appearance"
    table.loc[appearance, "diag_estimate"] = ["renormalised", "frequency", "renormalised", "renormalised"][
        :appearance.sum()]
    table.loc[appearance, "diag_chain_coverage_min"] = [0.995, 0.6, 0.999, 0.992][:appearance.sum()]
    lines = summary._provenance_section(table)
    entry = next(line for line in lines if "`estimate`" in line)
    assert entry.startswith("  - `estimate`: posterior values renormalised over the visited topologies in ")
    assert "visit frequencies in 1 of" in entry and "0.6 to 0.999" in entry
    variant_line = max(index for index, line in enumerate(lines[:lines.index(entry)]) if line.startswith("- **"))
    assert lines[variant_line] == "- **appearance**"
