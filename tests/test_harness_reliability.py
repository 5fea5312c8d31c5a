"""The harness under misuse (issue 10): bad config values, other experiments' tables, concurrent runs,
killed and interrupted sweeps, unwritable outputs, dead schedulers, corrupted files.

Cell functions here are tiny fakes (tests/sweep_fakes.py), so every test takes seconds.
"""

import pytest

from ptm_bench.evaluation import experiment

BASE = '[sweep]\nworlds = ["nested_loops"]\nseeds = [0]\n'


def load(tmp_path, text, name="tiny.toml"):
    path = tmp_path / name
    path.write_text(text)
    return experiment.load_experiment(path)


# -- config values are checked at load, before any simulation ---------------------------------------------------

@pytest.mark.parametrize("bad, message", [
    (BASE + '[inference]\nn_samples = "100"\n', r"inference\.n_samples must be a positive integer, got '100'"),
    (BASE + '[inference]\nn_samples = 0\n', r"inference\.n_samples must be a positive integer"),
    (BASE + '[inference]\nchains = 2.5\n', r"inference\.chains must be a positive integer"),
    (BASE + '[inference]\ndelayed_acceptance = "no"\n', r"inference\.delayed_acceptance must be true or false, got 'no'"),
    (BASE + '[inference]\ntemperatures = [0.5, 1.0]\n', r"inference\.temperatures must be a list of inverse temperatures"),
    (BASE + '[inference]\nprior_rate = -1\n', r"inference\.prior_rate must be a positive number"),
    (BASE + '[odometry]\nmax_penalty = -5\n', r"odometry\.max_penalty must be a non-negative number, got -5"),
    (BASE + '[odometry]\nsigma_xy = "0.1"\n', r"odometry\.sigma_xy must be a positive number"),
    (BASE + '[appearance]\ncomponents = true\n', r"appearance\.components must be a positive integer"),
    (BASE + '[[variants]]\nname = "v"\nmodels = ["odometry"]\ninference = { burn_in = -1 }\n',
     r"variant 'v': inference\.burn_in must be a non-negative integer"),
    (BASE + '[sweep.generator_options]\ncolour = 3\n', r"unknown key 'colour' in sweep\.generator_options"),
    (BASE + '[sweep.generator_options]\nmiss_rate = "0.1"\n', r"sweep\.generator_options\.miss_rate must be a float"),
    ('name = "../../elsewhere"\n' + BASE, r"name must be a folder name .* got '\.\./\.\./elsewhere'"),
    ('name = "a/b"\n' + BASE, r"name must be a folder name"),
    ('name = ".."\n' + BASE, r"name must be a folder name"),
])
def test_bad_config_values_are_refused_at_load_naming_the_key(tmp_path, bad, message):
    with pytest.raises(ValueError, match=message):
        load(tmp_path, bad)


def test_good_values_and_generator_options_still_load(tmp_path):
    config = load(tmp_path, 'name = "ok_1.2"\n' + BASE + '[sweep.generator_options]\nmiss_rate = 0\nroute = "main"\n'
                  '[inference]\nn_samples = 10\ndelayed_acceptance = false\n[odometry]\nmax_penalty = 0\n')
    assert config.name == "ok_1.2"
    assert config.settings["inference"]["delayed_acceptance"] is False
