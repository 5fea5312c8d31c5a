"""Peers: the robust pose-graph back ends roboticists run instead of a posterior, scored on the same data.

Every peer reads a dataset's odometry (and signatures, where the front end
uses them), never its labels, and answers with accepted loop closures, the
partition they imply and a score per pair (:class:`PeerResult`):

* ``gnc``: GTSAM's graduated non-convexity with a truncated-least-squares loss (:mod:`.gnc`);
* ``dcs``: dynamic covariance scaling, Levenberg-Marquardt (:mod:`.dcs`);
* ``pcm``: pairwise consistency maximisation, the maximum clique (:mod:`.pcm`);
* ``distance_rank``: pairs ranked by dead-reckoned distance alone (:mod:`.distance_rank`).

The first three close the pairs of the shared candidate front end
(:mod:`.candidates`). The noise is the posterior's (:class:`PeerNoise`), the
free settings are calibrated on held-out runs (:mod:`.calibration`). GTSAM is
the optional extra ``ptm[peers]``, imported when ``gnc`` or ``dcs`` first runs.

    >>> import numpy as np, ptm
    >>> square = np.tile([2.0, 0.0, np.pi / 2], (8, 1))          # a 2 m square driven twice
    >>> held_out = [ptm.Dataset(odometry=square, signatures=[[0.0], [1.0], [2.0], [3.0]] * 2 + [[0.0]],
    ...                         labels=[0, 1, 2, 3] * 2 + [0])]
    >>> scored = held_out[0].replace(labels=None)                 # the scored run's labels are never read
    >>> result, calibration = run_calibrated(PEERS["pcm"], scored, held_out, PeerNoise(0.05, 0.02, 0.3))
    >>> result.labels, calibration.source
    ((0, 1, 2, 3, 0, 1, 2, 3, 0), 'calibrated: best mean ARI 1.000 of 18 settings on 1 held-out run')
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

from ptm_bench.evaluation.peers import dcs, distance_rank, gnc, pcm
from ptm_bench.evaluation.peers.calibration import Calibration, calibrate, run_calibrated
from ptm_bench.evaluation.peers.candidates import CandidateSettings, candidate_pairs
from ptm_bench.evaluation.peers.noise import PeerNoise
from ptm_bench.evaluation.peers.result import PeerResult, score_peer

__all__ = ["PEERS", "Calibration", "CandidateSettings", "Peer", "PeerNoise", "PeerResult", "calibrate",
           "candidate_pairs", "run_calibrated", "score_peer"]


@dataclass(frozen=True)
class Peer:
    """A peer: ``run(dataset, noise, settings) -> PeerResult``, its ``settings`` class (defaults documented)
    and ``grid(with_signatures)``, the settings calibration tries, the default first."""

    name: str
    run: Callable
    settings: type
    grid: Callable


#: Peer name -> the peer.
PEERS: dict[str, Peer] = {
    "gnc": Peer("gnc", gnc.run, gnc.GncSettings, gnc.grid),
    "dcs": Peer("dcs", dcs.run, dcs.DcsSettings, dcs.grid),
    "pcm": Peer("pcm", pcm.run, pcm.PcmSettings, pcm.grid),
    "distance_rank": Peer("distance_rank", distance_rank.run, distance_rank.DistanceRankSettings, distance_rank.grid),
}
