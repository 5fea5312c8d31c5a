"""``ptm-bench import-carmen`` writes a normal dataset file and names a bad parameter."""

from __future__ import annotations

import ptm

from ptm_bench.cli import main


def test_import_a_shipped_log(tmp_path, capsys):
    out = tmp_path / "aces.npz"
    assert main(["import-carmen", "aces", "--out", str(out)]) == 0
    printed = capsys.readouterr().out
    assert "N = 53 detections of 41 places, 12 revisits, path 298 m" in printed
    assert "calibration drive: the first 25 m (40 scans, not scored)" in printed
    # the fitted noise and its source; what the drive measured, and that it is left in (Before: a JSON dump, and
    # the drive's scale and drift always "taken out of the odometry"; no normalised error.)
    assert ("odometry noise fitted on acapulco, fhw, intel over 4.5 m windows: alpha1 0.0147 rad/rad, alpha2 0.0087 "
            "rad/m, alpha3 0.0198 m/m, alpha4 0.0214 m/rad, floors 0.0777 m and 0.0169 rad; a 25 m drive misses the "
            "rest of its run by scale 0.0066, heading drift 0.0057 rad/m") in printed
    assert "heading drift +0.0020 rad/m (left in, within 3 sigma of 0); the rows' covariances x 1.00" in printed
    assert "mean normalised error 0.79" in printed
    dataset = ptm.Dataset.load(out)
    assert dataset.n == 53 and dataset.meta["world"] == "aces" and dataset.odometry_cov is not None


def test_without_a_calibration_drive_the_whole_log_is_scored(tmp_path, capsys):
    out = tmp_path / "aces.npz"
    assert main(["import-carmen", "aces", "--out", str(out), "--calibration-drive", "0"]) == 0
    assert "calibration drive" not in capsys.readouterr().out
    assert ptm.Dataset.load(out).meta["calibration_drive"] is None


def test_a_calibration_drive_longer_than_the_log_is_an_error(tmp_path, capsys):
    assert main(["import-carmen", "aces", "--out", str(tmp_path / "x.npz"), "--calibration-drive", "5000"]) == 2
    assert "shorter than 5000 m" in capsys.readouterr().err


def test_a_spacing_that_yields_one_place_is_an_error(tmp_path, capsys):
    assert main(["import-carmen", "aces", "--out", str(tmp_path / "x.npz"), "--place-spacing", "1000",
                 "--detection-radius", "1"]) == 2
    assert "place_spacing 1000 m yields 1 place" in capsys.readouterr().err
