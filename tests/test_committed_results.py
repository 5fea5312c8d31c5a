"""The committed results are those of the committed configs (issue 9 item 7: fresh results).

A change of a default in ``ptm_bench.evaluation.experiment.DEFAULTS``, of a world file or of a version
label changes the definition of every cell that relies on it, and ``ptm-bench run`` would then recompute
it: the committed tables would describe something the config no longer asks for. A config keeps its
results by pinning the old value (as they do for ``burn_in`` and ``sampling_coordinates``).

    python -m pytest tests/test_committed_results.py -q
"""

from pathlib import Path

import pandas as pd
import pytest

from ptm_bench.evaluation.experiment import expand_cells, load_experiment

ROOT = Path(__file__).resolve().parent.parent
CONFIGS = sorted((ROOT / "experiments").glob("*.toml"))


@pytest.mark.parametrize("config", CONFIGS, ids=[config.stem for config in CONFIGS])
def test_every_cell_of_the_config_has_a_fresh_committed_row(config, tmp_path, monkeypatch):
    monkeypatch.chdir(ROOT)  # recorded worlds name their dataset files relative to the repository
    experiment = load_experiment(config)
    table = ROOT / "results" / experiment.name / "cells.csv"
    assert table.is_file(), f"{config.name}: no committed table {table.relative_to(ROOT)}"
    rows = pd.read_csv(table).set_index("cell_id")
    cells = expand_cells(experiment, tmp_path)
    missing = [cell["cell_id"] for cell in cells if cell["cell_id"] not in rows.index]
    stale = [cell["cell_id"] for cell in cells
             if cell["cell_id"] in rows.index and rows.loc[cell["cell_id"], "definition"] != cell["definition"]]
    failed = [cell["cell_id"] for cell in cells
              if cell["cell_id"] in rows.index and rows.loc[cell["cell_id"], "status"] != "ok"]
    assert not missing and not stale and not failed, (
        f"{config.name}: {len(missing)} cells without a row (first {missing[:2]}), {len(stale)} rows of another "
        f"definition (first {stale[:2]}), {len(failed)} failed (first {failed[:2]})")
