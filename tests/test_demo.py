"""The README's main command: ``ptm-bench demo`` runs end to end and reports what it promises."""

from ptm_bench.cli import main


def test_demo_prints_scores_and_writes_figures(tmp_path, capsys):
    assert main(["demo", "--world", "short_loop", "--out", str(tmp_path)]) == 0
    printed = capsys.readouterr().out
    for method in ("odometry", "odometry+appearance", "greedy_odometry", "appearance_threshold", "gnc", "dcs", "pcm",
                   "distance_rank"):
        assert f"\n{method} " in printed
    # the truth itself, not its place in the top five: calibrated on other floors (nested_loops, office), the short
    # loop's penalty radius (8.8 m against its 2 m corners) merges every detection into one place (issue 44)
    assert "true topology" in printed
    written = {path.name for path in tmp_path.iterdir()}
    assert {"summary.md", "trajectory.png"} <= written
    assert any(name.startswith("top5_") for name in written)


def test_demo_refuses_an_unknown_world(tmp_path, capsys):
    assert main(["demo", "--world", "atlantis", "--out", str(tmp_path)]) == 2
    assert "atlantis" in capsys.readouterr().err
