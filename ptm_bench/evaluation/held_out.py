"""Held-out runs are never the scored run: runs are compared by their content, not by their file's name.

A calibration set that holds the scored run (its file copied or renamed) fits the parameters on the scored run's
own ground truth, and the scores say nothing about runs the parameters never saw (docs/model.md §6). Two runs are
the same run when they hold the same measurements and truth: :func:`content_hash` is the SHA-256 of the arrays
``odometry``, ``odometry_cov``, ``signatures``, ``labels`` and ``true_poses`` (each with its dtype and shape; the
panoramas and the meta are left out, so a copy re-saved without its images or with other provenance is still
the same run). :func:`refuse_scored_run` raises for a held-out run whose hash is the scored run's.

    >>> import ptm
    >>> scored = ptm.Dataset(labels=[0, 1, 0], meta={"source": "intel.npz"})
    >>> content_hash(scored) == content_hash(ptm.Dataset(labels=[0, 1, 0]))
    True
    >>> refuse_scored_run(scored, "intel.npz", {"aces.npz": ptm.Dataset(labels=[0, 1, 1]), "copy.npz": scored})
    ... # doctest: +ELLIPSIS
    Traceback (most recent call last):
    ValueError: calibration: copy.npz holds the same run as intel.npz (the same detections and truth); ...
"""

from __future__ import annotations

import hashlib
from collections.abc import Mapping

import ptm

__all__ = ["CONTENT_FIELDS", "content_hash", "refuse_scored_run"]

#: The arrays of a ``ptm.Dataset`` that make a run what it is: its measurements and its ground truth.
CONTENT_FIELDS = ("odometry", "odometry_cov", "signatures", "labels", "true_poses")


def content_hash(dataset: ptm.Dataset) -> str:
    """The SHA-256 (hex) of the dataset's :data:`CONTENT_FIELDS`: equal for a run and any copy of it."""
    digest = hashlib.sha256()
    for name in CONTENT_FIELDS:
        array = getattr(dataset, name)
        # the name, dtype and shape go in too: absent, empty and reshaped arrays all differ
        header = "absent" if array is None else f"{array.dtype.str} {array.shape}"
        digest.update(f"{name}: {header}\n".encode())
        if array is not None:
            digest.update(array.tobytes(order="C"))
    return digest.hexdigest()


def refuse_scored_run(scored: ptm.Dataset, scored_name: str, held_out: Mapping[str, ptm.Dataset]) -> None:
    """``ValueError`` naming both runs if a held-out run (``{name: dataset}``) has the content of ``scored``."""
    scored_hash = content_hash(scored)
    for name, dataset in held_out.items():
        if content_hash(dataset) == scored_hash:
            raise ValueError(f"calibration: {name} holds the same run as {scored_name} (the same detections and "
                             "truth); a run is never its own calibration: calibrate on other runs")
