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
serve every variant of a seed (common random numbers across variants).

A baseline cell runs a threshold baseline (:mod:`ptm_bench.evaluation.baselines`) or a peer, a robust
pose-graph back end (:mod:`ptm_bench.evaluation.peers`), on the same dataset, calibrated on the same
held-out runs as the posterior's cells. A peer assumes the posterior's noise: the configured odometry
sigmas, the dataset's ``odometry_cov`` where it has one, and the tie sigma by the posterior's rule
(:func:`ptm_bench.evaluation.calibration.topology_sigma`); the scored run reaches it without its labels
and true poses. Its row holds the scores of its partition (a point mass) with the average precision of its
pair scores, its chosen settings (``peer_settings``) and their source, and the time of its one run beside
that of its calibration. A peer whose solver fails on the scored run raises :class:`PeerFailed` with the
solver's message, which the sweep records as the cell's error.

The posterior is paper eq. (2), built by :func:`ptm_bench.evaluation.models.build_models`
from the cell's settings: the Poisson prior (eq. 8-9), the odometry likelihood
(eq. 11-14) with its normalised ties and the appearance likelihood (eq. 15-19,
corrected). The samplers run with the settings' values only; which moves and
starts they use is the library's rule (``ptm.SamplerOptions``, docs/model.md §3.4),
and the row records the move set and burn-in they ran (``inference_moves``,
``inference_burn_in``).

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
    >>> row["n_measurements"], row["source_threshold"]                 # calibrated on another floor
    (9, 'calibrated: best mean ARI on 1 held-out run [nested_loops]')
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
from ptm_bench.evaluation.calibration import calibration_datasets, described, topology_sigma
from ptm_bench.evaluation.datacache import dataset_for
from ptm_bench.evaluation.models import build_models
from ptm_bench.evaluation.peers import PEERS, PeerNoise, run_calibrated, score_peer
from ptm_bench.simulation.code_version import code_version

__all__ = ["cell_version", "INFERENCE_KEY", "PeerFailed", "run_cell", "build_posterior", "disagreement"]


class PeerFailed(RuntimeError):
    """A peer's solver failed on the scored run; the message is the solver's."""


def cell_version() -> str:
    """The version of the rules by which a cell computes its row, ``"sha256:<16 hex>"``.

    :func:`ptm_bench.simulation.code_version.code_version` of this module: a digest of the code of every module a
    cell can run (``ptm``, the calibration, scoring, the simulator, ...), docstrings and comments aside. It is part
    of every cell's definition digest, so a change of that code recomputes the rows on the next run of a sweep.
    """
    return code_version(__name__)


#: Spawn-key branch of the inference streams, apart from the simulator's streams of the same seed.
INFERENCE_KEY = 7_000
#: Method "auto" enumerates up to ``exact_max_n`` detections unless the odometry term would be needed on more
#: partitions than this (``ptm.exact_posterior``'s skip rule, known after one evaluation): then it samples.
AUTO_EXACT_GLOBAL_EVALUATIONS = 25_000
TOP_K = 5
TRACE_POINTS = 200


def run_cell(cell: dict) -> dict:
    """Generate (or load) the cell's dataset, run its variant or baseline, and score it."""
    started = time.perf_counter()
    settings, inputs = cell["settings"], cell["inputs"]
    dataset = dataset_for(inputs["world_spec"], cell["aliasing"], cell["noise"], cell["seed"],
                          inputs["generator_options"], inputs["cache_dir"], settings.appearance.components)
    if dataset.labels is None:
        raise ValueError(f"dataset of {cell['cell_id']} has no ground-truth labels to score against")
    inference_started = time.perf_counter()
    if cell["method"] == "baseline":
        row = _run_baseline(cell, dataset)
    else:
        row = _run_inference(cell, dataset)
    row["true_labels"] = json.dumps(list(ptm.canonical(dataset.labels)))
    # The measured aliasing of the run (docs/model.md §6), beside the aliasing knob; NaN where the generator did
    # not measure it.
    row["aliasing_auc"] = float(dataset.meta.get("aliasing_auc", math.nan))
    row["inference_wall_s"] = time.perf_counter() - inference_started
    row["wall_s"] = time.perf_counter() - started
    return row


def _run_baseline(cell: dict, dataset: ptm.Dataset) -> dict:
    if cell["variant"] in PEERS:
        return _run_peer(cell, dataset)
    features = BASELINE_FEATURES[cell["variant"]]
    held_out = calibration_datasets(cell)
    threshold = fit_threshold(held_out, features)
    labels = greedy_threshold_labels(features(dataset), threshold)
    row = scoring.score(scoring.point_mass(labels), dataset.labels)
    row["threshold"] = threshold
    row["source_threshold"] = f"calibrated: best mean ARI on {described(held_out)}"
    row["top5"] = json.dumps([[list(labels), 1.0]])
    return row


def _run_peer(cell: dict, dataset: ptm.Dataset) -> dict:
    """The cell's peer, calibrated on the held-out runs, run on the scored run without its labels, and scored."""
    odometry = cell["settings"].odometry
    held_out = calibration_datasets(cell)
    sigma_tie, tie_source = topology_sigma(odometry.sigma_topology, dataset.meta)
    noise = PeerNoise(odometry.sigma_xy, odometry.sigma_theta, sigma_tie)
    started = time.perf_counter()
    result, calibration = run_calibrated(PEERS[cell["variant"]], dataset.replace(labels=None, true_poses=None),
                                         held_out, noise)
    if result.failed:
        raise PeerFailed(result.error)
    row = score_peer(result, dataset.labels)
    del row["peer_error"]  # a failed run raised above
    row["peer_settings"] = json.dumps(result.settings)
    chosen = ", ".join(f"{name}={value}" for name, value in result.settings.items())
    row["source_peer_settings"] = f"{chosen}: {calibration.source}"
    row["sigma_topology"], row["source_sigma_topology"] = sigma_tie, tie_source
    row["source_odometry_noise"] = (
        "this run's odometry_cov" if dataset.odometry_cov is not None else
        f"config: sigma_xy {odometry.sigma_xy:g} m, sigma_theta {odometry.sigma_theta:g} rad")
    row["peer_run_wall_s"] = result.wall_s
    row["calibration_wall_s"] = time.perf_counter() - started - result.wall_s
    row["top5"] = json.dumps([[list(result.labels), 1.0]])
    return row


def build_posterior(cell: dict, dataset: ptm.Dataset) -> tuple[ptm.Posterior, dict]:
    """The posterior of the cell's variant, and the parameters it used with their sources (for the table).

    :func:`ptm_bench.evaluation.models.build_models` with the cell's settings, its held-out runs
    (:func:`ptm_bench.evaluation.calibration.calibration_datasets`, generated or loaded only if a parameter needs
    them) and the cell's importance-sampling stream.
    """
    _, importance_seed = _inference_seeds(cell["seed"])
    built = build_models(cell["settings"], dataset, functools.cache(lambda: calibration_datasets(cell)),
                         importance_seed=importance_seed)
    return ptm.Posterior(dataset, built.prior, built.models), built.used


def _run_inference(cell: dict, dataset: ptm.Dataset) -> dict:
    inference = cell["settings"].inference
    posterior, used = build_posterior(cell, dataset)
    sampler_seed, _ = _inference_seeds(cell["seed"])
    method = inference.method
    result = None
    if method == "auto":  # the exact posterior is the reference wherever it is affordable
        result = _affordable_exact_posterior(posterior, inference.exact_max_n)
        method = "tempered" if result is None else "exact"
    elif method == "exact":
        result = ptm.exact_posterior(posterior, max_n=inference.exact_max_n)
    options = {"burn_in": inference.burn_in, "chains": inference.chains, "max_doublings": inference.max_doublings,
               "moves": inference.moves}
    if method == "tempered":
        result = ptm.tempered_mcmc(posterior, inference.n_samples, seed=sampler_seed,
                                   temperatures=inference.temperatures, **options)
    elif method == "mcmc":
        result = ptm.mcmc(posterior, inference.n_samples, seed=sampler_seed, **options)
    sampled = method in ("mcmc", "tempered")
    row = scoring.score(result, dataset.labels)
    row.update(used)
    row["inference_method"] = method
    row["inference_moves"] = result.diagnostics["moves"] if sampled else ""
    row["inference_burn_in"] = result.diagnostics["burn_in"] if sampled else ""
    row["warning"] = disagreement(result.diagnostics)
    row.update(_flat_diagnostics(result.diagnostics))
    row["entropy"] = result.entropy()
    if hasattr(posterior.prior, "rate_posterior_of"):  # an uncertain rate: what the run taught about it
        row["prior_rate_posterior_mean"], row["prior_rate_posterior_sd"] = posterior.prior.rate_posterior_of(result)
    if any(getattr(term, "noise_scale_prior", None) is not None for term in posterior.terms):
        scale = ptm.noise_scale_posterior(result, posterior)
        row.update(noise_scale_posterior_mean=scale.mean, noise_scale_posterior_median=scale.quantiles[0.5],
                   noise_scale_in_prior_tail=scale.in_prior_tail)
    row["top5"] = json.dumps([[list(labels), round(probability, 6)] for labels, probability in result.top(TOP_K)])
    for name, trace in result.traces.items():
        row[f"trace_{name}"] = json.dumps(_thinned(trace).tolist())
    return row


def _affordable_exact_posterior(posterior: ptm.Posterior, exact_max_n: int) -> ptm.PTM | None:
    """The exact posterior if N <= ``exact_max_n`` and the odometry term is needed on at most
    ``AUTO_EXACT_GLOBAL_EVALUATIONS`` partitions, else None (method "auto" then samples)."""
    if posterior.n > exact_max_n:
        return None
    try:
        return ptm.exact_posterior(posterior, max_n=exact_max_n, max_global_evaluations=AUTO_EXACT_GLOBAL_EVALUATIONS)
    except ptm.exact.ExactBudgetExceeded:  # the cheap terms leave too many partitions in play
        return None


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
    """The warning's account of stray chains (:meth:`ptm.recorder.SampleRecorder.strays`), or ""."""
    strays = diagnostics.get("stray_chains", 0)
    if not strays:
        return ""
    chains = diagnostics.get("chains")
    counted = f"{strays} of {chains} chains" if chains else f"{strays} chain{'s' * (strays != 1)}"
    kept = ("the renormalised estimate gives their topologies next to nothing"
            if diagnostics.get("estimate") == "renormalised" else "their visits count in the frequencies")
    return (f"; {counted} stayed in topologies at least {diagnostics['stray_log_prob_gap']:.3g} nats below the best "
            f"found (at most {diagnostics['stray_mass_max']:.2g} of the renormalised mass each): {kept}")


def _inference_seeds(seed: int) -> tuple[np.random.SeedSequence, np.random.SeedSequence]:
    """The cell's sampler and importance-sampling seeds, spawned from the cell's seed on the inference branch."""
    sampler, importance = np.random.SeedSequence(seed, spawn_key=(INFERENCE_KEY,)).spawn(2)
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
