"""Recorded runs as worlds of an experiment: calibrated on the other recorded runs, never on themselves."""

from __future__ import annotations

from pathlib import Path

import pandas as pd
import pytest

from ptm_bench.evaluation.calibration import calibration_datasets
from ptm_bench.evaluation.cell import run_cell
from ptm_bench.evaluation.experiment import expand_cells, parse_experiment
from ptm_bench.reporting.summary import write_summary

ROOT = Path(__file__).resolve().parent.parent
LOGS = {name: str(ROOT / "data" / "real_logs" / f"{name}.npz") for name in ("intel", "aces", "fhw", "acapulco")}


def _config(worlds, **extra):
    return {"sweep": {"worlds": worlds, "seeds": [0]}, "baselines": ["greedy_odometry"],
            "variants": [{"name": "odometry", "models": ["odometry"]}], **extra}


def test_calibration_defaults_to_the_other_recorded_worlds(tmp_path):
    worlds = [{"dataset": LOGS[name], "name": name} for name in ("aces", "fhw", "intel")]
    experiment = parse_experiment(_config(worlds))
    aces = experiment.sweep.worlds[0]
    assert aces["calibration"] == [LOGS["fhw"], LOGS["intel"]]
    cells = expand_cells(experiment, tmp_path)
    cell = next(cell for cell in cells if cell["world"] == "aces" and cell["variant"] == "greedy_odometry")
    held_out = calibration_datasets(cell)
    assert [dataset.meta["world"] for dataset in held_out] == ["fhw", "intel"]
    row = run_cell(cell)
    assert row["n_pairs"] == 53 * 52 // 2 and "2 held-out runs" in row["source_threshold"]
    table_row = {key: value for key, value in cell.items() if isinstance(value, (str, int, float))}
    table = pd.DataFrame([{**table_row, **row, "status": "ok"}])
    header = write_summary(experiment, table, tmp_path, figures=False).read_text()
    assert "aces on fhw + intel; fhw on aces + intel; intel on aces + fhw" in header
    assert "seeds [1000" not in header  # a recorded run is not calibrated on simulator seeds


@pytest.mark.parametrize("worlds, message", [
    ([{"dataset": LOGS["aces"], "name": "aces"}], "has no calibration runs"),
    ([{"dataset": LOGS["aces"], "name": "aces", "calibration": [LOGS["fhw"], LOGS["aces"]]}], "lists itself"),
    ([{"dataset": LOGS["aces"], "name": "aces", "seed": 3}], r"sweep.worlds\[0\].seed is an unknown key"),
    ([{"dataset": LOGS["aces"]}, {"dataset": LOGS["fhw"], "name": "fhw"}], "needs a 'name'"),
])
def test_bad_recorded_worlds_are_refused(worlds, message):
    with pytest.raises(ValueError, match=message):
        parse_experiment(_config(worlds))


def test_the_shipped_config_parses():
    from ptm_bench.evaluation.experiment import load_experiment

    experiment = load_experiment(ROOT / "experiments" / "real_logs.toml")
    assert [world["name"] for world in experiment.sweep.worlds] == ["intel", "aces", "fhw", "acapulco"]
    assert all(world["dataset"] not in world["calibration"] and len(world["calibration"]) == 3
               for world in experiment.sweep.worlds)
