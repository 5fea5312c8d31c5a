"""The peers (robust pose-graph back ends and dead-reckoned distance) on worlds whose answer is known.

Each peer recovers the truth of an easy world (a loop of eight places driven
twice with exact odometry and distinct signatures) and fails on the control,
a hard world (every place looks alike and the odometry drifts), where it
accepts wrong closures. The candidate front end is deterministic; a missing
GTSAM and a failing solver are reported, not raised; calibration reads the
held-out runs' labels only. The wall time at N = 200 is printed, not asserted:
``python3 -m pytest -p no:cacheprovider -n 0 -s tests/test_peers.py -k wall_time``.
"""

from __future__ import annotations

import sys
import time
from dataclasses import asdict

import numpy as np
import pytest

import ptm
from ptm.se2 import dead_reckoning, relative_pose

from ptm_bench.evaluation.peers import PEERS, PeerNoise, calibrate, candidate_pairs, run_calibrated, score_peer
from ptm_bench.evaluation.peers import dcs, gnc, pcm
from ptm_bench.evaluation.peers.candidates import CandidateSettings, candidate_grid
from ptm_bench.evaluation.peers.result import PeerResult, bottleneck_scores, closure_labels
from ptm_bench.evaluation.scoring import adjusted_rand_index

GTSAM_PEERS = ("gnc", "dcs")
NOISE = PeerNoise.from_meta({"detection_radius": 1.0}, sigma_xy=0.1, sigma_theta=0.05)


def loop_world(places=8, laps=2, radius=10.0, jitter=0.3, step_sd=(0.0, 0.0), drift=0.0, aliased=False,
               signature_sd=0.01, seed=0) -> ptm.Dataset:
    """Places on a circle driven ``laps`` times counter-clockwise; a detection lies within ``jitter`` [m] of its place.

    Odometry: the true relative poses, plus per-step noise ``step_sd`` (m, rad) and a heading drift [rad/m]
    (``odometry_cov`` holds the per-step noise, never the drift). Signatures: one random 3-vector per place
    (the same one for every place when ``aliased``) plus noise ``signature_sd``.
    """
    rng = np.random.default_rng(seed)
    angles = 2.0 * np.pi * np.arange(places) / places
    labels = np.tile(np.arange(places), laps)
    centres = radius * np.column_stack([np.cos(angles), np.sin(angles)])
    positions = centres[labels] + rng.uniform(-jitter, jitter, (len(labels), 2)) / np.sqrt(2.0)
    headings = angles[labels] + np.pi / 2 + rng.normal(0.0, 0.2, len(labels))
    poses = np.column_stack([positions, headings])
    steps = relative_pose(poses[:-1], poses[1:])
    steps[:, :2] += rng.normal(0.0, step_sd[0], (len(steps), 2)) if step_sd[0] else 0.0
    steps[:, 2] += rng.normal(0.0, step_sd[1], len(steps)) if step_sd[1] else 0.0
    steps[:, 2] += drift * np.linalg.norm(steps[:, :2], axis=1)
    place_signatures = np.ones((places, 3)) if aliased else rng.uniform(0.0, 10.0, (places, 3))
    signatures = place_signatures[labels] + rng.normal(0.0, signature_sd, (len(labels), 3))
    covariance = np.diag([max(step_sd[0], 0.01) ** 2] * 2 + [max(step_sd[1], 0.005) ** 2])
    return ptm.Dataset(odometry=steps, odometry_cov=np.broadcast_to(covariance, (len(steps), 3, 3)),
                       signatures=signatures, labels=labels, true_poses=poses, meta={"detection_radius": 1.0})


def easy_world(seed=0) -> ptm.Dataset:
    return loop_world(seed=seed)


def hard_world(seed=0) -> ptm.Dataset:
    """The control: every place wears one decor and the heading drifts 0.03 rad per metre (0.23 rad a step)."""
    return loop_world(laps=3, aliased=True, drift=0.03, seed=seed)


def _peer_gtsam(name):
    if name in GTSAM_PEERS:
        pytest.importorskip("gtsam")


# -- the peers on the easy and the hard world ---------------------------------------------------------------------

@pytest.mark.parametrize("name", sorted(PEERS))
def test_each_peer_recovers_the_truth_of_an_easy_world(name):
    _peer_gtsam(name)
    dataset = easy_world()
    peer = PEERS[name]
    result = peer.run(dataset, NOISE, peer.settings())
    assert not result.failed
    assert result.labels == ptm.canonical(dataset.labels)
    row = score_peer(result, dataset.labels)
    assert row["ari"] == 1.0 and row["lc_f1"] == 1.0 and row["lc_ap"] == 1.0


@pytest.mark.parametrize("name", sorted(PEERS))
def test_each_peer_fails_on_the_hard_world_by_accepting_wrong_closures(name):
    """Negative control: with aliased signatures and drifting odometry a peer closes the wrong pairs."""
    _peer_gtsam(name)
    dataset = hard_world()
    peer = PEERS[name]
    result = peer.run(dataset, NOISE, peer.settings())
    assert not result.failed
    accepted = result.pairs[result.accepted]
    wrong = dataset.labels[accepted[:, 0]] != dataset.labels[accepted[:, 1]]
    assert wrong.any()
    assert adjusted_rand_index(result.labels, dataset.labels) < 0.5


@pytest.mark.parametrize("name", sorted(PEERS))
def test_a_calibrated_peer_recovers_an_easy_world_without_its_labels(name):
    _peer_gtsam(name)
    held_out = [easy_world(seed) for seed in (1, 2)]
    scored = easy_world(0)
    result, calibration = run_calibrated(PEERS[name], scored.replace(labels=None), held_out, NOISE)
    assert calibration.mean_ari == 1.0 and calibration.source.endswith("on 2 held-out runs")
    assert result.labels == ptm.canonical(scored.labels)
    assert calibration.settings == PEERS[name].settings()  # the default wins ties: the grid lists it first


# -- calibration ----------------------------------------------------------------------------------------------------

def test_calibration_reads_no_label_of_the_scored_run():
    held_out = [easy_world(seed) for seed in (1, 2)]
    scored = easy_world(0)
    with_labels, _ = run_calibrated(PEERS["pcm"], scored, held_out, NOISE)
    without, _ = run_calibrated(PEERS["pcm"], scored.replace(labels=None, true_poses=None), held_out, NOISE)
    assert with_labels.labels == without.labels
    np.testing.assert_array_equal(with_labels.pair_scores, without.pair_scores)


def test_calibration_refuses_held_out_runs_without_labels():
    with pytest.raises(ValueError, match="held-out run 1 has no labels"):
        calibrate(PEERS["distance_rank"], [easy_world(1), easy_world(2).replace(labels=None)], NOISE)
    with pytest.raises(ValueError, match="at least one held-out run"):
        calibrate(PEERS["distance_rank"], [], NOISE)


def test_calibration_picks_the_best_mean_ari_of_the_grid():
    held_out = [loop_world(jitter=0.9, seed=seed) for seed in (1, 2)]
    calibration = calibrate(PEERS["distance_rank"], held_out, NOISE)
    best = max(row[1] for row in calibration.table)
    assert calibration.mean_ari == best
    assert len(calibration.table) == len(PEERS["distance_rank"].grid(True))


def test_each_grid_lists_the_default_first():
    for name, peer in PEERS.items():
        for with_signatures in (True, False):
            grid = peer.grid(with_signatures)
            assert len(set(grid)) == len(grid), name
        assert peer.grid(True)[0] == peer.settings(), name


def test_a_failed_run_counts_ari_0_in_calibration(monkeypatch):
    pytest.importorskip("gtsam")
    monkeypatch.setattr(dcs, "LM_MAX_ITERATIONS", 1)
    calibration = calibrate(PEERS["dcs"], [easy_world(1)], NOISE)
    assert calibration.mean_ari == 0.0
    assert all(row[2] == 1 for row in calibration.table)  # every setting failed on the one run


# -- the candidate front end ----------------------------------------------------------------------------------------

def test_candidates_are_deterministic_pairs_of_distinct_detections():
    dataset = loop_world(laps=3, jitter=0.9, signature_sd=0.5)
    for settings in candidate_grid(True):
        pairs = candidate_pairs(dataset, settings, NOISE.sigma_tie)
        np.testing.assert_array_equal(pairs, candidate_pairs(dataset, settings, NOISE.sigma_tie))
        assert np.all(pairs[:, 0] < pairs[:, 1])
        assert len(np.unique(pairs, axis=0)) == len(pairs)
        assert np.all(np.diff(pairs[:, 0]) >= 0)


def test_candidates_are_the_k_nearest_in_appearance_ties_to_the_smaller_index():
    odometry = np.tile([1.0, 0.0, 0.0], (4, 1))
    dataset = ptm.Dataset(odometry=odometry, signatures=[[0.0], [1.0], [1.0], [1.0], [9.0]])
    # 0 -> 1 (1 and 2 and 3 tie: the smaller index), 1 -> 2, 2 -> 1, 3 -> 1, 4 -> 1 (1, 2 and 3 tie)
    assert candidate_pairs(dataset, CandidateSettings(k=1), 1.0).tolist() == [[0, 1], [1, 2], [1, 3], [1, 4]]
    # consecutive detections are kept; a gate of 1.5 m keeps only neighbours within 1.5 m of dead reckoning
    assert candidate_pairs(dataset, CandidateSettings(k=1, gate=1.5), 1.0).tolist() == [[0, 1], [1, 2], [2, 3],
                                                                                       [3, 4]]


def test_without_signatures_every_pair_within_the_gate_is_a_candidate():
    dataset = ptm.Dataset(odometry=np.tile([1.0, 0.0, 0.0], (4, 1)))
    assert candidate_pairs(dataset, CandidateSettings(gate=1.5), 1.0).tolist() == [[0, 1], [1, 2], [2, 3], [3, 4]]
    assert len(candidate_pairs(dataset, CandidateSettings(gate=10.0), 1.0)) == 10
    with pytest.raises(ValueError, match="needs a candidate gate"):
        candidate_pairs(dataset, CandidateSettings(), 1.0)


@pytest.mark.parametrize("name", sorted(PEERS))
def test_a_peer_runs_without_signatures(name):
    _peer_gtsam(name)
    dataset = easy_world().replace(signatures=None)
    peer = PEERS[name]
    settings = peer.grid(False)[0]
    result = peer.run(dataset, NOISE, settings)
    assert result.labels == ptm.canonical(dataset.labels)


@pytest.mark.parametrize("bad", [{"k": 0}, {"k": 2.5}, {"gate": -1.0}, {"gate": float("nan")}])
def test_candidate_settings_are_validated(bad):
    with pytest.raises(ValueError, match="candidate setting"):
        CandidateSettings(**bad)


# -- missing GTSAM, a failing solver --------------------------------------------------------------------------------

@pytest.mark.parametrize("name", GTSAM_PEERS)
def test_missing_gtsam_is_one_line_naming_the_extra(name, monkeypatch):
    monkeypatch.setitem(sys.modules, "gtsam", None)  # `import gtsam` now raises ImportError
    with pytest.raises(ImportError) as error:
        PEERS[name].run(easy_world(), NOISE, PEERS[name].settings())
    message = str(error.value)
    assert 'pip install "ptm[peers]"' in message and "\n" not in message


@pytest.mark.parametrize("name, solver", [("gnc", "GncLMOptimizer"), ("dcs", "LevenbergMarquardtOptimizer")])
def test_a_solver_exception_is_a_failed_result_with_its_message(name, solver, monkeypatch):
    gtsam = pytest.importorskip("gtsam")

    def singular(*args, **kwargs):
        raise RuntimeError("Indeterminant linear system detected")

    monkeypatch.setattr(gtsam, solver, singular)
    dataset = easy_world()
    result = PEERS[name].run(dataset, NOISE, PEERS[name].settings())
    assert result.failed and "Indeterminant linear system" in result.error and result.labels is None
    row = score_peer(result, dataset.labels)
    assert row["peer_error"] == result.error and np.isnan(row["ari"])


def test_dcs_reports_no_convergence(monkeypatch):
    pytest.importorskip("gtsam")
    monkeypatch.setattr(dcs, "LM_MAX_ITERATIONS", 1)
    result = PEERS["dcs"].run(easy_world(), NOISE, PEERS["dcs"].settings())
    assert result.failed and "did not converge in 1 iterations" in result.error


# -- the pieces: tie factor, PCM consistency, clique, scores --------------------------------------------------------

def test_a_tie_measures_the_distance_of_the_positions_whatever_the_headings():
    gtsam = pytest.importorskip("gtsam")
    from ptm_bench.evaluation.peers.pose_graph import tie_chi2, tie_graph

    dataset = ptm.Dataset(odometry=[[3.0, 4.0, 2.5]])  # the second detection 5 m away, turned by 2.5 rad
    graph = tie_graph(dataset, PeerNoise(0.1, 0.05, 0.5), np.array([[0, 1]]))
    assert tie_chi2(graph, graph.initial)[0] == pytest.approx((5.0 / 0.5) ** 2, rel=1e-6)
    values = gtsam.Values()
    values.insert(0, gtsam.Pose2(0.0, 0.0, 0.0))
    values.insert(1, gtsam.Pose2(0.0, 0.0, 2.5))
    assert tie_chi2(graph, values)[0] == pytest.approx(0.0, abs=1e-9)


def test_position_covariance_is_the_linearised_dead_reckoning():
    rng = np.random.default_rng(3)
    odometry = np.column_stack([rng.uniform(0.5, 2.0, 9), rng.normal(0.0, 0.3, 9), rng.normal(0.0, 0.8, 9)])
    factors = rng.normal(size=(9, 3, 3))
    covariances = factors @ np.swapaxes(factors, 1, 2) * 0.01 + 1e-3 * np.eye(3)
    step, flat = 1e-6, odometry.ravel()
    jacobian = np.column_stack([
        (dead_reckoning((flat + step * unit).reshape(-1, 3))[:, :2]
         - dead_reckoning((flat - step * unit).reshape(-1, 3))[:, :2]).ravel() / (2.0 * step)
        for unit in np.eye(flat.size)])
    blocks = np.zeros((27, 27))
    for row in range(9):
        blocks[3 * row:3 * row + 3, 3 * row:3 * row + 3] = covariances[row]
    expected = jacobian @ blocks @ jacobian.T
    actual = pcm.position_covariance(dead_reckoning(odometry), covariances).reshape(20, 20)
    np.testing.assert_allclose(actual, expected, atol=1e-7)


def test_pcm_consistency_of_two_true_closures_and_a_false_one():
    dataset = easy_world()
    # 0~8 and 1~9 are true (place 0, place 1), 0~9 is not: it passes neither its own cycle nor a pair's
    alone, together = pcm.consistency(dataset, NOISE, np.array([[0, 8], [1, 9], [0, 9]]), 9.21)
    assert alone.tolist() == [True, True, False]
    assert together[0, 1] and together[1, 0] and not together[0, 2] and not together.diagonal().any()


def test_the_greedy_clique_is_a_clique_and_finds_a_planted_one():
    rng = np.random.default_rng(0)
    adjacent = np.triu(rng.random((60, 60)) < 0.2, k=1)
    planted = rng.choice(60, size=15, replace=False)
    adjacent[np.ix_(planted, planted)] = True
    adjacent = np.triu(adjacent, k=1)
    adjacent |= adjacent.T
    clique = pcm.greedy_max_clique(adjacent)
    assert sorted(clique) == sorted(planted)
    assert all(adjacent[i, j] for i in clique for j in clique if i != j)
    assert pcm.core_numbers(np.ones((4, 4), dtype=bool) & ~np.eye(4, dtype=bool)).tolist() == [3, 3, 3, 3]


def test_bottleneck_scores_cut_at_any_level_give_the_components_above_it():
    pairs = np.array([[0, 1], [1, 2], [3, 4], [2, 3]])
    scores = np.array([0.9, 0.6, 0.8, 0.3])
    matrix = bottleneck_scores(5, pairs, scores)
    assert matrix[0, 2] == 0.6 and matrix[0, 4] == 0.3 and matrix[3, 4] == 0.8 and matrix[0, 0] == 0.0
    for level in (0.2, 0.5, 0.7, 0.85):
        from_matrix = closure_labels(5, np.argwhere(np.triu(matrix > level, k=1)))
        assert from_matrix == closure_labels(5, pairs[scores > level])


def test_a_result_with_no_candidates_is_all_singletons():
    result = PeerResult.from_candidates("gnc", {}, 3, np.zeros((0, 2)), [], [])
    assert result.labels == (0, 1, 2) and not result.pair_scores.any()


def test_noise_comes_from_odometry_cov_where_given_else_the_sigmas():
    dataset = easy_world()
    np.testing.assert_array_equal(NOISE.step_covariances(dataset), dataset.odometry_cov)
    plain = dataset.replace(odometry_cov=None)
    np.testing.assert_allclose(NOISE.step_covariances(plain)[0], np.diag([0.01, 0.01, 0.0025]))
    assert NOISE.sigma_tie == pytest.approx(1.0 / np.sqrt(2.0))
    with pytest.raises(ValueError, match="sigma_tie"):
        PeerNoise(0.1, 0.05, 0.0)
    with pytest.raises(ValueError, match="detection_radius"):
        PeerNoise.from_meta({}, 0.1, 0.05)


def test_settings_are_recorded_in_the_result():
    result = PEERS["pcm"].run(easy_world(), NOISE, pcm.PcmSettings(k=2))
    assert result.settings == asdict(pcm.PcmSettings(k=2)) and result.wall_s > 0
    with pytest.raises(ValueError, match="inlier_probability"):
        gnc.GncSettings(inlier_probability=1.0)


# -- time at N = 200 (printed, not asserted) ------------------------------------------------------------------------

def test_wall_time_at_200_detections():
    """A loop of 50 places driven four times with noisy odometry and appearance: each peer's time at its default
    settings and at the most candidates its grid proposes (k = 8, ungated)."""
    pytest.importorskip("gtsam")
    dataset = loop_world(places=50, laps=4, radius=60.0, jitter=0.7, step_sd=(0.05, 0.01), signature_sd=0.5)
    assert dataset.n == 200
    for name, peer in PEERS.items():
        widest = [settings for settings in peer.grid(True) if getattr(settings, "k", 0) == 8][:1]
        for settings in [peer.settings(), *widest]:
            seconds, cpu = [], []
            for _ in range(3):
                started, started_cpu = time.perf_counter(), time.process_time()
                result = peer.run(dataset, NOISE, settings)
                seconds.append(time.perf_counter() - started)
                cpu.append(time.process_time() - started_cpu)
            ari = adjusted_rand_index(result.labels, dataset.labels)
            print(f"\npeer {name:14s} N = 200 {settings}: {len(result.pairs)} candidates, wall {min(seconds):.3f} s, "
                  f"cpu {min(cpu):.3f} s (best of 3), ARI {ari:.3f}")
