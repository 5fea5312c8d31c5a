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


# -- issue 47: the library's validators (ValueError for a bad value, TypeError for a wrong type, argument named) --

SQUARE = np.tile([2.0, 0.0, np.pi / 2], (4, 1))  # a 2 m square, back at the start


def square_covariances(row: int, scale: float) -> np.ndarray:
    covariances = np.tile(np.diag([0.01, 0.01, 0.0025]), (4, 1, 1))
    covariances[row] = scale * np.eye(3)
    return covariances


@pytest.mark.parametrize("row, scale", [(0, 1e-100), (2, 1e-300), (3, 1e-30), (1, 1e50)])
def test_an_absurd_odometry_covariance_is_refused_naming_the_row(row, scale):
    dataset = ptm.Dataset(odometry=SQUARE, odometry_cov=square_covariances(row, scale))
    # was bound: at 1e-100 seven topologies at 1/7, the truth absent; at 1e-300 a log-probability of +1.5e253
    with pytest.raises(ValueError, match=rf"odometry_cov\[{row}\] has standard deviations .* STD_RANGE"):
        ptm.OdometryModel().bind(dataset)


def test_standard_deviations_far_below_any_odometry_but_above_its_rounding_are_kept_and_exact():
    def closing_the_loop(scale):  # log P(O | loop closed) - log P(O | all distinct): the same at any small scale
        dataset = ptm.Dataset(odometry=SQUARE + [0.03, -0.02, 0.01], odometry_cov=np.tile(scale * np.eye(3), (4, 1, 1)))
        term = ptm.OdometryModel(sigma_topology=0.1, penalty_radius=1.0).bind(dataset)
        return term.log_likelihood([0, 1, 2, 3, 0]) - term.log_likelihood([0, 1, 2, 3, 4])

    assert closing_the_loop(1e-20) == pytest.approx(closing_the_loop(1e-12), abs=0.01)  # 1e-10 m: the limit is 6e-12


@pytest.mark.parametrize("field, value", [("sigma_xy", 1e-200), ("sigma_theta", 1e-13), ("sigma_topology", 1e-13),
                                          ("sigma_topology", 1e8)])
def test_model_deviations_outside_the_range_are_refused_naming_them(field, value):
    with pytest.raises(ValueError, match=rf"{field} = .* STD_RANGE"):
        ptm.OdometryModel(**{field: value}).bind(ptm.Dataset(odometry=SQUARE))


def tiny_posterior():
    return ptm.Posterior(ptm.Dataset(signatures=[[0.3, 0.1], [0.4, 0.05], [0.31, 0.11]]), ptm.PoissonPrior(2.0),
                         [ptm.AppearanceModel(0.3, 0.05, 3.0, 2e-4)])


@pytest.mark.parametrize("call, error, name", [
    (lambda p: ptm.exact_posterior(p, max_n="12"), TypeError, "max_n"),  # was TypeError: '>' not supported ...
    (lambda p: ptm.exact_posterior(None), TypeError, "posterior"),  # was AttributeError
    (lambda p: ptm.exact_posterior(p, skip="no"), TypeError, "skip"),  # was taken as True
    (lambda p: ptm.exact_posterior(p, max_global_evaluations=-1), ValueError, "max_global_evaluations"),
    (lambda p: ptm.mcmc(None, 10), TypeError, "posterior"),
    (lambda p: ptm.mcmc(p, 10, seed="x"), TypeError, "seed"),
    (lambda p: ptm.mcmc(p, 10, seed=-1), ValueError, "seed"),
    (lambda p: ptm.mcmc(p, 10 ** 300), ValueError, "n_samples"),  # was "Maximum allowed dimension exceeded"
    (lambda p: ptm.mcmc(p, 10, chains=10 ** 300), ValueError, "chains"),  # was OverflowError
    (lambda p: ptm.tempered_mcmc(None, 10), TypeError, "posterior"),
    (lambda p: ptm.tempered_mcmc(p, 10, temperatures="hot"), TypeError, "temperatures"),
    (lambda p: ptm.tempered_mcmc(p, 10, seed=1.5), TypeError, "seed"),
    (lambda p: ptm.OdometryModel(sigma_xy=1e300), ValueError, "sigma_xy"),  # was OverflowError on binding
    (lambda p: ptm.OdometryModel(sigma_xy="0.1"), TypeError, "sigma_xy"),
    (lambda p: ptm.OdometryModel(n_importance=float("inf")), ValueError, "n_importance"),  # was OverflowError
    (lambda p: ptm.OdometryModel(n_importance=None), TypeError, "n_importance"),
    (lambda p: ptm.OdometryModel(max_penalty=1e308), ValueError, "max_penalty"),  # was "array must not contain infs"
    (lambda p: ptm.OdometryModel(seed="x"), TypeError, "seed"),
    (lambda p: ptm.OdometryModel(sparse_above=float("inf")), ValueError, "sparse_above"),
    (lambda p: ptm.OdometryModel(cache_size="x"), TypeError, "cache_size"),
    (lambda p: ptm.PoissonPrior("2"), TypeError, "rate"),
    (lambda p: ptm.PoissonPrior(None), TypeError, "rate"),
    (lambda p: ptm.PoissonPrior(1e300), ValueError, "rate"),  # was accepted; log_prob then hung
    (lambda p: ptm.AppearanceModel.fit(3), TypeError, "datasets"),
    (lambda p: ptm.AppearanceModel.fit([3]), TypeError, r"datasets\[0\]"),
    (lambda p: ptm.JointAppearanceModel.fit(None), TypeError, "datasets"),
    (lambda p: ptm.AppearanceModel(None, 1.0, 3.0, 1.0), TypeError, "mu"),
    (lambda p: ptm.AppearanceModel(0.0, 1.0, 1.7e308, 1.0), ValueError, "alpha"),  # was NaN from the term
    (lambda p: ptm.AppearanceModel(0.0, 1.0, 3.0, 1.0, outlier_share="x"), TypeError, "outlier_share"),
    (lambda p: ptm.JointAppearanceModel([0.0], 1.0, "many", [[1.0]]), TypeError, "nu"),
    (lambda p: ptm.OnlineMapper(ptm.PoissonPrior(2.0), [], screen="often"), TypeError, "screen"),
    (lambda p: ptm.OnlineMapper(ptm.PoissonPrior(2.0), 3), TypeError, "models"),
    (lambda p: ptm.OnlineMapper(ptm.PoissonPrior(2.0), [], seed=-1), ValueError, "seed"),
])
def test_a_library_argument_of_the_wrong_type_or_value_is_refused_by_name(call, error, name):
    with pytest.raises(error, match=name):
        call(tiny_posterior())


def labelled_runs():
    rng = np.random.default_rng(3)
    places = rng.normal(0.0, 1.0, (3, 2))
    return [ptm.Dataset(signatures=places[labels] + rng.normal(0.0, 0.1, (6, 2)), labels=labels)
            for labels in (np.array([0, 1, 0, 2, 1, 2]), np.array([2, 0, 2, 1, 0, 1]))]


@pytest.mark.parametrize("model", [ptm.AppearanceModel, ptm.JointAppearanceModel])
def test_a_fit_takes_any_iterable_of_datasets(model):
    expected = repr(model.fit(labelled_runs()))
    assert repr(model.fit(iter(labelled_runs()))) == expected  # was AttributeError: no attribute 'signatures'
    assert repr(model.fit(run for run in labelled_runs())) == expected


def refuse_enumeration(posterior, monkeypatch):
    """The posterior's set scores raise: a test that reached the enumeration fails at once instead of running it."""
    def enumerating(block):
        raise AssertionError("the enumeration started")

    monkeypatch.setattr(posterior, "block_score", enumerating)
    return posterior


def test_an_exact_enumeration_past_the_default_limit_warns_with_its_estimate_before_it_starts(monkeypatch):
    posterior = refuse_enumeration(ptm.Posterior(ptm.Dataset(labels=np.zeros(13, dtype=int)), ptm.PoissonPrior(2.0)),
                                   monkeypatch)
    with pytest.warns(UserWarning, match=r"N=13 detections visits 27,644,437 partitions: about 5 min and 0.581 GB"):
        with pytest.raises(AssertionError, match="the enumeration started"):  # was: minutes without a word
            ptm.exact_posterior(posterior, max_n=13)


def test_an_exact_enumeration_beyond_max_n_limit_is_refused_whatever_max_n_says(monkeypatch):
    posterior = refuse_enumeration(ptm.Posterior(ptm.Dataset(labels=np.zeros(15, dtype=int)), ptm.PoissonPrior(2.0)),
                                   monkeypatch)
    with pytest.raises(ValueError, match=r"1,382,958,545 partitions, beyond MAX_N = 14 .* about 3.84 h and 31.8 GB"):
        ptm.exact_posterior(posterior, max_n=20)
