"""Replaying a run through the online mapper, its parameters calibrated as a sweep calibrates them
(docs/model.md §3.8; :mod:`ptm_bench.evaluation.calibration`).

:func:`calibrated_mapper` builds the mapper's prior and models with the one builder of the harness,
:func:`ptm_bench.evaluation.models.build_models` (``online=True``), from the experiment's settings (by default
:data:`ptm_bench.evaluation.settings.DEFAULTS`). The mapper sees each detection once, in order, so what a sweep
takes from the whole scored run is not available; the builder says where that makes the two differ (the
appearance prior mean, the area of the normalised ties, the prior as a function of the detections so far).

    $ ptm-bench online intel.npz --calibration aces.npz fhw.npz acapulco.npz
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

import numpy as np

import ptm

from ptm_bench.evaluation.models import build_models
from ptm_bench.evaluation.settings import Variant

__all__ = ["COLLAPSED_ESS_SHARE", "calibrated_mapper", "collapse_warning", "replay"]

#: An online PTM whose particles' effective sample size fell below this share of the particles at some
#: detection descends from a handful of them: its probabilities are the shares of one or two lineages that
#: the rejuvenation moves could not spread again (docs/model.md §3.8).
COLLAPSED_ESS_SHARE = 0.05


def calibrated_mapper(dataset: ptm.Dataset, held_out: Sequence[ptm.Dataset], variant: Variant | None = None, *,
                      particles: int = 128, seed: int = 0) -> tuple[ptm.OnlineMapper, dict]:
    """An :class:`ptm.OnlineMapper` for ``dataset`` with the models of ``variant`` (by default the harness's
    defaults, odometry and appearance) calibrated on the labelled ``held_out`` runs, and the parameters it uses
    with their sources (``{name: value, "source_" + name: text}``).

    ``dataset`` is read only for what a robot knows before it starts: the detector's radius (its meta) and
    which measurements it has. A model the dataset has no measurements for is a ``ValueError``.
    """
    variant = Variant("online") if variant is None else variant
    if not variant.models:
        raise ValueError("the online mapper needs at least one model (odometry, appearance)")
    built = build_models(variant, dataset, held_out, online=True, importance_seed=seed)
    return ptm.OnlineMapper(built.prior, built.models, particles=particles, seed=seed), built.used


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
