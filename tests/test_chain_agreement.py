"""Independent runs that disagree are reported (issue 11, item 4; docs/model.md §3.4).

A cell's row carries a ``warning`` when its chains disagree -- split R-hat of
log P or of the number of places above 1.05, or two chains' co-assignment
matrices more than 0.05 apart -- with the values reached, and the sweep
(``ptm-bench run``) prints each such warning as its cell finishes and counts
them at the end.
"""

import pytest

from ptm_bench.evaluation.cell import disagreement
from ptm_bench.evaluation.sweep import run_sweep

AGREE = {"rhat_log_prob": 1.01, "rhat_num_places": 1.0, "coassignment_max_difference": 0.02}


def test_chains_that_agree_give_no_warning():
    assert disagreement(AGREE) == ""


def test_a_result_without_several_chains_gives_no_warning():
    assert disagreement({"partitions": 203, "log_normaliser": 1.5}) == ""  # the exact posterior


@pytest.mark.parametrize("name, value, shown", [
    ("rhat_log_prob", 1.52, "split R-hat of log P 1.52"),
    ("rhat_num_places", float("inf"), "of the number of places inf"),
    ("coassignment_max_difference", 0.3, "largest co-assignment difference 0.3 "),
    ("coassignment_max_difference", 0.0504, "largest co-assignment difference 0.0504 "),  # not "0.05 (<= 0.05)"
])
def test_each_disagreement_is_reported_with_every_value_reached(name, value, shown):
    message = disagreement({**AGREE, name: value})
    assert message.startswith("independent chains disagree") and shown in message
    assert "(want <= 1.05)" in message and "(<= 0.05)" in message


def test_the_sweep_reports_the_cells_that_warn(tmp_path, capsys):
    cells = [{"cell_id": "a", "experiment": "agreement", "warning": ""},
             {"cell_id": "b", "experiment": "agreement", "warning": "independent chains disagree: ..."}]
    table = run_sweep(cells, dict, tmp_path / "cells.csv", workers=1, progress=False)  # dict: the cell is its row
    assert table.attrs["warned"] == 1
    reported = capsys.readouterr().err
    assert "warning: b: independent chains disagree: ..." in reported and "1 of 2 cells warn" in reported
