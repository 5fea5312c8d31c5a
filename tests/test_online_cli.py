"""``ptm-bench online``: a dataset replayed through the online mapper, calibrated on held-out datasets.

The datasets are the hand-made square loops of tests/helpers.py (four corner places, noisy odometry, a
signature per place), so nothing is simulated.
"""

import numpy as np
import pytest

import ptm
from ptm_bench.cli import main
from ptm_bench.evaluation.online import calibrated_mapper, collapse_warning, replay
from ptm_bench.evaluation.settings import AppearanceSettings, Variant

from helpers import square_loop_dataset as loop_dataset

APPEARANCE = Variant("appearance", models=("appearance",))


@pytest.fixture
def runs(tmp_path):
    paths = {}
    for seed in (0, 10, 11):
        paths[seed] = loop_dataset(seed).save(tmp_path / f"loop{seed}.npz")
    return paths


def test_the_replay_finds_the_loop_and_reports_latency_and_the_truths_mass(runs, tmp_path, capsys):
    out = tmp_path / "final_ptm.npz"
    assert main(["online", str(runs[0]), "--calibration", str(runs[10]), str(runs[11]), "--particles", "64",
                 "--every", "3", "--ptm-out", str(out)]) == 0
    text = capsys.readouterr().out
    assert "N = 9 detections, models odometry + appearance, 64 particles, calibrated on 2 held-out run(s)" in text
    assert "penalty_radius: " in text and "(calibrated: 0.75 x " in text
    assert text.count("  n = ") == 3  # n = 3, 6, 9
    assert "latency per update: median" in text
    result = ptm.PTM.load(out)
    assert result.n == 9 and result.diagnostics["particles"] == 64
    assert f"ground truth's mass {result.probability(loop_dataset(0).labels):.3f}" in text
    assert "final MAP: ARI 1.000" in text
    assert "particles collapsed" not in text  # a healthy run does not warn


def test_the_replay_is_the_mappers_own_result_for_one_seed(runs):
    dataset, held_out = ptm.Dataset.load(runs[0]), [ptm.Dataset.load(runs[10])]
    first = replay(dataset, calibrated_mapper(dataset, held_out, APPEARANCE, particles=32, seed=3)[0])
    again = replay(dataset, calibrated_mapper(dataset, held_out, APPEARANCE, particles=32, seed=3)[0])
    assert np.array_equal(first.partitions, again.partitions)
    assert np.array_equal(first.probabilities, again.probabilities)
    assert len(first.diagnostics["latency_s"]) == dataset.n


def test_the_mapper_uses_the_settings_appearance_model(runs):
    dataset, held_out = ptm.Dataset.load(runs[0]), [ptm.Dataset.load(runs[10]), ptm.Dataset.load(runs[11])]

    def fitted(variant):
        mapper, used = calibrated_mapper(dataset, held_out, variant, particles=8)
        (model,) = mapper.models
        return model, used["source_appearance"]

    model, source = fitted(APPEARANCE)   # the default: rare outlier visits, the share at most 0.1
    assert 0.0 < model.outlier_share <= 0.1 and "outlier share" in source
    model, source = fitted(Variant("paper", models=("appearance",), appearance=AppearanceSettings(outliers=False)))
    assert model.outlier_share == 0.0 and "outlier share" not in source   # the paper's model, when asked for


@pytest.mark.parametrize("extra, message", [
    (["--calibration", "SELF"], "loop0.npz holds the same run as the replayed dataset"),
    (["--calibration", "CAL", "COPY"], "copy.npz holds the same run as the replayed dataset"),
    (["--calibration", "UNLABELLED"], "held-out run 0 has no labels"),
    (["--calibration", "CAL", "--ptm-out", "result.txt"], "PTM files end in .npz"),
    (["--calibration", "CAL", "--models", "odometry"], "no odometry for the odometry model"),
], ids=["itself", "copy", "unlabelled", "ptm-suffix", "missing-odometry"])
def test_bad_input_is_refused_with_the_reason(runs, tmp_path, capsys, extra, message):
    no_odometry = ptm.Dataset(signatures=loop_dataset(0).signatures, meta={"detection_radius": 0.5})
    dataset = no_odometry.save(tmp_path / "plain.npz") if "odometry" in extra else runs[0]
    unlabelled = ptm.Dataset(signatures=loop_dataset(10).signatures).save(tmp_path / "unlabelled.npz")
    # the replayed run under another name, its provenance rewritten: the same run all the same
    copy = loop_dataset(0).replace(meta={"source": "a copy"}).save(tmp_path / "copy.npz")
    names = {"SELF": str(dataset), "UNLABELLED": str(unlabelled), "CAL": str(runs[10]), "COPY": str(copy),
             "result.txt": str(tmp_path / "result.txt")}
    assert main(["online", str(dataset), *[names.get(item, item) for item in extra]]) == 2
    assert message in capsys.readouterr().err


def test_a_replay_whose_particles_collapsed_is_flagged():
    """One detection where the weights left 2 effective particles of 128 (FHW's run) is enough to warn; an
    ESS that stays above 5 % of the particles is not."""
    def online_ptm(ess):
        return ptm.PTM(np.array([[0, 1, 0], [0, 1, 2]]), np.array([0.985, 0.015]), "smc",
                       {"particles": 128, "ess": ess})

    warning = collapse_warning(online_ptm([128.0, 60.0, 2.0, 90.0]))
    assert "fell to 2.0 of 128 at detection 3" in warning and "--particles" in warning
    assert collapse_warning(online_ptm([128.0, 35.4, 7.0, 120.6])) is None
