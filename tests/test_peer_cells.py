"""The peers as baselines of a sweep: their cells, their failures, the config check and the side-by-side summary.

A peer cell scores the same simulated run as the posterior's cells (the short loop, nine detections), calibrated
on the same held-out runs, with the posterior's noise; the scored run reaches the peer without its labels. A
solver that fails and a missing GTSAM are failed cells with one-line messages, and the sweep goes on. The sweeps
run the baseline cells only (no sampling), so each takes a few seconds.
"""

from __future__ import annotations

import json
import math
import sys

import numpy as np
import pandas as pd
import pytest

import ptm
from ptm_bench.evaluation import baselines, calibration, cell, scoring, sweep
from ptm_bench.evaluation.experiment import (
    BASELINE_NAMES,
    PEER_NAMES,
    THRESHOLD_BASELINES,
    expand_cells,
    load_experiment,
    parse_experiment,
)
from ptm_bench.evaluation.peers import PEERS, PeerNoise
from ptm_bench.reporting import summary

CALIBRATION_SEEDS = [10, 11]


def tiny_experiment(peers, seeds=(0,), aliasing=(0.0,), **odometry):
    return parse_experiment({
        "name": "tiny_peers",
        "baselines": list(peers),
        # calibrated on the short loop itself: these tests are of the peers' cells, not of calibration that transfers
        # (a distance_rank calibrated on the presets' 12-24 m spacings closes no loop of the 2 m short loop)
        "sweep": {"worlds": ["short_loop"], "aliasing": list(aliasing), "seeds": list(seeds),
                  "calibration_seeds": CALIBRATION_SEEDS, "calibration": "same_floor"},
        "odometry": odometry,
        "variants": [{"name": "appearance", "models": ["appearance"], "inference": {"method": "exact"}}],
    }, source="test")


def baseline_cells(experiment, results_dir):
    return [entry for entry in expand_cells(experiment, results_dir) if entry["method"] == "baseline"]


@pytest.fixture(scope="module")
def results_dir(tmp_path_factory):
    """One results folder per test module (and xdist worker), so that the simulated runs are cached once."""
    return tmp_path_factory.mktemp("peer_cells")


# -- cell functions for the sweep's processes (module level, so that the fork server can import them) ---------------

def singular_solver_cell(entry: dict) -> dict:
    """``run_cell`` with GTSAM's GNC optimiser failing on every graph, as on an indeterminant linear system."""
    import gtsam

    def singular(*args, **kwargs):
        raise RuntimeError("Indeterminant linear system detected while working near variable 3")

    gtsam.GncLMOptimizer = singular
    return cell.run_cell(entry)


def no_gtsam_cell(entry: dict) -> dict:
    """``run_cell`` in a process where ``import gtsam`` fails."""
    sys.modules["gtsam"] = None
    return cell.run_cell(entry)


# -- the names and the config check ---------------------------------------------------------------------------------

def test_the_baseline_names_are_the_threshold_baselines_and_the_peers():
    assert THRESHOLD_BASELINES == tuple(baselines.BASELINE_FEATURES)
    assert PEER_NAMES == tuple(PEERS)
    assert BASELINE_NAMES == THRESHOLD_BASELINES + PEER_NAMES


def test_a_peer_for_a_recorded_run_without_odometry_is_refused_at_load(tmp_path):
    for name in ("look", "other"):
        ptm.Dataset(signatures=np.arange(8.0).reshape(4, 2), labels=[0, 1, 0, 1]).save(tmp_path / f"{name}.npz")
    config = tmp_path / "recorded.toml"
    text = ('baselines = [{baselines}]\n[sweep]\nworlds = [{{ dataset = "{path}", name = "look" }}, '
            '{{ dataset = "{other}", name = "other" }}]\nseeds = [0]\n[[variants]]\nname = "a"\n'
            'models = ["appearance"]\n')
    paths = {"path": tmp_path / "look.npz", "other": tmp_path / "other.npz"}
    config.write_text(text.format(baselines='"appearance_threshold", "pcm"', **paths))
    with pytest.raises(ValueError, match=r"baselines: the peers pcm need odometry, and the recorded run .*look\.npz "
                                         r"of sweep\.worlds\[0\] \('look'\) has none"):
        load_experiment(config)
    config.write_text(text.format(baselines='"appearance_threshold"', **paths))
    assert load_experiment(config).baselines == ("appearance_threshold",)


# -- a peer cell ------------------------------------------------------------------------------------------------------

def test_a_sweep_with_peers_writes_their_scores_settings_and_provenance(results_dir):
    experiment = tiny_experiment(["pcm", "distance_rank", "gnc"])
    cells = baseline_cells(experiment, results_dir)
    table = sweep.run_sweep(cells, cell.run_cell, results_dir / "scores" / "cells.csv", workers=2, progress=False)
    assert (table["status"] == "ok").all(), table["error"].tolist()
    rows = table.set_index("variant")
    for name in ("pcm", "distance_rank", "gnc"):
        row = rows.loc[name]
        for column in ("ari", "lc_f1", "lc_ap", "ece", "brier", "wall_s", "inference_wall_s", "peer_run_wall_s",
                       "calibration_wall_s"):
            assert math.isfinite(row[column]), (name, column)
        assert row["ari"] > 0.5 and row["lc_ap"] > 0.5, name  # the short loop is easy for every peer
        settings = json.loads(row["peer_settings"])
        assert set(settings) == {field for field in PEERS[name].settings.__dataclass_fields__}
        assert row["source_peer_settings"].endswith(f"on {len(CALIBRATION_SEEDS)} held-out runs [short_loop]")
        assert "calibrated: best mean ARI" in row["source_peer_settings"]
        assert row["source_sigma_topology"].startswith("sensor spec: detection radius")
        assert row["source_odometry_noise"] == "this run's odometry_cov"  # the simulator writes covariances
        assert row["peer_run_wall_s"] < row["inference_wall_s"] <= row["wall_s"]
        assert json.loads(row["top5"])[0][1] == 1.0 and row["n_topologies"] == 1
    assert rows.loc["pcm", "n_candidates"] > 0 and rows.loc["distance_rank", "n_candidates"] == 9 * 8 // 2


def test_a_peer_cell_calibrates_on_held_out_runs_with_the_posteriors_noise_never_the_scored_labels(
        results_dir, monkeypatch):
    experiment = tiny_experiment(["pcm"], sigma_xy=0.2, sigma_theta=0.07, sigma_topology=0.3)
    entry = baseline_cells(experiment, results_dir)[0]
    held_out_seen, calls = [], []
    real_held_out, real_run_calibrated = calibration.calibration_datasets, cell.run_calibrated

    def held_out(entry_):
        runs = real_held_out(entry_)
        held_out_seen.extend(runs)
        return runs

    def spy(peer, dataset, runs, noise):
        assert dataset.labels is None and dataset.true_poses is None  # nothing of the truth reaches the peer
        assert runs is not None and all(run.labels is not None for run in runs)
        calls.append((peer.name, noise, [run for run in runs]))
        return real_run_calibrated(peer, dataset, runs, noise)

    monkeypatch.setattr(cell, "calibration_datasets", held_out)
    monkeypatch.setattr(cell, "run_calibrated", spy)
    row = cell.run_cell(entry)
    (name, noise, runs), = calls
    assert name == "pcm" and runs == held_out_seen and len(runs) == len(CALIBRATION_SEEDS)
    assert noise == PeerNoise(0.2, 0.07, 0.3)  # the configured sigmas, as the posterior's builder takes them
    assert row["sigma_topology"] == 0.3 and row["source_sigma_topology"] == "config"

    # The same cell with the scored run's labels scrambled: the same partition and settings, other scores.
    scored = cell.dataset_for(entry["inputs"]["world_spec"], entry["aliasing"], entry["noise"], entry["seed"],
                              entry["inputs"]["generator_options"], entry["inputs"]["cache_dir"], None)
    scrambled = scored.replace(labels=np.arange(scored.n))
    monkeypatch.setattr(cell, "dataset_for", lambda *args: scrambled)
    again = cell.run_cell(entry)
    assert again["top5"] == row["top5"] and again["peer_settings"] == row["peer_settings"]
    assert again["source_peer_settings"] == row["source_peer_settings"]


def test_the_tie_sigma_of_a_peer_is_the_posteriors_rule():
    meta = {"detection_radius": 1.5}
    assert PeerNoise.from_meta(meta, 0.1, 0.05).sigma_tie == calibration.topology_sigma(None, meta)[0]
    assert PeerNoise.from_meta({}, 0.1, 0.05, sigma_tie=0.4).sigma_tie == 0.4
    with pytest.raises(ValueError, match="detection_radius"):
        PeerNoise.from_meta({}, 0.1, 0.05)


# -- failures --------------------------------------------------------------------------------------------------------

def test_a_solver_failure_is_a_failed_cell_with_its_message_and_the_sweep_goes_on(results_dir):
    pytest.importorskip("gtsam")
    experiment = tiny_experiment(["gnc", "pcm"], seeds=(0, 1))
    cells = baseline_cells(experiment, results_dir)
    table = sweep.run_sweep(cells, singular_solver_cell, results_dir / "solver" / "cells.csv", workers=2,
                            progress=False)
    assert len(table) == 4
    gnc = table[table["variant"] == "gnc"]
    assert (gnc["status"] == "error").all()
    assert gnc["error"].str.startswith("PeerFailed: gnc: GTSAM failed: Indeterminant linear system").all()
    assert (table.loc[table["variant"] == "pcm", "status"] == "ok").all()


def test_missing_gtsam_is_a_failed_cell_of_one_line_naming_the_extra(results_dir):
    experiment = tiny_experiment(["dcs", "distance_rank"])
    cells = baseline_cells(experiment, results_dir)
    table = sweep.run_sweep(cells, no_gtsam_cell, results_dir / "no_gtsam" / "cells.csv", workers=2, progress=False)
    rows = table.set_index("variant")
    assert rows.loc["dcs", "status"] == "error"
    message = rows.loc["dcs", "error"]
    assert 'pip install "ptm[peers]"' in message and "\n" not in message
    assert rows.loc["distance_rank", "status"] == "ok"  # a peer without GTSAM runs on


# -- the summary -----------------------------------------------------------------------------------------------------

TRUTH = (0, 1, 2, 0, 1)


def _row(entry, wall_s):
    """A scored row: the posterior spreads its mass, a baseline or peer commits to one partition."""
    if entry["method"] == "baseline":
        distribution = scoring.point_mass(TRUTH if entry["variant"] != "greedy_odometry" else (0, 1, 2, 3, 1))
    else:
        distribution = {TRUTH: 0.8, (0, 1, 2, 0, 3): 0.2}
    row = scoring.score(distribution, TRUTH)
    row.update(top5=json.dumps([[list(labels), p] for labels, p in distribution.items()]),
               true_labels=json.dumps(list(TRUTH)), wall_s=wall_s, status="ok", error="")
    return row


def test_the_summary_sets_every_method_side_by_side_and_draws_accuracy_against_cost(tmp_path, monkeypatch):
    monkeypatch.setattr(summary, "dataset_for", lambda *args, **kwargs: ptm.Dataset(
        odometry=np.tile([1.0, 0.0, 1.2], (4, 1)), labels=np.array(TRUTH)))
    experiment = tiny_experiment(["greedy_odometry", "pcm", "gnc"], seeds=(0, 1), aliasing=(0.0, 1.0))
    cells = expand_cells(experiment, tmp_path)
    wall = {"appearance": 60.0, "greedy_odometry": 0.5, "pcm": 1.0, "gnc": 2.0}
    plain = (str, int, float, bool)
    rows = [{**{key: value for key, value in entry.items() if isinstance(value, plain)},
             **_row(entry, wall[entry["variant"]])} for entry in cells]
    for row in rows:  # gnc's solver failed on one run
        if row["variant"] == "gnc" and row["seed"] == 1 and row["aliasing"] == 0.0:
            row.update(status="error", error="PeerFailed: gnc: GTSAM failed: Indeterminant linear system")
    table = pd.DataFrame(rows)
    side = summary.side_by_side(experiment, table)
    assert side["variant"].tolist() == ["appearance", "greedy_odometry", "pcm", "gnc"] * 2
    assert side["kind"].tolist() == ["posterior", "baseline", "peer", "peer"] * 2
    gnc = side[(side["variant"] == "gnc") & (side["aliasing"] == 0.0)].iloc[0]
    assert (gnc["cells"], gnc["failed"], gnc["ari"], gnc["wall_s"]) == (1, 1, 1.0, 2.0)

    text = summary.write_summary(experiment, table, tmp_path).read_text()
    section = text.split("## Side by side")[1].split("\n## ")[0]
    header = "| world | aliasing | noise | variant | kind | cells | failed | lc_ap | ari | lc_f1 | ece | wall_s |"
    assert header in section
    assert "| short_loop | 0 | 1 | pcm | peer | 2 | 0 | 1 | 1 | 1 | 0 | 1 |" in section
    assert "| short_loop | 0 | 1 | gnc | peer | 1 | 1 | 1 | 1 | 1 | 0 | 2 |" in section
    assert "| short_loop | 1 | 1 | appearance | posterior | 2 | 0 |" in section
    assert "Indeterminant linear system" in text.split("## Failed cells")[1]
    assert "(cost_accuracy.png)" in text and "one point per method and condition" in text
    assert (tmp_path / "cost_accuracy.png").stat().st_size > 0
