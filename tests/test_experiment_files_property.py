"""Property-based tests of experiment files (issue 47): any value at any key loads or is refused naming the key.

``parse_experiment`` takes a config as TOML reads it. Here one key of a valid config (top level, ``[sweep]``
and its lists and world tables, each model section, a variant and its overrides, ``[checks]``, ``[paper]``) gets
a value of any type: wrong types, NaN and infinities, huge and tiny numbers, control characters, lists, tables,
dates. The only outcomes are a loaded experiment or a ``ValueError`` whose message names the key's path; never
another exception. A section value that loads is the one the config gave, never a silently coerced one.
"""

import copy
import datetime
import math

from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st

from ptm_bench.evaluation.experiment import parse_experiment
from ptm_bench.evaluation.settings import DEFAULTS

SETTINGS = settings(max_examples=300, deadline=None, database=None, suppress_health_check=[HealthCheck.too_slow])

MODEL_SECTIONS = ("inference", "odometry", "appearance")
BASE = {
    "name": "fuzz",
    "description": "a valid config whose keys the tests replace one at a time",
    "sweep": {"worlds": ["short_loop", {"generator": "corridor_grid", "name": "grid", "rows": 2, "cols": 3,
                                       "loops": 1, "place_density": 0.5},
                         {"dataset": "recorded.npz", "name": "recorded", "calibration": ["other.npz"]}],
              "aliasing": [0.0], "noise": [1.0], "seeds": [0, 1], "calibration_seeds": [10]},
    "inference": {"n_samples": 100},
    "variants": [{"name": "v", "models": ["odometry", "appearance"], "odometry": {"sigma_xy": 0.2}}],
    "baselines": ["greedy_odometry"],
    "paper": {"v": {"gt_mass": 0.5}},
    "checks": {"gt_mass": ">= 0.5", "v": {"ari": "> 0.1"}},
}

#: (path into the config, the text its error must contain, or a tuple of texts one of which it must contain)
KEYS = [
    *[((key,), name) for key, name in (("name", "name"), ("description", "description"), ("variants", "variants"),
                                       ("baselines", "baselines"), ("paper", "paper"), ("checks", "[checks]"))],
    *[(("sweep", key), f"sweep.{key}") for key in DEFAULTS["sweep"]],
    *[(("sweep", key, 0), f"sweep.{key}") for key in ("worlds", "aliasing", "noise", "seeds", "calibration_seeds")],
    *[(("sweep", "worlds", index, key), f"sweep.worlds[{index}]") for index in (1, 2)
      for key in BASE["sweep"]["worlds"][index]],
    (("sweep", "worlds", 2, "calibration", 0), "sweep.worlds[2]"),
    (("sweep", "generator_options", "miss_rate"), "sweep.generator_options.miss_rate"),
    *[((section,), section) for section in MODEL_SECTIONS],
    *[((section, key), f"{section}.{key}") for section in MODEL_SECTIONS for key in DEFAULTS[section]],
    (("variants", 0), "variants[0]"),
    *[(("variants", 0, key), f"variants['v'].{key}") for key in ("models", *MODEL_SECTIONS)],
    (("variants", 0, "name"), ("variants[", "unknown variant 'v'")),  # a new name leaves [paper] and [checks] behind
    *[(("variants", 0, section, key), f"variants['v'].{section}.{key}")
      for section in MODEL_SECTIONS for key in DEFAULTS[section]],
    (("paper", "v"), "paper"),
    (("checks", "gt_mass"), "gt_mass"),
    (("checks", "v"), "[checks]"),
    (("checks", "v", "ari"), "ari"),
]

VALUES = st.one_of(
    st.none(),
    st.booleans(),
    st.integers(min_value=-(2 ** 70), max_value=2 ** 70),
    st.sampled_from([0, 1, -1, 2, 2 ** 31, 2 ** 63, 2 ** 64, 10 ** 30, 10 ** 400]),
    st.floats(allow_nan=True, allow_infinity=True),
    st.sampled_from([math.nan, math.inf, -math.inf, 1e308, -1e308, 5e-324, 1e-300, 0.0, -0.0, 0.5]),
    st.text(max_size=6),
    st.sampled_from(["", "auto", "mcmc", "100", "1e9", "nan", "short_loop", "a\nb", "\x00", "..", ">= nan",
                     ">= 1e999"]),
    st.lists(st.one_of(st.integers(min_value=-3, max_value=2 ** 64), st.floats(), st.text(max_size=3)), max_size=4),
    st.dictionaries(st.text(max_size=5), st.one_of(st.integers(), st.text(max_size=3)), max_size=2),
    st.dates(),
    st.just(datetime.time(12, 30)),
)


def with_value(config: dict, path: tuple, value) -> dict:
    """A deep copy of ``config`` with ``value`` at ``path`` (missing tables on the way are added)."""
    changed = copy.deepcopy(config)
    where = changed
    for key in path[:-1]:
        where = where.setdefault(key, {}) if isinstance(where, dict) else where[key]
    where[path[-1]] = value
    return changed


def stored(experiment, path: tuple):
    """The value a loaded experiment keeps for a model section's key (its experiment-wide or its variant's)."""
    if path[0] in MODEL_SECTIONS and len(path) == 2:
        return getattr(getattr(experiment.settings, path[0]), path[1])
    if path[:2] == ("variants", 0) and len(path) == 4:
        return getattr(getattr(experiment.variants[0], path[2]), path[3])
    return None


def entry(*path):
    """The entry of :data:`KEYS` for ``path``."""
    return next(item for item in KEYS if item[0] == path)


@SETTINGS
@given(st.sampled_from(KEYS), VALUES)
# what the fuzzing found before issue 47's fixes: an OverflowError, "embedded null byte" naming no key, a name
# with a newline and a description of any type accepted
@example(entry("sweep", "generator_options", "miss_rate"), 10 ** 400)
@example(entry("odometry", "max_penalty"), -(10 ** 400))
@example(entry("sweep", "worlds", 2, "dataset"), "run\x00.npz")
@example(entry("sweep", "worlds", 2, "calibration", 0), "\x00")
@example(entry("sweep", "worlds", 0), "x\x00.toml")
@example(entry("sweep", "worlds", 1, "name"), "grid\n2")
@example(entry("variants", 0, "name"), "v\n")
@example(entry("description"), None)
def test_any_value_at_any_key_loads_or_is_refused_naming_the_key(key, value):
    path, name = key
    try:
        experiment = parse_experiment(with_value(BASE, path, value))
    except ValueError as error:
        assert any(text in str(error) for text in ((name,) if isinstance(name, str) else name)), \
            f"{path} = {value!r}: {error}"
        return
    if path == ("description",):
        assert isinstance(value, str), f"description = {value!r} was accepted"
    kept = stored(experiment, path)
    if kept is not None and path[-1] != "outliers":  # outliers = "auto" resolves to true or false
        as_given = tuple(value) if isinstance(value, list) else value
        if isinstance(kept, float) and isinstance(value, int):
            as_given = float(value)  # a number setting is kept as a float
        assert kept == as_given, f"{path} = {value!r} was kept as {kept!r}"
        assert isinstance(kept, bool) == isinstance(value, bool), f"{path} = {value!r} was kept as {kept!r}"
