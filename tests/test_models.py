"""The one builder of the models (ptm_bench.evaluation.models): a sweep's cell, the online mapper, the summary's
maps and ``ptm-bench export`` get their models from it, and differ only where it says so.

The runs are the hand-made square loops of tests/helpers.py (four corner places, noisy odometry, a signature per
place, detector radius 0.5 m), so nothing is simulated.
"""

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

import ptm
from ptm_bench.cli import main
from ptm_bench.cli.export import map_models
from ptm_bench.evaluation import cell as cell_module
from ptm_bench.evaluation.experiment import expand_cells, parse_experiment
from ptm_bench.evaluation.models import ONLINE_DIFFERENCES, build_models
from ptm_bench.evaluation.online import calibrated_mapper
from ptm_bench.evaluation.settings import AppearanceSettings, OdometrySettings, Variant
from ptm_bench.reporting import summary

from helpers import square_loop_dataset

SCORED = square_loop_dataset(0)
HELD_OUT = [square_loop_dataset(10), square_loop_dataset(11)]
ODOMETRY_PARAMETERS = ("sigma_xy", "sigma_theta", "sigma_topology", "n_importance")


def batch_cell(monkeypatch, variants=None, **sections):
    """The first cell of a one-seed config on short_loop, its held-out runs the hand-made loops."""
    config = {"sweep": {"worlds": ["short_loop"], "seeds": [0], "calibration_seeds": [10, 11]}, **sections}
    if variants is not None:
        config["variants"] = variants
    monkeypatch.setattr(cell_module, "calibration_datasets", lambda cell: HELD_OUT)
    return expand_cells(parse_experiment(config), Path("unused"))[0]


def odometry_model(models):
    (model,) = [model for model in models if isinstance(model, ptm.OdometryModel)]
    return model


def test_the_batch_cell_the_online_mapper_and_the_export_build_the_same_odometry_model(monkeypatch):
    posterior, used = cell_module.build_posterior(batch_cell(monkeypatch), SCORED)
    batch = odometry_model(term.model for term in posterior.terms if hasattr(term, "model"))
    mapper, online_used = calibrated_mapper(SCORED, HELD_OUT, particles=8)
    online = odometry_model(mapper.models)
    exported = map_models(SCORED)
    export = odometry_model(exported.models)
    for name in ODOMETRY_PARAMETERS:
        assert getattr(batch, name) == getattr(online, name) == getattr(export, name), name
    assert batch.sigma_topology == pytest.approx(0.5 / np.sqrt(2.0))  # the detector's radius / sqrt 2
    assert batch.max_penalty == online.max_penalty
    # the radius: batch scales the held-out ratio by this run's route spacing, online (which knows the route only
    # at its end) takes the held-out runs' closest separation; on these runs of one floor the two nearly agree
    assert batch.penalty_radius == pytest.approx(online.penalty_radius, rel=0.1)
    assert "this run's route spacing" in used["source_penalty_radius"]
    # the same prior: online, a function of the detections so far, at the scored run's N the batch rate
    online_prior = build_models(Variant("online"), SCORED, HELD_OUT, online=True).prior
    assert online_prior(SCORED.n).rate == pytest.approx(used["prior_rate"], rel=1e-12)
    # batch and online differ only in the used entries the builder names
    differing = {key for key in used.keys() | online_used.keys() if used.get(key) != online_used.get(key)}
    assert differing <= set(ONLINE_DIFFERENCES), differing - set(ONLINE_DIFFERENCES)
    assert "one prior mean for every run" in online_used["source_appearance"]
    assert online_used["source_tie_area"].startswith("the detections so far: ")
    # the export has no held-out runs: no prior and no penalty, which the map does not depend on, and it says so
    assert export.max_penalty == 0.0 and exported.prior is None
    assert exported.used["source_max_penalty"].startswith("no held-out runs to calibrate the penalty radius on")
    assert {key: value for key, value in exported.used.items() if "penalty" not in key and "prior" not in key} == {
        key: value for key, value in used.items() if key in exported.used and "penalty" not in key
        and "prior" not in key}


def test_the_online_build_differs_where_the_builder_says(monkeypatch):
    """The appearance prior mean is global online (the run's mean is known only at its end), the tie normaliser
    grows with the route, the prior with the detections."""
    variant = Variant("v")
    batch = build_models(variant, SCORED, HELD_OUT)
    online = build_models(variant, SCORED, HELD_OUT, online=True)
    global_mean = build_models(replace(variant, appearance=AppearanceSettings(prior_mean="global")), SCORED, HELD_OUT)
    assert isinstance(batch.models[1], ptm.TieNormaliser)
    assert isinstance(online.models[1], ptm.DeadReckonedTieNormaliser)
    assert online.models[1].bind(SCORED).area == pytest.approx(batch.used["tie_area"])
    assert np.allclose(online.models[2].mu, global_mean.models[2].mu)  # the global mean, as the batch "global"
    assert not np.allclose(batch.models[2].mu, global_mean.models[2].mu)  # the batch default: the run's own
    assert callable(online.prior) and isinstance(batch.prior, ptm.GammaPoissonPrior)
    assert isinstance(online.prior(SCORED.n), ptm.GammaPoissonPrior)


def test_the_builder_refuses_what_it_cannot_build():
    with pytest.raises(ValueError, match="no odometry for the odometry model"):
        build_models(Variant("v", models=("odometry",)), ptm.Dataset(signatures=SCORED.signatures), HELD_OUT)
    with pytest.raises(ValueError, match="no signatures for the appearance model"):
        build_models(Variant("v", models=("appearance",)), ptm.Dataset(odometry=SCORED.odometry), HELD_OUT)
    with pytest.raises(ValueError, match="fitted on labelled held-out runs: none were given"):
        build_models(Variant("v", models=("appearance",)), SCORED, None)
    with pytest.raises(ValueError, match="detection_radius"):
        build_models(Variant("v", models=("odometry",)), ptm.Dataset(odometry=SCORED.odometry), HELD_OUT)
    calls = []
    configured = Variant("v", models=("odometry",), odometry=OdometrySettings(penalty_radius=1.0, sigma_topology=0.3))
    configured = replace(configured, inference=replace(configured.inference, prior_rate=3.0))
    built = build_models(configured, SCORED, lambda: calls.append(1) or HELD_OUT)
    assert calls == [] and built.used["source_prior_rate"] == built.used["source_penalty_radius"] == "config"
    assert isinstance(built.prior, ptm.PoissonPrior) and built.prior.rate == 3.0  # a configured rate is plugged in


def test_the_summarys_maps_are_the_scored_models_modes(monkeypatch):
    cell = batch_cell(monkeypatch, variants=[{"name": "odometry", "models": ["odometry"]}],
                      odometry={"sigma_xy": 0.2})
    posterior, used = cell_module.build_posterior(cell, SCORED)
    term = next(term for term in posterior.terms if getattr(term, "name", "") == "odometry")
    experiment = parse_experiment({"sweep": {"worlds": ["short_loop"], "seeds": [0], "calibration_seeds": [10, 11]},
                                   "odometry": {"sigma_xy": 0.2},
                                   "variants": [{"name": "odometry", "models": ["odometry"]}]})
    row = {"variant": "odometry", "sigma_topology": used["sigma_topology"]}
    topologies = [SCORED.labels, np.arange(SCORED.n)]
    modes = summary._modes(experiment, row, SCORED, topologies)
    for mode, labels in zip(modes, topologies):
        assert np.allclose(mode, term.mode_poses(labels))


def test_the_default_export_is_the_map_a_sweep_scored(monkeypatch, tmp_path, capsys):
    posterior, _ = cell_module.build_posterior(batch_cell(monkeypatch), SCORED)
    term = next(term for term in posterior.terms if getattr(term, "name", "") == "odometry")
    path = SCORED.save(tmp_path / "loop.npz")
    assert main(["export", str(path), "--labels", "truth", "--out", str(tmp_path / "map")]) == 0
    printed = capsys.readouterr().out
    assert "sigma_topology: 0.354 (sensor spec: detection radius 0.5 m / sqrt 2)" in printed
    assert "max_penalty: 0 (no held-out runs to calibrate the penalty radius on" in printed
    exported = np.loadtxt(tmp_path / "map" / "map.tum")[:, 1:3]
    assert np.allclose(exported, term.mode_poses(SCORED.labels)[:, :2], atol=1e-5)
