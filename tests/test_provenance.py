"""Where a cell's parameters come from, and when cached datasets and rows count as stale (issue 9, items 4 and 7a).

* Inference never reads the scored run's ground truth: the posterior of a
  cell is the same with the scored dataset's labels, true poses and world
  places removed or scrambled; the parameters not configured are a sensor
  specification or calibrated on held-out runs, and each row says which.
* The dataset cache key and a cell's definition digest follow the world's
  content and the simulator's version.

The datasets here are hand made (a square loop driven twice, four corner
places) and put into the cache where the cells look for them, so no test
runs the simulator.
"""

import copy
import functools
import math
import re

import numpy as np
import pytest

import ptm
from ptm.se2 import relative_pose
from ptm_bench.evaluation import calibration
from ptm_bench.evaluation import datacache
from ptm_bench.evaluation import experiment
from ptm_bench.simulation import code_version
from ptm_bench.evaluation.cell import build_posterior, run_cell
from ptm_bench.world.floorplan import WORLDS_DIR

CORNERS = np.array([[0.0, 0.0], [2.0, 0.0], [2.0, 2.0], [0.0, 2.0]])
LOOP_LABELS = np.array([0, 1, 2, 3, 0, 1, 2, 3, 0])


def loop_dataset(seed: int, labels=LOOP_LABELS, meta=None) -> ptm.Dataset:
    """Detections of the square loop's corners: true poses near the corners, noisy odometry, signatures per place."""
    rng = np.random.default_rng(seed)
    labels = np.asarray(labels)
    xy = CORNERS[labels % len(CORNERS)] + rng.normal(0.0, 0.05, size=(len(labels), 2))
    heading = np.arctan2(np.roll(xy, -1, axis=0)[:, 1] - xy[:, 1], np.roll(xy, -1, axis=0)[:, 0] - xy[:, 0])
    poses = np.column_stack([xy, heading])
    odometry = relative_pose(poses[:-1], poses[1:])
    odometry += rng.normal(0.0, [0.1, 0.1, 0.05], size=odometry.shape)
    covariance = np.tile(np.diag([0.01, 0.01, 0.0025]), (len(labels) - 1, 1, 1))
    place_looks = np.array([[0.3, 0.1], [0.5, 0.2], [0.2, 0.4], [0.6, 0.5]])
    signatures = place_looks[labels % len(CORNERS)] + rng.normal(0.0, 0.02, size=(len(labels), 2))
    return ptm.Dataset(odometry=odometry, odometry_cov=covariance, signatures=signatures, labels=labels,
                       true_poses=poses, meta={"detection_radius": 0.5, **(meta or {})})


CONFIG = {
    "name": "provenance",
    "baselines": ["greedy_odometry"],
    "sweep": {"worlds": ["short_loop"], "seeds": [0], "calibration_seeds": [10, 11]},
    "inference": {"n_samples": 200, "burn_in": 20, "chains": 2},
    "odometry": {"n_importance": 10},
    "variants": [{"name": "odometry+appearance", "models": ["odometry", "appearance"]}],
}


def cells_with_cached_datasets(tmp_path, config=CONFIG, scored_meta=None):
    """The config's cells, with hand-made datasets in the cache for the scored run and the held-out runs (on the
    floors and at the seeds ``calibration.held_out_floors`` names)."""
    parsed = experiment.parse_experiment(copy.deepcopy(config), source="test")
    cells = experiment.expand_cells(parsed, tmp_path)
    inputs = cells[0]["inputs"]
    held_out = calibration.held_out_floors(inputs["world_spec"], inputs["calibration"], inputs["calibration_seeds"])
    for world, seed in [(inputs["world_spec"], 0), *((spec, seed) for _, spec, seed in held_out)]:
        meta = {"places": {"0": [0, 0]}, "min_place_spacing": 2.0, **(scored_meta or {})} if seed == 0 else None
        path = datacache.dataset_path(world, 0.0, 1.0, seed, inputs["generator_options"], inputs["cache_dir"], None)
        path.parent.mkdir(parents=True, exist_ok=True)
        loop_dataset(seed, meta=meta).save(path)
    return cells


# -- calibration on hand-made held-out runs ---------------------------------------------------


def test_places_per_detection_pools_places_and_detections_over_runs():
    runs = [loop_dataset(0, labels=[0, 1, 0, 2]), loop_dataset(1, labels=[0, 1, 1])]
    assert calibration.places_per_detection(runs) == pytest.approx(5 / 7)
    # a false detection (negative label) is a place of its own
    assert calibration.places_per_detection([loop_dataset(0, labels=[0, -1, 0, -2])]) == pytest.approx(3 / 4)


def test_the_prior_rate_is_configured_or_expects_places_per_detection_times_n_places():
    runs = [loop_dataset(0, labels=[0, 1, 0, 2]), loop_dataset(1, labels=[0, 1, 1])]
    rate, source = calibration.prior_rate(None, n=14, held_out=runs)
    shape = calibration.PRIOR_RATE_SHAPE
    assert ptm.GammaPoissonPrior(rate, shape).expected_places(14) == pytest.approx(10.0, rel=1e-9)
    assert rate > ptm.PoissonPrior.with_expected_places(14, 10.0).rate > 10.0 + 3.0  # unvisited landmarks count too
    assert source == ("calibrated: mean rate for E[places] = 0.714 places/detection on 2 held-out runs x N=14 = 10, "
                      "Gamma shape 2")
    # every held-out detection its own place: the expected places stay half a place below N
    distinct = [loop_dataset(0, labels=[0, 1, 2, 3])]
    rate, _ = calibration.prior_rate(None, n=14, held_out=distinct)
    assert ptm.GammaPoissonPrior(rate, shape).expected_places(14) == pytest.approx(13.5, rel=1e-9)

    def never_called():
        raise AssertionError("a configured parameter must not load the held-out runs")

    assert calibration.prior_rate(4, n=14, held_out=never_called) == (4.0, "config")


def test_the_place_separation_is_the_closest_pair_of_different_places_over_runs():
    first = ptm.Dataset(labels=[0, 1, 0, 2], true_poses=[[0, 0, 0], [3, 0, 0], [0.2, 0, 0], [0, 4, 0]])
    second = ptm.Dataset(labels=[0, 0, 1, -1, -2],  # two false detections 0.1 m apart do not count
                         true_poses=[[0, 0, 0], [0.5, 0, 0], [2.5, 0, 0], [9, 9, 0], [9.1, 9, 0]])
    assert calibration.place_separation([first]) == pytest.approx(2.8)
    assert calibration.place_separation([first, second]) == pytest.approx(2.0)
    radius, source = calibration.penalty_radius(None, 0.75, [first, second])  # online: no scored run's spacing
    assert radius == pytest.approx(1.5)
    assert source == "calibrated: 0.75 x 2 m, the closest detections of different places on 2 held-out runs"
    assert calibration.penalty_radius(2.5, 0.75, []) == (2.5, "config")
    with pytest.raises(ValueError, match="no held-out run detects two different places"):
        calibration.place_separation([ptm.Dataset(labels=[0, 0], true_poses=np.zeros((2, 3)))])
    with pytest.raises(ValueError, match="at least one held-out run"):
        calibration.place_separation([])


def test_the_tie_sigma_is_configured_or_the_detector_radius_over_root_two():
    sigma, source = calibration.topology_sigma(None, {"detection_radius": 1.0})
    assert sigma == pytest.approx(math.sqrt(0.5)) and source == "sensor spec: detection radius 1 m / sqrt 2"
    assert calibration.topology_sigma(0.3, {}) == (0.3, "config")
    with pytest.raises(ValueError, match="detection_radius"):
        calibration.topology_sigma(None, {})


# -- no ground truth inside inference -------------------------------------------------------------


def test_the_posterior_does_not_read_the_scored_runs_ground_truth(tmp_path):
    cell = cells_with_cached_datasets(tmp_path)[0]
    scored = datacache.dataset_for("short_loop", 0.0, 1.0, 0, {}, cell["inputs"]["cache_dir"])
    blind = ptm.Dataset(odometry=scored.odometry, odometry_cov=scored.odometry_cov, signatures=scored.signatures,
                        meta={"detection_radius": scored.meta["detection_radius"]})
    rng = np.random.default_rng(1)
    scrambled = ptm.Dataset(odometry=scored.odometry, odometry_cov=scored.odometry_cov, signatures=scored.signatures,
                            labels=rng.permutation(scored.n), true_poses=rng.normal(size=(scored.n, 3)) * 50,
                            meta={**scored.meta, "places": {str(i): [9.0 * i, 0.0] for i in range(7)},
                                  "min_place_spacing": 9.0})
    partitions = [scored.labels, np.zeros(scored.n, dtype=int), np.arange(scored.n), [0, 1, 2, 3, 4, 1, 2, 3, 0],
                  rng.integers(0, 3, size=scored.n)]
    reference, used = build_posterior(cell, scored)
    for variant in (blind, scrambled):
        posterior, variant_used = build_posterior(cell, variant)
        assert variant_used == used
        for labels in partitions:
            assert posterior.log_prob(labels) == reference.log_prob(labels)


def test_rows_record_each_parameters_source_and_the_measured_aliasing(tmp_path):
    cells = cells_with_cached_datasets(tmp_path, scored_meta={"aliasing_auc": 0.93})
    inference, baseline = (run_cell(cell) for cell in cells)
    assert inference["source_prior_rate"] == ("calibrated: mean rate for E[places] = 0.444 places/detection on 2 "
                                              "held-out runs [nested_loops, office] x N=9 = 4, Gamma shape 2")
    prior = ptm.GammaPoissonPrior(inference["prior_rate"], calibration.PRIOR_RATE_SHAPE)
    assert prior.expected_places(9) == pytest.approx(4.0, rel=1e-9)
    assert 0.0 < inference["prior_rate_posterior_sd"] < inference["prior_rate_posterior_mean"] < 10 * prior.rate
    assert inference["noise_scale_prior"].startswith("IG(shape 1.5") and inference["noise_scale_posterior_mean"] > 0.0
    assert inference["noise_scale_in_prior_tail"] in (True, False)
    assert inference["source_penalty_radius"].startswith("calibrated: 0.75 x ")
    scored = datacache.dataset_for("short_loop", 0.0, 1.0, 0, {}, cells[0]["inputs"]["cache_dir"])
    assert inference["penalty_radius"] == pytest.approx(0.75 * calibration.spacing_ratio(
        calibration.calibration_datasets(cells[0])) * calibration.route_spacing(scored))
    assert inference["source_sigma_topology"] == "sensor spec: detection radius 0.5 m / sqrt 2"
    assert inference["sigma_topology"] == pytest.approx(0.5 / math.sqrt(2.0))
    assert inference["source_tie_area"] == ("this run's detections: within 0.5 m (the detection radius) of their "
                                            "dead-reckoned route, no labels")
    assert re.fullmatch(r"empirical Bayes \(independent, outlier share [0-9.e-]+ at [0-9.]+ x the variance\) on 2 "
                        r"held-out runs \[nested_loops, office\] around each run's mean; prior mean = this run's mean "
                        r"signature", inference["source_appearance"])
    assert baseline["source_threshold"] == "calibrated: best mean ARI on 2 held-out runs [nested_loops, office]"
    assert inference["aliasing_auc"] == baseline["aliasing_auc"] == 0.93

    configured = copy.deepcopy(CONFIG)
    configured["inference"]["prior_rate"] = 3.0
    configured["odometry"]["penalty_radius"] = 1.2
    row = run_cell(cells_with_cached_datasets(tmp_path / "configured", configured)[0])
    assert (row["prior_rate"], row["source_prior_rate"]) == (3.0, "config")
    assert (row["penalty_radius"], row["source_penalty_radius"]) == (1.2, "config")
    assert math.isnan(row["aliasing_auc"])  # the generator did not measure it


# -- fresh results: cache keys and definitions follow the world's content and the simulator's version ----


def edited_world(folder, radius="0.5"):
    path = folder / "loop.toml"
    text = (WORLDS_DIR / "short_loop.toml").read_text()
    path.write_text(text.replace("detection_radius = 0.5", f"detection_radius = {radius}"))
    return path


GRID = {"generator": "corridor_grid", "name": "g", "rows": 2, "cols": 3, "loops": 1, "place_density": 0.8}


@pytest.fixture
def edit_code(monkeypatch):
    """``edit_code(module)``: the module's source reads as edited (a statement added) from now on, as an edit of its
    file would (tests/test_code_version.py tests the versions themselves); no version of it outlives the test."""
    def edit(module):
        read = code_version.module_source
        monkeypatch.setattr(code_version, "module_source",
                            lambda name: read(name) + ("\n_EDITED = True\n" if name == module else ""))
        code_version.code_version.cache_clear()

    # each module read once: the tree as the test found it, whatever is saved meanwhile
    monkeypatch.setattr(code_version, "module_source", functools.cache(code_version.module_source))
    code_version.code_version.cache_clear()
    yield edit
    code_version.code_version.cache_clear()


def test_the_cache_key_follows_the_world_content_and_the_simulator_version(tmp_path, edit_code):
    def key(world):
        return datacache.dataset_path(world, 0.0, 1.0, 3, {}, tmp_path / "cache", None)

    world = edited_world(tmp_path)
    before = {"preset": key("short_loop"), "file": key(str(world)), "grid": key(GRID)}
    assert before == {"preset": key("short_loop"), "file": key(str(world)), "grid": key(GRID)}  # deterministic
    assert before["file"].name.startswith("loop_a0_n1_s3_")
    assert key(str(edited_world(tmp_path, radius="0.4"))) != before["file"]
    assert key({**GRID, "loops": 2}) != before["grid"]
    edit_code("ptm_bench.evaluation.cell")  # the code turning a dataset into a row leaves the datasets fresh
    assert key("short_loop") == before["preset"]
    edit_code(code_version.GENERATOR)  # the simulator's code
    assert key("short_loop") != before["preset"]
    assert key(str(edited_world(tmp_path))) != before["file"]
    assert key(GRID) != before["grid"]


def test_a_cell_definition_follows_the_world_content_and_the_simulator_version(tmp_path, edit_code):
    world = edited_world(tmp_path)
    config = {**CONFIG, "sweep": {**CONFIG["sweep"], "worlds": [str(world), GRID]}}

    def definitions():
        return [cell["definition"] for cell in experiment.expand_cells(experiment.parse_experiment(config), tmp_path)]

    before = definitions()
    assert definitions() == before
    edited_world(tmp_path, radius="0.4")
    after_edit = definitions()
    assert after_edit[:2] != before[:2] and after_edit[2:] == before[2:]  # only the cells of the edited world
    edit_code(code_version.GENERATOR)  # the simulator's code
    after_simulator = definitions()
    assert all(new != old for new, old in zip(after_simulator, after_edit))
    edit_code("ptm_bench.evaluation.cell")  # the code turning a dataset into a row
    assert all(new != old for new, old in zip(definitions(), after_simulator))


@pytest.mark.parametrize("exact_max_n, chosen", [(9, "exact"), (8, "tempered")])
def test_auto_method_is_exact_up_to_its_limit_and_tempered_beyond(tmp_path, exact_max_n, chosen):
    config = copy.deepcopy(CONFIG)
    config["inference"] = {**config["inference"], "method": "auto", "exact_max_n": exact_max_n}
    config["variants"] = [{"name": "appearance", "models": ["appearance"]}]
    row = run_cell(cells_with_cached_datasets(tmp_path, config)[0])
    assert row["inference_method"] == chosen  # the scored loop has N = 9 detections
    assert (row["n_topologies"] == 21147) == (chosen == "exact")


def test_the_tie_normaliser_is_a_term_with_its_area_from_dead_reckoning(tmp_path):
    cell = cells_with_cached_datasets(tmp_path)[0]
    scored = datacache.dataset_for("short_loop", 0.0, 1.0, 0, {}, cell["inputs"]["cache_dir"])
    posterior, used = build_posterior(cell, scored)
    expected = ptm.TieNormaliser.from_dead_reckoning(scored, 0.5 / math.sqrt(2.0), 0.5)  # sigma_T = r/sqrt 2, margin r
    assert used["tie_area"] == pytest.approx(expected.area)
    assert used["source_tie_area"] == ("this run's detections: within 0.5 m (the detection radius) of their "
                                       "dead-reckoned route, no labels")
    [term] = [term for term in posterior.terms if term.name == "tie_normaliser"]
    for labels in (scored.labels, np.zeros(scored.n, dtype=int), np.arange(scored.n)):
        partition = posterior.partition(labels)
        assert term.log_likelihood(partition) == pytest.approx(expected.log_likelihood(partition), abs=1e-9)
    assert expected.log_likelihood(posterior.partition(scored.labels)) > 0  # merges gain: no lean to all-distinct
