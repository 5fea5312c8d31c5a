"""What the repository says about its committed results is what they are.

Every config in ``experiments/`` has a committed table, and ``docs/results.md``, the index that
``ptm-bench index`` writes, is the index of the committed files at today's code: for each experiment how many
of its config's cells the table holds as today's code and settings would compute them (a cell's definition
includes versions derived from the source of the code it runs, ``ptm_bench.simulation.code_version``). An
edit to the code that a committed row depends on therefore makes this test fail until the index is
regenerated, and the index then says which tables are stale: freshness is computed, never claimed.

    python -m pytest tests/test_committed_results.py -q
"""

from pathlib import Path

import pytest

from ptm_bench.evaluation.experiment import load_experiment
from ptm_bench.reporting.results_index import render_index

ROOT = Path(__file__).resolve().parent.parent
CONFIGS = sorted((ROOT / "experiments").glob("*.toml"))


@pytest.mark.parametrize("config", CONFIGS, ids=[config.stem for config in CONFIGS])
def test_every_config_has_a_committed_table(config):
    table = ROOT / "results" / load_experiment(config).name / "cells.csv"
    assert table.is_file(), f"{config.name}: no committed table {table.relative_to(ROOT)}"


def test_the_results_index_is_that_of_the_committed_files_at_this_code(monkeypatch):
    monkeypatch.chdir(ROOT)  # recorded worlds name their dataset files relative to the repository
    index = ROOT / "docs" / "results.md"
    expected = render_index(ROOT / "results", ROOT / "experiments", index)
    assert index.read_text(encoding="utf-8") == expected, (
        "docs/results.md is not the index of the committed results at this code: run `ptm-bench index`")
