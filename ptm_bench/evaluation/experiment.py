"""Experiment configs: TOML files in ``experiments/``, validated and expanded into sweep cells (docs/model.md §6).

A config names the worlds, aliasing and noise levels, scored seeds and the
separate calibration seeds, the inference settings, and the model variants
to compare; :func:`load_experiment` validates it once, into the typed records of
:mod:`ptm_bench.evaluation.settings` (an unknown or removed key, a bad value, an
unknown world, model or baseline, a peer baseline on a recorded run without
odometry raises ``ValueError`` naming the key's path), and
:func:`expand_cells` crosses worlds x aliasing x noise x seeds x (variants + baselines)
into the cells that :func:`ptm_bench.evaluation.sweep.run_sweep` runs with
:func:`ptm_bench.evaluation.cell.run_cell`. The format, with every key and its default,
is :data:`DEFAULTS`; a variant may override any key of ``[inference]``,
``[odometry]`` and ``[appearance]``; an optional ``[checks]`` table holds
accuracy thresholds on the summary (:data:`CHECK_METRICS`, checked by
``ptm-bench run --check``, see ``ptm_bench.reporting.checks``)::

    name = "exp3_nested"
    [sweep]
    worlds = ["nested_loops"]
    seeds = [0, 1, 2]
    calibration_seeds = [100, 101]
    [[variants]]
    name = "odometry+appearance"
    models = ["odometry", "appearance"]

:func:`load_experiment` reads such a file (``load_experiment("experiments/exp3_nested.toml")``);
:func:`parse_experiment` takes the same content as a dict:

    >>> experiment = parse_experiment({"name": "tiny", "sweep": {"worlds": ["short_loop"], "seeds": [0, 1]},
    ...                                "variants": [{"name": "appearance", "models": ["appearance"]}]})
    >>> cells = expand_cells(experiment, results_dir=Path("results/tiny"))
    >>> len(cells), cells[0]["cell_id"], cells[0]["settings"].inference.n_samples
    (2, 'short_loop|a=0|noise=1|seed=0|appearance', 20000)
    >>> parse_experiment({"sweep": {"worlds": ["short_loop"], "seeds": [0]}, "inference": {"n_samples": "100"}})
    Traceback (most recent call last):
    ValueError: config: inference.n_samples must be a positive integer, got '100'
"""

from __future__ import annotations

import hashlib
import itertools
import json
import re
import tomllib
import zipfile
from dataclasses import asdict, dataclass, replace
from pathlib import Path

from ptm_bench.evaluation.settings import (
    DEFAULTS,
    MODEL_NAMES,
    SECTIONS,
    SettingError,
    SweepSettings,
    Variant,
    parsed,
    world_name,
)

__all__ = ["DEFAULTS", "DEMO_CONFIG", "MODEL_NAMES", "BASELINE_NAMES", "PEER_NAMES", "THRESHOLD_BASELINES",
           "Experiment", "describe", "expand_cells", "load_experiment", "parse_experiment"]

#: The threshold baselines (``ptm_bench.evaluation.baselines.BASELINE_FEATURES``) and the peers, the robust
#: back ends roboticists run instead (``ptm_bench.evaluation.peers.PEERS``). Named here, not imported, so that
#: reading a config loads neither; a test holds the names equal.
THRESHOLD_BASELINES = ("greedy_odometry", "appearance_threshold")
PEER_NAMES = ("gnc", "dcs", "pcm", "distance_rank")
BASELINE_NAMES = THRESHOLD_BASELINES + PEER_NAMES

_VARIANT_KEYS = ("name", "models", "inference", "odometry", "appearance")
_TOP_LEVEL_KEYS = ("name", "description", "variants", "baselines", "paper", "checks", *DEFAULTS)
_MODEL_SECTIONS = ("inference", "odometry", "appearance")

#: Summary figures a ``[checks]`` threshold may name: columns of ``ptm_bench.reporting.summary.aggregate``,
#: one value per world x aliasing x noise x variant (the mean over seeds unless the name says min / max /
#: median; ``ece`` and ``brier`` pooled over the seeds' pairs). ``NAME_mean`` is accepted for ``NAME``.
CHECK_METRICS = ("gt_mass", "gt_mass_min", "gt_mass_max", "gt_rank_median", "map_correct", "ari", "lc_f1", "lc_ap",
                 "expected_places", "map_places", "ece", "brier", "log_score", "confidently_wrong", "rhat_over_1.1")
_CHECK_CONDITION = re.compile(r"\s*(>=|<=|==|>|<)\s*([-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?)\s*")


@dataclass(frozen=True)
class Experiment:
    """A validated experiment config."""

    name: str
    description: str
    sweep: SweepSettings
    variants: tuple[Variant, ...]  # each with the experiment-wide sections, its own overrides applied
    baselines: tuple[str, ...]
    paper: dict  # the paper's reported figures per variant, for the summary
    settings: Variant  # the experiment-wide sections, named after the experiment, no models (baselines use these)
    checks: tuple[dict, ...] = ()  # [checks] thresholds: each variant, metric, operator, threshold, condition


def load_experiment(path) -> Experiment:
    """Read and validate an experiment config (TOML); the name defaults to the file's stem."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"no experiment config at {path}")
    try:
        raw = tomllib.loads(path.read_text())
    except tomllib.TOMLDecodeError as error:
        raise ValueError(f"{path}: not valid TOML: {error}") from None
    return parse_experiment(raw, default_name=path.stem, source=str(path))


def parse_experiment(raw: dict, default_name: str = "experiment", source: str = "config") -> Experiment:
    """Validate a config dict (as read from TOML) into an :class:`Experiment`, the defaults filled in.

    Every ``ValueError`` starts with ``source`` and names the path of the key it refuses.
    """
    try:
        return _parsed_experiment(raw, default_name)
    except ValueError as error:
        raise ValueError(f"{source}: {error}") from None


def _parsed_experiment(raw: dict, default_name: str) -> Experiment:
    if not isinstance(raw, dict):
        raise ValueError(f"a config is a table, got {raw!r}")
    for key in raw:
        if key not in _TOP_LEVEL_KEYS:
            raise SettingError(key, f" is an unknown key at the top level; known keys: {', '.join(_TOP_LEVEL_KEYS)}")
    name = _validated_name(raw.get("name", default_name))
    sweep = parsed(SweepSettings, raw.get("sweep", {}), "sweep")
    tables = {section: raw.get(section, {}) for section in _MODEL_SECTIONS}
    settings = Variant(name, (), **{section: parsed(SECTIONS[section], tables[section], section)
                                    for section in _MODEL_SECTIONS})
    entries = raw.get("variants") or [{"name": "odometry+appearance", "models": list(MODEL_NAMES)}]
    if not isinstance(entries, list):
        raise SettingError("variants", " must be a list of tables ([[variants]])")
    variants = tuple(_validated_variant(entry, index, tables) for index, entry in enumerate(entries))
    names = [variant.name for variant in variants]
    baselines = raw.get("baselines", [])
    if not isinstance(baselines, list):
        raise SettingError("baselines", f" must be a list of {', '.join(BASELINE_NAMES)}")
    for baseline in baselines:
        if baseline not in BASELINE_NAMES:
            raise SettingError("baselines", f": unknown baseline {baseline!r}; known baselines: "
                                            f"{', '.join(BASELINE_NAMES)}")
    duplicates = sorted({name for name in names + baselines if (names + baselines).count(name) > 1})
    if duplicates:
        raise SettingError("variants", f": variant and baseline names must be unique; repeated: {duplicates}")
    _refuse_peers_without_odometry(sweep, [baseline for baseline in baselines if baseline in PEER_NAMES])
    paper = raw.get("paper", {})
    if not isinstance(paper, dict):
        raise SettingError("paper", " must be a table of variants")
    for variant_name in paper:
        if variant_name not in names:
            raise SettingError("paper", f": names unknown variant {variant_name!r}; variants: {names}")
    return Experiment(
        checks=_validated_checks(raw.get("checks", {}), names, baselines),
        name=name,
        description=_validated_description(raw.get("description", "")),
        sweep=sweep,
        variants=variants,
        baselines=tuple(baselines),
        paper=paper,
        settings=settings,
    )


def expand_cells(experiment: Experiment, results_dir: Path) -> list[dict]:
    """The sweep cells: worlds x aliasing x noise x seeds x (variants, then baselines).

    A cell is a dict: its plain values (``cell_id``, the condition, the variant's name, models and method) become
    table columns; ``settings`` is its :class:`ptm_bench.evaluation.settings.Variant` (a baseline's: the
    experiment-wide sections), ``inputs`` what it needs to make its datasets, and ``definition`` the digest
    that decides whether a row of an earlier run is still the cell's.
    """
    sweep = experiment.sweep
    cache_dir = str(Path(results_dir) / "datasets")
    runs = [(variant.name, "+".join(variant.models), variant.inference.method, variant)
            for variant in experiment.variants]
    runs += [(baseline, baseline, "baseline", replace(experiment.settings, name=baseline))
             for baseline in experiment.baselines]
    cells = []
    identities = [_identity(world, sweep) for world in sweep.worlds]
    for (index, world), aliasing, noise, seed in itertools.product(enumerate(sweep.worlds), sweep.aliasing,
                                                                   sweep.noise, sweep.seeds):
        condition = {
            "experiment": experiment.name,
            "world": world_name(world),
            "aliasing": aliasing,
            "noise": noise,
            "seed": seed,
        }
        # Nested, so not table columns: what the cell needs to make its dataset and calibrate.
        inputs = {
            "world_spec": world,
            "calibration_seeds": list(sweep.calibration_seeds),
            "calibration": sweep.calibration,  # in the definition: a resumed sweep never mixes protocols
            "generator_options": sweep.generator_options,
            "cache_dir": cache_dir,
        }
        for variant_name, models, method, settings in runs:
            cell_id = f"{condition['world']}|a={aliasing:g}|noise={noise:g}|seed={seed}|{variant_name}"
            cell = {"cell_id": cell_id, **condition, "variant": variant_name, "models": models,
                    "method": method, "settings": settings, "inputs": inputs}
            cells.append({**cell, "definition": _definition(cell, identities[index])})
    return cells


def _definition(cell: dict, identity: dict) -> str:
    """A digest of everything that decides a cell's row.

    Its config (everything in the cell but where its datasets are cached, so its calibration seeds and
    protocol, ``sweep.calibration``, too), the ``identity`` of its world and of its held-out floors
    (:func:`_identity`: edit a world file or the simulator's code and the cell is recomputed on the next
    run), and :func:`ptm_bench.evaluation.cell.cell_version`, the version of the code that turns a
    dataset into a row. The settings enter as the JSON of the cell's
    :class:`ptm_bench.evaluation.settings.Variant` (``dataclasses.asdict``).
    """
    # Imported here: it pulls in the inference package, which parsing configs does not need.
    from ptm_bench.evaluation.cell import cell_version

    decisive = {**cell, "settings": asdict(cell["settings"]),
                "inputs": {key: value for key, value in cell["inputs"].items() if key != "cache_dir"},
                **identity, "cell_version": cell_version()}
    return hashlib.sha256(json.dumps(decisive, sort_keys=True, default=str).encode()).hexdigest()[:16]


def _identity(world, sweep: SweepSettings) -> dict:
    """The content and simulator version (:func:`ptm_bench.evaluation.datacache.world_identity`) of a world and of
    each floor its held-out runs drive (:func:`ptm_bench.evaluation.calibration.held_out_floors`; a recorded
    world's identity holds its calibration files)."""
    # Imported here: they pull in the simulator's code version and the floors, which parsing configs does not need.
    from ptm_bench.evaluation.calibration import held_out_floors
    from ptm_bench.evaluation.datacache import is_recorded, world_identity

    floors = {} if is_recorded(world) else {
        name: spec for name, spec, _ in held_out_floors(world, sweep.calibration, sweep.calibration_seeds)}
    return {"world_identity": world_identity(world),
            "held_out_identity": [world_identity(spec) for spec in floors.values()]}


def _refuse_peers_without_odometry(sweep: SweepSettings, peers: list[str]) -> None:
    """The peers close loops on a pose graph: every run they see, scored or held out, needs odometry.

    Simulated runs always have it; a recorded run (a ``.npz`` dataset file) is checked for its ``odometry`` array.
    A file that is missing or unreadable is left to the cell that loads it, which names the problem.
    """
    if not peers:
        return
    for index, world in enumerate(sweep.worlds):
        if not (isinstance(world, dict) and "dataset" in world):
            continue
        for path in [world["dataset"], *world["calibration"]]:
            try:
                with zipfile.ZipFile(path) as archive:
                    has_odometry = "odometry.npy" in archive.namelist()
            except (OSError, zipfile.BadZipFile):
                continue
            if not has_odometry:
                raise SettingError("baselines", f": the peers {', '.join(peers)} need odometry, and the recorded "
                                                f"run {path} of sweep.worlds[{index}] ({world['name']!r}) has none; "
                                                "drop the peers from baselines or the world from the sweep")


def _validated_variant(entry, index: int, tables: dict) -> Variant:
    """A ``[[variants]]`` entry: the experiment-wide sections ``tables`` with the entry's overrides, as a
    :class:`Variant`; errors name the variant's path, ``variants['NAME']`` (``variants[INDEX]`` without a name)."""
    if not isinstance(entry, dict):
        raise SettingError(f"variants[{index}]", " must be a table")
    name = entry.get("name")
    where = f"variants[{name!r}]" if isinstance(name, str) and name else f"variants[{index}]"
    for key in entry:
        if key not in _VARIANT_KEYS:
            raise SettingError(f"{where}.{key}", f" is an unknown key; known keys of a variant: "
                                                 f"{', '.join(_VARIANT_KEYS)}")
    if not entry.get("models") or not isinstance(entry["models"], list):
        raise SettingError(f"{where}.models", f" must be a non-empty list of {', '.join(MODEL_NAMES)}")
    sections = {}
    for section in _MODEL_SECTIONS:
        overrides = entry.get(section, {})
        if not isinstance(overrides, dict):
            raise SettingError(f"{where}.{section}", f" must be a table, got {overrides!r}")
        sections[section] = parsed(SECTIONS[section], {**tables[section], **overrides}, f"{where}.{section}")
    try:
        return Variant(name, entry["models"], **sections)
    except SettingError as error:
        raise error.at(where) from None


def _validated_checks(raw, variants: list[str], baselines: list[str]) -> tuple[dict, ...]:
    """``[checks]``: ``METRIC = "OP NUMBER"`` for every variant, or ``"VARIANT".METRIC = "OP NUMBER"`` for one."""
    if not isinstance(raw, dict):
        raise ValueError("[checks] must be a table")
    checks = []
    for key, value in raw.items():
        if isinstance(value, dict):
            if key not in variants + baselines:
                raise ValueError(f"[checks] names unknown variant {key!r}; variants: {variants + baselines}")
            targets, items = [key], value.items()
        else:
            targets, items = variants, [(key, value)]  # a bare metric holds for every model variant
        for metric, condition in items:
            name = metric[: -len("_mean")] if metric.endswith("_mean") and metric[: -len("_mean")] in CHECK_METRICS \
                else metric
            if name not in CHECK_METRICS:
                raise ValueError(f"[checks] unknown metric {metric!r}; known: {', '.join(CHECK_METRICS)}")
            match = _CHECK_CONDITION.fullmatch(condition) if isinstance(condition, str) else None
            if match is None:
                raise ValueError(f"[checks] {metric} must be a condition such as \">= 0.9\", got {condition!r}")
            checks += [{"variant": target, "metric": name, "operator": match.group(1),
                        "threshold": float(match.group(2)), "condition": f"{match.group(1)} {match.group(2)}"}
                       for target in targets]
    return tuple(checks)


def _validated_description(description) -> str:
    if not isinstance(description, str):
        raise SettingError("description", f" must be a string, got {description!r}")
    return description


def _validated_name(name) -> str:
    # The name is a folder under --out: a separator or '..' would write elsewhere.
    if not isinstance(name, str) or not _NAME_PATTERN.fullmatch(name) or set(name) == {"."}:
        raise SettingError("name", f" must be a folder name of letters, digits and '_.+-' (no path separator), "
                                   f"got {name!r}")
    return name


_NAME_PATTERN = re.compile(r"[A-Za-z0-9_.+-]+")


def describe(experiment: Experiment) -> str:
    """A one-paragraph human description of the sweep size."""
    sweep = experiment.sweep
    runs = len(experiment.variants) + len(experiment.baselines)
    count = len(sweep.worlds) * len(sweep.aliasing) * len(sweep.noise) * len(sweep.seeds) * runs
    return (f"{experiment.name}: {count} cells = {len(sweep.worlds)} world(s) x {len(sweep.aliasing)} aliasing "
            f"x {len(sweep.noise)} noise x {len(sweep.seeds)} seeds x {runs} variants/baselines "
            f"({json.dumps([variant.name for variant in experiment.variants] + list(experiment.baselines))})")


#: The embedded experiment: one world, one seed, two calibration seeds, two models, the two threshold baselines
#: and the four robust pose-graph peers.
DEMO_CONFIG = {
    "name": "demo",
    "description": "ptm-bench demo: one simulated run, inference with and without appearance, scored.",
    "baselines": ["greedy_odometry", "appearance_threshold", "gnc", "dcs", "pcm", "distance_rank"],
    "sweep": {"worlds": ["nested_loops"], "aliasing": [0.0], "noise": [1.0], "seeds": [0],
              "calibration_seeds": [1000, 1001]},
    "inference": {"n_samples": 10000, "burn_in": 1000, "chains": 4},
    "variants": [
        {"name": "odometry", "models": ["odometry"]},
        {"name": "odometry+appearance", "models": ["odometry", "appearance"]},
    ],
}
