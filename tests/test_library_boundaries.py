"""The library at its boundaries (issue 10): CSV imports, corrupted files, labels, huge and tied inputs.

Every bad input is a ``ValueError`` naming what is wrong; nothing is silently dropped or wrapped round.
"""

import json

import numpy as np
import pytest

import ptm


# -- CSV import ------------------------------------------------------------------------------------------------

def test_a_byte_order_mark_does_not_turn_the_first_row_into_a_header(tmp_path):
    path = tmp_path / "signatures.csv"
    path.write_bytes("1.0,2.0\n3.0,4.0\n5.0,6.0\n".encode("utf-8-sig"))  # as Excel writes it
    dataset = ptm.Dataset.from_csv(signatures=path)
    assert dataset.n == 3
    np.testing.assert_array_equal(dataset.signatures[0], [1.0, 2.0])


def test_a_typo_in_the_first_row_is_an_error_naming_file_line_and_cell(tmp_path):
    path = tmp_path / "signatures.csv"
    path.write_text("3O,2.0\n3.0,4.0\n5.0,6.0\n")
    with pytest.raises(ValueError, match=r"signatures: .*signatures.csv:1: not a row of numbers: '3O' is not a number"):
        ptm.Dataset.from_csv(signatures=path)


def test_a_header_of_names_is_still_skipped(tmp_path):
    path = tmp_path / "odometry.csv"
    path.write_bytes("\ufeffdx,dy,dtheta\n1,0,0\n1,0,0.1\n".encode())
    assert ptm.Dataset.from_csv(odometry=path).n == 3


def test_a_file_that_is_not_text_is_an_error_naming_it(tmp_path):
    path = tmp_path / "signatures.csv"
    path.write_bytes(b"1,2\n\xff\xfe,3\n")
    with pytest.raises(ValueError, match="signatures.csv is not UTF-8 text"):
        ptm.Dataset.from_csv(signatures=path)


# -- corrupted dataset files -------------------------------------------------------------------------------------

def write_corrupted(kind: str, path):
    if kind == "truncated":
        ptm.Dataset(signatures=np.arange(12.0).reshape(4, 3)).save(path)
        path.write_bytes(path.read_bytes()[:-40])
    elif kind == "renamed .npy":
        np.save(path.with_suffix(".npy"), np.arange(4.0))
        path.with_suffix(".npy").rename(path)
    elif kind == "bad meta JSON":
        np.savez(path, signatures=np.arange(12.0).reshape(4, 3), meta=np.array('{"world": "office"'))
    elif kind == "meta not an object":
        np.savez(path, signatures=np.arange(12.0).reshape(4, 3), meta=np.array(json.dumps([1, 2])))
    elif kind == "wrong shapes":
        np.savez(path, signatures=np.arange(12.0).reshape(4, 3), labels=np.arange(3))
    else:
        path.write_bytes(b"PK\x03\x04 not really a zip")


@pytest.mark.parametrize("kind", ["truncated", "renamed .npy", "bad meta JSON", "meta not an object", "wrong shapes",
                                  "garbage"])
def test_a_corrupted_dataset_file_is_a_value_error_naming_it(tmp_path, kind):
    path = tmp_path / "run.npz"
    write_corrupted(kind, path)
    with pytest.raises(ValueError, match=str(path)):
        ptm.Dataset.load(path)


def test_ptm_bench_show_reports_a_corrupted_file_in_one_line(tmp_path, capsys):
    from ptm_bench.cli import main

    path = tmp_path / "run.npz"
    write_corrupted("truncated", path)
    assert main(["show", str(path), "--out", str(tmp_path / "run.png")]) == 2
    err = capsys.readouterr().err
    assert f"{path} is not a readable dataset file" in err and "Traceback" not in err


# -- labels: canonical, distinct, never wrapped round -------------------------------------------------------------

def test_a_ptm_refuses_non_canonical_or_repeated_partitions():
    with pytest.raises(ValueError, match=r"canonical labels .* row 0 is \(5, 5, 7\)"):
        ptm.PTM([[5, 5, 7], [0, 0, 1]], [0.5, 0.5], "mcmc")  # was accepted: probability([0, 0, 1]) gave 0.5
    with pytest.raises(ValueError, match=r"row 1 is \(1, 0, 0\)"):
        ptm.PTM([[0, 0, 1], [1, 0, 0]], [0.5, 0.5], "mcmc")
    with pytest.raises(ValueError, match=r"row 0 is \(0, 2, 1\)"):
        ptm.PTM([[0, 2, 1]], [1.0], "mcmc")
    with pytest.raises(ValueError, match="distinct; rows 0 and 1 are equal"):
        ptm.PTM([[0, 0, 1], [0, 0, 1]], [0.5, 0.5], "mcmc")
    with pytest.raises(ValueError, match="not whole numbers"):
        ptm.PTM([[0.0, 0.5]], [1.0], "mcmc")
    with pytest.raises(ValueError, match="canonical labels"):
        ptm.PTM(np.array([[0, 1e20]]), [1.0], "mcmc")
    with pytest.raises(ValueError, match="canonical labels"):
        ptm.PTM(np.array([[0, 2 ** 63]], dtype=np.uint64), [1.0], "mcmc")
    result = ptm.PTM(np.array([[0.0, 0.0, 1.0], [0.0, 1.0, 2.0]]), [0.5, 0.5], "mcmc")  # whole floats are fine
    assert result.probability([0, 0, 1]) == 0.5 and result.expected_num_places() == 2.5


def tampered(tmp_path, partitions):
    path = ptm.PTM([[0, 0, 1], [0, 1, 2]], [0.5, 0.5], "exact").save(tmp_path / "result.npz")
    with np.load(path) as archive:
        contents = dict(archive)
    contents["partitions"] = np.asarray(partitions)
    np.savez(path, **contents)
    return path


@pytest.mark.parametrize("partitions", [[[5, 5, 7], [0, 0, 1]], [[0, 0, 40000], [0, 1, 2]], [[0, 0, 1], [0, 0, 1]]])
def test_a_tampered_ptm_file_is_refused_naming_it(tmp_path, partitions):
    path = tampered(tmp_path, np.asarray(partitions, dtype=np.int64))
    with pytest.raises(ValueError, match=rf"{path}: PTM partitions must be"):
        ptm.PTM.load(path)


@pytest.mark.parametrize("kind", ["truncated", "renamed .npy", "garbage"])
def test_a_corrupted_ptm_file_is_a_value_error_naming_it(tmp_path, kind):
    path = tmp_path / "result.npz"
    if kind == "truncated":
        ptm.PTM([[0, 0, 1], [0, 1, 2]], [0.5, 0.5], "exact").save(path)
        path.write_bytes(path.read_bytes()[:-30])
    else:
        write_corrupted(kind, path)
    with pytest.raises(ValueError, match=rf"{path} is not a readable PTM file"):
        ptm.PTM.load(path)


def test_dataset_labels_that_overflow_are_refused():
    with pytest.raises(ValueError, match="64-bit"):
        ptm.Dataset(signatures=np.ones((2, 3)), labels=[1e20, 2e20])  # both became -2**63: one place
    with pytest.raises(ValueError, match="64-bit"):
        ptm.Dataset(signatures=np.ones((2, 3)), labels=np.array([0, 2 ** 63], dtype=np.uint64))
    assert ptm.Dataset(signatures=np.ones((2, 3)), labels=[1e15, 2.0]).labels.tolist() == [10 ** 15, 2]


# -- the MAP: one deterministic tie-break, shared with scoring -----------------------------------------------------

@pytest.mark.parametrize("rows", [[[0, 1, 2], [0, 0, 0]], [[0, 0, 0], [0, 1, 2]]])
def test_map_ties_go_to_the_lexicographically_smallest_labels_as_in_scoring(rows):
    from ptm_bench.evaluation import scoring

    result = ptm.PTM(rows, [0.5, 0.5], "mcmc")
    assert result.map() == (0, 0, 0)  # was (0, 1, 2) when listed first
    assert result.top(2) == [((0, 0, 0), 0.5), ((0, 1, 2), 0.5)]
    assert scoring.score(result, (0, 0, 0))["map_correct"]
    assert scoring.score(dict(reversed(result.top(2))), (0, 0, 0))["map_correct"]
