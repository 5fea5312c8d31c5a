"""Accuracy checks for CI (issue 10): [checks] thresholds, ``ptm-bench run --check`` and its JUnit report."""

import xml.etree.ElementTree as ElementTree

import pytest

import ptm_bench.cli.run
from ptm_bench.cli import main
from ptm_bench.evaluation.experiment import parse_experiment

BASE = {"sweep": {"worlds": ["short_loop"], "seeds": [0, 1], "calibration_seeds": [10]},
        "variants": [{"name": "appearance", "models": ["appearance"]}], "baselines": ["greedy_odometry"]}


def test_checks_are_read_per_variant_or_for_every_variant():
    experiment = parse_experiment({**BASE, "checks": {"ece": "<= 0.05", "greedy_odometry": {"gt_mass_mean": "> 0.4"}}})
    assert [(c["variant"], c["metric"], c["operator"], c["threshold"]) for c in experiment.checks] == [
        ("appearance", "ece", "<=", 0.05), ("greedy_odometry", "gt_mass", ">", 0.4)]


@pytest.mark.parametrize("checks, message", [
    ({"odometry": {"gt_mass": ">= 0.9"}}, "unknown variant 'odometry'"),
    ({"accuracy": ">= 0.9"}, "unknown metric 'accuracy'"),
    ({"gt_mass": "at least 0.9"}, r"gt_mass must be a condition such as \">= 0.9\", got 'at least 0.9'"),
    ({"gt_mass": 0.9}, "gt_mass must be a condition"),
    ("gt_mass >= 0.9", r"\[checks\] must be a table"),
])
def test_bad_checks_are_refused_at_load(checks, message):
    with pytest.raises(ValueError, match=message):
        parse_experiment({**BASE, "checks": checks})


CONFIG = """
name = "ci"
baselines = ["greedy_odometry"]
[sweep]
worlds = ["short_loop"]
seeds = [0, 1]
calibration_seeds = [10]
[[variants]]
name = "appearance"
models = ["appearance"]
[checks]
map_correct = ">= 0.5"
greedy_odometry.gt_mass = ">= 0.9"
"""


def test_run_check_prints_what_held_writes_junit_and_fails_when_one_falls_short(tmp_path, monkeypatch, capsys):
    from sweep_fakes import scored_cell

    monkeypatch.setattr(ptm_bench.cli.run, "run_cell", scored_cell)  # seed 0 right, seed 1 wrong: mass 0.5
    config = tmp_path / "ci.toml"
    config.write_text(CONFIG)
    code = main(["run", str(config), "--out", str(tmp_path), "--workers", "2", "--no-figures", "--no-progress", "--check"])
    printed = capsys.readouterr().out
    assert code == 1
    assert "ok   appearance" in printed and "FAIL greedy_odometry" in printed
    assert "1 held, 1 did not" in printed
    report = ElementTree.parse(tmp_path / "ci" / "checks.xml").getroot()
    assert report.get("tests") == "2" and report.get("failures") == "1"
    failure = report.find(".//failure")
    assert failure.get("message") == "gt_mass = 0.5, expected >= 0.9"
    # a threshold that holds: exit 0 (the table is reused, nothing recomputed)
    config.write_text(CONFIG.replace('greedy_odometry.gt_mass = ">= 0.9"', 'greedy_odometry.gt_mass = ">= 0.5"'))
    junit = tmp_path / "report.xml"
    assert main(["run", str(config), "--out", str(tmp_path), "--no-figures", "--no-progress", "--check",
                 "--junit", str(junit)]) == 0
    assert ElementTree.parse(junit).getroot().get("failures") == "0"


def test_a_run_whose_every_cell_fails_writes_its_summary_and_failed_checks(tmp_path, monkeypatch, capsys):
    """Before issue 47 a table of failed cells alone (no score columns) ended in ``KeyError: 'gt_mass'``: no
    summary.md, no checks.xml, a traceback."""
    from sweep_fakes import failing_cell

    monkeypatch.setattr(ptm_bench.cli.run, "run_cell", failing_cell)
    config = tmp_path / "ci.toml"
    config.write_text(CONFIG)
    code = main(["run", str(config), "--out", str(tmp_path), "--workers", "2", "--no-progress", "--check"])
    printed = capsys.readouterr().out
    assert code == 1
    assert "0 cells finished, 4 failed" in printed and "0 held, 2 did not" in printed
    summary = (tmp_path / "ci" / "summary.md").read_text()
    assert "**Every cell failed** (4 of 4)" in summary
    assert all(f"ValueError: seed {seed}: no signal" in summary for seed in (0, 1))
    assert r"| short_loop\|a=0\|noise=1\|seed=0\|appearance | ValueError: seed 0: no signal" in summary
    report = ElementTree.parse(tmp_path / "ci" / "checks.xml").getroot()
    assert report.get("tests") == "2" and report.get("failures") == "2"
    assert {failure.get("message") for failure in report.iter("failure")} == {
        "map_correct = no finished cells, expected >= 0.5", "gt_mass = no finished cells, expected >= 0.9"}
