"""The data contract (docs/model.md §2.2): validation, atomic round trip, CSV import."""

import io
import json
import zipfile

import numpy as np
import pytest
from numpy.lib import format as npy

import ptm
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


# -- issue 47: labels read exactly, headers only when they are one, complex refused, forged sizes refused ----------

def test_csv_labels_are_read_exactly(tmp_path):
    (tmp_path / "signatures.csv").write_text("0.1\n0.2\n0.3\n0.4\n0.5\n0.6\n")
    (tmp_path / "labels.csv").write_text(f"label\n{2 ** 53}\n{2 ** 53 + 1}\n{2 ** 63 - 1}\n{-2 ** 63}\n1e6\n3.0\n")
    labels = Dataset.from_csv(signatures=tmp_path / "signatures.csv", labels=tmp_path / "labels.csv").labels
    # were 2**53, 2**53 (one place: read through floats), and 2**63 - 1 refused as 9.223372036854776e+18
    assert labels.tolist() == [2 ** 53, 2 ** 53 + 1, 2 ** 63 - 1, -2 ** 63, 10 ** 6, 3]


@pytest.mark.parametrize("cell, problem", [
    (str(2 ** 63), rf"'{2 ** 63}' does not fit in a 64-bit integer \(-2\*\*63 <= label < 2\*\*63\)"),
    ("1e19", r"'1e19' does not fit in a 64-bit integer \(-2\*\*63"),
    ("2.5", "'2.5' is not a whole number"),
    ("inf", "'inf' is not a whole number"),
])
def test_csv_labels_out_of_range_are_refused_naming_file_line_and_limit(tmp_path, cell, problem):
    (tmp_path / "signatures.csv").write_text("0.1\n0.2\n")
    (tmp_path / "labels.csv").write_text(f"0\n{cell}\n")
    with pytest.raises(ValueError, match=rf"labels: .*labels.csv:2: not a row of numbers: {problem}"):
        Dataset.from_csv(signatures=tmp_path / "signatures.csv", labels=tmp_path / "labels.csv")


def test_dataset_labels_at_the_int64_limits_are_exact_and_past_them_named_exactly():
    assert Dataset(labels=[2 ** 63 - 1, -2 ** 63]).labels.tolist() == [2 ** 63 - 1, -2 ** 63]  # 2**63 - 1 was refused
    with pytest.raises(ValueError, match=rf"labels\[1\] = {2 ** 63} does not fit in a 64-bit integer"):
        Dataset(labels=[-1, 2 ** 63])  # numpy made floats of these: the message named 9.223372036854776e+18
    with pytest.raises(ValueError, match=rf"labels\[0\] = {2 ** 70} does not fit"):
        Dataset(labels=[2 ** 70, 0])  # was "labels must be integers, got dtype object"


def test_a_typo_in_a_one_column_file_is_an_error_not_a_header(tmp_path):
    path = tmp_path / "one.csv"
    path.write_text("O.5\n0.2\n0.3\n")  # the row was dropped as a header: N = 2
    with pytest.raises(ValueError, match=r"signatures: .*one.csv:1: not a row of numbers: 'O.5' is not a number"):
        Dataset.from_csv(signatures=path)


@pytest.mark.parametrize("header", ["signature", "s_0,s 1", "\ufeffdtheta (rad),Δx [m]"])
def test_a_header_of_names_is_skipped(tmp_path, header):
    path = tmp_path / "signatures.csv"
    width = header.count(",") + 1
    path.write_text(f"{header}\n" + "\n".join([",".join(["0.5"] * width)] * 2))
    assert Dataset.from_csv(signatures=path).signatures.tolist() == [[0.5] * width] * 2


def test_a_header_must_name_every_column_and_no_number_is_a_header(tmp_path):
    path = tmp_path / "odometry.csv"
    path.write_text("dx,dy\n1,0,0\n1,0,0\n")
    with pytest.raises(ValueError, match="odometry.csv:1: the header names 2 columns, the rows have 3"):
        Dataset.from_csv(odometry=path)
    path = tmp_path / "signatures.csv"
    path.write_text("nan\n0.1\n")  # "nan" reads as a number: not a name
    with pytest.raises(ValueError, match="signatures.csv:1: not a row of numbers: 'nan' is not a finite number"):
        Dataset.from_csv(signatures=path)


def test_complex_signatures_are_refused_everywhere(tmp_path):
    spectrum = np.fft.fft(np.arange(12.0).reshape(3, 4))  # an FFT without abs(): the imaginary part was dropped
    with pytest.raises(ValueError, match="signatures must be real numbers, got a complex array"):
        Dataset(signatures=spectrum)
    path = tmp_path / "signatures.csv"
    path.write_text("1.0,(1+2j)\n2.0,3.0\n")
    with pytest.raises(ValueError, match=r"signatures.csv:1: not a row of numbers: '\(1\+2j\)' is a complex number"):
        Dataset.from_csv(signatures=path)
    path.write_text("1+2j\n0.5\n")  # was a header: the row was lost
    with pytest.raises(ValueError, match=r"signatures.csv:1: .*'1\+2j' is a complex number"):
        Dataset.from_csv(signatures=path)
    stored = tmp_path / "run.npz"
    np.savez(stored, signatures=spectrum, meta=json.dumps({}))
    with pytest.raises(ValueError, match=rf"{stored}: signatures must be real numbers"):
        Dataset.load(stored)


def forged(path, kind, member, shape, compression=zipfile.ZIP_STORED):
    """A valid ``kind`` file at ``path`` whose ``member`` is replaced by an .npy header declaring ``shape`` (float64)
    over 64 zero bytes."""
    valid = path.with_name("valid.npz")
    if kind == "dataset":
        Dataset(signatures=np.ones((4, 3)), labels=[0, 1, 0, 2]).save(valid)
    else:
        ptm.PTM([[0, 0, 1], [0, 1, 2]], [0.25, 0.75], "exact").save(valid)
    header = io.BytesIO()
    npy.write_array_header_1_0(header, {"descr": "<f8", "fortran_order": False, "shape": shape})
    with zipfile.ZipFile(valid) as source, zipfile.ZipFile(path, "w", compression) as target:
        for name in source.namelist():
            target.writestr(name, header.getvalue() + bytes(64) if name == member else source.read(name))
    valid.unlink()
    return path


@pytest.mark.parametrize("compression", [zipfile.ZIP_STORED, zipfile.ZIP_DEFLATED])
@pytest.mark.parametrize("kind, member", [("dataset", "signatures.npy"), ("PTM", "partitions.npy")])
def test_a_forged_npz_header_is_refused_before_allocating(tmp_path, kind, member, compression):
    path = forged(tmp_path / "run.npz", kind, member, (100_000, 1_000_000), compression)
    load = Dataset.load if kind == "dataset" else ptm.PTM.load
    with pytest.raises(ValueError, match=rf"{path} is not a readable {kind} file \(ValueError: member '{member}' "
                                         r"declares a float64 array of shape \(100000, 1000000\) "
                                         r"\(800,000,000,000 bytes\), more than its \d+ bytes can hold\)"):
        load(path)  # was a MemoryError: "Unable to allocate 745. GiB"


def test_a_forged_zip_size_is_bounded_by_what_its_compressed_bytes_can_hold(tmp_path):
    path = forged(tmp_path / "run.npz", "dataset", "signatures.npy", (2 ** 23,), zipfile.ZIP_DEFLATED)
    content = bytearray(path.read_bytes())
    with zipfile.ZipFile(path) as archive:
        info = archive.getinfo("signatures.npy")
    directory = content.index(b"PK\x01\x02")  # the central directory's first entry, the member written first
    assert content[directory + 46:].startswith(b"signatures.npy")
    content[directory + 24:directory + 28] = (2 ** 32 - 1).to_bytes(4, "little")  # claims 4 GiB uncompressed
    path.write_bytes(bytes(content))
    with pytest.raises(ValueError, match=f"member 'signatures.npy' declares .* more than its "
                                         f"{1032 * info.compress_size:,} bytes can hold"):
        Dataset.load(path)  # numpy allocated the 64 MiB it declares, then ran out of data (EOFError)


def test_ptm_bench_show_names_a_forged_file_in_one_line(tmp_path, capsys):
    from ptm_bench.cli import main

    path = forged(tmp_path / "run.npz", "dataset", "signatures.npy", (100_000, 1_000_000))
    assert main(["show", str(path), "--out", str(tmp_path / "run.png")]) == 2  # was a MemoryError traceback
    err = capsys.readouterr().err
    assert f"{path} is not a readable dataset file" in err and "declares" in err and "Traceback" not in err
