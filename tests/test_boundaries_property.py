"""Property-based tests of the library's boundaries (issue 10): every input works or raises ValueError.

Random label sequences for partitions and PTMs, random shapes and values for ``Dataset``, random and
damaged bytes for ``Dataset.load`` and ``PTM.load``: never another exception type, never a hang, never a
silently wrong answer (what is accepted is checked against a plain-Python reference). The samplers' settings
(``ptm.SamplerOptions``, ``n_samples``) take any value or refuse it with a ``ValueError`` or ``TypeError`` naming
the setting, never an ``OverflowError`` from deep inside.
"""

import tempfile
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

import ptm
from ptm.partitions import Partition, canonical
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
    total = probabilities.sum()
    for row, p in zip(rows, probabilities):
        assert result.probability(row) == pytest.approx(p / total)
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
