"""The CARMEN reader: both odometry forms, the reference trajectory, and clear errors on bad logs."""

from __future__ import annotations

import gzip

import numpy as np
import pytest

from ptm.se2 import relative_pose

from ptm_bench.logs.carmen import SHIPPED_LOGS, read_carmen, shipped_log

# Three scans in GMapping's corrected form: raw ODOM stretches, FLASER with the corrected pose X_k twice,
# a re-anchoring ODOM line at X_k (timestamp 0), NEFF.
CORRECTED = """\
# message formats defined: PARAM SYNC ODOM FLASER
PARAM robot_frontlaser_offset 0.0 nohost 0
ODOM 0 0 0 0 0 0 0.5 host 0.5
ODOM 0.1 0 0 0 0 0 0.9 host 0.9
FLASER 3 1.0 2.0 3.0 0.1 0.0 0.0 0.1 0.0 0.0 1.0 host 1.0
ODOM 0.1 0.0 0.0 0 0 0 0 host 0
NEFF 10
ODOM 0.6 0.1 0.2 0 0 0 1.5 host 1.5
ODOM 1.2 0.2 0.4 0 0 0 1.9 host 1.9
FLASER 3 1.5 2.5 3.5 1.0 0.3 0.5 1.0 0.3 0.5 2.0 host 2.0
ODOM 1.0 0.3 0.5 0 0 0 0 host 0
NEFF 8
ODOM 1.3 0.9 1.4 0 0 0 2.9 host 2.9
FLASER 3 1.1 2.1 3.1 1.4 0.8 1.5 1.4 0.8 1.5 3.0 host 3.0
ODOM 1.4 0.8 1.5 0 0 0 0 host 0
"""

# A plain log: one continuous odometry frame, TRUEPOS lines give the reference, the laser's odometry is raw.
PLAIN = """\
ODOM 0 0 0 0 0 0 0.9 host 0.9
TRUEPOS 5 5 0 0 0 0 0.9 host 0.9
FLASER 2 1.0 2.0 0 0 0 0 0 0 1.0 host 1.0
ODOM 1.0 0.0 0.1 0 0 0 1.9 host 1.9
TRUEPOS 6 5 0.1 1 0 0.1 1.9 host 1.9
FLASER 2 1.0 2.0 1 0 0.1 1 0 0.1 2.0 host 2.0
ODOM 2.0 0.5 0.3 0 0 0 2.9 host 2.9
TRUEPOS 7 5.6 0.3 2 0.5 0.3 2.9 host 2.9
FLASER 2 1.0 2.0 2 0.5 0.3 2 0.5 0.3 3.0 host 3.0
"""


def _write(tmp_path, text, name="run.log"):
    path = tmp_path / name
    if name.endswith(".gz"):
        with gzip.open(path, "wt") as handle:
            handle.write(text)
    else:
        path.write_text(text)
    return path


def test_corrected_form_recovers_raw_increments_from_the_anchor(tmp_path):
    log = read_carmen(_write(tmp_path, CORRECTED, "run.log.gz"))
    assert log.form == "corrected" and log.n_scans == 3
    np.testing.assert_array_equal(log.timestamps, [1.0, 2.0, 3.0])
    np.testing.assert_array_equal(log.lines, [5, 10, 14])
    np.testing.assert_allclose(log.ranges[1], [1.5, 2.5, 3.5])
    assert log.params == {"robot_frontlaser_offset": "0.0"}
    corrected = np.array([[0.1, 0.0, 0.0], [1.0, 0.3, 0.5], [1.4, 0.8, 1.5]])
    np.testing.assert_allclose(log.reference, corrected)
    # u_k = X_{k-1}^-1 o P_k: the last ODOM pose before the scan, seen from the previous corrected pose
    expected = relative_pose(corrected[:2], [[1.2, 0.2, 0.4], [1.3, 0.9, 1.4]])
    np.testing.assert_allclose(log.raw_increments, expected)
    assert not np.allclose(log.raw_increments, log.reference_increments())  # raw, not the corrected poses


def test_plain_form_uses_consecutive_odometry_and_truepos(tmp_path):
    log = read_carmen(_write(tmp_path, PLAIN))
    assert log.form == "plain"
    odometry = np.array([[0, 0, 0], [1.0, 0.0, 0.1], [2.0, 0.5, 0.3]])
    np.testing.assert_allclose(log.raw_increments, relative_pose(odometry[:-1], odometry[1:]))
    np.testing.assert_allclose(log.reference, [[5, 5, 0], [6, 5, 0.1], [7, 5.6, 0.3]])
    np.testing.assert_allclose(log.odometry_poses()[-1, 2], 0.3)
    no_truth = read_carmen(_write(tmp_path, "\n".join(l for l in PLAIN.splitlines() if not l.startswith("TRUEPOS"))))
    assert no_truth.reference is None
    with pytest.raises(ValueError, match="no reference trajectory"):
        no_truth.reference_increments()


@pytest.mark.parametrize("text, message", [
    (CORRECTED.rsplit("FLASER", 1)[0] + "FLASER 3 1.1 2.1 3.1 1.4 0.8", r"run.log:14: FLASER with 3 ranges needs 10 fields"),
    (CORRECTED.replace("ODOM 0.6 0.1 0.2", "ODOM 0.6 abc 0.2"), r"run.log:8: ODOM has a field that is not a number"),
    ("\n".join(l for l in CORRECTED.splitlines() if not l.startswith("ODOM")), r"run.log:3: FLASER before any ODOM line"),
    (CORRECTED.replace("1.0 0.3 0.5 2.0 host 2.0", "1.0 0.3 0.5 -0.5 host -0.5"), r"run.log:10: scan timestamp -0.5 s is earlier"),
    ("# only a comment\nODOM 0 0 0 0 0 0 1 h 1\n", "no FLASER lines"),
    (CORRECTED.replace("FLASER 3", "FLASER 2.5"), r"run.log:5: FLASER beam count"),
])
def test_bad_logs_are_refused_naming_the_line(tmp_path, text, message):
    with pytest.raises(ValueError, match=message):
        read_carmen(_write(tmp_path, text))


def test_small_timestamp_reversals_are_tolerated_and_counted(tmp_path):
    log = read_carmen(_write(tmp_path, CORRECTED.replace("1.0 0.3 0.5 2.0 host 2.0", "1.0 0.3 0.5 0.6 host 0.6")))
    assert log.time_reversals == 1
    with pytest.raises(ValueError, match="tolerance 0.1 s"):
        read_carmen(tmp_path / "run.log", time_tolerance=0.1)


def test_truncated_gzip_is_refused(tmp_path):
    path = _write(tmp_path, CORRECTED * 20, "run.log.gz")
    path.write_bytes(path.read_bytes()[:-30])
    with pytest.raises(ValueError, match="truncated log"):
        read_carmen(path)


def test_shipped_logs_match_their_readme():
    """The Intel log: 910 scans, 500 m, raw odometry that ends 62 m and 151 degrees from the reference."""
    assert SHIPPED_LOGS == ("intel", "aces", "fhw", "acapulco")
    log = read_carmen(shipped_log("intel"))
    assert log.form == "corrected" and log.n_scans == 910 and log.time_reversals == 4
    assert log.path_length() == pytest.approx(500, abs=1)
    end = relative_pose(log.reference[-1], log.odometry_poses()[-1])
    assert np.hypot(end[0], end[1]) == pytest.approx(62, abs=1) and abs(np.degrees(end[2])) == pytest.approx(151, abs=1)
    with pytest.raises(ValueError, match="unknown log 'mit'"):
        shipped_log("mit")
