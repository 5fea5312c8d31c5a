"""The sweep engine: resume, errors, killed workers, and local vs Dask tables (ptm_bench.evaluation.sweep).

Cells here score a tiny synthetic appearance-only dataset built with numpy, so
the engine is exercised end to end without the simulator.
"""

import os
import signal
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from ptm_bench.evaluation import scoring

from ptm_bench.evaluation import sweep


def synthetic_cell(cell: dict) -> dict:
    """Cluster noisy 2-D signatures of 4 places by a distance threshold and score the answer."""
    rng = np.random.default_rng(np.random.SeedSequence([cell["seed"], int(cell["noise"] * 1000)]))
    truth = np.array([0, 1, 2, 3, 0, 1, 2, 3])
    centres = rng.normal(size=(4, 2)) * 3.0
    signatures = centres[truth] + rng.normal(scale=cell["noise"], size=(len(truth), 2))
    labels = []
    for index, signature in enumerate(signatures):
        distances = np.linalg.norm(signatures[:index] - signature, axis=1)
        labels.append(labels[int(np.argmin(distances))] if index and distances.min() < 1.0 else index)
    log = cell.get("inputs", {}).get("call_log")  # nested, so not a table column
    if log:
        with open(log, "a") as handle:
            handle.write(cell["cell_id"] + "\n")
    return {**scoring.score(scoring.point_mass(labels), truth), "wall_s": float(rng.random())}


def raising_cell(cell: dict) -> dict:
    if cell["seed"] == 1:
        raise ValueError("signatures: the sky is falling")
    return synthetic_cell(cell)


def dying_cell(cell: dict) -> dict:
    marker = Path(cell["marker_dir"]) / f"{cell['cell_id']}.started"
    if cell["seed"] == 0 or (cell["seed"] == 1 and not marker.exists()):
        marker.touch()
        os.kill(os.getpid(), signal.SIGKILL)  # seed 0 always dies; seed 1 dies on its first attempt only
    return synthetic_cell(cell)


def make_cells(seeds=range(4), noises=(0.1, 0.8), **extra):
    return [
        {"cell_id": f"noise={noise}|seed={seed}", "experiment": "test", "noise": noise, "seed": seed, **extra}
        for noise in noises
        for seed in seeds
    ]


def test_a_sweep_writes_one_row_per_cell_in_cell_order(tmp_path):
    cells = make_cells()
    table = sweep.run_sweep(cells, synthetic_cell, tmp_path / "cells.csv", workers=2, progress=False)
    assert list(table["cell_id"]) == [cell["cell_id"] for cell in cells]
    assert (table["status"] == "ok").all()
    # Low noise clusters perfectly; high noise makes mistakes on some seed.
    assert table.loc[table["noise"] == 0.1, "ari"].mean() > table.loc[table["noise"] == 0.8, "ari"].mean()


def test_a_resumed_sweep_equals_an_uninterrupted_one_and_skips_finished_cells(tmp_path, monkeypatch):
    cells = make_cells()
    whole = sweep.run_sweep(cells, synthetic_cell, tmp_path / "whole.csv", workers=2, progress=False)

    interrupted_path = tmp_path / "interrupted.csv"
    real_write, writes = sweep._write_table, []

    def write_then_interrupt(*args):
        real_write(*args)
        writes.append(1)
        if len(writes) == 3:
            raise KeyboardInterrupt  # as if the user pressed Ctrl-C after three cells

    monkeypatch.setattr(sweep, "_write_table", write_then_interrupt)
    with pytest.raises(KeyboardInterrupt):
        sweep.run_sweep(cells, synthetic_cell, interrupted_path, workers=2, progress=False)
    monkeypatch.setattr(sweep, "_write_table", real_write)
    finished = set(sweep.read_table(interrupted_path)["cell_id"])
    assert len(finished) == 3

    log = tmp_path / "calls.log"
    logged_cells = [{**cell, "inputs": {"call_log": str(log)}} for cell in cells]
    resumed = sweep.run_sweep(logged_cells, synthetic_cell, interrupted_path, workers=2, progress=False)
    rerun = set(log.read_text().split())
    assert rerun == {cell["cell_id"] for cell in cells} - finished
    pd.testing.assert_frame_equal(sweep.comparable(resumed), sweep.comparable(whole))


def test_a_cell_that_raises_is_recorded_and_the_sweep_goes_on(tmp_path):
    table = sweep.run_sweep(make_cells(seeds=range(3)), raising_cell, tmp_path / "cells.csv", workers=2, progress=False)
    failed = table[table["status"] == "error"]
    assert sorted(failed["seed"]) == [1, 1]
    assert failed["error"].str.contains("ValueError: signatures: the sky is falling").all()
    assert (table.loc[table["seed"] != 1, "status"] == "ok").all()
    assert table.loc[table["seed"] != 1, "gt_mass"].notna().all()


def test_retry_failed_reruns_only_the_failed_cells(tmp_path):
    path = tmp_path / "cells.csv"
    sweep.run_sweep(make_cells(seeds=range(3)), raising_cell, path, workers=2, progress=False)
    log = tmp_path / "calls.log"
    cells = make_cells(seeds=range(3), inputs={"call_log": str(log)})
    table = sweep.run_sweep(cells, synthetic_cell, path, workers=2, retry_failed=True, progress=False)
    assert sorted(log.read_text().split()) == ["noise=0.1|seed=1", "noise=0.8|seed=1"]
    assert (table["status"] == "ok").all()


def test_cells_whose_definition_changed_are_recomputed_and_only_those(tmp_path):
    path = tmp_path / "cells.csv"
    sweep.run_sweep(make_cells(seeds=range(2), definition="v1"), synthetic_cell, path, workers=2, progress=False)
    log = tmp_path / "calls.log"
    cells = make_cells(seeds=range(2), definition="v1", inputs={"call_log": str(log)})
    cells[1] = {**cells[1], "definition": "v2"}  # as if its config had been edited
    table = sweep.run_sweep(cells, synthetic_cell, path, workers=2, progress=False)
    assert log.read_text().split() == [cells[1]["cell_id"]]
    assert table.attrs == {"recomputed_changed": 1, "reused_unverified": 0, "warned": 0}
    assert table.set_index("cell_id").loc[cells[1]["cell_id"], "definition"] == "v2"
    # a table from before definitions existed is reused as it is, and counted as unverified
    legacy = tmp_path / "legacy.csv"
    sweep.run_sweep(make_cells(seeds=range(2)), synthetic_cell, legacy, workers=2, progress=False)
    table = sweep.run_sweep(make_cells(seeds=range(2), definition="v1"), raising_cell, legacy, workers=2, progress=False)
    assert (table["status"] == "ok").all()
    assert table.attrs == {"recomputed_changed": 0, "reused_unverified": 4, "warned": 0}


def test_a_killed_worker_is_retried_then_marked_failed_never_lost(tmp_path):
    cells = make_cells(seeds=range(3), noises=(0.1,), marker_dir=str(tmp_path))
    table = sweep.run_sweep(cells, dying_cell, tmp_path / "cells.csv", workers=2, max_attempts=2, progress=False)
    by_seed = table.set_index("seed")
    assert by_seed.loc[0, "status"] == "error" and "worker died" in by_seed.loc[0, "error"]
    assert by_seed.loc[0, "attempts"] == 2
    assert by_seed.loc[1, "status"] == "ok" and by_seed.loc[1, "attempts"] == 2
    assert by_seed.loc[2, "status"] == "ok" and by_seed.loc[2, "attempts"] == 1


def test_duplicate_cell_ids_are_refused(tmp_path):
    cells = make_cells(seeds=[0]) * 2
    with pytest.raises(ValueError, match="appears twice"):
        sweep.run_sweep(cells, synthetic_cell, tmp_path / "cells.csv", progress=False)


def test_local_and_dask_local_cluster_give_identical_tables(tmp_path):
    distributed = pytest.importorskip("distributed")
    cells = make_cells()
    local = sweep.run_sweep(cells, synthetic_cell, tmp_path / "local.csv", workers=2, progress=False)
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None) as cluster:
        remote = sweep.run_sweep(cells, synthetic_cell, tmp_path / "dask.csv", scheduler=cluster.scheduler_address, progress=False)
    assert (remote["status"] == "ok").all()
    pd.testing.assert_frame_equal(sweep.comparable(remote), sweep.comparable(local))


# -- experiment configs ----------------------------------------------------------------------

from ptm_bench.evaluation import experiment  # noqa: E402

MINIMAL_CONFIG = """
name = "tiny"
[sweep]
worlds = ["nested_loops"]
aliasing = [0.0, 1.0]
seeds = [0, 1]
calibration_seeds = [10]
[odometry]
max_penalty = 50
[[variants]]
name = "odometry"
models = ["odometry"]
[[variants]]
name = "both"
models = ["appearance", "odometry"]
odometry = { max_penalty = 150 }
"""


def write_config(tmp_path, text):
    path = tmp_path / "tiny.toml"
    path.write_text(text)
    return path


def test_a_config_expands_into_named_cells_with_variant_overrides(tmp_path):
    config = experiment.load_experiment(write_config(tmp_path, 'baselines = ["greedy_odometry"]\n' + MINIMAL_CONFIG))
    cells = experiment.expand_cells(config, tmp_path)
    assert len(cells) == 1 * 2 * 1 * 2 * 3
    assert cells[0]["cell_id"] == "nested_loops|a=0|noise=1|seed=0|odometry"
    both = next(cell for cell in cells if cell["variant"] == "both")
    assert both["models"] == "odometry+appearance"
    assert both["settings"].odometry.max_penalty == 150.0 and both["settings"].models == ("odometry", "appearance")
    odometry_only = next(cell for cell in cells if cell["variant"] == "odometry")
    assert odometry_only["settings"].odometry.max_penalty == 50.0
    assert {cell["method"] for cell in cells if cell["variant"] == "greedy_odometry"} == {"baseline"}
    # the definition digest follows the config, not where the results go
    assert len({cell["definition"] for cell in cells}) == len(cells)
    elsewhere = experiment.expand_cells(config, tmp_path / "elsewhere")
    assert [cell["definition"] for cell in elsewhere] == [cell["definition"] for cell in cells]
    edited = experiment.load_experiment(write_config(
        tmp_path, 'baselines = ["greedy_odometry"]\n' + MINIMAL_CONFIG.replace("max_penalty = 150", "max_penalty = 100")))
    changed = {cell["cell_id"] for cell, before in zip(experiment.expand_cells(edited, tmp_path), cells)
               if cell["definition"] != before["definition"]}
    assert changed == {cell["cell_id"] for cell in cells if cell["variant"] == "both"}


@pytest.mark.parametrize("bad, message", [
    ('[sweep]\nworlds = ["nested_loops"]\nseeds = [0]\ncolour = 1\n', r"sweep\.colour is an unknown key"),
    ('[sweep]\nworlds = ["atlantis"]\nseeds = [0]\n', r"sweep\.worlds\[0\]: unknown world 'atlantis'"),
    ('flavour = "x"\n[sweep]\nworlds = ["nested_loops"]\nseeds = [0]\n', "flavour is an unknown key at the top level"),
    ('[sweep]\nworlds = ["nested_loops"]\nseeds = [0, 1]\ncalibration_seeds = [1]\n',
     r"sweep\.calibration_seeds must be held out from seeds"),
    ('[sweep]\nworlds = ["nested_loops"]\nseeds = [0]\n[[variants]]\nname = "v"\nmodels = ["lidar"]\n',
     r"variants\['v'\]\.models: unknown model 'lidar'"),
    ('[sweep]\nworlds = ["nested_loops"]\nseeds = [0]\n[[variants]]\nname = "v"\nmodels = ["odometry"]\n'
     'odometry = { penalty = 3 }\n', r"variants\['v'\]\.odometry\.penalty is an unknown key"),
    ('baselines = ["oracle"]\n[sweep]\nworlds = ["nested_loops"]\nseeds = [0]\n', "unknown baseline 'oracle'"),
    ('[sweep]\nworlds = ["nested_loops"]\nseeds = [0]\naliasing = [1.5]\n', r"sweep\.aliasing values must lie in"),
])
def test_bad_configs_are_refused_with_the_offending_name(tmp_path, bad, message):
    with pytest.raises(ValueError, match=message):
        experiment.load_experiment(write_config(tmp_path, bad))


# -- cells end to end, on the simulator's short loop --------------------------------------------

from ptm_bench.evaluation.cell import run_cell  # noqa: E402
from ptm_bench.reporting.summary import write_summary  # noqa: E402


END_TO_END_CONFIG = """
name = "tiny"
baselines = ["greedy_odometry", "appearance_threshold"]
[sweep]
worlds = ["short_loop"]
aliasing = [0.0, 1.0]
seeds = [0]
calibration_seeds = [10, 11, 12]
calibration = "same_floor"   # the mechanics end to end, on three tiny runs of the short loop (no larger floors)
[inference]
n_samples = 300
burn_in = 50
[odometry]
n_importance = 20
[[variants]]
name = "appearance"
models = ["appearance"]
[[variants]]
name = "odometry+appearance"
models = ["odometry", "appearance"]
[[variants]]
name = "exact appearance"
models = ["appearance"]
inference = { method = "exact" }
[paper.appearance]
gt_mass = 0.5
"""


def test_cells_run_end_to_end_and_the_summary_is_written(tmp_path):
    config = experiment.load_experiment(write_config(tmp_path, END_TO_END_CONFIG))
    results = tmp_path / "tiny"
    cells = experiment.expand_cells(config, results)
    table = sweep.run_sweep(cells, run_cell, results / "cells.csv", workers=2, progress=False)
    assert (table["status"] == "ok").all(), table.loc[table["status"] != "ok", "error"].tolist()
    unique = table[table["aliasing"] == 0.0].set_index("variant")
    aliased = table[table["aliasing"] == 1.0].set_index("variant")
    # Unique palettes make the truth plausible to appearance alone; one shared palette makes it hopeless.
    assert unique.loc["exact appearance", "gt_mass"] > 0.02  # 0.035 with three tiny calibration runs
    assert aliased.loc["exact appearance", "gt_mass"] < 0.01 * unique.loc["exact appearance", "gt_mass"]
    # MCMC on the same posterior agrees with enumeration (1 200 samples: a loose bound).
    assert abs(unique.loc["appearance", "gt_mass"] - unique.loc["exact appearance", "gt_mass"]) < 0.1
    baselines = table[table["method"] == "baseline"]
    assert (baselines["n_topologies"] == 1).all() and baselines["gt_mass"].isin([0.0, 1.0]).all()
    summary = write_summary(config, table, results).read_text()
    assert "## The paper's figures and ours" in summary
    assert (results / "top5_odometry_appearance.png").is_file()
    assert (results / "gt_mass_heatmap.png").is_file()
    assert (results / "trajectory.png").is_file()
    # Every cell, baselines included, carries its calibration columns, and the summary pools them.
    assert table["reliability"].notna().all() and table["log_score"].notna().all()
    assert (table["n_pairs"] == table["n_measurements"] * (table["n_measurements"] - 1) // 2).all()
    assert "## Calibration" in summary and (results / "reliability.png").is_file()
