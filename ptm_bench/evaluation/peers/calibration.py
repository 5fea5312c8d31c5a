"""Each peer's free settings, chosen on held-out runs only (docs/model.md §6, the provenance rule).

A peer gets the best of its documented grid (its module's ``grid``: the
candidate front end's k and gate, and its back end's threshold) the way the
threshold baselines get theirs: every setting runs on every labelled
held-out run, and the one with the best mean adjusted Rand index of its
partition wins, ties going to the earlier setting of the grid (each grid
lists its default first). A run whose solver fails counts ARI 0 (what the
all-singletons answer scores against a truth with any revisit). The same rule
serves every world; the scored run is never looked at, so its labels may be
absent (:func:`run_calibrated`).

    >>> import numpy as np, ptm
    >>> from ptm_bench.evaluation.peers import PEERS, PeerNoise
    >>> square = np.tile([2.0, 0.0, np.pi / 2], (8, 1))          # a 2 m square driven twice
    >>> held_out = [ptm.Dataset(odometry=square, labels=[0, 1, 2, 3] * 2 + [0])]
    >>> calibration = calibrate(PEERS["distance_rank"], held_out, PeerNoise(0.05, 0.02, 0.3))
    >>> calibration.settings, round(calibration.mean_ari, 3)
    (DistanceRankSettings(threshold=2.0), 1.0)
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import asdict, dataclass

import numpy as np

from ptm_bench.evaluation.calibration import described, labelled_runs
from ptm_bench.evaluation.scoring import adjusted_rand_index

__all__ = ["Calibration", "calibrate", "run_calibrated"]


@dataclass(frozen=True)
class Calibration:
    """The chosen ``settings``, their ``mean_ari`` on the held-out runs, every setting's row in ``table``
    (settings as a dict, ``mean_ari``, ``failures``), and a one-line ``source`` for the sweep's table."""

    peer: str
    settings: object
    mean_ari: float
    table: tuple
    source: str


def calibrate(peer, held_out: Sequence, noise) -> Calibration:
    """The setting of ``peer`` (an entry of ``PEERS``) with the best mean ARI on the labelled ``held_out`` runs."""
    held_out = labelled_runs(held_out, f"peer {peer.name!r}")
    for index, dataset in enumerate(held_out):
        if dataset.odometry is None:
            raise ValueError(f"calibration of peer {peer.name!r}: held-out run {index} has no odometry")
    with_signatures = {dataset.signatures is not None for dataset in held_out}
    if len(with_signatures) != 1:
        raise ValueError(f"calibration of peer {peer.name!r}: some held-out runs have signatures and some do not")
    table = []
    for settings in peer.grid(with_signatures.pop()):
        scores, failures = [], 0
        for dataset in held_out:
            result = peer.run(dataset, noise, settings)
            failures += result.failed
            scores.append(0.0 if result.failed else adjusted_rand_index(result.labels, dataset.labels))
        table.append((settings, float(np.mean(scores)), failures))
    best = max(range(len(table)), key=lambda index: (table[index][1], -index))
    settings, mean_ari, _ = table[best]
    return Calibration(peer.name, settings, mean_ari,
                       tuple((asdict(row[0]), row[1], row[2]) for row in table),
                       f"calibrated: best mean ARI {mean_ari:.3f} of {len(table)} settings on {described(held_out)}")


def run_calibrated(peer, dataset, held_out: Sequence, noise):
    """(result, calibration): ``peer`` calibrated on ``held_out``, then run on ``dataset`` (its labels unread)."""
    calibration = calibrate(peer, held_out, noise)
    return peer.run(dataset, noise, calibration.settings), calibration
