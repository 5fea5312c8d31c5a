"""Accuracy checks on small, fast configurations of the full pipeline (simulator -> PTM -> scores).

Each test reads the cells of its own condition, swept once per test session
(one process each: pytest-xdist spreads the four over its workers). The thresholds were set from runs of these settings over eight
seeds (0-7), recorded in each test's docstring (``run_conditions(folder,
seeds=range(8))`` repeats them); CI runs the first three seeds, and every
threshold leaves room for a bad seed among them. The configurations sample
with the harness's defaults (docs/model.md §3.4, §6) but for their length:
four chains of 1 500 steps, doubled once where they disagree. They are
calibrated on other floors (the default) but for the aliased nested_loops
condition, which is calibrated on its own floor: on other floors it does not
yet hold (see its test). The sweeps in ``experiments/`` use exact posteriors
or tempering instead.
"""

import copy
import fcntl
import os

import numpy as np
import pytest

from ptm_bench.evaluation.cell import run_cell
from ptm_bench.evaluation.experiment import expand_cells, parse_experiment
from ptm_bench.evaluation.sweep import run_sweep

pytestmark = pytest.mark.slow  # four small sweeps, 20-60 s each on one core

SEEDS = [0, 1, 2]

BASE = {
    "sweep": {"seeds": SEEDS, "calibration_seeds": [1000, 1001]},
    "inference": {"n_samples": 1500, "burn_in": 150, "chains": 4, "max_doublings": 1},
    "odometry": {"n_importance": 50},
    "variants": [
        {"name": "odometry", "models": ["odometry"]},
        {"name": "odometry+appearance", "models": ["odometry", "appearance"]},
    ],
}
CONDITIONS = {
    "nested_low_noise": {"worlds": ["nested_loops"], "aliasing": [0.0], "noise": [0.25]},
    "nested_moderate_noise": {"worlds": ["nested_loops"], "aliasing": [0.0], "noise": [1.0]},
    "nested_moderate_noise_aliased": {"worlds": ["nested_loops"], "aliasing": [1.0], "noise": [1.0]},
    "short_loop_aliased": {"worlds": ["short_loop"], "aliasing": [1.0], "noise": [1.0]},
}


def accuracy_config(name: str, seeds=SEEDS) -> dict:
    config = copy.deepcopy(BASE)
    config["name"] = name
    config["sweep"].update(CONDITIONS[name], seeds=list(seeds))
    if name in ("nested_low_noise", "nested_moderate_noise_aliased"):  # only the full model is checked there
        config["variants"] = config["variants"][1:]
    if name == "short_loop_aliased":
        config["odometry"]["max_penalty"] = 50.0
    if name == "nested_moderate_noise_aliased":  # appearance fitted on other floors misleads here (its test)
        config["sweep"]["calibration"] = "same_floor"
    return config


def run_condition(folder, name, seeds=SEEDS, workers=1):
    """The table of one accuracy condition."""
    experiment = parse_experiment(accuracy_config(name, seeds), source=f"accuracy:{name}")
    cells = expand_cells(experiment, folder / name)
    table = run_sweep(cells, run_cell, folder / name / "cells.csv", workers=workers, progress=False)
    failed = table[table["status"] != "ok"]
    assert failed.empty, failed["error"].tolist()
    return table


def run_conditions(folder, seeds=SEEDS, workers=2):
    """The table of every accuracy condition (to re-measure the thresholds over more seeds)."""
    return {name: run_condition(folder, name, seeds, workers) for name in CONDITIONS}


@pytest.fixture(scope="session")
def table(tmp_path_factory):
    """The table of a condition, swept once per test session. The pytest-xdist workers share one folder in the
    session's temporary directory, with a lock per condition: the first worker to take it sweeps, another that
    needs the same condition waits and then reads the finished cells (a sweep skips the cells its table holds)."""
    shared = tmp_path_factory.getbasetemp()
    if os.environ.get("PYTEST_XDIST_WORKER"):
        shared = shared.parent  # the session's directory, holding every worker's own
    folder = shared / "accuracy_sweep"
    folder.mkdir(exist_ok=True)

    def of(name):
        with open(folder / f"{name}.lock", "w") as lock:
            fcntl.flock(lock, fcntl.LOCK_EX)  # released when the file closes, or when a worker dies
            return run_condition(folder, name)
    return of


def mass(table, variant):
    rows = table[table["variant"] == variant]
    return rows.sort_values("seed")["gt_mass"].to_numpy()


def test_unaliased_low_noise_nested_loops_puts_most_mass_on_the_truth(table):
    """nested_loops, aliasing 0, noise 0.25, odometry + appearance.

    Measured ground-truth mass, seeds 0-7 (calibrated on other floors): 1.00 on every seed (mean 1.000).
    Threshold: mean over the CI seeds > 0.6 (one bad seed among three would still pass if the others are near 1).
    """
    masses = mass(table("nested_low_noise"), "odometry+appearance")
    assert masses.mean() > 0.6, masses


def test_at_moderate_noise_odometry_finds_the_loops_and_appearance_never_lowers_the_truth(table):
    """nested_loops, aliasing 0, noise 1.0.

    Measured, seeds 0-7, calibrated on other floors: odometry alone 1.000 1.000 0.717 1.000 1.000 1.000 1.000
    1.000 (mean 0.965; seed 2's chains disagree and its row warns); odometry + appearance 1.00 on every seed.
    Thresholds: odometry alone's mean over the CI seeds above 0.7 (seeds 0-2: 0.906), and odometry + appearance
    above 0.95 and not below odometry alone on any of them.
    """
    odometry, both = mass(table("nested_moderate_noise"), "odometry"), mass(table("nested_moderate_noise"),
                                                                            "odometry+appearance")
    assert odometry.mean() > 0.7, odometry
    assert np.all(both > 0.95) and np.all(both >= odometry - 1e-9), (both, odometry)


def test_aliased_appearance_does_not_mislead_the_odometry(table):
    """nested_loops, noise 1.0, aliasing 1 (every place carries the same decor), odometry + appearance: the
    truth keeps the mass odometry gives it, however alike the places look.

    Calibrated on this floor's own held-out runs. Measured, seeds 0-7: 0.920 1.000 1.000 1.000 1.000 1.000
    1.000 1.000, against odometry alone's (calibrated on other floors) 1.000 1.000 0.717 1.000 1.000 1.000 1.000
    1.000. Threshold: the mean over the CI seeds above 0.9 and at least odometry alone's mean minus 0.05 (seeds
    0-2: 0.973 against 0.906). Calibrated on other floors (office and short_loop) it fails: 0.04 0.01 0.00 1.00
    1.00 1.00 0.65 1.00 at 3 000 steps, as the appearance fitted there expects revisits 2-4 x more alike than
    they are on nested_loops and the MAP splits them (issue 44, CHANGELOG).
    """
    # odometry alone does not see the decor: its cells are those at aliasing 0 (the same runs but for the panels)
    aliased, odometry = mass(table("nested_moderate_noise_aliased"), "odometry+appearance"), mass(
        table("nested_moderate_noise"), "odometry")
    assert aliased.mean() > 0.9 and aliased.mean() >= odometry.mean() - 0.05, (aliased, odometry)


def test_fully_aliased_appearance_does_not_help_on_congruent_places(table):
    """short_loop (four congruent corners), aliasing 1, noise 1.0, maximum penalty 50.

    Measured, seeds 0-7, calibrated on other floors: odometry alone and odometry + appearance 1.00 on every
    seed: with one shared decor, appearance cannot help, and it must not favour merging the corners. Threshold:
    odometry + appearance is not above odometry alone by more than 0.05 on average (seeds 0-2: 0.00).
    """
    cells = table("short_loop_aliased")
    gain = mass(cells, "odometry+appearance") - mass(cells, "odometry")
    assert np.mean(gain) <= 0.05, gain
