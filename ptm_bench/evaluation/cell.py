"""One sweep cell: a dataset, a model variant or baseline, inference, and its scores (docs/model.md §6).

:func:`run_cell` takes a cell from :func:`ptm_bench.evaluation.experiment.expand_cells`
and returns its table row: the scores of :func:`ptm_bench.evaluation.scoring.score`,
the sampler diagnostics, the parameters the posterior used with the source
of each (``source_<parameter>``: the config, a sensor specification, or a
calibration on held-out runs — never the scored run's ground truth), the
run's measured aliasing, the top five topologies and thinned sampler traces
(as JSON, so that summaries and figures need only the table), and the wall
time. Everything random is seeded from the cell's seed: the dataset by the
simulator, and the inference streams (sampler, importance-sampling noise)
from ``SeedSequence(seed, spawn_key=(INFERENCE_KEY,))``, a branch the
simulator's own spawned streams never use. The same streams
serve every variant of a seed (common random numbers across variants);
``inference.sampler_stream`` branches the sampler's stream alone.

The posterior is paper eq. (2): the Poisson prior (eq. 8-9), the odometry
likelihood (eq. 11-14) and the appearance likelihood (eq. 15-19, corrected).

    >>> import tempfile
    >>> from pathlib import Path
    >>> from ptm_bench.evaluation.experiment import expand_cells, parse_experiment
    >>> experiment = parse_experiment({"name": "example", "baselines": ["appearance_threshold"],
    ...     "sweep": {"worlds": ["short_loop"], "aliasing": [0.0], "noise": [1.0], "seeds": [0],
    ...               "calibration_seeds": [1000]}})
    >>> cells = expand_cells(experiment, Path(tempfile.mkdtemp()))   # datasets are cached in that folder
    >>> [cell["variant"] for cell in cells]
    ['odometry+appearance', 'appearance_threshold']
    >>> row = run_cell(cells[1])                                      # the baseline: no sampling, a few seconds
    >>> row["n_measurements"], row["gt_mass"], row["source_threshold"]
    (9, 1.0, 'calibrated: best mean ARI on 1 held-out run')
"""

from __future__ import annotations

import functools
import json
import math
import time

import numpy as np

import ptm

from ptm_bench.evaluation import scoring
from ptm_bench.evaluation.baselines import BASELINE_FEATURES, fit_threshold, greedy_threshold_labels
from ptm_bench.evaluation.calibration import (
    APPEARANCE_HYPERPARAMETERS,
    calibration_datasets,
    fitted_appearance,
    penalty_radius,
    prior_rate,
    tie_area_margin,
    tie_area_source,
    topology_sigma,
)
from ptm_bench.evaluation.datacache import dataset_for

__all__ = ["CELL_VERSION", "GUIDED_FROM_N", "INFERENCE_KEY", "run_cell", "build_posterior", "disagreement",
           "resolved_moves"]

#: Version of the rules by which a cell computes its row (this file, ptm_bench.evaluation.calibration, ptm_bench.evaluation.scoring).
#: It is part of every cell's definition digest: bump it when a change alters the rows of configs that did not
#: change, and a rerun of a sweep recomputes its cells instead of reusing their rows.
CELL_VERSION = "ptm_bench.cell/3"  # a version label (it keeps its name when modules move)

#: Spawn-key branch of the inference streams, apart from the simulator's streams of the same seed.
INFERENCE_KEY = 7_000
#: Method "auto" enumerates up to ``exact_max_n`` detections unless the odometry term would be needed on more
#: partitions than this (``ptm.exact_posterior``'s skip rule, known after one evaluation): then it samples.
AUTO_EXACT_GLOBAL_EVALUATIONS = 25_000
#: ``inference.moves = "auto"`` samples with the guided moves from this many detections on. Below it the default
#: moves: on 12-detection runs with shared decors the guided ones mixed worst (results/ablations). From 25
#: detections on the default ones leave a chain at all-one-place, with odometry (docs/model.md §3.4) and with
#: appearance alone (four chains on a 25-detection grid: split R-hat 1.66, MAP all-one-place; guided: 1.001).
GUIDED_FROM_N = 20
#: Particles of each chain's SMC start (``inference.warm_up = "smc"``, :func:`ptm.online.smc_start`). On a
#: 95-detection grid (grid9x9, seed 0) four passes of 16 took 7-12 s each and all ended on the truth, where the
#: warm-up took 28 s and ended 245 nats below it.
SMC_START_PARTICLES = 16
TOP_K = 5
TRACE_POINTS = 200


def run_cell(cell: dict) -> dict:
    """Generate (or load) the cell's dataset, run its variant or baseline, and score it."""
    started = time.perf_counter()
    settings, inputs = cell["settings"], cell["inputs"]
    dataset = dataset_for(inputs["world_spec"], cell["aliasing"], cell["noise"], cell["seed"],
                          inputs["generator_options"], inputs["cache_dir"], settings["appearance"]["components"])
    if dataset.labels is None:
        raise ValueError(f"dataset of {cell['cell_id']} has no ground-truth labels to score against")
    inference_started = time.perf_counter()
    if cell["method"] == "baseline":
        row = _run_baseline(cell, dataset)
    else:
        row = _run_inference(cell, dataset)
    row["true_labels"] = json.dumps(list(ptm.canonical(dataset.labels)))
    # The measured aliasing of the run (docs/model.md §6), beside the aliasing knob; NaN where the generator did not measure it.
    row["aliasing_auc"] = float(dataset.meta.get("aliasing_auc", math.nan))
    row["inference_wall_s"] = time.perf_counter() - inference_started
    row["wall_s"] = time.perf_counter() - started
    return row


def _run_baseline(cell: dict, dataset: ptm.Dataset) -> dict:
    features = BASELINE_FEATURES[cell["variant"]]
    held_out = calibration_datasets(cell)
    threshold = fit_threshold(held_out, features)
    labels = greedy_threshold_labels(features(dataset), threshold)
    row = scoring.score(scoring.point_mass(labels), dataset.labels)
    row["threshold"] = threshold
    row["source_threshold"] = f"calibrated: best mean ARI on {len(held_out)} held-out run{'s' * (len(held_out) != 1)}"
    row["top5"] = json.dumps([[list(labels), 1.0]])
    return row


def build_posterior(cell: dict, dataset: ptm.Dataset) -> tuple[ptm.Posterior, dict]:
    """The posterior of the cell's variant, and the parameters it used with their sources (for the table).

    Only what a user of a real robot has is read from ``dataset``: its odometry,
    signatures, number of detections and the detector's radius (a sensor
    specification). Never its labels, true poses, or the world's places: the
    rest is configured or calibrated on the held-out runs (:mod:`ptm_bench.evaluation.calibration`).
    For each parameter ``p`` the returned dict holds its value ``p`` and its provenance ``source_p``.
    """
    settings, models, used = cell["settings"], [], {}
    _, importance_seed = _inference_seeds(cell["seed"])
    held_out = functools.cache(lambda: calibration_datasets(cell))  # generated or loaded only if some parameter needs them
    if "odometry" in settings["models"]:
        odometry = settings["odometry"]
        used["penalty_radius"], used["source_penalty_radius"] = penalty_radius(odometry, held_out)
        used["sigma_topology"], used["source_sigma_topology"] = topology_sigma(odometry, dataset.meta)
        used["max_penalty"] = float(odometry["max_penalty"])
        models.append(ptm.OdometryModel(
            sigma_xy=odometry["sigma_xy"], sigma_theta=odometry["sigma_theta"],
            sigma_topology=used["sigma_topology"], penalty_radius=used["penalty_radius"],
            max_penalty=odometry["max_penalty"], n_importance=odometry["n_importance"], seed=importance_seed,
            sampling_coordinates=odometry["sampling_coordinates"], penalty_proposal=odometry["penalty_proposal"],
            fit_starts=odometry["fit_starts"],
        ))
        if odometry["tie_normaliser"]:
            margin = tie_area_margin(dataset.meta)
            normaliser = ptm.TieNormaliser.from_dead_reckoning(dataset, used["sigma_topology"], margin,
                                                                odometry["tie_area"])
            used["tie_area"] = normaliser.area
            used["source_tie_area"] = tie_area_source(odometry["tie_area"], margin, "this run's dead-reckoned detections")
            models.append(normaliser)
    if "appearance" in settings["models"]:
        appearance = settings["appearance"]
        model, used["source_appearance"] = fitted_appearance(held_out(), appearance["model"], appearance["evidence"],
                                                             appearance["prior_mean"], dataset.signatures,
                                                             appearance["outliers"], appearance["max_outlier_share"])
        names = APPEARANCE_HYPERPARAMETERS[appearance["model"]]
        hyperparameters = {name: np.round(np.atleast_1d(getattr(model, name)), 6).tolist() for name in names}
        if appearance["outliers"]:
            hyperparameters.update(outlier_share=round(model.outlier_share, 6), outlier_scale=round(model.outlier_scale, 6))
        used["appearance_hyperparameters"] = json.dumps(hyperparameters)
        models.append(model)
    used["prior_rate"], used["source_prior_rate"] = prior_rate(settings["inference"], dataset.n, held_out)
    return ptm.Posterior(dataset, ptm.PoissonPrior(used["prior_rate"]), models), used


def _run_inference(cell: dict, dataset: ptm.Dataset) -> dict:
    inference = cell["settings"]["inference"]
    posterior, used = build_posterior(cell, dataset)
    sampler_seed, _ = _inference_seeds(cell["seed"], inference["sampler_stream"])
    method = inference["method"]
    moves = resolved_moves(inference["moves"], posterior.n)
    burn_in = resolved_burn_in(inference)
    result = None
    if method == "auto":  # the exact posterior is the reference wherever it is affordable
        result = _affordable_exact_posterior(posterior, inference)
        method = "tempered" if result is None else "exact"
    elif method == "exact":
        result = ptm.exact_posterior(posterior, max_n=inference["exact_max_n"])
    if method == "tempered":
        result = ptm.tempered_mcmc(posterior, inference["n_samples"], temperatures=inference["temperatures"],
                                   burn_in=burn_in, thin=inference["thin"], seed=sampler_seed,
                                   chains=inference["chains"], max_doublings=inference["max_doublings"],
                                   estimate=inference["estimate"], **_sampler_options(moves, inference, posterior))
    elif method == "mcmc":
        result = ptm.mcmc(posterior, inference["n_samples"], burn_in=burn_in, thin=inference["thin"],
                          seed=sampler_seed, chains=inference["chains"], max_doublings=inference["max_doublings"],
                          estimate=inference["estimate"], **_sampler_options(moves, inference, posterior))
    row = scoring.score(result, dataset.labels)
    row.update(used)
    row["inference_method"] = method
    row["inference_moves"] = moves if method in ("mcmc", "tempered") else ""
    row["inference_burn_in"] = burn_in if method in ("mcmc", "tempered") else ""
    row["warning"] = disagreement(result.diagnostics)
    row.update(_flat_diagnostics(result.diagnostics))
    row["entropy"] = result.entropy()
    row["top5"] = json.dumps([[list(labels), round(probability, 6)] for labels, probability in result.top(TOP_K)])
    for name, trace in result.traces.items():
        row[f"trace_{name}"] = json.dumps(_thinned(trace).tolist())
    return row


def _affordable_exact_posterior(posterior: ptm.Posterior, inference: dict) -> ptm.PTM | None:
    """The exact posterior if N <= ``exact_max_n`` and the odometry term is needed on at most
    ``AUTO_EXACT_GLOBAL_EVALUATIONS`` partitions, else None (method "auto" then samples)."""
    if posterior.n > inference["exact_max_n"]:
        return None
    try:
        return ptm.exact_posterior(posterior, max_n=inference["exact_max_n"],
                                   max_global_evaluations=AUTO_EXACT_GLOBAL_EVALUATIONS)
    except ptm.exact.ExactBudgetExceeded:  # the cheap terms leave too many partitions in play
        return None


def resolved_moves(moves: str, n: int) -> str:
    """The move set ``inference.moves`` stands for on ``n`` detections: ``"auto"`` is ``"guided"`` from
    ``GUIDED_FROM_N`` detections on, else ``"default"``."""
    if moves != "auto":
        return moves
    return "guided" if n >= GUIDED_FROM_N else "default"


def resolved_burn_in(inference: dict) -> int:
    """The steps each chain discards first: ``inference.burn_in``, or half of ``n_samples`` when unset."""
    return inference["n_samples"] // 2 if inference["burn_in"] is None else inference["burn_in"]


def _sampler_options(moves: str, inference: dict, posterior: ptm.Posterior) -> dict:
    """The sampler's moves, delayed acceptance and start for a resolved move set (:func:`resolved_moves`):
    with ``inference.warm_up = "smc"`` every chain starts from its own SMC pass (``SMC_START_PARTICLES``);
    otherwise ``"guided"`` always warms up (docs/model.md §3.4), the others with ``inference.warm_up = "all"``. With
    odometry, ``inference.map_window`` = "default" or "all" adds the map-steered window to the default moves
    (:func:`ptm.sampler.default_moves`), and "all" steers the guided moves' window by the map too."""
    unscreened = {"unscreened_share": inference["unscreened_share"]}
    smc = {"warm_up": 0, "smc_start": SMC_START_PARTICLES} if inference["warm_up"] == "smc" else {}
    map_window = inference["map_window"]
    if moves == "guided":
        return {**ptm.sampler.guided_options(posterior, inference["delayed_acceptance"], map_window == "all"),
                **unscreened, **smc}
    chosen = [(ptm.moves.SplitMerge(), 1.0)] if moves == "paper" else None
    steered = moves == "default" and map_window in ("default", "all")
    surrogate = ptm.surrogate.OdometrySurrogate(posterior) if steered else None
    if surrogate is not None and surrogate.terms:  # without a map, the default moves as they were
        chosen = ptm.sampler.default_moves(surrogate)
    warm_up = ptm.sampler.WARM_UP_PER_DETECTION * posterior.n if inference["warm_up"] == "all" else 0
    return {"moves": chosen, "delayed_acceptance": inference["delayed_acceptance"], "warm_up": warm_up, **unscreened, **smc}


def disagreement(diagnostics: dict) -> str:
    """A warning when a sampler's independent chains disagree (:func:`ptm.diagnostics.chains_agree`: split
    R-hat of log P and of the number of places, co-assignments), saying what was reached and which chains
    strayed into a mode far below the others', or "" when they agree or the result has no several chains (the
    exact posterior, one chain).

        >>> disagreement({"rhat_log_prob": 1.52, "rhat_num_places": 1.01, "coassignment_max_difference": 0.4,
        ...               "doublings": 2})
        'independent chains disagree: split R-hat of log P 1.52 (want <= 1.05), of the number of places 1.01 (<= 1.05), largest co-assignment difference 0.4 (<= 0.05), after doubling the chains 2 times; the PTM is not converged: sample longer (inference.n_samples, inference.max_doublings), or try inference.method = "tempered"'
    """
    if ptm.diagnostics.chains_agree(diagnostics) in (True, None):
        return ""
    rhat, coassignment = ptm.diagnostics.AGREEMENT_RHAT, ptm.diagnostics.AGREEMENT_COASSIGNMENT
    doublings = diagnostics.get("doublings", 0)
    judged = diagnostics.get("estimate") != "renormalised"  # the R-hats count (ptm.diagnostics.chains_agree)
    rhats = (f"split R-hat of log P {diagnostics['rhat_log_prob']:.3g}" + f" (want <= {rhat})" * judged
             + f", of the number of places {diagnostics['rhat_num_places']:.3g}" + f" (<= {rhat})" * judged)
    difference = (f"largest co-assignment difference {diagnostics['coassignment_max_difference']:.3g} "
                  f"(<= {coassignment})")
    reached = (f"{rhats}, {difference}" if judged else
               f"{difference} between the chains' renormalised estimates ({rhats}: not judged, as the estimate "
               "does not count visits)")
    return (f"independent chains disagree: {reached}"
            + (f", after doubling the chains {doublings} time{'s' * (doublings != 1)}" if doublings else "")
            + _strays(diagnostics)
            + '; the PTM is not converged: sample longer (inference.n_samples, inference.max_doublings), or try '
              'inference.method = "tempered"')


def _strays(diagnostics: dict) -> str:
    """The warning's account of stray chains (:meth:`ptm.sampler.SampleRecorder.strays`), or ""."""
    strays = diagnostics.get("stray_chains", 0)
    if not strays:
        return ""
    chains = diagnostics.get("chains")
    counted = f"{strays} of {chains} chains" if chains else f"{strays} chain{'s' * (strays != 1)}"
    kept = ("the renormalised estimate gives their topologies next to nothing"
            if diagnostics.get("estimate") == "renormalised" else "their visits count in the frequencies")
    return (f"; {counted} stayed in topologies at least {diagnostics['stray_log_prob_gap']:.3g} nats below the best "
            f"found (at most {diagnostics['stray_mass_max']:.2g} of the renormalised mass each): {kept}")


def _inference_seeds(seed: int, sampler_stream: int = 0) -> tuple[np.random.SeedSequence, np.random.SeedSequence]:
    """The cell's sampler and importance-sampling seeds; a ``sampler_stream`` other than 0 branches the sampler's
    alone (``inference.sampler_stream``), so that the posterior stays the same."""
    sampler, importance = np.random.SeedSequence(seed, spawn_key=(INFERENCE_KEY,)).spawn(2)
    if sampler_stream:
        sampler = np.random.SeedSequence(sampler.entropy, spawn_key=(*sampler.spawn_key, sampler_stream))
    return sampler, importance


def _flat_diagnostics(diagnostics: dict, prefix: str = "") -> dict:
    """Scalar diagnostics as ``diag_<name>`` columns; nested per-term dicts become ``diag_<term>_<name>``."""
    flat = {}
    for key, value in diagnostics.items():
        name = f"{prefix}{key}"
        if isinstance(value, dict):
            flat.update(_flat_diagnostics(value, prefix=f"{name}_"))
        elif isinstance(value, (bool, int, float, np.integer, np.floating, str)):
            flat[f"diag_{name}"] = value.item() if isinstance(value, np.generic) else value
    return flat


def _thinned(trace) -> np.ndarray:
    trace = np.asarray(trace, dtype=float)
    step = max(1, trace.shape[-1] // TRACE_POINTS)
    return np.round(trace[..., ::step], 3)
