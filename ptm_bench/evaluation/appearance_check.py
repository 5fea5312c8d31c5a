"""Predictive check of the appearance models on held-out simulated runs (docs/model.md §3.2, §6).

An appearance model is fitted by empirical Bayes on labelled calibration runs
and then asked about runs it has never seen, at aliasing 0 (every place has
its own decor, so a good model should rarely be fooled):

* **revisit pairs favouring "split"**: the share of pairs of detections of one
  place whose Bayes factor log p({i, j}) - log p({i}) - log p({j}) is below 0;
* **different-place pairs favouring "merge"**: the share of pairs of distinct
  places whose Bayes factor is above 0 (both shares with an exact binomial 95 %
  interval: pairs are few, and the interval says whether a target is met);
* **probability integral transform (PIT)** of each revisit under the
  posterior predictive given the other visits of its place, per signature
  component (uniform on [0, 1] when the model's predictive is calibrated; piled
  up at 0 and 1 when it is overconfident), with the share of two-sided
  predictive p-values below 0.001 (0.1 % expected) and the Kolmogorov-Smirnov
  p-value against the uniform.

The independent-component model with visits from unusual standpoints
(``appearance.outliers = true``, docs/model.md §3.2.2; with the share of such
visits bounded at 0.1, ``appearance.max_outlier_share``, and unbounded), the
joint Normal-Inverse-Wishart model (``ptm.JointAppearanceModel``) and the
paper's independent-component model (``ptm.AppearanceModel``) are checked on
the same runs, with the prior mean the harness uses by default (the
scored run's own mean signature, ``appearance.prior_mean = "run"``), the last
two also with the paper's one global mean (:data:`APPEARANCE_MODELS`); the fits are those of
:func:`ptm_bench.evaluation.calibration.fitted_appearance`, as in a sweep (fitted once per world and model). ``ptm-bench appearance-check`` writes ``checks.csv``, ``pit.csv``,
``summary.md`` and ``pit.png`` to its output folder.

    $ ptm-bench appearance-check --worlds office --runs 30 --calibration-runs 10
"""

from __future__ import annotations

import time

import numpy as np
import pandas as pd
from scipy import stats

import ptm

from ptm_bench.evaluation.calibration import appearance_fitter
from ptm_bench.evaluation.datacache import dataset_for

__all__ = ["APPEARANCE_MODELS", "CONFIDENCE", "DEFAULT_WORLDS", "EXTREME_P", "PIT_BINS", "predictive_check"]

#: The models checked: name -> the ``[appearance]`` settings of a sweep's config that make it (``model``,
#: ``prior_mean``, ``outliers``, ``max_outlier_share``; the keyword arguments of
#: :func:`ptm_bench.evaluation.calibration.appearance_fitter`).
APPEARANCE_MODELS = {
    "independent + rare outliers": {"model": "independent", "prior_mean": "run", "outliers": True,
                                    "max_outlier_share": 0.1},
    "independent + outliers": {"model": "independent", "prior_mean": "run", "outliers": True},
    "independent": {"model": "independent", "prior_mean": "run", "outliers": False},
    "joint": {"model": "joint", "prior_mean": "run", "outliers": False},
    "independent (global mean)": {"model": "independent", "prior_mean": "global", "outliers": False},
    "joint (global mean)": {"model": "joint", "prior_mean": "global", "outliers": False},
}
DEFAULT_WORLDS = {
    "office": "office",
    "nested_loops": "nested_loops",
    "grid3x3": {"generator": "corridor_grid", "name": "grid3x3", "rows": 3, "cols": 3, "loops": 2, "place_density": 0.6},
}
PIT_BINS = 10
EXTREME_P = 1e-3  # a two-sided predictive p-value below this is an "extreme" visit
CONFIDENCE = 0.95  # of the intervals around the pair shares
CALIBRATION_FIRST_SEED = 1000


def predictive_check(worlds: dict, runs: int = 30, calibration_runs: int = 10, aliasing: float = 0.0,
                     noise: float = 1.0, cache_dir=None) -> tuple[pd.DataFrame, pd.DataFrame]:
    """Fit every model on ``calibration_runs`` runs per world and check it on ``runs`` others.

    Returns (one row per world and model with the pair shares and PIT summaries,
    one row per world, model, held-out visit and component with its PIT value).
    Scored runs use seeds 0..runs-1, calibration runs 1000..; they never overlap.
    """
    if runs < 1 or calibration_runs < 1:
        raise ValueError(f"runs and calibration_runs must be >= 1, got {runs} and {calibration_runs}")
    if runs > CALIBRATION_FIRST_SEED:
        raise ValueError(f"runs must be at most {CALIBRATION_FIRST_SEED} so scored and calibration seeds stay apart")
    rows, pit_rows = [], []
    for world_name, world_spec in worlds.items():
        def datasets(seeds):
            return [dataset_for(world_spec, aliasing, noise, seed, cache_dir=cache_dir) for seed in seeds]

        calibration = datasets(range(CALIBRATION_FIRST_SEED, CALIBRATION_FIRST_SEED + calibration_runs))
        scored = datasets(range(runs))
        for model_name, settings in APPEARANCE_MODELS.items():
            started = time.perf_counter()
            fitter = appearance_fitter(calibration, **settings)
            row, pits = _check(lambda dataset: fitter(dataset.signatures)[0], scored)
            rows.append({"world": world_name, "model": model_name, "runs": runs,
                         "calibration_runs": calibration_runs, "aliasing": aliasing, "noise": noise,
                         "aliasing_auc": float(np.nanmean([d.meta.get("aliasing_auc", np.nan) for d in scored])),
                         **row, "wall_s": time.perf_counter() - started})
            pit_rows.extend({"world": world_name, "model": model_name, "visit": visit, "component": component,
                             "pit": value}
                            for visit, values in enumerate(pits) for component, value in enumerate(values))
    return pd.DataFrame(rows), pd.DataFrame(pit_rows)


def _check(fitted, datasets) -> tuple[dict, np.ndarray]:
    """``fitted(dataset)``: the appearance model a sweep would use to score ``dataset``."""
    same_factors, different_factors, pits = [], [], []
    for dataset in datasets:
        real = dataset.labels >= 0
        signatures, labels = dataset.signatures[real], dataset.labels[real]
        term = fitted(dataset).bind(ptm.Dataset(signatures=signatures))
        factors = ptm.appearance.pairwise_log_bayes_factors(term)
        upper = np.triu_indices(len(labels), 1)
        same = labels[upper[0]] == labels[upper[1]]
        same_factors.append(factors[upper][same])
        different_factors.append(factors[upper][~same])
        loo = ptm.appearance.leave_one_out_pit(term, labels)
        pits.append(loo[~np.isnan(loo).any(axis=1)])
    same_factors = np.concatenate(same_factors)
    different_factors = np.concatenate(different_factors)
    pits = np.concatenate(pits)
    two_sided = 2 * np.minimum(pits, 1 - pits)
    row = {
        "revisit_pairs": same_factors.size,
        **_share("revisits_favouring_split", same_factors < 0),
        "different_pairs": different_factors.size,
        **_share("different_favouring_merge", different_factors > 0),
        "held_out_visits": pits.shape[0],
        "extreme_share_max": float((two_sided < EXTREME_P).mean(axis=0).max()) if pits.size else np.nan,
    }
    for component in range(pits.shape[1]):
        row[f"extreme_share_{component}"] = float(np.mean(two_sided[:, component] < EXTREME_P))
        row[f"ks_p_{component}"] = float(stats.kstest(pits[:, component], "uniform").pvalue)
    return row, pits


def _share(name: str, hits: np.ndarray) -> dict:
    """The share of True in ``hits`` and its exact (Clopper-Pearson) 95 % interval, NaN when empty.

    A pair share is a binomial proportion: 3 of 132 is 0.023, but the interval
    is 0.005-0.065, so a run count that leaves the interval straddling a target
    cannot say on which side of it the model lies. Pairs that share a detection
    are not independent, so the interval is, if anything, too narrow.
    """
    if hits.size == 0:
        return {name: np.nan, f"{name}_low": np.nan, f"{name}_high": np.nan}
    interval = stats.binomtest(int(hits.sum()), hits.size).proportion_ci(CONFIDENCE, method="exact")
    return {name: float(hits.mean()), f"{name}_low": float(interval.low), f"{name}_high": float(interval.high)}
