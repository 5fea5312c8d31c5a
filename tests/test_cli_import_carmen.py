"""``ptm-bench import-carmen`` writes a normal dataset file and names a bad parameter."""

from __future__ import annotations

import ptm

from ptm_bench.cli import main


def test_import_a_shipped_log(tmp_path, capsys):
    out = tmp_path / "aces.npz"
    assert main(["import-carmen", "aces", "--out", str(out)]) == 0
    printed = capsys.readouterr().out
    assert "N = 55 detections of 40 places, 15 revisits, path 323 m" in printed
    dataset = ptm.Dataset.load(out)
    assert dataset.n == 55 and dataset.meta["world"] == "aces" and dataset.odometry_cov is not None


def test_a_spacing_that_yields_one_place_is_an_error(tmp_path, capsys):
    assert main(["import-carmen", "aces", "--out", str(tmp_path / "x.npz"), "--place-spacing", "1000",
                 "--detection-radius", "1"]) == 2
    assert "place_spacing 1000 m yields 1 place" in capsys.readouterr().err
