"""The data contract (docs/model.md §2.2): validation, atomic round trip, CSV import."""

import json

import numpy as np
import pytest

from ptm import Dataset


def full_dataset(n=4, k=5):
    rng = np.random.default_rng(0)
    covariance = np.tile(np.diag([0.01, 0.01, 0.001]), (n - 1, 1, 1))
    return Dataset(
        odometry=rng.normal(size=(n - 1, 3)), signatures=rng.uniform(size=(n, k)),
        labels=np.arange(n) % 2, true_poses=rng.normal(size=(n, 3)), odometry_cov=covariance,
        panoramas=rng.integers(0, 256, size=(n, 4, 16, 3), dtype=np.uint8), meta={"world": "test", "seed": 1})


def test_round_trip_preserves_every_field(tmp_path):
    dataset = full_dataset()
    loaded = Dataset.load(dataset.save(tmp_path / "run.npz"))
    for name in ("odometry", "signatures", "labels", "true_poses", "odometry_cov", "panoramas"):
        assert np.array_equal(getattr(loaded, name), getattr(dataset, name)), name
    assert loaded.meta == {"world": "test", "seed": 1}
    assert loaded.n == 4
    assert [p.name for p in tmp_path.iterdir()] == ["run.npz"]  # no temporary file left


def test_odometry_angles_are_wrapped():
    dataset = Dataset(odometry=[[1.0, 0.0, 3 * np.pi / 2]])
    assert dataset.odometry[0, 2] == pytest.approx(-np.pi / 2)


def test_head_keeps_the_first_detections():
    head = full_dataset(n=5).head(3)
    assert head.n == 3 and head.odometry.shape == (2, 3) and head.odometry_cov.shape == (2, 3, 3)


@pytest.mark.parametrize("kwargs, message", [
    (dict(), "at least one of"),
    (dict(signatures=np.zeros((0, 5))), "N=0"),
    (dict(signatures=np.array([[np.nan, 1.0]])), "signatures contains a non-finite value"),
    (dict(signatures=np.array([[np.inf, 1.0]])), "signatures contains a non-finite"),
    (dict(signatures=np.ones((3, 2)), labels=[0, 1]), "mismatched lengths"),
    (dict(signatures=np.ones((3, 2)), odometry=np.zeros((3, 3))), "mismatched lengths"),
    (dict(odometry=np.zeros((2, 2))), "odometry must have shape"),
    (dict(labels=[0.5, 1.0]), "labels must be integers"),
    (dict(labels=["a", "b"]), "labels must be integers"),
    (dict(odometry=np.zeros((1, 3)), odometry_cov=-np.eye(3)[None]), "not positive definite"),
    (dict(odometry=np.zeros((1, 3)), odometry_cov=np.array([[[1, 1, 0], [0, 1, 0], [0, 0, 1.0]]])), "not symmetric"),
    (dict(odometry_cov=np.eye(3)[None], labels=[0, 1]), "without odometry"),
    (dict(labels=[0, 1], panoramas=np.zeros((2, 4, 4, 3))), "uint8"),
    (dict(labels=[0, 1], true_poses=np.zeros((2, 2))), "true_poses"),
    (dict(labels=[0], meta={"bad": object()}), "JSON"),
])
def test_validation_errors_name_the_problem(kwargs, message):
    with pytest.raises(ValueError, match=message):
        Dataset(**kwargs)


def test_loading_a_corrupt_or_missing_file_fails_clearly(tmp_path):
    with pytest.raises(FileNotFoundError):
        Dataset.load(tmp_path / "missing.npz")
    corrupt = tmp_path / "corrupt.npz"
    corrupt.write_bytes(b"not a zip file")
    with pytest.raises(ValueError, match="not a readable dataset"):
        Dataset.load(corrupt)
    bad = tmp_path / "bad.npz"
    np.savez(bad, signatures=np.array([[np.nan]]), meta=json.dumps({}))
    with pytest.raises(ValueError, match="non-finite"):
        Dataset.load(bad)


def test_failed_save_leaves_the_previous_file_intact(tmp_path, monkeypatch):
    path = full_dataset().save(tmp_path / "run.npz")
    before = path.read_bytes()

    def explode(*args, **kwargs):
        raise OSError("disk full")

    monkeypatch.setattr(np, "savez_compressed", explode)
    with pytest.raises(OSError, match="disk full"):
        full_dataset(n=6).save(path)
    assert path.read_bytes() == before
    assert [p.name for p in tmp_path.iterdir()] == ["run.npz"]
    with pytest.raises(ValueError, match=".npz"):
        full_dataset().save(tmp_path / "run.txt")
    with pytest.raises(ValueError, match="does not exist"):
        full_dataset().save(tmp_path / "missing" / "run.npz")


def test_csv_import(tmp_path):
    (tmp_path / "odometry.csv").write_text("dx,dy,dtheta\n1.0,0.0,0.1\n0.5,0.2,-0.1\n")
    (tmp_path / "signatures.csv").write_text("0.1,0.2\n0.3,0.4\n0.5,0.6\n")
    (tmp_path / "labels.csv").write_text("0\n1\n0\n")
    dataset = Dataset.from_csv(tmp_path / "odometry.csv", tmp_path / "signatures.csv", tmp_path / "labels.csv")
    assert dataset.n == 3 and dataset.signatures.shape == (3, 2) and list(dataset.labels) == [0, 1, 0]
    (tmp_path / "ragged.csv").write_text("0.1,0.2\n0.3\n")
    with pytest.raises(ValueError, match="ragged.csv:2"):
        Dataset.from_csv(signatures=tmp_path / "ragged.csv")
    (tmp_path / "words.csv").write_text("0.1,0.2,0.3\nfoo,bar,baz\n")
    with pytest.raises(ValueError, match="words.csv:2: not a row of numbers"):
        Dataset.from_csv(odometry=tmp_path / "words.csv")


def test_saved_files_get_the_usual_permissions(tmp_path):
    import os
    import stat

    path = full_dataset().save(tmp_path / "run.npz")
    mask = os.umask(0)
    os.umask(mask)
    assert stat.S_IMODE(path.stat().st_mode) == 0o666 & ~mask
