"""Replaying a run through the online mapper, with its parameters calibrated as a sweep calibrates them
(docs/model.md §3.8; :mod:`ptm_bench.evaluation.calibration`).

The mapper sees each detection once, in order, so what a sweep takes from the whole scored run is not
available: the appearance model (the harness's default, rare outlier visits included) is fitted with one
prior mean for every run (the run's own mean signature is known only at its end), and the prior rate is
a function of n (places per detection on the held-out runs x n,
:func:`ptm_bench.evaluation.calibration.prior_rate`), and so is the area of the normalised ties
(``odometry.tie_normaliser``: :class:`ptm.DeadReckonedTieNormaliser`, the detections so far). The
penalty radius comes from the held-out places and the tie from the detector's radius, as in a sweep.

    $ ptm-bench online intel.npz --calibration aces.npz fhw.npz acapulco.npz
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

import numpy as np

import ptm

from ptm_bench.evaluation import calibration
from ptm_bench.evaluation.experiment import DEFAULTS, MODEL_NAMES, resolved_appearance

__all__ = ["COLLAPSED_ESS_SHARE", "calibrated_mapper", "collapse_warning", "replay"]

#: An online PTM whose particles' effective sample size fell below this share of the particles at some
#: detection descends from a handful of them: its probabilities are the shares of one or two lineages that
#: the rejuvenation moves (accepting 0.1-1 % of their proposals on the real logs) could not spread again.
#: On FHW the ESS fell to 2.0 of 128 and the final MAP, 3 nats below the truth under the batch posterior,
#: had probability 0.985; on ACES and Intel, which it did not warn about, 52 and 35.
COLLAPSED_ESS_SHARE = 0.05


def calibrated_mapper(dataset: ptm.Dataset, held_out: Sequence[ptm.Dataset], models=MODEL_NAMES,
                      particles: int = 128, seed: int = 0) -> tuple[ptm.OnlineMapper, dict]:
    """An :class:`ptm.OnlineMapper` for ``dataset`` with ``models`` calibrated on the labelled ``held_out`` runs,
    and the parameters it uses with their sources (``{name: value, "source_" + name: text}``).

    ``dataset`` is read only for what a robot knows before it starts: the detector's radius (its meta) and
    which measurements it has. A model the dataset has no measurements for is a ``ValueError``.
    """
    unknown = set(models) - set(MODEL_NAMES)
    if unknown or not models:
        raise ValueError(f"models must be a non-empty subset of {MODEL_NAMES}, got {list(models)}")
    settings, built, used = DEFAULTS["odometry"], [], {}
    if "appearance" in models:
        if dataset.signatures is None:
            raise ValueError("the dataset has no signatures for the appearance model")
        appearance = resolved_appearance(DEFAULTS["appearance"])
        model, used["source_appearance"] = calibration.fitted_appearance(
            held_out, appearance["model"], appearance["evidence"], prior_mean="global", outliers=appearance["outliers"],
            max_outlier_share=appearance["max_outlier_share"])
        built.append(model)
    if "odometry" in models:
        if dataset.odometry is None:
            raise ValueError("the dataset has no odometry for the odometry model")
        used["penalty_radius"], used["source_penalty_radius"] = calibration.penalty_radius(settings, held_out)
        used["sigma_topology"], used["source_sigma_topology"] = calibration.topology_sigma(settings, dataset.meta)
        built.append(ptm.OdometryModel(settings["sigma_xy"], settings["sigma_theta"], used["sigma_topology"],
                                       used["penalty_radius"], settings["max_penalty"],
                                       n_importance=settings["n_importance"], seed=seed,
                                       sampling_coordinates=settings["sampling_coordinates"],
                                       penalty_proposal=settings["penalty_proposal"],
                                       fit_starts=settings["fit_starts"]))
        if settings["tie_normaliser"]:
            margin = calibration.tie_area_margin(dataset.meta)
            built.append(ptm.DeadReckonedTieNormaliser(used["sigma_topology"], margin, settings["tie_area"]))
            used["source_tie_area"] = calibration.tie_area_source(settings["tie_area"], margin,
                                                                  "the dead-reckoned detections so far")
    share = calibration.places_per_detection(held_out)
    used["source_prior_rate"] = (f"calibrated: for n detections, the rate expecting {share:.3g} places/detection "
                                 f"(held out) x n places")

    def prior_of(n: int) -> ptm.PoissonPrior:
        return ptm.PoissonPrior(calibration.prior_rate({"prior_rate": None}, n, held_out)[0])

    return ptm.OnlineMapper(prior_of, built, particles=particles, seed=seed), used


def collapse_warning(result: ptm.PTM) -> str | None:
    """A warning when the online PTM's particles collapsed (:data:`COLLAPSED_ESS_SHARE`), else None."""
    particles, ess = result.diagnostics["particles"], result.diagnostics["ess"]
    lowest = int(np.argmin(ess))
    if ess[lowest] >= COLLAPSED_ESS_SHARE * particles:
        return None
    return (f"the particles collapsed: their effective sample size fell to {ess[lowest]:.1f} of {particles} at "
            f"detection {lowest + 1}, so the probabilities are those of the few lineages that survived, not a "
            "converged posterior; replay with more particles (--particles) and compare")


def replay(dataset: ptm.Dataset, mapper: ptm.OnlineMapper,
           each: Callable[[int, ptm.PTM], None] | None = None) -> ptm.PTM:
    """Feed ``dataset``'s detections to ``mapper`` one at a time (signature, odometry row and covariance, as
    it has them); ``each(n, ptm)`` after every update. Returns the PTM after the last detection."""
    uses_appearance = any(isinstance(model, (ptm.AppearanceModel, ptm.JointAppearanceModel))
                          for model in mapper.models)
    uses_odometry = any(isinstance(model, ptm.OdometryModel) for model in mapper.models)
    fed = ptm.Dataset(signatures=dataset.signatures if uses_appearance else None,
                      odometry=dataset.odometry if uses_odometry else None,
                      odometry_cov=dataset.odometry_cov if uses_odometry else None)
    return mapper.extend(fed, each)
