"""``ptm-bench speed --section scale`` runs end to end on small grids (its full size is a benchmark, not a test).

At ``--scale 0.1`` the agreement grid shrinks to 3 x 3 (about ten detections) and the online ones to 3 x 3,
4 x 4 and 5 x 5: the time to agreement comes from the sampler's own doublings (``diag_doublings`` of the sweep
cell), and the online mapper replays the three runs, with a latency row per 20 updates.
"""

import math

import pandas as pd

from ptm_bench.benchmarks.scale import AGREEMENT_DOUBLINGS, AGREEMENT_FIRST_SAMPLES
from ptm_bench.cli import main

METRICS = {"agreement_samples_per_chain", "agreement_wall_s", "agreement_rhat_log_prob",
           "agreement_coassignment_max_difference", "agreement_map_ari", "odometry_evaluations_per_s",
           "online_latency_median_s", "online_latency_p90_s", "online_latency_max_s",
           "online_latency_last_quarter_median_s", "online_map_ari", "online_resamplings", "online_window_median_s"}


def test_the_scale_section_writes_every_metric_on_small_grids(tmp_path):
    assert main(["speed", "--section", "scale", "--scale", "0.1", "--out", str(tmp_path)]) == 0
    rows = pd.read_csv(tmp_path / "speed.csv")
    rows = rows[rows["section"] == "scale"]
    online_runs = rows.loc[rows["metric"] == "online_map_ari", "n"].tolist()
    windows = rows.loc[rows["metric"] == "online_window_median_s", "n"].tolist()
    assert len(online_runs) == 3 and windows == [end for n in online_runs for end in range(20, n + 1, 20)]
    rows = rows.drop_duplicates("metric", keep="last").set_index("metric")["value"]
    assert set(rows.index) == METRICS
    samples = rows["agreement_samples_per_chain"]
    assert samples in {AGREEMENT_FIRST_SAMPLES * 2 ** k for k in range(AGREEMENT_DOUBLINGS + 1)}
    assert rows["agreement_rhat_log_prob"] <= 1.05 and rows["agreement_coassignment_max_difference"] <= 0.05
    assert math.isfinite(rows["agreement_wall_s"])
    assert 0 < rows["online_latency_median_s"] <= rows["online_latency_max_s"]
    assert 0.0 <= rows["online_map_ari"] <= 1.0
