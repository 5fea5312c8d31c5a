"""The result: a probabilistic topological map (paper Section III, docs/model.md §3.6).

A PTM is a histogram over canonical partitions — exact probabilities from
enumeration, or from MCMC visit frequencies or posterior values renormalised
over the visited partitions (:mod:`ptm.recorder`). It answers: the k most probable
topologies, the probability of any partition (0 if never visited), the MAP,
pairwise co-assignment probabilities P(i and j are the same place), the
expected number of places, the entropy, a pandas export and, for sampled
PTMs, the chains' traces as an ArviZ ``InferenceData``.

``ptm.mcmc(posterior, 10_000, seed=0)`` and ``ptm.exact_posterior(posterior)`` return one; by hand:

    >>> result = PTM([[0, 1, 0, 2], [0, 1, 2, 3]], [0.75, 0.25], "exact")
    >>> result.top(1), result.map()
    ([((0, 1, 0, 2), 0.75)], (0, 1, 0, 2))
    >>> result.probability([5, 2, 5, 7]), float(result.coassignment()[0, 2])
    (0.75, 0.75)
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from ._npz import read_npz
from ._validation import finite_array
from .dataset import atomic_write
from .diagnostics import import_arviz
from .partitions import canonical

__all__ = ["PTM", "total_variation"]

_COASSIGNMENT_CHUNK = 20_000


class PTM:
    """A distribution over topologies.

    Parameters
    ----------
    partitions : (P, N) int array
        Distinct canonical label rows (restricted growth strings, :func:`ptm.partitions.canonical`);
        anything else is a ``ValueError`` naming the first bad row.
    probabilities : (P,) array
        Their probabilities (normalised here, unless they already sum to one to rounding).
    method : str
        "exact" or "mcmc".
    diagnostics : dict
        Sampler or enumeration diagnostics.
    traces : dict of (chains, samples) arrays, optional
        Per-sample scalars of the chains ("log_prob", "num_places").
    """

    def __init__(self, partitions, probabilities, method: str, diagnostics=None, traces=None):
        partitions = np.asarray(partitions)
        probabilities = finite_array("PTM probabilities", probabilities)  # complex refused, not cast
        if (partitions.ndim != 2 or probabilities.ndim != 1 or partitions.shape[0] != probabilities.shape[0]
                or partitions.shape[0] == 0 or partitions.shape[1] == 0):
            raise ValueError("a PTM needs a non-empty (P, N) array of partitions and P probabilities")
        if np.any(probabilities < 0) or not np.any(probabilities > 0):
            raise ValueError("PTM probabilities must be finite, non-negative and not all zero")
        partitions, label_rank = _canonical_rows(partitions)
        # Most probable first; ties in the order of the labels (lexicographically smallest first), so that
        # top() and map() do not depend on the order the partitions came in.
        order = np.lexsort((label_rank, -probabilities))
        self.partitions = partitions[order].astype(np.int16 if partitions.shape[1] < 32_000 else np.int32)
        with np.errstate(over="ignore"):
            total = probabilities.sum()
        if np.isinf(total):  # finite weights past the float range together (1e308 + 1e308): the largest becomes 1
            probabilities = probabilities / probabilities.max()
            total = probabilities.sum()
        # Normalised here, unless they sum to one to rounding already (a saved PTM loads to the bit: dividing by
        # such a sum again would move the last digits).
        normalised = abs(total - 1.0) <= len(probabilities) * np.finfo(float).eps
        self.probabilities = probabilities[order] if normalised else probabilities[order] / total
        self.method = method
        self.diagnostics = dict(diagnostics or {})
        self.traces = {name: np.asarray(value) for name, value in (traces or {}).items()}
        self._index: dict | None = None

    @property
    def n(self) -> int:
        """Number of detections N."""
        return self.partitions.shape[1]

    def __len__(self) -> int:
        return self.partitions.shape[0]

    def top(self, k: int = 5) -> list[tuple[tuple[int, ...], float]]:
        """The ``k`` most probable topologies as (canonical tuple, probability)."""
        return [(tuple(int(x) for x in row), float(p))
                for row, p in zip(self.partitions[:k], self.probabilities[:k])]

    def probability(self, labels) -> float:
        """Probability of a partition given as any label sequence (0 if never visited)."""
        key = canonical(labels)
        if len(key) != self.n:
            raise ValueError(f"this PTM is over {self.n} detections, got {len(key)} labels")
        if self._index is None:
            self._index = {row.tobytes(): i for i, row in enumerate(self.partitions)}
        position = self._index.get(np.asarray(key, dtype=self.partitions.dtype).tobytes())
        return 0.0 if position is None else float(self.probabilities[position])

    def rank(self, labels) -> int | None:
        """1-based rank of a partition by probability (ties share the better rank); None if never visited."""
        probability = self.probability(labels)
        if probability == 0.0:
            return None
        return int(np.sum(self.probabilities > probability)) + 1

    def map(self) -> tuple[int, ...]:
        """The most probable topology (canonical tuple); of tied ones, the lexicographically smallest labels."""
        return self.top(1)[0][0]

    def num_places(self) -> np.ndarray:
        """Number of places M of each stored partition."""
        return self.partitions.max(axis=1).astype(int) + 1

    def expected_num_places(self) -> float:
        return float(np.dot(self.probabilities, self.num_places()))

    def entropy(self) -> float:
        """Shannon entropy of the distribution over topologies, in nats."""
        p = self.probabilities[self.probabilities > 0]
        return float(-np.dot(p, np.log(p)))

    def coassignment(self) -> np.ndarray:
        """N x N matrix of P(detections i and j are at the same place)."""
        n = self.n
        matrix = np.zeros((n, n))
        for start in range(0, len(self), _COASSIGNMENT_CHUNK):
            rows = self.partitions[start:start + _COASSIGNMENT_CHUNK]
            weights = self.probabilities[start:start + _COASSIGNMENT_CHUNK]
            same = rows[:, :, None] == rows[:, None, :]
            matrix += np.tensordot(weights, same, axes=(0, 0))
        return matrix

    def to_frame(self, limit: int | None = None):
        """A pandas DataFrame, one row per topology: topology, probability, num_places."""
        import pandas as pd

        rows = self.partitions if limit is None else self.partitions[:limit]
        return pd.DataFrame({
            "topology": ["".join(f"{int(x)}," for x in row).rstrip(",") for row in rows],
            "probability": self.probabilities[: len(rows)],
            "num_places": rows.max(axis=1).astype(int) + 1,
        })

    def to_inference_data(self):
        """The sampler traces as an ArviZ ``InferenceData``, for ``arviz.summary``, ``arviz.plot_trace`` and the like.

        The ``posterior`` group holds every trace the sampler kept (``log_prob``,
        log P(T | Z) of the sampled topology up to a constant, and
        ``num_places``), one chain per sampler chain or tempered ladder, one
        draw per kept sample; ``sample_stats`` holds ``lp`` (log_prob under
        ArviZ's name for the log density). Raises ``ValueError`` for a PTM without
        traces (an exact enumeration, or one built from probabilities). Needs
        the ``arviz`` package, imported here.
        """
        if not self.traces:
            raise ValueError(f"this PTM (method {self.method!r}) has no sampler traces to convert: "
                             "only ptm.mcmc and ptm.tempered_mcmc results carry them")
        shapes = {name: trace.shape for name, trace in self.traces.items()}
        if any(len(shape) != 2 for shape in shapes.values()) or len(set(shapes.values())) != 1:
            raise ValueError(f"traces must all have one shape (chains, samples), got {shapes}")
        arviz = import_arviz()
        sample_stats = {"lp": self.traces["log_prob"]} if "log_prob" in self.traces else None
        data = arviz.from_dict(posterior=dict(self.traces), sample_stats=sample_stats)
        for group in data.groups():
            data[group].attrs.update({"inference_library": "ptm", "ptm_method": self.method})
        return data

    def save(self, path) -> Path:
        """Write the PTM (partitions, probabilities, traces, diagnostics) to one ``.npz`` file, atomically."""
        path = Path(path)
        if path.suffix != ".npz":
            raise ValueError(f"PTM files end in .npz, got {path.name!r}")
        arrays = {"partitions": self.partitions, "probabilities": self.probabilities,
                  "method": np.array(self.method),
                  "diagnostics": np.array(json.dumps(self.diagnostics, default=_jsonable))}
        arrays.update({f"trace_{name}": value for name, value in self.traces.items()})
        atomic_write(path, lambda handle: np.savez_compressed(handle, **arrays))
        return path

    @classmethod
    def load(cls, path) -> "PTM":
        """Read a PTM written by :meth:`save`; a truncated, foreign or tampered file is a ``ValueError`` naming it."""
        path = Path(path)
        if not path.is_file():
            raise FileNotFoundError(f"no PTM file at {path}")
        contents = read_npz(path, "PTM")
        missing = {"partitions", "probabilities", "method", "diagnostics"} - set(contents)
        if missing:
            raise ValueError(f"{path} is not a readable PTM file (it lacks {', '.join(sorted(missing))})")
        traces = {name[len("trace_"):]: value for name, value in contents.items() if name.startswith("trace_")}
        try:
            diagnostics = json.loads(str(contents["diagnostics"]))
            if not isinstance(diagnostics, dict):
                raise ValueError(f"diagnostics must be a JSON object, got {type(diagnostics).__name__}")
            return cls(contents["partitions"], contents["probabilities"], str(contents["method"]), diagnostics, traces)
        except ValueError as error:  # JSONDecodeError included
            raise ValueError(f"{path}: {error}") from None

    def __repr__(self) -> str:
        best, p = self.top(1)[0]
        return (f"PTM(method={self.method!r}, n={self.n}, topologies={len(self)}, "
                f"map={best}, p_map={p:.3f})")


def _canonical_rows(partitions: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The rows as int64 and each row's rank in lexicographic order; ``ValueError`` unless they are distinct RGS."""
    rows, n = partitions.shape
    kind = partitions.dtype.kind
    if kind not in "iuf":
        raise ValueError(f"PTM partitions must be integer labels, got dtype {partitions.dtype}")
    if kind == "f" and not np.all(np.isfinite(partitions) & (partitions == np.round(partitions))):
        raise ValueError("PTM partitions must be integer labels; some are not whole numbers")
    # A canonical label lies in [0, N): checked before the cast, so that 1e20 or 2**63 cannot wrap round.
    in_range = (partitions >= 0) & (partitions < n)
    labels = np.where(in_range, partitions, -1).astype(np.int64)
    ceiling = np.concatenate([np.zeros((rows, 1), dtype=np.int64), np.maximum.accumulate(labels, axis=1)[:, :-1] + 1],
                             axis=1)
    bad = np.flatnonzero(np.any(~in_range | (labels > ceiling), axis=1))
    if bad.size:
        row = partitions[bad[0]]
        shown = ", ".join(str(label) for label in row[:12].tolist()) + (", ..." if n > 12 else "")
        raise ValueError(f"PTM partitions must be canonical labels (restricted growth strings: the first 0, each "
                         f"at most one more than any before it; ptm.partitions.canonical makes them): row {bad[0]} "
                         f"is ({shown})")
    # Rows as byte strings of big-endian unsigned labels: byte order is then the lexicographic order of the labels
    # (one argsort of P keys, instead of np.unique(axis=0), which took 6 s on the 678 570 partitions of N = 11).
    width = np.dtype(">u2") if n <= np.iinfo(np.uint16).max else np.dtype(">u4")
    keys = np.ascontiguousarray(labels.astype(width)).view(np.dtype((np.void, n * width.itemsize))).ravel()
    lexicographic = np.argsort(keys, kind="stable")
    repeats = np.flatnonzero(keys[lexicographic][1:] == keys[lexicographic][:-1])
    if repeats.size:
        first, second = sorted(lexicographic[repeats[0]:repeats[0] + 2].tolist())
        raise ValueError(f"PTM partitions must be distinct; rows {first} and {second} are equal "
                         "(add up the probabilities of equal partitions first)")
    rank = np.empty(rows, dtype=np.int64)
    rank[lexicographic] = np.arange(rows)
    return labels, rank


def _jsonable(value):
    """JSON fallback for numpy scalars and arrays in diagnostics."""
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, np.generic):
        return value.item()
    raise TypeError(f"{type(value).__name__} is not JSON-serialisable")


def total_variation(first: PTM, second: PTM) -> float:
    """Total variation distance between two PTMs over the same detections."""
    if first.n != second.n:
        raise ValueError(f"PTMs over different numbers of detections ({first.n} vs {second.n})")
    mass: dict[bytes, float] = {}
    for sign, result in ((1.0, first), (-1.0, second)):
        rows = result.partitions.astype(np.int32)
        for row, p in zip(rows, result.probabilities):
            key = row.tobytes()
            mass[key] = mass.get(key, 0.0) + sign * p
    return 0.5 * float(sum(abs(v) for v in mass.values()))
