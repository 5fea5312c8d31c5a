"""The one builder from settings to models: the prior, the likelihood models and the parameters they use
(docs/model.md §3, §6).

:func:`build_models` turns a :class:`ptm_bench.evaluation.settings.Variant`, a dataset and its labelled held-out
runs into what the posterior of paper eq. (2) is made of: the Poisson prior (eq. 8-9), the odometry likelihood
(eq. 11-14) with the normaliser of its ties (docs/model.md §3.3) and the appearance likelihood (eq. 15-19,
corrected, fitted on the held-out runs), and the parameters used, each with its source (``source_<parameter>``:
the config, a sensor specification, or a calibration on held-out runs). Every entry point calls it: a sweep's cell
(:func:`ptm_bench.evaluation.cell.build_posterior`), the online mapper
(:func:`ptm_bench.evaluation.online.calibrated_mapper`), the summary's map figures and ``ptm-bench export``.

Only what a user of a real robot has is read from the dataset: its odometry, its signatures, its number of
detections and the detector's radius (meta ``detection_radius``, a sensor specification); never its labels, true
poses or the world's places.

Batch and online (``online=True``) differ only where the online mapper cannot know the whole run, in the used
entries named by :data:`ONLINE_DIFFERENCES`:

* the appearance prior mean is one mean for every run ("global"), as the run's own mean signature
  (``appearance.prior_mean = "run"``) is known only at its end;
* the landmarks' area of the normalised ties is that of the dead-reckoned route so far
  (:class:`ptm.DeadReckonedTieNormaliser`, bound anew to each prefix of the run), not of the whole run;
* the prior is a function of the number of detections so far (the held-out places per detection x n);
* the penalty radius is the factor x the closest separation of places on the held-out runs, as the run's own
  route spacing, by which a batch build scales it, is known only at its end.

Without held-out runs (``held_out=None``: a map, whose mode needs neither the prior nor the landmark-density
penalty, docs/model.md §3.3) a parameter that would be calibrated is left out and the used entries say so.

    >>> import ptm
    >>> from ptm_bench.evaluation.settings import Variant
    >>> run = ptm.Dataset(odometry=[[2.0, 0.0, 1.5708]] * 3, meta={"detection_radius": 1.5})
    >>> built = build_models(Variant("map", models=("odometry",)), run, held_out=None)
    >>> round(built.models[0].sigma_topology, 3), built.used["source_sigma_topology"], built.prior is None
    (1.061, 'sensor spec: detection radius 1.5 m / sqrt 2', True)
"""

from __future__ import annotations

import functools
import json
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

import ptm

from ptm_bench.evaluation import calibration
from ptm_bench.evaluation.settings import AppearanceSettings, OdometrySettings, Variant

__all__ = ["ONLINE_DIFFERENCES", "Models", "build_models"]

#: The used entries in which an online build may differ from a batch build of the same settings and dataset.
ONLINE_DIFFERENCES = ("source_appearance", "appearance_hyperparameters", "tie_area", "source_tie_area", "prior_rate",
                      "source_prior_rate", "penalty_radius", "source_penalty_radius")


@dataclass(frozen=True)
class Models:
    """What :func:`build_models` returns.

    ``prior``: a ``ptm.GammaPoissonPrior`` (a ``ptm.PoissonPrior`` where the rate is configured); online, a
    function from the number of detections to one; None without
    held-out runs to calibrate its rate on. ``models``: the likelihood models, to bind to a dataset
    (``ptm.Posterior(dataset, prior, models)``, ``ptm.OnlineMapper(prior, models)``). ``used``: every parameter
    used, ``{name: value, "source_" + name: where it came from}``.
    """

    prior: ptm.GammaPoissonPrior | ptm.PoissonPrior | Callable[[int], ptm.GammaPoissonPrior] | None
    models: tuple
    used: dict


def build_models(variant: Variant, dataset: ptm.Dataset, held_out, *, online: bool = False,
                 importance_seed=0) -> Models:
    """The prior, the likelihood models of ``variant.models`` and the used parameters for ``dataset``.

    ``held_out``: the labelled held-out runs (never ``dataset`` itself), a function returning them (called only
    when a parameter needs them), or None where there are none. ``online``: build for the online mapper, which
    sees the run one detection at a time (the differences are listed in the module's docstring).
    ``importance_seed``: the odometry integral's importance-sampling noise (docs/model.md §3.3, step 3).
    A model the dataset has no measurements for, or that needs held-out runs it was not given, is a
    ``ValueError``.
    """
    runs = None if held_out is None else functools.cache(held_out if callable(held_out) else lambda: list(held_out))
    models, used = [], {}
    if "odometry" in variant.models:
        models += _odometry(variant.odometry, dataset, runs, online, importance_seed, used)
    if "appearance" in variant.models:
        models.append(_appearance(variant.appearance, dataset, runs, online, used))
    return Models(_prior(variant.inference.prior_rate, dataset, runs, online, used), tuple(models), used)


def _odometry(settings: OdometrySettings, dataset: ptm.Dataset, runs, online: bool, seed, used: dict) -> list:
    """The odometry model and the normaliser of its ties (docs/model.md §3.3)."""
    if dataset.odometry is None:
        raise ValueError("the dataset has no odometry for the odometry model")
    sigma, used["source_sigma_topology"] = calibration.topology_sigma(settings.sigma_topology, dataset.meta)
    used["sigma_topology"] = sigma
    if runs is None and settings.penalty_radius is None:
        penalty = {"max_penalty": 0.0}
        used["max_penalty"], used["source_max_penalty"] = 0.0, (
            "no held-out runs to calibrate the penalty radius on: the penalty is off (the map, the mode of the pose "
            "graph, does not depend on it)")
    else:
        radius, used["source_penalty_radius"] = calibration.penalty_radius(
            settings.penalty_radius, settings.penalty_radius_factor, runs, None if online else dataset)
        used["penalty_radius"], used["max_penalty"] = radius, settings.max_penalty
        penalty = {"penalty_radius": radius, "max_penalty": settings.max_penalty}
    scale_prior = ptm.odometry.NoiseScalePrior.wide()  # the covariances' scale, integrated out (docs/model.md §3.3)
    used["noise_scale_prior"] = f"IG(shape {scale_prior.shape:g}, scale {scale_prior.scale:.4g})"
    used["source_noise_scale_prior"] = "wide, median 1 x the configured covariances (95 % within 0.25-11)"
    model = ptm.OdometryModel(sigma_xy=settings.sigma_xy, sigma_theta=settings.sigma_theta, sigma_topology=sigma,
                              n_importance=settings.n_importance, seed=seed, noise_scale_prior=scale_prior,
                              normalised_ties=True, **penalty)
    margin = calibration.tie_area_margin(dataset.meta)
    route = f"within {margin:g} m (the detection radius) of their dead-reckoned route, no labels"
    if online:
        used["source_tie_area"] = f"the detections so far: {route}"
        return [model, ptm.DeadReckonedTieNormaliser(sigma, margin)]
    normaliser = ptm.TieNormaliser.from_dead_reckoning(dataset, sigma, margin)
    used["tie_area"], used["source_tie_area"] = normaliser.area, f"this run's detections: {route}"
    return [model, normaliser]


def _appearance(settings: AppearanceSettings, dataset: ptm.Dataset, runs, online: bool, used: dict):
    """The appearance model, fitted by empirical Bayes on the held-out runs (docs/model.md §3.2)."""
    if dataset.signatures is None:
        raise ValueError("the dataset has no signatures for the appearance model")
    if runs is None:
        raise ValueError("the appearance model is fitted on labelled held-out runs: none were given")
    prior_mean = "global" if online else settings.prior_mean
    model, source = calibration.fitted_appearance(runs(), settings.model, settings.evidence, prior_mean,
                                                  None if online else dataset.signatures, settings.outliers,
                                                  settings.max_outlier_share)
    if prior_mean != settings.prior_mean:
        source += "; one prior mean for every run (online, the run's own mean signature is known only at its end)"
    used["source_appearance"] = source
    hyperparameters = {name: np.round(np.atleast_1d(getattr(model, name)), 6).tolist()
                       for name in calibration.APPEARANCE_HYPERPARAMETERS[settings.model]}
    if settings.outliers:
        hyperparameters.update(outlier_share=round(model.outlier_share, 6), outlier_scale=round(model.outlier_scale, 6))
    used["appearance_hyperparameters"] = json.dumps(hyperparameters)
    return model


def _prior(configured: float | None, dataset: ptm.Dataset, runs, online: bool, used: dict):
    """The Poisson prior (paper eq. 8-9): its rate configured, or calibrated for the run's number of detections
    (online: for each number of detections so far)."""
    if runs is None and configured is None:
        used["source_prior_rate"] = "no held-out runs to calibrate the prior rate on: no prior (a map needs none)"
        return None
    if not online:
        used["prior_rate"], used["source_prior_rate"] = calibration.prior_rate(configured, dataset.n, runs)
        return _prior_of_rate(used["prior_rate"], configured)
    if configured is not None:
        used["prior_rate"], used["source_prior_rate"] = float(configured), calibration.CONFIG
        return ptm.PoissonPrior(configured)
    share = calibration.places_per_detection(runs())
    used["source_prior_rate"] = (f"calibrated: for n detections, the rate expecting {share:.3g} places/detection "
                                 f"on {calibration.described(runs())} x n places")
    return functools.partial(_calibrated_prior, runs=runs)


def _calibrated_prior(n: int, runs: Callable[[], Sequence[ptm.Dataset]]) -> ptm.GammaPoissonPrior:
    return _prior_of_rate(calibration.prior_rate(None, n, runs)[0], None)


def _prior_of_rate(rate: float, configured: float | None):
    """A configured rate is plugged in (``ptm.PoissonPrior``); a calibrated one is uncertain
    (``ptm.GammaPoissonPrior`` of shape ``calibration.PRIOR_RATE_SHAPE``, docs/model.md §3.1)."""
    if configured is not None:
        return ptm.PoissonPrior(rate)
    return ptm.GammaPoissonPrior(rate, calibration.PRIOR_RATE_SHAPE)
