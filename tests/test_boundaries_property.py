"""Property-based tests of the library's boundaries (issue 10): every input works or raises ValueError.

Random label sequences for partitions and PTMs, random shapes and values for ``Dataset``, random and
damaged bytes for ``Dataset.load`` and ``PTM.load``: never another exception type, never a hang, never a
silently wrong answer (what is accepted is checked against a plain-Python reference). The samplers' settings
(``ptm.SamplerOptions``, ``n_samples``) take any value or refuse it with a ``ValueError`` or ``TypeError`` naming
the setting, never an ``OverflowError`` from deep inside. The CSV reader (``Dataset.from_csv``) reads any text exactly
or refuses it naming the file, and an ``.npz`` whose headers are forged loads or is refused naming the file, never
after allocating what it declares (issue 47).
"""

import io
import tempfile
import zipfile
from decimal import Decimal
from fractions import Fraction
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp
from numpy.lib import format as npy

import ptm
from ptm.partitions import Partition, canonical
from ptm.se2 import wrap_angle
from ptm._validation import count

SETTINGS = settings(max_examples=150, deadline=None, database=None, suppress_health_check=[HealthCheck.too_slow])

labels = st.one_of(
    st.integers(min_value=-(2 ** 70), max_value=2 ** 70),
    st.floats(allow_nan=True, allow_infinity=True),
    st.booleans(),
    st.text(max_size=2),
    st.none(),
)


def reference_canonical(values):
    renumber = {}
    return tuple(renumber.setdefault(value, len(renumber)) for value in values)


@SETTINGS
@given(st.lists(labels, max_size=12))
def test_any_label_sequence_is_a_partition_or_a_value_error(values):
    try:
        rgs = canonical(values)
    except ValueError:
        assert any(isinstance(v, (bool, str, type(None))) or (isinstance(v, float) and not float(v).is_integer())
                   for v in values)
        return
    assert rgs == reference_canonical([int(v) for v in values])
    if values:
        assert Partition.from_labels(values).labels == rgs


@SETTINGS
@given(hnp.arrays(st.sampled_from([np.int64, np.int16, np.uint64, np.float64]),
                  hnp.array_shapes(min_dims=1, max_dims=3, max_side=6)),
       st.lists(st.floats(allow_nan=True, allow_infinity=True), min_size=1, max_size=6))
def test_any_array_is_a_ptm_or_a_value_error(partitions, probabilities):
    probabilities = np.asarray(probabilities[: len(partitions)] if partitions.ndim == 2 else probabilities)
    try:
        result = ptm.PTM(partitions, probabilities, "test")
    except ValueError:
        return
    # accepted: distinct canonical rows, a normalised distribution, answers that agree with them
    rows = [tuple(int(x) for x in row) for row in partitions]
    assert all(reference_canonical(row) == row for row in rows) and len(set(rows)) == len(rows)
    assert result.probabilities.sum() == pytest.approx(1.0)
    total = sum(Fraction(p) for p in probabilities)  # exact: 1e308 + 1e308 overflows a float sum
    for row, p in zip(rows, probabilities):
        assert result.probability(row) == pytest.approx(float(Fraction(p) / total))
    best = max(zip(rows, probabilities), key=lambda item: (item[1], [-x for x in item[0]]))[0]
    assert result.map() == best


floats = st.floats(allow_nan=True, allow_infinity=True, width=64)


@SETTINGS
@given(st.integers(0, 5), st.integers(0, 4), st.data())
def test_any_fields_are_a_dataset_or_a_value_error(n, k, data):
    def maybe_array(shape):
        if not data.draw(st.booleans()):
            return None
        shape = data.draw(st.sampled_from([shape, (n + 1,) + shape[1:], shape[:-1] or (1,)]))
        return data.draw(hnp.arrays(np.float64, shape, elements=floats))

    fields = {"odometry": maybe_array((max(n - 1, 0), 3)), "signatures": maybe_array((n, k)),
              "labels": maybe_array((n,)), "true_poses": maybe_array((n, 3))}
    try:
        dataset = ptm.Dataset(**fields)
    except ValueError:
        return
    for name, value in fields.items():
        stored = getattr(dataset, name)
        if value is not None and name != "odometry":  # odometry angles are wrapped on construction
            np.testing.assert_array_equal(stored, value)


def valid_file(kind: str, folder: Path) -> Path:
    if kind == "dataset":
        return ptm.Dataset(signatures=np.arange(12.0).reshape(4, 3), labels=[0, 1, 0, 2],
                           meta={"world": "x"}).save(folder / "data.npz")
    return ptm.PTM([[0, 0, 1], [0, 1, 2]], [0.25, 0.75], "exact", {"steps": 3}).save(folder / "data.npz")


@SETTINGS
@given(st.sampled_from(["dataset", "ptm"]), st.one_of(
    st.tuples(st.just("bytes"), st.binary(max_size=300)),
    st.tuples(st.just("truncate"), st.integers(min_value=0, max_value=2000)),
    st.tuples(st.just("flip"), st.lists(st.tuples(st.integers(0, 2000), st.integers(1, 255)), min_size=1, max_size=4)),
))
def test_any_bytes_load_or_raise_a_value_error(kind, damage):
    load = ptm.Dataset.load if kind == "dataset" else ptm.PTM.load
    with tempfile.TemporaryDirectory() as folder:
        path = valid_file(kind, Path(folder))
        content = bytearray(path.read_bytes())
        how, what = damage
        if how == "bytes":
            content = bytearray(what)
        elif how == "truncate":
            content = content[: what % (len(content) + 1)]
        else:
            for position, xor in what:
                content[position % len(content)] ^= xor
        path.write_bytes(bytes(content))
        try:
            load(path)
        except ValueError as error:
            assert str(path) in str(error)


anything = st.one_of(
    st.none(), st.booleans(), st.integers(min_value=-(2 ** 70), max_value=2 ** 70),
    st.floats(allow_nan=True, allow_infinity=True), st.text(max_size=3), st.lists(st.integers(0, 3), max_size=4),
)
WHOLE_FIELDS = {"burn_in": 0, "thin": 1, "chains": 1, "max_doublings": 0}


@SETTINGS
@given(st.sampled_from(sorted(WHOLE_FIELDS) + ["unscreened_share", "delayed_acceptance", "start", "moves"]), anything)
def test_any_sampler_setting_is_kept_valid_or_refused_by_name(field, value):
    try:
        options = ptm.SamplerOptions(**{field: value})
    except (ValueError, TypeError) as error:
        assert field in str(error)
        return
    kept = getattr(options, field)
    if field in WHOLE_FIELDS:
        assert kept is None if field == "burn_in" and value is None else (isinstance(kept, int) and kept == value
                                                                           and kept >= WHOLE_FIELDS[field])
    elif field == "unscreened_share":
        assert 0.0 <= kept <= 1.0 and kept == value
    elif field == "delayed_acceptance":
        assert kept is value
    elif field == "start":
        assert kept in ("smc", "dispersed") or kept == canonical(value)
    else:
        assert kept in ("auto", "default", "paper", "guided")


@SETTINGS
@given(anything)
def test_any_count_is_a_whole_number_or_refused_by_name(value):
    try:
        number = count("n_samples", value, 1)
    except (ValueError, TypeError) as error:
        assert "n_samples" in str(error)
        return
    assert isinstance(number, int) and number == value and number >= 1


@pytest.mark.parametrize("value", [float("inf"), None, "100", float("nan"), 2.5, True])
@pytest.mark.parametrize("sampler", [ptm.mcmc, ptm.tempered_mcmc])
def test_a_bad_sample_count_is_refused_before_sampling(sampler, value):
    posterior = ptm.Posterior(ptm.Dataset(labels=[0, 1]), ptm.PoissonPrior(1.0))
    with pytest.raises((ValueError, TypeError), match="n_samples"):
        sampler(posterior, value)


# -- issue 47: the CSV reader and forged .npz headers ----------------------------------------------------------------

FEW = settings(max_examples=60, deadline=None, database=None, suppress_health_check=[HealthCheck.too_slow])

names_and_typos = st.sampled_from(["O.5", "3O", "l.5", "dx", "x (m)", "Δθ", "s_0 [a.u.]", "nan", "", " 1 ", "1e6",
                                   "3.0", "2.5", "-inf"])
csv_cells = st.one_of(
    st.floats(allow_nan=True, allow_infinity=True).map(repr),
    st.integers(min_value=-(2 ** 70), max_value=2 ** 70).map(str),
    (st.integers(2 ** 53, 2 ** 63 - 1) | st.integers(-(2 ** 63), -(2 ** 53))).map(str),  # past a float's exact integers
    st.complex_numbers(max_magnitude=1e6).map(str),
    names_and_typos,
    st.text(alphabet="0123456789.eE+-jxO θ()_", min_size=1, max_size=6),
)


@FEW
@given(st.sampled_from(["odometry", "signatures", "labels"]), st.integers(1, 3),
       st.lists(names_and_typos | csv_cells, min_size=3, max_size=3),
       st.lists(st.lists(csv_cells, min_size=3, max_size=3), max_size=4),
       st.booleans(), st.sampled_from(["\n", "\r\n"]))
def test_any_csv_text_is_read_exactly_or_refused_naming_the_file(field, width, first, rows, bom, newline):
    width = {"odometry": 3, "labels": 1}.get(field, width)
    rows = [row[:width] for row in [first] + rows]
    lines = [",".join(row) for row in rows]
    with tempfile.TemporaryDirectory() as folder:
        path = Path(folder) / f"{field}.csv"
        path.write_text(("\ufeff" if bom else "") + newline.join(lines) + newline, encoding="utf-8", newline="")
        data_rows = [row for row, line in zip(rows, lines) if line.strip()]
        files = {field: path}
        if field == "labels":  # labels come with signatures, one row each
            files["signatures"] = Path(folder) / "signatures.csv"
            files["signatures"].write_text("0.5\n" * max(len(data_rows), 1))
        try:
            dataset = ptm.Dataset.from_csv(**files)
        except ValueError as error:
            assert str(path) in str(error) or (field == "labels" and "labels" in str(error))
            return
    stored = dataset.labels if field == "labels" else getattr(dataset, field)
    dropped = len(data_rows) - len(stored)
    # only a first line of names is a header: each starts with a letter, with no decimal point before its unit
    assert dropped in (0, 1) and (dropped == 0 or (lines[0].strip() and all(
        (cell[0].isalpha() or cell[0] == "_") and "." not in cell.split("(")[0].split("[")[0] and not is_float(cell)
        for cell in rows[0])))
    for row, values in zip(data_rows[dropped:], stored.reshape(len(stored), -1)):
        if field == "labels":
            assert values.tolist() == [int(Decimal(row[0].strip()))]  # exactly, never through a float
        else:
            expected = [float(cell) for cell in row]
            if field == "odometry":
                expected[2] = float(wrap_angle(expected[2]))
            assert values.tolist() == expected


def is_float(cell: str) -> bool:
    try:
        float(cell)
    except ValueError:
        return False
    return True


def central_directory_entry(content: bytes, member: str) -> int:
    """Offset of ``member``'s entry in the zip's central directory."""
    offset = content.index(b"PK\x01\x02")
    while content[offset + 46:offset + 46 + len(member)] != member.encode():
        offset = content.index(b"PK\x01\x02", offset + 1)
    return offset


@FEW
@given(st.sampled_from(["dataset", "ptm"]), st.data(),
       st.tuples(st.one_of(st.integers(0, 6), st.integers(-(2 ** 65), 2 ** 65)), st.integers(0, 6)).map(tuple)
       | st.lists(st.integers(0, 2 ** 40), max_size=3).map(tuple),
       st.sampled_from(["<f8", "<i8", "|u1", "<c16", "|V0", "<U3", "|O", "|b1", ">f4", [("a", "<f8")]]),
       st.sampled_from([npy.write_array_header_1_0, npy.write_array_header_2_0]),
       st.binary(max_size=200), st.sampled_from([zipfile.ZIP_STORED, zipfile.ZIP_DEFLATED]),
       st.none() | st.integers(0, 2 ** 32 - 1))
def test_an_npz_with_a_forged_header_loads_or_raises_a_value_error_naming_it(kind, data, shape, descr, write_header,
                                                                            payload, compression, claimed_size):
    load = ptm.Dataset.load if kind == "dataset" else ptm.PTM.load
    with tempfile.TemporaryDirectory() as folder:
        valid = valid_file(kind, Path(folder))
        path = Path(folder) / "forged.npz"
        with zipfile.ZipFile(valid) as source:
            names = source.namelist()
            member = data.draw(st.sampled_from(names))
            header = io.BytesIO()
            write_header(header, {"descr": descr, "fortran_order": False, "shape": shape})
            with zipfile.ZipFile(path, "w", compression) as target:
                for name in names:
                    target.writestr(name, header.getvalue() + payload if name == member else source.read(name))
        if claimed_size is not None:  # the zip directory's uncompressed size forged too
            content = bytearray(path.read_bytes())
            entry = central_directory_entry(bytes(content), member)
            content[entry + 24:entry + 28] = claimed_size.to_bytes(4, "little")
            path.write_bytes(bytes(content))
        try:
            load(path)
        except ValueError as error:
            assert str(path) in str(error)


@FEW
@given(st.sampled_from(["odometry", "signatures", "true_poses"]),
       hnp.arrays(np.complex128, st.tuples(st.integers(1, 4), st.just(3)),
                  elements=st.complex_numbers(allow_nan=True, allow_infinity=True)))
def test_a_complex_field_is_refused_by_name(field, values):
    arrays = {"odometry": values[1:], "signatures": values, "true_poses": values}
    fields = {field: arrays[field]} if field != "odometry" else {"odometry": arrays["odometry"],
                                                                 "labels": np.zeros(len(values), dtype=int)}
    with pytest.raises(ValueError, match=f"{field} must be real numbers"):
        ptm.Dataset(**fields)
