"""Typed settings of an experiment: one frozen dataclass per config section, validated once (docs/model.md §6).

An experiment config's ``[sweep]``, ``[inference]``, ``[odometry]`` and ``[appearance]`` tables become
:class:`SweepSettings`, :class:`InferenceSettings`, :class:`OdometrySettings` and :class:`AppearanceSettings`;
a ``[[variants]]`` entry a :class:`Variant` (its name, its likelihood models and the three model sections). Each
record checks its values when it is built (types, ranges, choices: a :class:`SettingError`, a ``ValueError`` that
starts with the field's name), so a record that exists is valid; :func:`parsed` builds one from a TOML table,
refusing an unknown key, or a key that was removed (:data:`REMOVED_KEYS`), with the path of the key. :data:`DEFAULTS` is read off the
dataclasses: every key a config may set, with its default. A cell's definition digest is the JSON of its
:class:`Variant` (``dataclasses.asdict``), so two configs that mean the same settings (``max_penalty = 100`` and
``100.0``) are the same cell.

    >>> InferenceSettings(chains=2).n_samples, OdometrySettings().sigma_topology   # None: detector radius / sqrt 2
    (20000, None)
    >>> parsed(InferenceSettings, {"n_samples": 0}, "inference")
    Traceback (most recent call last):
    ptm_bench.evaluation.settings.SettingError: inference.n_samples must be a positive integer, got 0
    >>> parsed(OdometrySettings, {"tie_normaliser": False}, "odometry")  # doctest: +ELLIPSIS
    Traceback (most recent call last):
    ptm_bench.evaluation.settings.SettingError: odometry.tie_normaliser was removed; it pinned an old mode ...
"""

from __future__ import annotations

import inspect
import math
import sys
from dataclasses import MISSING, dataclass, field, fields
from pathlib import Path

__all__ = ["APPEARANCE_MODELS", "APPEARANCE_PRIOR_MEANS", "AppearanceSettings", "CALIBRATION_PROTOCOLS", "DEFAULTS",
           "EVIDENCE_FORMS", "InferenceSettings", "METHODS", "MODEL_NAMES", "MOVE_SETS", "OdometrySettings",
           "REMOVED_KEYS", "SECTIONS", "SettingError", "SweepSettings", "Variant", "WORLD_GENERATORS", "parsed",
           "world_name"]

MODEL_NAMES = ("odometry", "appearance")
METHODS = ("mcmc", "tempered", "exact", "auto")  # auto: exact when N <= exact_max_n and affordable, else tempered
MOVE_SETS = ("auto", "default", "paper", "guided")  # ptm.SamplerOptions.moves (docs/model.md §3.4)
EVIDENCE_FORMS = ("corrected", "paper_eq19")
APPEARANCE_MODELS = ("independent", "joint")
APPEARANCE_PRIOR_MEANS = ("run", "global")
WORLD_GENERATORS = ("corridor_grid",)
#: Where a simulated world's held-out runs drive (``ptm_bench.evaluation.calibration.held_out_floors``): other
#: floors (the default), or the scored floor itself (the old protocol, kept to report the gap).
CALIBRATION_PROTOCOLS = ("other_floors", "same_floor")
RESULTS_TAG = "results-2026-12-06"

#: Keys a config may no longer set, each with the rule that replaced it: they pinned the modes of results that
#: are reproducible from the git tag :data:`RESULTS_TAG`, not from live options.
REMOVED_KEYS = {
    "inference": {
        "thin": "every sample after burn-in is kept",
        "delayed_acceptance": "the sampler screens with the posterior's screen wherever it has one",
        "unscreened_share": "the sampler's own share of unscreened steps",
        "estimate": "the sampler's automatic choice of estimate",
        "warm_up": "each chain starts from its own SMC pass",
        "sampler_stream": "the sampler's stream is the cell seed's",
        "map_window": "the default moves take the map-steered window",
    },
    "odometry": {
        "sigma_topology_factor": "sigma_topology defaults to the detector's radius / sqrt 2",
        "tie_normaliser": "the ties are always normalised",
        "tie_area": "the landmarks' area is within the detector's radius of the route",
        "sampling_coordinates": "importance samples are drawn in the increments",
        "penalty_proposal": "the penalty's proposal is the Laplace fit of the whole energy",
        "fit_starts": "the Laplace fit starts from the chordal relaxation",
    },
}


class SettingError(ValueError):
    """A bad setting: ``path`` (relative to the record that raised it) and what is wrong with it."""

    def __init__(self, path: str, problem: str):
        super().__init__(f"{path}{problem}")
        self.path, self.problem = path, problem

    def at(self, where: str) -> "SettingError":
        """The same error, its path below ``where``."""
        return SettingError(f"{where}.{self.path}", self.problem)


#: What a variant's or a world's name must be: it is part of every cell's id and a value of the table's rows.
ROW_NAME = "a non-empty string of printable characters (no newline, tab or other control character) without '|'"


def _is_row_name(value) -> bool:
    return isinstance(value, str) and bool(value) and value.isprintable() and "|" not in value


def _is_int(value) -> bool:
    return isinstance(value, int) and not isinstance(value, bool)


def _is_number(value) -> bool:
    """A finite real a float holds: not a bool, NaN or infinity, nor an integer beyond the largest float (10**400)."""
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        return False
    return math.isfinite(value) if isinstance(value, float) else abs(value) <= sys.float_info.max


def _setting(default=None, *, check=None, must_be: str = "", choices=None, number: bool = False):
    """A field of a section: its default, and either a ``check`` (with what the value ``must_be``) or ``choices``.
    A field whose default is None also accepts None. ``number``: stored as a float."""
    return field(default=default, metadata={"check": check, "must_be": must_be, "choices": choices, "number": number})


def _positive_int(default):
    return _setting(default, check=lambda v: _is_int(v) and v >= 1, must_be="a positive integer")


def _non_negative_int(default):
    return _setting(default, check=lambda v: _is_int(v) and v >= 0, must_be="a non-negative integer")


def _positive_number(default):
    return _setting(default, check=lambda v: _is_number(v) and v > 0, must_be="a positive number", number=True)


class _Section:
    """Checks every field of a section record against its metadata when the record is built."""

    def __post_init__(self) -> None:
        for item in fields(self):
            value = getattr(self, item.name)
            if isinstance(value, list):
                value = tuple(value)
            meta = item.metadata
            if meta.get("choices") is not None and value not in meta["choices"]:
                raise SettingError(item.name, f" must be one of {', '.join(map(repr, meta['choices']))}, got {value!r}")
            if meta.get("check") is not None and not (value is None and item.default is None):
                if not meta["check"](value):
                    raise SettingError(item.name, f" must be {meta['must_be']}, got {value!r}")
                if meta["number"]:
                    value = float(value)
            object.__setattr__(self, item.name, value)


def _is_temperature_ladder(value) -> bool:
    return (isinstance(value, (list, tuple)) and len(value) >= 2 and all(_is_number(beta) for beta in value)
            and value[0] == 1.0 and all(a > b for a, b in zip(value, value[1:])) and value[-1] > 0)


@dataclass(frozen=True)
class InferenceSettings(_Section):
    """How a variant's posterior is computed (docs/model.md §3.4-3.5).

    ``method``: "mcmc" (``ptm.mcmc``), "tempered" (``ptm.tempered_mcmc``), "exact" (every partition, up to
    ``exact_max_n`` detections) or "auto" (exact where N <= ``exact_max_n`` and the odometry term is needed on few
    enough partitions, else tempered). ``n_samples``, ``burn_in`` (None: half of ``n_samples``), ``chains`` (chains
    of "mcmc", ladders of "tempered"), ``max_doublings`` (chains that disagree run on, twice as long, at most this
    many times), ``moves`` and ``temperatures`` go to the sampler as they are (``ptm.SamplerOptions``; "auto" moves:
    guided from ``ptm``'s threshold of detections on, else default; "paper": split/merge alone, an ablation).
    ``prior_rate``: None calibrates the Poisson rate on the held-out runs (docs/model.md §6).
    """

    method: str = _setting("mcmc", choices=METHODS)
    n_samples: int = _positive_int(20000)
    burn_in: int | None = _non_negative_int(None)
    chains: int = _positive_int(4)
    max_doublings: int = _non_negative_int(2)
    prior_rate: float | None = _positive_number(None)
    exact_max_n: int = _positive_int(10)
    moves: str = _setting("auto", choices=MOVE_SETS)
    temperatures: tuple[float, ...] = _setting(
        (1.0, 0.5, 0.25, 0.12, 0.06, 0.03), check=_is_temperature_ladder,
        must_be="a list of inverse temperatures from 1.0 strictly down to a positive value")


@dataclass(frozen=True)
class OdometrySettings(_Section):
    """The odometry likelihood's parameters (paper eq. 3, 11-14; docs/model.md §3.3).

    ``sigma_xy`` [m] and ``sigma_theta`` [rad]: the per-step odometry spread where a dataset has no
    ``odometry_cov``. ``sigma_topology`` [m]: the tie between detections of one place; None is the detector's
    radius r / sqrt 2 (a sensor specification: two positions each uniform within r of their place differ by
    r / sqrt 2 per axis). ``penalty_radius`` [m]: None is ``penalty_radius_factor`` x the held-out runs' closest
    places in units of their route spacing x this run's route spacing (``calibration.penalty_radius``). ``max_penalty`` [nats] and ``n_importance`` (importance samples per
    evaluation of the odometry integral). The ties are always normalised (``ptm.TieNormaliser``, landmarks within
    r of the dead-reckoned route).
    """

    sigma_xy: float = _positive_number(0.1)
    sigma_theta: float = _positive_number(0.05)
    sigma_topology: float | None = _positive_number(None)
    penalty_radius: float | None = _positive_number(None)
    penalty_radius_factor: float = _positive_number(0.75)
    max_penalty: float = _setting(100.0, check=lambda v: _is_number(v) and v >= 0, must_be="a non-negative number",
                                  number=True)
    n_importance: int = _positive_int(100)


@dataclass(frozen=True)
class AppearanceSettings(_Section):
    """The appearance likelihood and how it is fitted on the held-out runs (paper eq. 15-19; docs/model.md §3.2).

    ``model``: "independent" (the paper's per-component model) or "joint" (Normal-Inverse-Wishart over the
    K-vector). ``evidence``: "corrected", or "paper_eq19" (the printed formula, independent model only).
    ``prior_mean``: "run", a place's prior mean is the scored run's own mean signature and the spread is fitted
    around each held-out run's mean (docs/model.md §3.2), or "global", one mean for every run (the paper).
    ``outliers``: visits from unusual standpoints (docs/model.md §3.2.2), their share at most
    ``max_outlier_share``; "auto" is true where the model has them (independent, corrected evidence) and false
    elsewhere, and the record holds the resolved true or false; false is the paper's model. ``components``: None
    keeps the signatures as generated; an integer K recomputes them from the panoramas.
    """

    model: str = _setting("independent", choices=APPEARANCE_MODELS)
    evidence: str = _setting("corrected", choices=EVIDENCE_FORMS)
    prior_mean: str = _setting("run", choices=APPEARANCE_PRIOR_MEANS)
    outliers: bool | str = _setting("auto", check=lambda v: isinstance(v, bool) or v == "auto",
                                    must_be='true, false or "auto"')
    max_outlier_share: float = _setting(0.1, check=lambda v: _is_number(v) and 0.001 < v <= 0.5,
                                        must_be="a number in (0.001, 0.5]", number=True)
    components: int | None = _positive_int(None)

    def __post_init__(self) -> None:
        super().__post_init__()
        if self.evidence != "corrected" and self.model != "independent":
            raise SettingError("evidence", f" = {self.evidence!r} needs appearance.model = 'independent' (the "
                                           "printed eq. 19 is a form of the paper's model)")
        has_outliers = (self.model, self.evidence) == ("independent", "corrected")
        if self.outliers is True and not has_outliers:
            raise SettingError("outliers", " = true exists for appearance.model = 'independent' with evidence = "
                                           "'corrected' only; set appearance.outliers = false or \"auto\"")
        if self.outliers == "auto":
            object.__setattr__(self, "outliers", has_outliers)


@dataclass(frozen=True)
class SweepSettings:
    """What a sweep crosses: worlds x aliasing x noise x seeds, and the held-out calibration seeds (docs/model.md §6).

    ``worlds``: names of ``ptm_bench.world.floorplan.list_worlds()`` or floor ``.toml`` paths; generated worlds
    ``{generator = "corridor_grid", name = ..., rows = ..., ...}``; recorded runs ``{dataset = "run.npz", name =
    ..., calibration = ["other.npz", ...]}`` (calibration: every other recorded world of the sweep unless given; a
    run is never its own calibration). ``calibration_seeds`` must be held out from ``seeds``. ``calibration``:
    "other_floors", a simulated world's held-out runs drive other floors than the scored one (other presets and
    generated grids, or grids of other seeds and sizes), or "same_floor", the scored world itself (the old
    protocol, to report the gap); a recorded world is calibrated on other logs under either.
    ``generator_options``: keyword arguments of ``ptm_bench.simulation.generate.generate_dataset``.
    """

    worlds: tuple = None
    aliasing: tuple[float, ...] = (0.0,)
    noise: tuple[float, ...] = (1.0,)
    seeds: tuple[int, ...] = None
    calibration_seeds: tuple[int, ...] = (1000, 1001, 1002)
    calibration: str = "other_floors"
    generator_options: dict = field(default_factory=dict)

    def __post_init__(self) -> None:
        for key in ("worlds", "seeds"):
            if not isinstance(getattr(self, key), (list, tuple)) or not getattr(self, key):
                raise SettingError(key, " must be a non-empty list (it is required)")
        worlds = [_validated_world(world, index) for index, world in enumerate(self.worlds)]
        object.__setattr__(self, "worlds", tuple(_with_calibration(worlds)))
        object.__setattr__(self, "aliasing", _number_tuple(self.aliasing, "aliasing", 0.0, 1.0))
        object.__setattr__(self, "noise", _number_tuple(self.noise, "noise", 0.0, math.inf))
        for key in ("seeds", "calibration_seeds"):
            object.__setattr__(self, key, _seed_tuple(getattr(self, key), key))
        shared = sorted(set(self.seeds) & set(self.calibration_seeds))
        if shared:
            raise SettingError("calibration_seeds", f" must be held out from seeds; both contain {shared}")
        if self.calibration not in CALIBRATION_PROTOCOLS:
            raise SettingError("calibration", f" must be one of {', '.join(map(repr, CALIBRATION_PROTOCOLS))}, "
                                              f"got {self.calibration!r}")
        if not isinstance(self.generator_options, dict):
            raise SettingError("generator_options", " must be a table")
        _check_generator_options(self.generator_options)

    def world_names(self) -> list[str]:
        """The worlds' names, as the table's ``world`` column holds them."""
        return [world_name(world) for world in self.worlds]


@dataclass(frozen=True)
class Variant:
    """A model variant of an experiment: its ``name``, its likelihood ``models`` (a subset of :data:`MODEL_NAMES`,
    in that order; empty for a baseline, which samples nothing) and its three model sections."""

    name: str
    models: tuple[str, ...] = MODEL_NAMES
    inference: InferenceSettings = field(default_factory=InferenceSettings)
    odometry: OdometrySettings = field(default_factory=OdometrySettings)
    appearance: AppearanceSettings = field(default_factory=AppearanceSettings)

    def __post_init__(self) -> None:
        if not _is_row_name(self.name):
            raise SettingError("name", f" must be {ROW_NAME}, got {self.name!r}")
        if isinstance(self.models, str) or not isinstance(self.models, (list, tuple)):
            raise SettingError("models", f" must be a list of {', '.join(MODEL_NAMES)}, got {self.models!r}")
        unknown = [model for model in self.models if model not in MODEL_NAMES]
        if unknown:
            raise SettingError("models", f": unknown model {unknown[0]!r}; known models: {', '.join(MODEL_NAMES)}")
        object.__setattr__(self, "models", tuple(model for model in MODEL_NAMES if model in self.models))


#: The config's section tables and their records.
SECTIONS = {"sweep": SweepSettings, "inference": InferenceSettings, "odometry": OdometrySettings,
            "appearance": AppearanceSettings}

#: Every section and key a config may set, with its default (read off the records). ``None`` means "required"
#: for ``sweep.worlds`` and ``sweep.seeds``, and "calibrated or derived" elsewhere (see each record).
DEFAULTS = {section: {item.name: item.default if item.default_factory is MISSING else item.default_factory()
                      for item in fields(record)}
            for section, record in SECTIONS.items()}


def parsed(record, table, where: str):
    """The ``record`` (a section dataclass) of a config ``table`` at path ``where`` (e.g. ``"inference"`` or
    ``"variants['v'].odometry"``). A ``ValueError`` names the path of a removed or unknown key, or of a bad value."""
    if not isinstance(table, dict):
        raise SettingError(where, f" must be a table, got {table!r}")
    section = where.rsplit(".", 1)[-1]
    known = [item.name for item in fields(record)]
    for key in table:
        if key in REMOVED_KEYS.get(section, {}):
            raise SettingError(f"{where}.{key}", f" was removed; it pinned an old mode ({REMOVED_KEYS[section][key]}): "
                                                 f"see the tag {RESULTS_TAG}")
        if key not in known:
            raise SettingError(f"{where}.{key}", f" is an unknown key; known keys of [{section}]: {', '.join(known)}")
    try:
        return record(**table)
    except SettingError as error:
        raise error.at(where) from None


def world_name(world) -> str:
    """The name of a world of ``sweep.worlds``: the preset or path itself, or its table's ``name``."""
    return world if isinstance(world, str) else world["name"]


def _validated_world(world, index: int):
    where = f"worlds[{index}]"
    if isinstance(world, str):
        from ptm_bench.world.floorplan import list_worlds  # imported here: parsing a config needs no world otherwise

        known = list_worlds()
        if not _is_path(world):
            raise SettingError(where, f": a world name or path is a non-empty string without NUL, got {world!r}")
        if world not in known and Path(world).suffix != ".toml":
            raise SettingError(where, f": unknown world {world!r}; known worlds: {', '.join(sorted(known))}")
        return world
    if not isinstance(world, dict):
        raise SettingError(where, f": a world is a name or a table, got {world!r}")
    if "dataset" in world:  # a recorded run (ptm-bench import-carmen writes them)
        _refuse_unknown(world, ("dataset", "name", "calibration"), where, "a recorded world")
        calibration = world.get("calibration", [])
        if not _is_path(world["dataset"]) or not isinstance(calibration, (list, tuple)) or \
                not all(_is_path(path) for path in calibration):
            raise SettingError(where, ": 'dataset' is a .npz path and 'calibration' a list of .npz paths (non-empty "
                                      f"strings without NUL), got {world['dataset']!r} and {calibration!r}")
    else:
        if world.get("generator") not in WORLD_GENERATORS:
            raise SettingError(f"{where}.generator", f": unknown world generator {world.get('generator')!r}; known: "
                                                     f"{', '.join(WORLD_GENERATORS)}")
        from ptm_bench.world.floorplan import corridor_grid

        _refuse_unknown(world, ("generator", "name", *inspect.signature(corridor_grid).parameters), where,
                        "a generated world")
    if "name" not in world:
        raise SettingError(where, " needs a 'name' (the world's name in the table)")
    if not _is_row_name(world["name"]):
        raise SettingError(f"{where}.name", f" must be {ROW_NAME} (the world's name in the table), got "
                                            f"{world['name']!r}")
    return dict(world)


def _is_path(value) -> bool:
    return isinstance(value, str) and bool(value) and "\x00" not in value


def _refuse_unknown(table: dict, known, where: str, what: str) -> None:
    for key in table:
        if key not in known:
            raise SettingError(f"{where}.{key}", f" is an unknown key; known keys of {what}: {', '.join(known)}")


def _with_calibration(worlds: list) -> list:
    """Recorded worlds with their calibration runs: as given, or every other recorded world of the sweep."""
    recorded = [world["dataset"] for world in worlds if isinstance(world, dict) and "dataset" in world]
    for index, world in enumerate(worlds):
        if not (isinstance(world, dict) and "dataset" in world):
            continue
        world["calibration"] = list(world.get("calibration", [path for path in recorded if path != world["dataset"]]))
        if not world["calibration"]:
            raise SettingError(f"worlds[{index}].calibration", f": recorded world {world['name']!r} has no "
                               "calibration runs: list them, or add other recorded worlds to the sweep")
        if any(Path(path).resolve() == Path(world["dataset"]).resolve() for path in world["calibration"]):
            raise SettingError(f"worlds[{index}].calibration", f": recorded world {world['name']!r} lists itself; a "
                               "scored run is never its own calibration")
    return worlds


def _number_tuple(values, key: str, low: float, high: float) -> tuple[float, ...]:
    if not isinstance(values, (list, tuple)) or not values or not all(_is_number(value) for value in values):
        raise SettingError(key, f" must be a non-empty list of numbers, got {values!r}")
    if any(not low <= value <= high for value in values):
        raise SettingError(key, f" values must lie in [{low:g}, {high:g}], got {list(values)}")
    return tuple(float(value) for value in values)


def _seed_tuple(values, key: str) -> tuple[int, ...]:
    if not isinstance(values, (list, tuple)) or not values or not all(_is_int(v) and v >= 0 for v in values):
        raise SettingError(key, f" must be a non-empty list of non-negative integers, got {values!r}")
    if len(set(values)) != len(values):
        raise SettingError(key, f" has repeated seeds {list(values)}")
    return tuple(values)


def _check_generator_options(options: dict) -> None:
    """Generator options are keyword arguments of generate_dataset: known names, values of the default's type."""
    if not options:
        return
    from ptm_bench.simulation.generate import generate_dataset  # imported here: it pulls in MuJoCo

    parameters = {name: parameter.default for name, parameter in inspect.signature(generate_dataset).parameters.items()
                  if parameter.kind is inspect.Parameter.KEYWORD_ONLY and name != "signature_k"}
    for key, value in options.items():
        if key not in parameters:
            raise SettingError(f"generator_options.{key}", f" is an unknown key; known keys: "
                               f"{', '.join(sorted(parameters))} (the number of components is appearance.components)")
        default = parameters[key]
        if isinstance(default, (bool, str)) or not isinstance(default, (int, float)):
            expected, ok = type(default), isinstance(value, type(default))
        else:
            expected, ok = float, _is_number(value)
        if not ok:
            raise SettingError(f"generator_options.{key}", f" must be a {expected.__name__}, got {value!r}")
