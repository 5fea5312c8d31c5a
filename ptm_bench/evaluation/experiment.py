"""Experiment configs: TOML files in ``experiments/``, validated and expanded into sweep cells (docs/model.md §6).

A config names the worlds, aliasing and noise levels, scored seeds and the
separate calibration seeds, the inference settings, and the model variants
to compare; :func:`load_experiment` validates it (an unknown key, world,
model or baseline raises ``ValueError`` naming it) and :func:`expand_cells`
crosses worlds x aliasing x noise x seeds x (variants + baselines) into the
cells that :func:`ptm_bench.evaluation.sweep.run_sweep` runs with
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
    >>> len(cells), cells[0]["cell_id"]
    (2, 'short_loop|a=0|noise=1|seed=0|appearance')
    >>> parse_experiment({"sweep": {"worlds": ["short_loop"], "seeds": [0]}, "inference": {"n_samples": "100"}})
    Traceback (most recent call last):
    ValueError: config: inference.n_samples must be a positive integer, got '100'
"""

from __future__ import annotations

import copy
import hashlib
import itertools
import json
import math
import re
import tomllib
from dataclasses import dataclass
from pathlib import Path

__all__ = ["DEFAULTS", "DEMO_CONFIG", "MODEL_NAMES", "BASELINE_NAMES", "Experiment", "describe", "expand_cells", "load_experiment",
           "parse_experiment", "resolved_appearance"]

MODEL_NAMES = ("odometry", "appearance")
BASELINE_NAMES = ("greedy_odometry", "appearance_threshold")
METHODS = ("mcmc", "tempered", "exact", "auto")  # auto: exact when N <= exact_max_n, else tempered
MOVE_SETS = ("auto", "default", "paper", "guided")
MAP_WINDOWS = ("default", "all", "none")
WARM_UPS = ("smc", "all", "guided")
ESTIMATES = ("frequency", "renormalised", "auto")  # ptm.sampler.ESTIMATES
EVIDENCE_FORMS = ("corrected", "paper_eq19")
SAMPLING_COORDINATES = ("increments", "poses")  # ptm.odometry.SAMPLING_COORDINATES (parsing imports no inference)
PENALTY_PROPOSALS = ("mode", "subspace")  # ptm.odometry.PENALTY_PROPOSALS
FIT_STARTS = ("chordal", "aligned")  # ptm.odometry.FIT_STARTS
APPEARANCE_MODELS = ("joint", "independent")
APPEARANCE_PRIOR_MEANS = ("global", "run")
WORLD_GENERATORS = ("corridor_grid",)

#: Every section and key a config may set, with its default. ``None`` means "required" for
#: ``sweep.worlds`` and ``sweep.seeds``, and "choose automatically" elsewhere.
DEFAULTS = {
    "sweep": {
        "worlds": None,  # names from ptm_bench.world.floorplan.list_worlds(), or {generator = "corridor_grid", ...} tables,
        # or recorded runs {dataset = "run.npz", name = "intel", calibration = ["other.npz", ...]} (calibration defaults
        # to every other recorded world of the sweep; a run is never its own calibration)
        "aliasing": [0.0],
        "noise": [1.0],
        "seeds": None,
        "calibration_seeds": [1000, 1001, 1002],
        "generator_options": {},  # extra keyword arguments of ptm_bench.simulation.generate.generate_dataset
    },
    "inference": {
        "method": "mcmc",
        "n_samples": 20000,
        # None: half of n_samples. At 80-100 detections chains found the bulk only after 2 000-10 000 steps
        # (results/scale, README "Scale"), so the default discards the first half of every chain.
        "burn_in": None,
        "thin": 1,
        "chains": 4,  # independent chains of "mcmc", independent ladders of "tempered"
        # chains that disagree after n_samples (ptm.diagnostics.chains_agree) are run on, twice as long each time,
        # at most this many times: the default keeps up to 4 x n_samples per chain where that is what agreement takes
        "max_doublings": 2,
        # how "mcmc" and "tempered" turn chains into probabilities: visit frequencies, P(T|Z) renormalised over the
        # visited topologies, or "auto": renormalised where every chain visited nearly all of them (ptm.mcmc)
        "estimate": "auto",
        "prior_rate": None,  # None: places per detection on the calibration runs x the run's detections
        "delayed_acceptance": True,
        # the share of steps of "mcmc" and "tempered" that skip delayed acceptance's screening and accept on the
        # exact ratio (ptm.sampler.MoveMixture): a wrong map misleads the guided moves' surrogate, which then
        # screens out the moves that would repair it (10 x 10 grids: chains agreeing in 2 of 2 runs instead of 0)
        "unscreened_share": 0.05,
        "exact_max_n": 10,
        # "default" (split/merge + Gibbs), "paper" (split/merge only), "guided" (for many detections: data-driven
        # moves, the odometry surrogate in delayed acceptance's first stage, a cheap warm-up per chain of "mcmc";
        # docs/model.md §3.4), or "auto": "guided" from ptm_bench.evaluation.cell.GUIDED_FROM_N detections on,
        # else "default" (the row's inference_moves says which)
        "moves": "auto",
        # how the chains of "mcmc" and "tempered" start. "smc" (the default): each from its own sequential Monte
        # Carlo pass over the detections (ptm.online.smc_start, ptm_bench.evaluation.cell.SMC_START_PARTICLES
        # particles), which on 95-detection grids put every chain on the truth where the warm-up left chains
        # 245 nats below it (docs/model.md §3.4, "Starts"); "all": every chain starts with a cheap warm-up
        # (ptm.sampler.warm_up_start, WARM_UP_PER_DETECTION x N steps) instead of at a dispersed extreme,
        # where under the sharp normalised ties the default moves' chains stayed (nested_loops, 12 detections:
        # truth 0.35 on average over seeds 0-3, 1.00 with the warm-up); "guided": only the guided moves warm up,
        # as the committed results were run
        "warm_up": "smc",
        "temperatures": [1.0, 0.5, 0.25, 0.12, 0.06, 0.03],  # inverse temperatures of method "tempered"
        # which random stream drives the sampler (chains, moves, warm-ups); the posterior, its importance-sampling
        # noise included, is the same for every stream. 0 (the default) is the stream every committed result
        # used; another value reruns a cell with other chains, to see whether its agreement was luck (README
        # "Scale", "Other sampler streams")
        "sampler_stream": 0,
        # where the window of consecutive detections allocated again jointly is steered by the map
        # (ptm.moves.MapWindowReallocation): "default" (the default moves take it, one step in ten, where there is
        # odometry), "all" (the guided moves' window too), "none" (as the committed results were run). A loop whose
        # single closures are each worse than none then closes in one move (nested_loops, 12 detections, odometry
        # alone: truth 0.21-0.75 without it on seeds 0-3, 0.985-1.000 with it); on the scale grids it cost
        # up to 3.6 times the wall time and made two of three disagreeing runs agree, so "default" leaves them be
        "map_window": "default",
    },
    "odometry": {
        "sigma_xy": 0.1,
        "sigma_theta": 0.05,
        "sigma_topology": None,  # None: sigma_topology_factor x the detector's radius (a sensor specification)
        # r / sqrt 2: the per-axis spread of two positions each uniform within r of their place (README
        # "Evaluation"); the paper-like 2 r that committed results pin reads "up to 2 r apart" as an sd
        "sigma_topology_factor": 0.7071,
        "penalty_radius": None,  # None: penalty_radius_factor x the closest detections of different places
        # on the calibration runs
        "penalty_radius_factor": 0.75,
        "max_penalty": 100.0,
        "n_importance": 100,
        # true (the default): add the normaliser of the topology ties (ptm.TieNormaliser, docs/model.md §3.3):
        # landmarks uniform on the area of the run's dead-reckoned detections (plus the detection radius on
        # every side). False is the paper's model, whose unnormalised ties make odometry lean to "every
        # detection its own place"; committed results run before pin it.
        "tie_normaliser": True,
        # the landmarks' area for the normalised ties (ptm.TieNormaliser.from_dead_reckoning): "route" (the
        # default), within the detection radius of the dead-reckoned route through the detections;
        # "bounding_box", the box around them (the rule until 2026-12-04), which corridors fill a fifth of
        "tie_area": "route",
        # "increments" (the default): importance samples of the odometry integral drawn in the relative poses
        # between consecutive detections and composed; "poses": drawn around P* in the poses (the paper), which
        # degenerates on long routes (docs/model.md §3.3, erratum E12). Committed results run before pin "poses".
        "sampling_coordinates": "increments",
        # "mode" (the default): where the penalty is active at P*, half the importance samples come from the
        # Laplace fit of E + Pen over all poses; "subspace": from a fit over the penalised detections'
        # positions only, the other poses following linearly (docs/model.md §3.3). Committed results pin "subspace".
        "penalty_proposal": "mode",
        # the fixed starts whose lower converged minimum is the Laplace mode P* (docs/model.md §3.3, "Which
        # minimum is P*"): "chordal" (the default), the chordal relaxation's headings and dead reckoning;
        # "aligned", dead reckoning with and without its positions aligned (the rule until 2026-12-06), which on a
        # 208-detection grid left the true partition's fit 862 nats above its minimum. Committed results pin it.
        "fit_starts": "chordal",
    },
    "appearance": {
        # "independent": the paper's per-component model (the default: the better of the two in the predictive
        # check of `ptm-bench appearance-check`, results/appearance_check/); "joint": Normal-Inverse-Wishart over
        # the K-vector
        "model": "independent",
        "evidence": "corrected",  # "paper_eq19" (the printed formula) exists for the independent model only
        # "run" (the default): the prior mean of a place's appearance is the scored run's own mean signature
        # (its detections, no labels) and the spread around it is fitted on calibration runs with each run's
        # mean removed, so that differences between worlds (another decor library) do not count as differences
        # between places; "global": one prior mean for every world, fitted across the calibration runs (the
        # paper), which reads a run whose places all look alike as one place
        "prior_mean": "run",
        # true: each visit may be seen from an unusual standpoint, with the share of such visits and their
        # variance fitted on the calibration runs (docs/model.md §3.2.2; the independent model with the corrected
        # evidence only); false: the paper's model, every visit of a place with the same variance, which fails the
        # predictive check of `ptm-bench appearance-check`; "auto" (the default): true where it exists, that is
        # for model = "independent" with evidence = "corrected", false for the joint model and the printed eq. 19
        # (README "Evaluation", "Rare outlier visits are the default"). Committed results run before pin false.
        "outliers": "auto",
        # the largest share of outlier visits the calibration fit may find (with outliers on): at most one visit in
        # ten (the default; the evidence of the calibration runs alone puts it at 0.35-0.5, and the unbounded fit
        # merges distinct places that share a decor more readily: README "Outlier visits in the sweeps")
        "max_outlier_share": 0.1,
        "components": None,  # None: the signatures as generated; an integer K recomputes them from the panoramas
    },
}

_VARIANT_KEYS = {"name", "models", "inference", "odometry", "appearance"}
_TOP_LEVEL_KEYS = {"name", "description", "variants", "baselines", "paper", "checks", *DEFAULTS}

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
    sweep: dict
    variants: tuple[dict, ...]  # each: name, models, inference, odometry, appearance (merged with the defaults)
    baselines: tuple[str, ...]
    paper: dict  # the paper's reported figures per variant, for the summary
    settings: dict  # the experiment-wide inference, odometry and appearance sections (baselines use these)
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
    """Validate a config dict (as read from TOML) and fill in the defaults."""
    _reject_unknown(raw, _TOP_LEVEL_KEYS, source, "the top level")
    sections = {}
    for section, defaults in DEFAULTS.items():
        given = raw.get(section, {})
        if not isinstance(given, dict):
            raise ValueError(f"{source}: [{section}] must be a table")
        _reject_unknown(given, defaults, source, f"[{section}]")
        sections[section] = {**copy.deepcopy(defaults), **given}
    for section in _VALUE_CHECKS:
        _check_values(sections[section], section, source, "")
    sweep = sections["sweep"]
    for key in ("worlds", "seeds"):
        if not sweep[key]:
            raise ValueError(f"{source}: [sweep] needs a non-empty '{key}' list")
    sweep["worlds"] = _with_calibration([_validated_world(world, source) for world in sweep["worlds"]], source)
    for key in ("aliasing", "noise"):
        values = _number_list(sweep[key], f"sweep.{key}", source)
        if key == "aliasing" and any(not 0.0 <= value <= 1.0 for value in values):
            raise ValueError(f"{source}: sweep.aliasing values must lie in [0, 1], got {values}")
        if key == "noise" and any(value < 0.0 for value in values):
            raise ValueError(f"{source}: sweep.noise values must be >= 0, got {values}")
        sweep[key] = values
    for key in ("seeds", "calibration_seeds"):
        sweep[key] = _seed_list(sweep[key], f"sweep.{key}", source)
    shared = sorted(set(sweep["seeds"]) & set(sweep["calibration_seeds"]))
    if shared:
        raise ValueError(f"{source}: sweep.calibration_seeds must be held out from sweep.seeds; both contain {shared}")
    if not isinstance(sweep["generator_options"], dict):
        raise ValueError(f"{source}: sweep.generator_options must be a table")
    _check_generator_options(sweep["generator_options"], source)

    raw_variants = raw.get("variants") or [{"name": "odometry+appearance", "models": list(MODEL_NAMES)}]
    variants = tuple(_validated_variant(variant, sections, source) for variant in raw_variants)
    names = [variant["name"] for variant in variants]
    baselines = tuple(raw.get("baselines", ()))
    for baseline in baselines:
        if baseline not in BASELINE_NAMES:
            raise ValueError(f"{source}: unknown baseline {baseline!r}; known baselines: {', '.join(BASELINE_NAMES)}")
    duplicates = sorted({name for name in names + list(baselines) if (names + list(baselines)).count(name) > 1})
    if duplicates:
        raise ValueError(f"{source}: variant names must be unique; repeated: {duplicates}")
    paper = raw.get("paper", {})
    for variant_name in paper:
        if variant_name not in names:
            raise ValueError(f"{source}: [paper] names unknown variant {variant_name!r}; variants: {names}")
    checks = _validated_checks(raw.get("checks", {}), names, list(baselines), source)
    return Experiment(
        checks=checks,
        name=_validated_name(raw.get("name", default_name), source),
        description=str(raw.get("description", "")),
        sweep=sweep,
        variants=variants,
        baselines=baselines,
        paper=paper,
        settings={"inference": sections["inference"], "odometry": sections["odometry"],
                  "appearance": resolved_appearance(sections["appearance"])},
    )


def expand_cells(experiment: Experiment, results_dir: Path) -> list[dict]:
    """The sweep cells: worlds x aliasing x noise x seeds x (variants, then baselines)."""
    sweep = experiment.sweep
    cache_dir = str(Path(results_dir) / "datasets")
    cells = []
    for world, aliasing, noise, seed in itertools.product(sweep["worlds"], sweep["aliasing"], sweep["noise"], sweep["seeds"]):
        condition = {
            "experiment": experiment.name,
            "world": _world_name(world),
            "aliasing": aliasing,
            "noise": noise,
            "seed": seed,
        }
        # Nested, so not table columns: what the cell needs to make its dataset and calibrate.
        inputs = {
            "world_spec": world,
            "calibration_seeds": list(sweep["calibration_seeds"]),
            "generator_options": sweep["generator_options"],
            "cache_dir": cache_dir,
        }
        runs = [(variant["name"], "+".join(variant["models"]), variant["inference"]["method"], variant) for variant in experiment.variants]
        runs += [(baseline, baseline, "baseline", _baseline_settings(experiment, baseline)) for baseline in experiment.baselines]
        for variant_name, models, method, settings in runs:
            cell_id = f"{condition['world']}|a={aliasing:g}|noise={noise:g}|seed={seed}|{variant_name}"
            cell = {"cell_id": cell_id, **condition, "variant": variant_name, "models": models,
                    "method": method, "settings": settings, "inputs": inputs}
            cells.append({**cell, "definition": _definition(cell)})
    return cells


#: Keys added to DEFAULTS after results existed, with the value that reproduces what the code did before
#: them: at that value a key stays out of a cell's definition, so adding an option does not make every
#: existing row stale (a cell that sets another value is a new cell).
_ADDED_KEYS = {("odometry", "tie_normaliser"): False, ("odometry", "sampling_coordinates"): "poses",
               ("odometry", "penalty_proposal"): "subspace", ("inference", "max_doublings"): 0,
               ("inference", "estimate"): "frequency", ("inference", "warm_up"): "guided",
               ("appearance", "outliers"): False, ("appearance", "max_outlier_share"): 0.5,
               ("odometry", "tie_area"): "bounding_box", ("inference", "unscreened_share"): 0.0,
               ("inference", "sampler_stream"): 0, ("inference", "map_window"): "none",
               ("odometry", "fit_starts"): "aligned"}
#: Keys that act only when another key of their section is true: left out of a cell's definition when it is
#: false, so that changing their default does not make the cells that switch them off stale.
_DEPENDENT_KEYS = {("appearance", "max_outlier_share"): "outliers", ("odometry", "tie_area"): "tie_normaliser"}
_UNSET = object()


def _decides(section: str, key: str, value, values: dict) -> bool:
    """Whether a setting can change a cell's row (see :data:`_ADDED_KEYS` and :data:`_DEPENDENT_KEYS`)."""
    switch = _DEPENDENT_KEYS.get((section, key))
    return _ADDED_KEYS.get((section, key), _UNSET) != value and (switch is None or bool(values.get(switch)))


def _definition(cell: dict) -> str:
    """A digest of everything that decides a cell's row.

    Its config (everything in the cell but where its datasets are cached), the
    world's content and the simulator's version
    (:func:`ptm_bench.evaluation.datacache.world_identity`: edit a world file or bump
    ``GENERATOR_VERSION`` and the cell is recomputed on the next run), and
    :data:`ptm_bench.evaluation.cell.CELL_VERSION`, the version of the rules that turn a
    dataset into a row. A key of :data:`_ADDED_KEYS` at its old-behaviour value, and one of
    :data:`_DEPENDENT_KEYS` whose switch is off, are left out.
    """
    # Imported here: both pull in the simulator or the inference package, which parsing configs does not need.
    from ptm_bench.evaluation.cell import CELL_VERSION
    from ptm_bench.evaluation.datacache import world_identity

    settings = {section: ({key: value for key, value in values.items() if _decides(section, key, value, values)}
                          if isinstance(values, dict) else values)
                for section, values in cell["settings"].items()}
    decisive = {**cell, "settings": settings,
                "inputs": {key: value for key, value in cell["inputs"].items() if key != "cache_dir"},
                "world_identity": world_identity(cell["inputs"]["world_spec"]), "cell_version": CELL_VERSION}
    return hashlib.sha256(json.dumps(decisive, sort_keys=True, default=str).encode()).hexdigest()[:16]


def _baseline_settings(experiment: Experiment, baseline: str) -> dict:
    # A baseline uses the experiment-wide settings (penalty radius, appearance components).
    return {"name": baseline, "models": [], **experiment.settings}


def _validated_variant(variant, sections: dict, source: str) -> dict:
    if not isinstance(variant, dict):
        raise ValueError(f"{source}: each [[variants]] entry must be a table")
    name = variant.get("name")
    where = f"variant {name!r}" if name else "a [[variants]] entry"
    _reject_unknown(variant, _VARIANT_KEYS, source, where)
    if not name or not isinstance(name, str) or "|" in name:
        raise ValueError(f"{source}: {where} needs a 'name' (a string without '|')")
    models = variant.get("models")
    if not models or not isinstance(models, list):
        raise ValueError(f"{source}: {where} needs a non-empty 'models' list")
    for model in models:
        if model not in MODEL_NAMES:
            raise ValueError(f"{source}: {where}: unknown model {model!r}; known models: {', '.join(MODEL_NAMES)}")
    merged = {"name": name, "models": [model for model in MODEL_NAMES if model in models]}
    for section in ("inference", "odometry", "appearance"):
        overrides = variant.get(section, {})
        if not isinstance(overrides, dict):
            raise ValueError(f"{source}: {where}: '{section}' must be a table")
        _reject_unknown(overrides, DEFAULTS[section], source, f"{where} {section}")
        merged[section] = {**sections[section], **overrides}
        if section in _VALUE_CHECKS:
            _check_values(overrides, section, source, f"{where}: ")
    _check_choice(merged["inference"]["method"], METHODS, f"{where} inference.method", source)
    _check_choice(merged["inference"]["moves"], MOVE_SETS, f"{where} inference.moves", source)
    _check_choice(merged["inference"]["warm_up"], WARM_UPS, f"{where} inference.warm_up", source)
    _check_choice(merged["inference"]["map_window"], MAP_WINDOWS, f"{where} inference.map_window", source)
    _check_choice(merged["inference"]["estimate"], ESTIMATES, f"{where} inference.estimate", source)
    _check_choice(merged["odometry"]["sampling_coordinates"], SAMPLING_COORDINATES,
                  f"{where} odometry.sampling_coordinates", source)
    _check_choice(merged["odometry"]["penalty_proposal"], PENALTY_PROPOSALS, f"{where} odometry.penalty_proposal",
                  source)
    _check_choice(merged["odometry"]["fit_starts"], FIT_STARTS, f"{where} odometry.fit_starts", source)
    _check_choice(merged["appearance"]["evidence"], EVIDENCE_FORMS, f"{where} appearance.evidence", source)
    _check_choice(merged["appearance"]["model"], APPEARANCE_MODELS, f"{where} appearance.model", source)
    _check_choice(merged["appearance"]["prior_mean"], APPEARANCE_PRIOR_MEANS, f"{where} appearance.prior_mean", source)
    if merged["appearance"]["evidence"] != "corrected" and merged["appearance"]["model"] != "independent":
        raise ValueError(f"{source}: {where}: appearance.evidence = {merged['appearance']['evidence']!r} needs "
                         "appearance.model = 'independent' (the printed eq. 19 is a form of the paper's model)")
    if merged["appearance"]["outliers"] is True and not _outliers_exist(merged["appearance"]):
        raise ValueError(f"{source}: {where}: appearance.outliers = true exists for appearance.model = "
                         "'independent' with evidence = 'corrected' only; set appearance.outliers = false or \"auto\"")
    merged["appearance"] = resolved_appearance(merged["appearance"])
    return merged


def _outliers_exist(appearance: dict) -> bool:
    """Whether the appearance model has a form with outlier visits (docs/model.md §3.2.2)."""
    return (appearance["model"], appearance["evidence"]) == ("independent", "corrected")


def resolved_appearance(appearance: dict) -> dict:
    """The appearance section with ``outliers = "auto"`` made true or false, as a cell's settings hold it."""
    if appearance["outliers"] != "auto":
        return appearance
    return {**appearance, "outliers": _outliers_exist(appearance)}


def _validated_world(world, source: str):
    if isinstance(world, str):
        from ptm_bench.world.floorplan import list_worlds  # imported late: the simulator is optional for parsing tests

        known = list_worlds()
        if world not in known and not Path(world).suffix == ".toml":
            raise ValueError(f"{source}: unknown world {world!r}; known worlds: {', '.join(sorted(known))}")
        return world
    if isinstance(world, dict) and "dataset" in world:  # a recorded run (ptm-bench import-carmen writes them)
        _reject_unknown(world, ("dataset", "name", "calibration"), source, f"recorded world {world.get('name')!r}")
        if not isinstance(world.get("name"), str) or not world["name"] or "|" in world["name"]:
            raise ValueError(f"{source}: a recorded world needs a 'name' (a string without '|') for the table")
        calibration = world.get("calibration", [])
        if not isinstance(world["dataset"], str) or not isinstance(calibration, list) or \
                not all(isinstance(path, str) for path in calibration):
            raise ValueError(f"{source}: recorded world {world['name']!r}: 'dataset' is a .npz path and "
                             "'calibration' a list of .npz paths")
        return dict(world)
    if isinstance(world, dict):
        generator = world.get("generator")
        if generator not in WORLD_GENERATORS:
            raise ValueError(f"{source}: unknown world generator {generator!r}; known: {', '.join(WORLD_GENERATORS)}")
        if "name" not in world:
            raise ValueError(f"{source}: a generated world needs a 'name' for the table")
        return dict(world)
    raise ValueError(f"{source}: a world is a name or a table, got {world!r}")


def _validated_checks(raw, variants: list[str], baselines: list[str], source: str) -> tuple[dict, ...]:
    """``[checks]``: ``METRIC = "OP NUMBER"`` for every variant, or ``"VARIANT".METRIC = "OP NUMBER"`` for one."""
    if not isinstance(raw, dict):
        raise ValueError(f"{source}: [checks] must be a table")
    checks = []
    for key, value in raw.items():
        if isinstance(value, dict):
            if key not in variants + baselines:
                raise ValueError(f"{source}: [checks] names unknown variant {key!r}; variants: {variants + baselines}")
            targets, items = [key], value.items()
        else:
            targets, items = variants, [(key, value)]  # a bare metric holds for every model variant
        for metric, condition in items:
            name = metric[: -len("_mean")] if metric.endswith("_mean") and metric[: -len("_mean")] in CHECK_METRICS \
                else metric
            if name not in CHECK_METRICS:
                raise ValueError(f"{source}: [checks] unknown metric {metric!r}; known: {', '.join(CHECK_METRICS)}")
            match = _CHECK_CONDITION.fullmatch(condition) if isinstance(condition, str) else None
            if match is None:
                raise ValueError(f"{source}: [checks] {metric} must be a condition such as \">= 0.9\", got {condition!r}")
            checks += [{"variant": target, "metric": name, "operator": match.group(1),
                        "threshold": float(match.group(2)), "condition": f"{match.group(1)} {match.group(2)}"}
                       for target in targets]
    return tuple(checks)


def _validated_name(name, source: str) -> str:
    # The name is a folder under --out: a separator or '..' would write elsewhere.
    if not isinstance(name, str) or not _NAME_PATTERN.fullmatch(name) or set(name) == {"."}:
        raise ValueError(f"{source}: name must be a folder name of letters, digits and '_.+-' (no path "
                         f"separator), got {name!r}")
    return name


def _check_values(section_values: dict, section: str, source: str, where: str) -> None:
    """The type and range of each set key of an [inference], [odometry] or [appearance] section."""
    for key, value in section_values.items():
        check = _VALUE_CHECKS[section].get(key)
        if check is not None and value is not None and not check[0](value):
            raise ValueError(f"{source}: {where}{section}.{key} must be {check[1]}, got {value!r}")


def _check_generator_options(options: dict, source: str) -> None:
    """Generator options are keyword arguments of generate_dataset: known names, values of the default's type."""
    if not options:
        return
    import inspect

    from ptm_bench.simulation.generate import generate_dataset  # imported here: it pulls in MuJoCo

    parameters = {name: parameter.default for name, parameter in inspect.signature(generate_dataset).parameters.items()
                  if parameter.kind is inspect.Parameter.KEYWORD_ONLY and name != "signature_k"}
    for key, value in options.items():
        if key not in parameters:
            raise ValueError(f"{source}: unknown key {key!r} in sweep.generator_options; known keys: "
                             f"{', '.join(sorted(parameters))} (the number of components is appearance.components)")
        default = parameters[key]
        if isinstance(default, (bool, str)) or not isinstance(default, (int, float)):
            expected = type(default)
            ok = isinstance(value, expected)
        else:
            expected = float
            ok = _is_number(value)
        if not ok:
            raise ValueError(f"{source}: sweep.generator_options.{key} must be a {expected.__name__}, got {value!r}")


def _is_number(value) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)


def _is_int(value) -> bool:
    return isinstance(value, int) and not isinstance(value, bool)


def _is_temperature_ladder(value) -> bool:
    return (isinstance(value, list) and len(value) >= 2 and all(_is_number(beta) for beta in value)
            and value[0] == 1.0 and all(a > b for a, b in zip(value, value[1:])) and value[-1] > 0)


_NAME_PATTERN = re.compile(r"[A-Za-z0-9_.+-]+")

#: section -> key -> (check, what it must be); keys not listed are checked as choices in _validated_variant.
_VALUE_CHECKS = {
    "inference": {
        "n_samples": (lambda v: _is_int(v) and v >= 1, "a positive integer"),
        "burn_in": (lambda v: _is_int(v) and v >= 0, "a non-negative integer"),
        "thin": (lambda v: _is_int(v) and v >= 1, "a positive integer"),
        "chains": (lambda v: _is_int(v) and v >= 1, "a positive integer"),
        "max_doublings": (lambda v: _is_int(v) and v >= 0, "a non-negative integer"),
        "prior_rate": (lambda v: _is_number(v) and v > 0, "a positive number"),
        "delayed_acceptance": (lambda v: isinstance(v, bool), "true or false"),
        "unscreened_share": (lambda v: _is_number(v) and 0 <= v <= 1, "a number in [0, 1]"),
        "exact_max_n": (lambda v: _is_int(v) and v >= 1, "a positive integer"),
        "sampler_stream": (lambda v: _is_int(v) and v >= 0, "a non-negative integer"),
        "temperatures": (_is_temperature_ladder, "a list of inverse temperatures from 1.0 strictly down to a positive value"),
    },
    "odometry": {
        **{key: (lambda v: _is_number(v) and v > 0, "a positive number")
           for key in ("sigma_xy", "sigma_theta", "sigma_topology", "sigma_topology_factor", "penalty_radius",
                       "penalty_radius_factor")},
        "max_penalty": (lambda v: _is_number(v) and v >= 0, "a non-negative number"),
        "n_importance": (lambda v: _is_int(v) and v >= 1, "a positive integer"),
        "tie_normaliser": (lambda v: isinstance(v, bool), "true or false"),
        # the rules of ptm.tie_normaliser.AREA_RULES (configs are parsed without importing the inference library)
        "tie_area": (lambda v: v in ("route", "bounding_box"), '"route" or "bounding_box"'),
    },
    "appearance": {
        "components": (lambda v: _is_int(v) and v >= 1, "a positive integer"),
        "outliers": (lambda v: isinstance(v, bool) or v == "auto", 'true, false or "auto"'),
        "max_outlier_share": (lambda v: _is_number(v) and 0.001 < v <= 0.5, "a number in (0.001, 0.5]"),
    },
}


def _with_calibration(worlds: list, source: str) -> list:
    """Recorded worlds with their calibration runs: as given, or every other recorded world of the sweep."""
    recorded = [world["dataset"] for world in worlds if isinstance(world, dict) and "dataset" in world]
    for world in worlds:
        if not (isinstance(world, dict) and "dataset" in world):
            continue
        if "calibration" not in world:
            world["calibration"] = [path for path in recorded if path != world["dataset"]]
        if not world["calibration"]:
            raise ValueError(f"{source}: recorded world {world['name']!r} has no calibration runs: list them in its "
                             "'calibration' or add other recorded worlds to the sweep")
        if any(Path(path).resolve() == Path(world["dataset"]).resolve() for path in world["calibration"]):
            raise ValueError(f"{source}: recorded world {world['name']!r} lists itself among its calibration runs; "
                             "a scored run is never its own calibration")
    return worlds


def _world_name(world) -> str:
    return world if isinstance(world, str) else world["name"]


def _reject_unknown(table: dict, known, source: str, where: str) -> None:
    for key in table:
        if key not in known:
            raise ValueError(f"{source}: unknown key {key!r} in {where}; known keys: {', '.join(sorted(known))}")


def _check_choice(value, choices, where: str, source: str) -> None:
    if value not in choices:
        raise ValueError(f"{source}: {where} must be one of {', '.join(choices)}, got {value!r}")


def _number_list(values, where: str, source: str) -> list[float]:
    if not isinstance(values, list) or not values:
        raise ValueError(f"{source}: {where} must be a non-empty list of numbers")
    try:
        return [float(value) for value in values]
    except (TypeError, ValueError):
        raise ValueError(f"{source}: {where} must be a list of numbers, got {values!r}") from None


def _seed_list(values, where: str, source: str) -> list[int]:
    if not isinstance(values, list) or not values or any(isinstance(v, bool) or not isinstance(v, int) or v < 0 for v in values):
        raise ValueError(f"{source}: {where} must be a non-empty list of non-negative integers, got {values!r}")
    if len(set(values)) != len(values):
        raise ValueError(f"{source}: {where} has repeated seeds {values!r}")
    return list(values)


def describe(experiment: Experiment) -> str:
    """A one-paragraph human description of the sweep size."""
    sweep = experiment.sweep
    runs = len(experiment.variants) + len(experiment.baselines)
    count = len(sweep["worlds"]) * len(sweep["aliasing"]) * len(sweep["noise"]) * len(sweep["seeds"]) * runs
    return (f"{experiment.name}: {count} cells = {len(sweep['worlds'])} world(s) x {len(sweep['aliasing'])} aliasing "
            f"x {len(sweep['noise'])} noise x {len(sweep['seeds'])} seeds x {runs} variants/baselines "
            f"({json.dumps([variant['name'] for variant in experiment.variants] + list(experiment.baselines))})")


#: The embedded experiment: one world, one seed, two calibration seeds, two models, two baselines.
DEMO_CONFIG = {
    "name": "demo",
    "description": "ptm-bench demo: one simulated run, inference with and without appearance, scored.",
    "baselines": ["greedy_odometry", "appearance_threshold"],
    "sweep": {"worlds": ["nested_loops"], "aliasing": [0.0], "noise": [1.0], "seeds": [0],
              "calibration_seeds": [1000, 1001]},
    "inference": {"n_samples": 10000, "burn_in": 1000, "chains": 4},
    "variants": [
        {"name": "odometry", "models": ["odometry"]},
        {"name": "odometry+appearance", "models": ["odometry", "appearance"]},
    ],
}
