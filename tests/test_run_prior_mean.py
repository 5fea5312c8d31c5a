"""appearance.prior_mean = "run": the prior mean of a place's appearance is the scored run's own mean.

Synthetic worlds in which every run draws its decor anew: at "aliasing 1" all
places of a run share the run's one appearance, at "aliasing 0" each place has
its own. Fitted across runs with one global mean, the spread between runs is
taken for spread between places, and a run whose places all look alike is
read, confidently, as a single place; centred on each run, the fit sees that
places of one world do not differ, and the posterior stays near the prior.
"""

import numpy as np
import pytest

import ptm
from ptm_bench.evaluation.calibration import fitted_appearance
from ptm_bench.evaluation.experiment import parse_experiment
from ptm_bench.evaluation.scoring import score

LABELS = np.array([0, 1, 2, 3, 0, 1, 2, 3])


def _run(rng, aliased: bool) -> ptm.Dataset:
    world = rng.normal(1.0, 0.5, size=3)  # this run's decor
    places = world + (0.0 if aliased else rng.normal(0.0, 0.5, size=(4, 3)))
    signatures = np.broadcast_to(places, (4, 3))[LABELS] + rng.normal(0.0, 0.02, size=(len(LABELS), 3))
    return ptm.Dataset(signatures=signatures, labels=LABELS)


def _scores(aliased: bool, prior_mean: str, seeds=range(3)) -> list[dict]:
    rng = np.random.default_rng(4)
    calibration = [_run(rng, aliased) for _ in range(10)]
    rows = []
    for _ in seeds:
        scored = _run(rng, aliased)
        model, _ = fitted_appearance(calibration, prior_mean=prior_mean, scored_signatures=scored.signatures)
        posterior = ptm.Posterior(ptm.Dataset(signatures=scored.signatures), ptm.PoissonPrior(4.0), [model])
        result = ptm.exact_posterior(posterior)
        rows.append(score(dict(result.top(len(result))), scored.labels))
    return rows


def test_a_global_prior_mean_is_confidently_wrong_when_every_place_of_a_run_looks_alike():
    """The negative control: the failure the run mean removes (measured on the grid at aliasing 1)."""
    assert all(row["confidently_wrong"] and row["map_places"] == 1 for row in _scores(True, "global"))


def test_a_run_prior_mean_stays_uncertain_when_every_place_of_a_run_looks_alike():
    for row in _scores(True, "run"):
        assert not row["confidently_wrong"] and row["map_mass"] < 0.5


def test_a_run_prior_mean_still_tells_distinct_places_apart():
    assert all(row["gt_mass"] > 0.9 for row in _scores(False, "run"))


def test_the_run_prior_mean_needs_the_scored_signatures_and_a_known_name():
    calibration = [_run(np.random.default_rng(0), False)]
    with pytest.raises(ValueError, match="needs the scored run's signatures"):
        fitted_appearance(calibration, prior_mean="run")
    with pytest.raises(ValueError, match="appearance.prior_mean"):
        parse_experiment({"sweep": {"worlds": ["short_loop"], "seeds": [0]}, "appearance": {"prior_mean": "world"}})


def test_the_run_mean_is_the_default_and_the_global_mean_is_another_cell():
    from pathlib import Path

    from ptm_bench.evaluation.experiment import expand_cells

    def definition(appearance):
        config = {"sweep": {"worlds": ["short_loop"], "aliasing": [0.0], "noise": [1.0], "seeds": [0]},
                  "variants": [{"name": "a", "models": ["appearance"], "appearance": appearance}]}
        (cell,) = expand_cells(parse_experiment(config), Path("unused"))
        return cell["definition"]

    assert definition({}) == definition({"prior_mean": "run"}) != definition({"prior_mean": "global"})
