"""Accuracy checks on small, fast configurations of the full pipeline (simulator -> PTM -> scores).

One module-level sweep runs every configuration below once; each test reads
its cells. The thresholds were set from runs of exactly these settings over
eight seeds (0-7), recorded in each test's docstring (``run_conditions(folder,
seeds=range(8))`` repeats them, about 8 minutes on two cores); CI runs the
first three seeds, and every threshold leaves room for a bad seed among them.

What we measured differs from the issue's expectation in one place: at
aliasing 1 on ``nested_loops`` appearance still raises the ground-truth mass,
because one shared palette does not make a corner look like a straight
corridor (the walls differ, and so do the Fourier signatures). On
``short_loop``, whose four places are congruent corners, appearance at
aliasing 1 does not help, which is what the last test checks.
"""

import copy

import numpy as np
import pytest

from ptm_bench.cell import run_cell
from ptm_bench.experiment import expand_cells, parse_experiment
from ptm_bench.sweep import run_sweep

SEEDS = [0, 1, 2]

BASE = {
    "sweep": {"seeds": SEEDS, "calibration_seeds": [1000, 1001]},
    "inference": {"n_samples": 3000, "burn_in": 300, "chains": 4},
    "odometry": {"n_importance": 50},
    "variants": [
        {"name": "odometry", "models": ["odometry"]},
        {"name": "odometry+appearance", "models": ["odometry", "appearance"]},
    ],
}
CONDITIONS = {
    "nested_low_noise": {"worlds": ["nested_loops"], "aliasing": [0.0], "noise": [0.25]},
    "nested_moderate_noise": {"worlds": ["nested_loops"], "aliasing": [0.0, 1.0], "noise": [1.0]},
    "short_loop_aliased": {"worlds": ["short_loop"], "aliasing": [1.0], "noise": [1.0]},
}


def accuracy_config(name: str, seeds=SEEDS) -> dict:
    config = copy.deepcopy(BASE)
    config["name"] = name
    config["sweep"].update(CONDITIONS[name], seeds=list(seeds))
    if name == "nested_low_noise":  # only the full model is checked there
        config["variants"] = config["variants"][1:]
    if name == "short_loop_aliased":
        config["odometry"]["max_penalty"] = 50.0
    return config


def run_conditions(folder, seeds=SEEDS, workers=2):
    """The table of every accuracy condition (also used to re-measure the thresholds over more seeds)."""
    tables = {}
    for name in CONDITIONS:
        experiment = parse_experiment(accuracy_config(name, seeds), source=f"accuracy:{name}")
        cells = expand_cells(experiment, folder / name)
        tables[name] = run_sweep(cells, run_cell, folder / name / "cells.csv", workers=workers, progress=False)
        failed = tables[name][tables[name]["status"] != "ok"]
        assert failed.empty, failed["error"].tolist()
    return tables


@pytest.fixture(scope="module")
def tables(tmp_path_factory):
    return run_conditions(tmp_path_factory.mktemp("accuracy"))


def mass(table, variant, aliasing=None):
    rows = table[table["variant"] == variant]
    if aliasing is not None:
        rows = rows[rows["aliasing"] == aliasing]
    return rows.sort_values("seed")["gt_mass"].to_numpy()


def test_unaliased_low_noise_nested_loops_puts_most_mass_on_the_truth(tables):
    """nested_loops, aliasing 0, noise 0.25, odometry + appearance.

    Measured ground-truth mass, seeds 0-7: 1.00 1.00 1.00 1.00 0.00 1.00 1.00 1.00
    (mean 0.875; on seed 4 the posterior prefers another topology). Threshold: mean over
    the CI seeds > 0.6 (one such seed among three would still pass if the others are near 1).
    """
    masses = mass(tables["nested_low_noise"], "odometry+appearance")
    assert masses.mean() > 0.6, masses


def test_appearance_raises_the_truth_mass_over_odometry_at_moderate_noise(tables):
    """nested_loops, aliasing 0, noise 1.0.

    Measured, seeds 0-7: odometry alone 0.00 0.00 0.00 0.00 0.00 0.00 0.08 0.00 (mean 0.010);
    odometry + appearance 0.52 0.88 0.58 0.25 0.00 1.00 0.97 0.76 (mean 0.620).
    Threshold: the mean gain over the CI seeds exceeds 0.3 (measured on seeds 0-2: 0.66).
    """
    table = tables["nested_moderate_noise"]
    gain = mass(table, "odometry+appearance", 0.0) - mass(table, "odometry", 0.0)
    assert gain.mean() > 0.3, gain


def test_aliasing_shrinks_what_appearance_adds(tables):
    """nested_loops, noise 1.0: the gain of appearance at aliasing 1 is below its gain at aliasing 0.

    Measured gains, seeds 0-7: aliasing 0 mean 0.610; aliasing 1 mean 0.254 (0.22 0.17 0.10 0.23
    0.00 0.42 0.39 0.50). Threshold: mean gain at aliasing 1 < mean gain at aliasing 0 - 0.15
    (seeds 0-2: 0.16 against 0.66).
    """
    table = tables["nested_moderate_noise"]
    gains = {a: (mass(table, "odometry+appearance", a) - mass(table, "odometry", a)).mean() for a in (0.0, 1.0)}
    assert gains[1.0] < gains[0.0] - 0.15, gains


def test_fully_aliased_appearance_does_not_help_on_congruent_places(tables):
    """short_loop (four congruent corners), aliasing 1, noise 1.0, maximum penalty 50.

    Measured, seeds 0-7: odometry alone 1.00 0.98 1.00 0.98 1.00 0.99 0.98 0.96 (mean 0.986);
    odometry + appearance 0.00 1.00 1.00 0.98 1.00 0.25 0.50 0.25 (mean 0.622): one shared palette
    makes appearance mislead the sampler rather than help it. Threshold: odometry + appearance
    is not above odometry alone by more than 0.05 on average (seeds 0-2: -0.33).
    """
    table = tables["short_loop_aliased"]
    gain = mass(table, "odometry+appearance") - mass(table, "odometry")
    assert np.mean(gain) <= 0.05, gain
