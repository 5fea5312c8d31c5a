"""``ptm-bench index``: the index of the results names each experiment, its computed figures and its figure.

Checked on a tiny fake repository in a temporary folder: one experiment config, its three-row table and a
PNG. The figures are computed from the table (a wrong mean fails), the write is atomic (a crash in the middle
of writing leaves the previous index), and the same files give the same index byte for byte.

    python3 -m pytest tests/test_results_index.py -q
"""

from __future__ import annotations

import os
from pathlib import Path

import pandas as pd
import pytest

import ptm.dataset
from ptm_bench.cli import main
from ptm_bench.evaluation.experiment import expand_cells, load_experiment
from ptm_bench.reporting.results_index import experiment_entries, freshness, provenance_table

CONFIG = """name = "tiny"
description = "short_loop, odometry against odometry + appearance."
baselines = ["greedy_odometry"]

[sweep]
worlds = ["short_loop"]
seeds = [0, 1]

[[variants]]
name = "odometry"
models = ["odometry"]

[[variants]]
name = "odometry+appearance"
models = ["odometry", "appearance"]
"""

README = """# Results

| experiment | produced at |
|---|---|
| `tiny` | tag `results-test` (commit abc1234) |
"""


@pytest.fixture
def repository(tmp_path):
    """experiments/tiny.toml, results/tiny/{cells.csv, reliability.png}, results/README.md and docs/."""
    (tmp_path / "experiments").mkdir()
    (tmp_path / "experiments" / "tiny.toml").write_text(CONFIG)
    folder = tmp_path / "results" / "tiny"
    folder.mkdir(parents=True)
    pd.DataFrame({
        "cell_id": ["a", "b", "c"],
        "variant": ["odometry", "odometry", "odometry+appearance"],
        "gt_mass": [0.25, 0.5, 1.0],
        "ari": [0.5, 1.0, 1.0],
        "lc_ap": [0.75, 0.9, 1.0],
        "status": ["ok", "ok", "ok"],
    }).to_csv(folder / "cells.csv", index=False)
    (folder / "reliability.png").write_bytes(b"\x89PNG\r\n\x1a\n")
    (tmp_path / "results" / "README.md").write_text(README)
    (tmp_path / "docs").mkdir()
    return tmp_path


def _index(repository: Path) -> int:
    return main(["index", "--results", str(repository / "results"), "--experiments",
                 str(repository / "experiments"), "--out", str(repository / "docs" / "results.md")])


def test_the_index_names_the_experiment_its_figures_and_its_figure(repository):
    assert _index(repository) == 0
    text = (repository / "docs" / "results.md").read_text()
    assert "## tiny" in text and "short_loop, odometry against odometry + appearance." in text
    # the means of the table's rows per variant: (0.25 + 0.5) / 2, (0.5 + 1) / 2, (0.75 + 0.9) / 2
    assert "`odometry` 0.375 / 0.750 / 0.825" in text
    assert "`odometry+appearance` 1.000 / 1.000 / 1.000" in text
    assert "Mean truth mass / MAP ARI / loop-closure AP over each variant's rows" in text
    assert "![tiny: reliability.png](../results/tiny/reliability.png)" in text
    assert "produced at tag `results-test` (commit abc1234)" in text
    assert "3 finished rows" in text
    assert "Named by the config, without rows: `greedy_odometry`." in text


def test_running_it_twice_gives_the_same_file(repository):
    _index(repository)
    first = (repository / "docs" / "results.md").read_bytes()
    _index(repository)
    assert (repository / "docs" / "results.md").read_bytes() == first


def test_a_crash_while_writing_leaves_the_previous_index(repository, monkeypatch):
    out = repository / "docs" / "results.md"
    out.write_text("the previous index\n")

    def crash(descriptor):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(ptm.dataset.os, "fsync", crash)  # the new text is written, then the disk fails
    assert _index(repository) == 1
    monkeypatch.setattr(ptm.dataset.os, "fsync", os.fsync)
    assert out.read_text() == "the previous index\n"
    assert sorted(path.name for path in out.parent.iterdir()) == ["results.md"]  # no temporary file left


def test_rows_that_record_their_commit_say_so_and_failed_rows_do_not_count(repository):
    table_path = repository / "results" / "tiny" / "cells.csv"
    table = pd.read_csv(table_path)
    table["commit"] = ["0123abc", "0123abc", "0123abc"]
    table.loc[2, "status"] = "failed"
    table.to_csv(table_path, index=False)
    (entry,) = experiment_entries(repository / "results", repository / "experiments")
    assert entry.produced_at == "commit `0123abc`"
    assert entry.rows == 2 and set(entry.means) == {"odometry"}
    assert entry.unrun_variants == ("odometry+appearance", "greedy_odometry")


def test_without_a_provenance_the_index_says_it_is_not_recorded(repository):
    (repository / "results" / "README.md").unlink()
    assert provenance_table(repository / "results" / "README.md") == {}
    _index(repository)
    assert "where it was produced is not recorded" in (repository / "docs" / "results.md").read_text()


def test_a_config_without_a_table_is_listed_as_not_run(repository):
    (repository / "experiments" / "later.toml").write_text(
        'name = "later"\ndescription = "not run yet"\n[sweep]\nworlds = ["short_loop"]\nseeds = [0]\n')
    _index(repository)
    text = (repository / "docs" / "results.md").read_text()
    assert "## later" in text and "No committed table yet (0 of 1 cells fresh" in text


def test_freshness_counts_rows_computed_by_todays_code(repository):
    """A row is fresh only where its definition is the cell's definition now; the index says how many are."""
    config = repository / "experiments" / "tiny.toml"
    cells = expand_cells(load_experiment(config), repository / "results" / "tiny")
    first, second, third = cells[:3]
    table = pd.DataFrame({"cell_id": [first["cell_id"], second["cell_id"], third["cell_id"]],
                          "definition": [first["definition"], "another definition", third["definition"]],
                          "status": ["ok", "ok", "error"]})
    counted = freshness(config, table)
    assert (counted.cells, counted.fresh, counted.stale, counted.failed, counted.missing) == (len(cells), 1, 1, 1,
                                                                                               len(cells) - 3)
    assert not counted.all_fresh and "1 of 6 cells fresh" in counted.describe()
    entries = experiment_entries(repository / "results", repository / "experiments")
    assert entries[0].freshness.fresh == 0 and entries[0].freshness.missing == len(cells)  # the fake rows' ids
