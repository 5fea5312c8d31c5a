"""Parameters of a cell's posterior, from the config, a sensor specification, or held-out runs (docs/model.md §3, §6).

Nothing inside inference may come from the scored run's ground truth: a user
with a real robot knows neither the number of places nor their spacing. Every
parameter is therefore one of

* **configured** (the experiment's TOML sets it);
* a **sensor specification** a user knows: the detector's radius r (dataset
  meta ``detection_radius``) gives the tie sigma_T = r / sqrt 2 (two positions
  each uniform within r of their place differ by r / sqrt 2 per axis) and the
  margin of the landmarks' area of the normalised ties (docs/model.md §3.3);
* **calibrated** on the *held-out* runs (:func:`calibration_datasets`):
  labelled runs at the cell's aliasing and noise, at seeds the experiment never
  scores (the config loader refuses overlapping seed lists), on floors that are
  not the scored one, as a user never calibrates on the floor they map
  (``sweep.calibration = "other_floors"``, :func:`held_out_floors`): a preset or
  floor file is calibrated on the other presets and the generated grids
  :data:`CALIBRATION_GRIDS`, a generated grid on grids of one row or one column
  more drawn at the calibration seeds; the k-th calibration seed drives the k-th
  floor of that list, cyclically. ``"same_floor"`` keeps the old protocol, the
  scored world itself at the calibration seeds, to report the gap. A recorded
  log is calibrated on the other logs it names under either. A held-out run
  with the scored run's content (a copy under another name) is refused
  (:func:`ptm_bench.evaluation.held_out.refuse_scored_run`).

The calibrated ones:

* the Poisson rate of the prior (paper eq. 8-9) is the rate whose expected
  number of *visited* places for N detections (N: the scored run's, which
  inference knows) is (distinct true places / detections, pooled over the
  held-out runs) x N. The rate itself counts landmarks visited or not, so
  setting it to the expected visits would lean the prior towards too few
  places (N = 9 at 0.568 places per detection: rate 5.1 expects 4.1 places,
  the calibrated rate 7.3 expects the 5.1 the held-out runs have). Places
  per detection, not a count:
  generated grids draw a different floor per seed, so a held-out run has other
  places than the scored run, and a count from other floors does not fit this
  one (a floor with more places has a longer route and more detections); the
  share of detections that are first visits is set by the route rules that
  every floor of a generator shares, so it transfers;
* the penalty radius D (paper eq. 11-12) is ``penalty_radius_factor`` x the
  scored run's :func:`route_spacing` (the median dead-reckoned distance between
  consecutive detections: odometry, no labels) x the *spacing ratio* of the
  held-out runs (:func:`spacing_ratio`: the smallest distance between true
  positions of detections of different places over the run's own route
  spacing, the minimum over every held-out run). D says "distinct places are
  not closer than this"; the penalty fires on any topology that puts two places
  closer, so D must not exceed a spacing that true topologies have. Floors
  differ in scale (places 1.7 m apart on ``short_loop``, 12 m on
  ``nested_loops``), so an absolute spacing from other floors does not transfer
  (1.3 m on ``nested_loops`` from ``short_loop``); the ratio is dimensionless
  and does (0.67-1.0 on the simulated floors, 0.56-0.70 on the four logs).
  The minimum is the largest ratio no held-out run contradicts. False
  detections (negative labels) are left out of the separation: they are noise,
  not landmarks, and two of them may fire at one spot. Online, where the run's
  spacing is known only at its end, D is the factor x the closest separation
  on the held-out runs (``ptm_bench.evaluation.models.ONLINE_DIFFERENCES``);
* the appearance hyperparameters (mu, kappa, alpha, beta per Fourier
  component, paper eq. 15-19) by empirical Bayes — maximising the evidence of
  the held-out runs' true partitions (``ptm.AppearanceModel.fit``).

Each function takes the configured value (None: not configured) and returns
``(value, source)``: the number and a one-line provenance that the builder of
the models (:func:`ptm_bench.evaluation.models.build_models`) records as the
``source_<parameter>`` column. A calibrated source names the floors or logs of
its held-out runs in brackets (:func:`described`, read back by
:func:`floors_in`), e.g. ``on 3 held-out runs [nested_loops, office, grid3x3]``.

    >>> import numpy as np, ptm
    >>> square = np.array([[0.0, 0.0, 0.0], [4.0, 0.0, 0.0], [4.0, 4.0, 0.0], [0.0, 0.0, 0.0]])
    >>> steps = [[4.0, 0.0, 1.5708], [4.0, 0.0, 2.3562], [5.657, 0.0, 0.0]]             # its odometry: 4 m, 4 m, 5.7 m
    >>> held_out = [ptm.Dataset(labels=[0, 1, 2, 0], true_poses=square, odometry=steps, meta={"world": "office"})]
    >>> rate, source = prior_rate(None, n=12, held_out=held_out)
    >>> round(rate, 2)
    29.45
    >>> source
    'calibrated: mean rate for E[places] = 0.75 places/detection on 1 held-out run [office] x N=12 = 9, Gamma shape 2'
    >>> penalty_radius(None, 0.75, held_out)                  # online: the held-out runs' closest separation
    (3.0, 'calibrated: 0.75 x 4 m, the closest detections of different places on 1 held-out run [office]')
    >>> scored = ptm.Dataset(odometry=[[6.0, 0.0, 0.0], [6.0, 0.0, 1.57], [8.0, 0.0, 0.0]])
    >>> penalty_radius(None, 0.75, held_out, scored)        # batch: ratio 4 / 4 m on the held-out run, x 6 m
    (4.5, "calibrated: 0.75 x 1 (separation / route spacing on 1 held-out run [office]) x 6 m, this run's route spacing")
    >>> floors_in(source), [(name, seed) for name, _, seed in held_out_floors("office", "other_floors", [7, 8, 9])]
    (['office'], [('nested_loops', 7), ('short_loop', 8), ('grid3x3', 9)])
    >>> topology_sigma(None, {"detection_radius": 1.5})
    (1.0606601717798212, 'sensor spec: detection radius 1.5 m / sqrt 2')
"""

from __future__ import annotations

import math
import re
from collections.abc import Sequence
from dataclasses import replace
from pathlib import Path

import numpy as np

import ptm

from ptm_bench.evaluation.datacache import dataset_for, is_recorded, load_recorded
from ptm_bench.evaluation.held_out import refuse_scored_run
from ptm_bench.evaluation.settings import CALIBRATION_PROTOCOLS, world_name
from ptm_bench.world.floorplan import list_worlds, load_world

__all__ = ["APPEARANCE_HYPERPARAMETERS", "CALIBRATION_GRIDS", "HELD_OUT_FLOOR", "appearance_fitter",
           "calibration_datasets", "described", "fitted_appearance", "floors_in", "held_out_floors",
           "labelled_runs", "other_floors", "penalty_radius", "place_separation", "places_per_detection", "prior_rate",
           "route_spacing", "spacing_ratio",
           "tie_area_margin", "topology_sigma"]

CONFIG = "config"
#: The Gamma shape of a calibrated prior rate: a coefficient of variation of 1 / sqrt 2, since places per
#: detection carry over from other floors only roughly (the central 95 % of rates spans 0.12-2.8 x the mean).
PRIOR_RATE_SHAPE = 2.0

#: The generated floors a preset or floor-file world is calibrated on beside the other presets: the grid sweep's
#: 3 x 3 grid and a 4 x 4 one, each calibration seed drawing its own layout.
CALIBRATION_GRIDS = (
    {"generator": "corridor_grid", "name": "grid3x3", "rows": 3, "cols": 3, "loops": 2, "place_density": 0.6},
    {"generator": "corridor_grid", "name": "grid4x4", "rows": 4, "cols": 4, "loops": 3, "place_density": 0.6},
)
#: The dataset meta key under which :func:`calibration_datasets` names the floor or log a held-out run drove.
HELD_OUT_FLOOR = "held_out_floor"


def calibration_datasets(cell: dict) -> list[ptm.Dataset]:
    """The labelled held-out runs of a cell (never its scored run), each named in its meta (:data:`HELD_OUT_FLOOR`).

    A simulated world's: the cell's aliasing and noise at its calibration seeds on :func:`held_out_floors`; a
    recorded world's: the recorded runs in its ``calibration`` list. A held-out run with the scored run's content
    is a ``ValueError`` (:func:`ptm_bench.evaluation.held_out.refuse_scored_run`: compared by hash, not by name).
    """
    inputs, aliasing, noise = cell["inputs"], cell["aliasing"], cell["noise"]
    components = cell["settings"].appearance.components
    world_spec, options, cache_dir = inputs["world_spec"], inputs["generator_options"], inputs["cache_dir"]
    if is_recorded(world_spec):  # a recorded run is calibrated on the other recorded runs it names
        runs = [(Path(path).stem, path, load_recorded(path, components)) for path in world_spec["calibration"]]
    else:
        seeds = inputs["calibration_seeds"]
        if cell["seed"] in seeds:
            raise ValueError(f"seed {cell['seed']} is both scored and a calibration seed")
        runs = [(name, f"{name} at seed {seed}",
                 dataset_for(spec, aliasing, noise, seed, options, cache_dir, components))
                for name, spec, seed in held_out_floors(world_spec, inputs["calibration"], seeds)]
    scored = dataset_for(world_spec, aliasing, noise, cell["seed"], options, cache_dir, components)
    scored_name = world_spec["dataset"] if is_recorded(world_spec) else f"the scored run of {cell['cell_id']}"
    refuse_scored_run(scored, scored_name,
                      {f"held-out run {index} ({run})": dataset for index, (_, run, dataset) in enumerate(runs)})
    return [dataset.replace(meta={**dataset.meta, HELD_OUT_FLOOR: name}) for name, _, dataset in runs]


def held_out_floors(world_spec, protocol: str, seeds: Sequence[int]) -> list[tuple[str, object, int]]:
    """``(name, world spec, seed)`` of a simulated world's held-out runs, one per calibration seed.

    ``protocol`` (``sweep.calibration``): "other_floors", the k-th seed on the k-th floor of :func:`other_floors`,
    cyclically; "same_floor", the world itself.
    """
    if protocol == "same_floor":
        return [(world_name(world_spec), world_spec, seed) for seed in seeds]
    if protocol != "other_floors":
        raise ValueError(f"sweep.calibration must be one of {', '.join(map(repr, CALIBRATION_PROTOCOLS))}, "
                         f"got {protocol!r}")
    floors = other_floors(world_spec)
    return [(*floors[index % len(floors)], seed) for index, seed in enumerate(seeds)]


def other_floors(world_spec) -> list[tuple[str, object]]:
    """``(name, world spec)`` of the floors a simulated world is calibrated on, none with its layout.

    A preset or floor file: the presets of another layout (compared by content, not by name), then
    :data:`CALIBRATION_GRIDS`. A generated grid: its generator table with one row more, then with one column more,
    the world seed left to the calibration seed (another size and another draw: never the scored layout).
    """
    if isinstance(world_spec, str):
        layout = _layout(load_world(world_spec))
        presets = [(name, name) for name in list_worlds() if _layout(load_world(name)) != layout]
        return presets + [(grid["name"], grid) for grid in CALIBRATION_GRIDS]
    if "rows" not in world_spec or "cols" not in world_spec:
        raise ValueError(f"world {world_name(world_spec)!r}: a generated grid needs 'rows' and 'cols'")
    table = {key: value for key, value in world_spec.items() if key != "seed"}
    sizes = ((table["rows"] + 1, table["cols"]), (table["rows"], table["cols"] + 1))
    return [(f"grid{rows}x{cols}", {**table, "name": f"grid{rows}x{cols}", "rows": rows, "cols": cols})
            for rows, cols in sizes]


def _layout(floor) -> tuple:
    return floor.nodes, floor.corridors, floor.places, floor.routes


def described(held_out: Sequence[ptm.Dataset]) -> str:
    """``"N held-out runs [floor, ...]"``: the count and the floors or logs they drove, in order of first use
    (meta :data:`HELD_OUT_FLOOR`, else ``world``); without brackets where no run is named."""
    names = [dataset.meta.get(HELD_OUT_FLOOR, dataset.meta.get("world")) for dataset in held_out]
    count = f"{len(held_out)} held-out run{'s' if len(held_out) != 1 else ''}"
    if not any(names):
        return count
    return f"{count} [{', '.join(dict.fromkeys(str(name) if name else 'unnamed' for name in names))}]"


def floors_in(source: str) -> list[str]:
    """The floors or logs a calibrated ``source_<parameter>`` names (:func:`described`); [] for any other source."""
    return [name for match in _NAMED_RUNS.finditer(str(source)) for name in match.group(1).split(", ")]


_NAMED_RUNS = re.compile(r"held-out runs? \[([^\]]*)\]")


def fitted_appearance(held_out: Sequence[ptm.Dataset], model: str = "independent", evidence: str = "corrected",
                      prior_mean: str = "global", scored_signatures=None, outliers: bool = False,
                      max_outlier_share: float = ptm.appearance_outliers.SHARE_BOUNDS[1]):
    """Empirical-Bayes appearance hyperparameters from the labelled held-out runs, and their source.

    ``model`` is ``"joint"`` (``ptm.JointAppearanceModel``, Normal-Inverse-Wishart over the K-vector) or
    ``"independent"`` (the paper's ``ptm.AppearanceModel``, whose ``evidence`` may be the printed eq. 19).

    ``prior_mean = "run"`` models a world-level mean (docs/model.md §3.2): places of one world scatter
    around that world's mean appearance, which differs from world to world (at aliasing 1 every place of
    a run wears the run's one decor, drawn anew for each run). The spread is fitted on the held-out runs
    with each run's mean signature removed, and the prior mean is the scored run's own mean signature
    (``scored_signatures``: all its detections, no labels). With ``"global"`` the spread between worlds
    counts as spread between places, and a run whose places all look alike is read as one place.

    ``outliers=True`` (the independent model only) also fits the share of visits seen from unusual
    standpoints and their variance scale (docs/model.md §3.2.2), the share at most ``max_outlier_share``.
    """
    return appearance_fitter(held_out, model, evidence, prior_mean, outliers, max_outlier_share)(scored_signatures)


def appearance_fitter(held_out: Sequence[ptm.Dataset], model: str = "independent", evidence: str = "corrected",
                      prior_mean: str = "global", outliers: bool = False,
                      max_outlier_share: float = ptm.appearance_outliers.SHARE_BOUNDS[1]):
    """:func:`fitted_appearance` fitted once: a function from a scored run's signatures to (model, source).

    The empirical-Bayes fit depends on the held-out runs only; with ``prior_mean = "run"`` each scored run
    then shifts its prior mean. For scoring many runs against one calibration set.
    """
    held_out = labelled_runs(held_out, "appearance hyperparameters")
    if prior_mean == "run":
        centred = [replace(run, signatures=run.signatures - run.signatures.mean(axis=0)) for run in held_out]
        fitted, source = appearance_fitter(centred, model, evidence, outliers=outliers,
                                           max_outlier_share=max_outlier_share)(None)
        extra = {} if model == "joint" else {"evidence": evidence, **fitted.outliers}

        def around_run_mean(scored_signatures):
            if scored_signatures is None:
                raise ValueError("appearance.prior_mean = 'run' needs the scored run's signatures")
            hyper = {name: getattr(fitted, name) for name in APPEARANCE_HYPERPARAMETERS[model]}
            hyper["mu"] = hyper["mu"] + np.asarray(scored_signatures, dtype=float).mean(axis=0)
            return (type(fitted)(**hyper, **extra),
                    f"{source} around each run's mean; prior mean = this run's mean signature")
        return around_run_mean
    if prior_mean != "global":
        raise ValueError(f"appearance.prior_mean must be 'global' or 'run', got {prior_mean!r}")
    if model == "joint":
        if evidence != "corrected":
            raise ValueError(f"appearance.evidence = {evidence!r} exists only for the independent model")
        if outliers:
            raise ValueError("appearance.outliers = true exists only for appearance.model = 'independent'; "
                             "set appearance.outliers = false for the joint model")
        fitted = ptm.JointAppearanceModel.fit(held_out)
    elif model == "independent":
        fitted = ptm.AppearanceModel.fit(held_out, evidence=evidence, outliers=outliers,
                                         max_outlier_share=max_outlier_share)
    else:
        raise ValueError(f"appearance.model must be 'joint' or 'independent', got {model!r}")
    with_outliers = (f", outlier share {fitted.outlier_share:.3g} at {fitted.outlier_scale:.3g} x the variance"
                     if outliers else "")
    source = f"empirical Bayes ({model}{with_outliers}) on {described(held_out)}"
    return lambda scored_signatures: (fitted, source)


#: The hyperparameters of each appearance model, in its constructor's order.
APPEARANCE_HYPERPARAMETERS = {"independent": ("mu", "kappa", "alpha", "beta"), "joint": ("mu", "kappa", "nu", "psi")}


def places_per_detection(held_out: Sequence[ptm.Dataset]) -> float:
    """Distinct true places / detections, pooled over labelled runs (a false detection is its own place)."""
    held_out = labelled_runs(held_out, "the prior rate")
    places = sum(len(np.unique(dataset.labels)) for dataset in held_out)
    return places / sum(dataset.n for dataset in held_out)


def place_separation(held_out: Sequence[ptm.Dataset]) -> float:
    """The smallest distance [m] between true positions of detections of different places, over all runs.

    False detections (negative labels) are left out. Raises ``ValueError`` if
    no run has detections of two different places.
    """
    held_out = labelled_runs(held_out, "the penalty radius")
    closest = math.inf
    for index, dataset in enumerate(held_out):
        if dataset.true_poses is None:
            raise ValueError(f"calibration of the penalty radius: held-out run {index} has no true_poses")
        real = dataset.labels >= 0
        labels, xy = dataset.labels[real], dataset.true_poses[real, :2]
        different = labels[:, None] != labels[None, :]
        if different.any():
            gaps = np.linalg.norm(xy[:, None, :] - xy[None, :, :], axis=2)
            closest = min(closest, float(gaps[different].min()))
    if not math.isfinite(closest):
        raise ValueError("calibration of the penalty radius: no held-out run detects two different places; "
                         "set odometry.penalty_radius in the config")
    return closest


def prior_rate(configured: float | None, n: int, held_out) -> tuple[float, str]:
    """The ``configured`` ``inference.prior_rate`` (a plug-in ``ptm.PoissonPrior``), or the mean rate of the
    ``ptm.GammaPoissonPrior`` of shape ``PRIOR_RATE_SHAPE`` that expects places per detection (held-out) x ``n``
    places (docs/model.md §3.1, "Uncertain rate").

    The expected places are kept below ``n - 0.5`` (a held-out share of 1, every detection its own place, would
    need an infinite rate) and ``n = 1`` needs no prior (any rate gives the one partition).
    ``held_out`` is the list of held-out runs, or a function returning it (called only when needed).
    """
    if configured is not None:
        return float(configured), CONFIG
    held_out = _materialised(held_out)
    share = places_per_detection(held_out)
    places = min(share * n, n - 0.5)
    if places <= 1.0:
        return 1.0, f"calibrated: {share:.3g} places/detection on {described(held_out)} x N={n} <= 1 place; rate 1"
    rate = ptm.GammaPoissonPrior.with_expected_places(n, places, PRIOR_RATE_SHAPE).rate
    return rate, (f"calibrated: mean rate for E[places] = {share:.3g} places/detection on {described(held_out)} "
                  f"x N={n} = {places:.3g}, Gamma shape {PRIOR_RATE_SHAPE:g}")


def penalty_radius(configured: float | None, factor: float, held_out,
                   scored: ptm.Dataset | None = None) -> tuple[float, str]:
    """The ``configured`` penalty radius D, or ``factor`` (``odometry.penalty_radius_factor``) x
    :func:`spacing_ratio` of the held-out runs x :func:`route_spacing` of the ``scored`` run; without a scored run
    (online: its spacing is known only at its end), ``factor`` x :func:`place_separation` of the held-out runs.

    ``held_out`` is the list of held-out runs, or a function returning it (called only when needed).
    """
    if configured is not None:
        return float(configured), CONFIG
    factor = float(factor)
    held_out = _materialised(held_out)
    if scored is None:
        separation = place_separation(held_out)
        return factor * separation, (f"calibrated: {factor:g} x {separation:.3g} m, the closest detections of "
                                     f"different places on {described(held_out)}")
    ratio, spacing = spacing_ratio(held_out), route_spacing(scored)
    return factor * ratio * spacing, (f"calibrated: {factor:g} x {ratio:.3g} (separation / route spacing on "
                                      f"{described(held_out)}) x {spacing:.3g} m, this run's route spacing")


def route_spacing(dataset: ptm.Dataset) -> float:
    """The median dead-reckoned distance [m] between consecutive detections: the scale of a run's place spacing,
    from its odometry alone (no labels). A ``ValueError`` for a run without odometry or without movement."""
    if dataset.odometry is None or len(dataset.odometry) == 0:
        raise ValueError("the penalty radius is scaled by the run's route spacing: the run has no odometry "
                         "between detections; set odometry.penalty_radius in the config")
    spacing = float(np.median(np.linalg.norm(np.asarray(dataset.odometry)[:, :2], axis=1)))
    if not spacing > 0.0:
        raise ValueError("the penalty radius is scaled by the run's route spacing: the median distance between "
                         "consecutive detections is 0; set odometry.penalty_radius in the config")
    return spacing


def spacing_ratio(held_out: Sequence[ptm.Dataset]) -> float:
    """The smallest ratio of :func:`place_separation` to :func:`route_spacing` over labelled runs: how close
    distinct places come, in units of the run's own spacing, a number that carries over between floors of
    different scale."""
    held_out = labelled_runs(held_out, "the penalty radius")
    return min(place_separation([dataset]) / route_spacing(dataset) for dataset in held_out)


def topology_sigma(configured: float | None, meta: dict) -> tuple[float, str]:
    """The ``configured`` tie sigma_T, or the detector's radius r / sqrt 2 (a sensor specification).

    Two detections of one place lie anywhere within r of it; two positions each uniform on that disc differ
    by r / sqrt 2 per axis (their spread), which is the tie's standard deviation (docs/model.md §3.3, §6).
    """
    if configured is not None:
        return float(configured), CONFIG
    if "detection_radius" not in meta:
        raise ValueError("odometry.sigma_topology is not set and the dataset meta has no 'detection_radius' "
                         "(the detector's specification) to derive it from")
    radius = float(meta["detection_radius"])
    return radius / math.sqrt(2.0), f"sensor spec: detection radius {radius:g} m / sqrt 2"


def tie_area_margin(meta: dict) -> float:
    """The margin [m] of the landmarks' area of the normalised ties (``ptm.TieNormaliser``: within the margin of
    the dead-reckoned route): the detector's radius, a sensor specification."""
    if "detection_radius" not in meta:
        raise ValueError("the normalised ties need the detector's radius (dataset meta 'detection_radius') for "
                         "the margin of the landmarks' area")
    return float(meta["detection_radius"])


def _materialised(held_out) -> list[ptm.Dataset]:
    return list(held_out() if callable(held_out) else held_out)


def labelled_runs(held_out, what: str) -> list[ptm.Dataset]:
    """``held_out`` as a list, refused unless it holds at least one run and every run has labels."""
    held_out = list(held_out)
    if not held_out:
        raise ValueError(f"calibration of {what} needs at least one held-out run (sweep.calibration_seeds)")
    for index, dataset in enumerate(held_out):
        if dataset.labels is None:
            raise ValueError(f"calibration of {what}: held-out run {index} has no labels")
    return held_out
