"""The measurements of one run: odometry, appearance signatures and ground truth.

Implements the data contract of docs/model.md §2.2. A dataset holds N detections; row k
of ``odometry`` is the motion from detection k-1 to k expressed in the robot
frame at k-1, ``(dx, dy, dtheta)`` with the angle wrapped to (-pi, pi].
Everything is validated on construction and on load; files are written
atomically (a temporary file in the same folder, then a rename).

    >>> import tempfile
    >>> ds = Dataset(signatures=np.ones((4, 5)), labels=[0, 1, 0, 2])
    >>> path = ds.save(Path(tempfile.mkdtemp()) / "run.npz"); Dataset.load(path).n
    4
"""

from __future__ import annotations

import json
import os
import tempfile
import zipfile
import zlib
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ._validation import finite_array
from .se2 import wrap_angle

__all__ = ["Dataset", "wrap_angle"]  # wrap_angle: re-exported from ptm.se2 for older imports

_ARRAY_FIELDS = ("odometry", "odometry_cov", "signatures", "labels", "true_poses", "panoramas")


@dataclass(frozen=True)
class Dataset:
    """Landmark detections of one robot run (docs/model.md §2.2).

    Parameters
    ----------
    odometry : (N-1, 3) array or None
        Relative motion between consecutive detections, robot frame of the earlier one.
    signatures : (N, K) array or None
        Appearance measurement (Fourier signature) of each detection.
    labels : (N,) int array or None
        Ground-truth place id of each detection (simulation only).
    true_poses : (N, 3) array or None
        Ground-truth world poses (x, y, theta).
    odometry_cov : (N-1, 3, 3) array or None
        Covariance of each odometry row; symmetric positive definite.
    panoramas : (N, H, W, 3) uint8 array or None
        The panoramic images, if kept.
    meta : dict
        JSON-serialisable provenance (world, seeds, noise, generator version).
    """

    odometry: np.ndarray | None = None
    signatures: np.ndarray | None = None
    labels: np.ndarray | None = None
    true_poses: np.ndarray | None = None
    odometry_cov: np.ndarray | None = None
    panoramas: np.ndarray | None = None
    meta: dict = field(default_factory=dict)

    def __post_init__(self):
        n = self._infer_n()
        set_ = object.__setattr__
        if self.odometry is not None:
            odometry = finite_array("odometry", self.odometry, ndim=2)
            if odometry.shape != (n - 1, 3):
                raise ValueError(f"odometry must have shape ({n - 1}, 3) for N={n}, got {odometry.shape}")
            odometry = odometry.copy()
            odometry[:, 2] = wrap_angle(odometry[:, 2])
            set_(self, "odometry", odometry)
        if self.odometry_cov is not None:
            if self.odometry is None:
                raise ValueError("odometry_cov given without odometry")
            set_(self, "odometry_cov", _validated_covariances(self.odometry_cov, n))
        if self.signatures is not None:
            signatures = finite_array("signatures", self.signatures, ndim=2)
            if signatures.shape[0] != n or signatures.shape[1] < 1:
                raise ValueError(f"signatures must have shape ({n}, K>=1), got {signatures.shape}")
            set_(self, "signatures", signatures)
        if self.labels is not None:
            set_(self, "labels", _validated_labels(self.labels, n))
        if self.true_poses is not None:
            poses = finite_array("true_poses", self.true_poses, ndim=2)
            if poses.shape != (n, 3):
                raise ValueError(f"true_poses must have shape ({n}, 3), got {poses.shape}")
            set_(self, "true_poses", poses)
        if self.panoramas is not None:
            panoramas = np.asarray(self.panoramas)
            if panoramas.dtype != np.uint8 or panoramas.ndim != 4 or panoramas.shape[0] != n or panoramas.shape[3] != 3:
                raise ValueError(
                    f"panoramas must be a uint8 array of shape ({n}, H, W, 3), "
                    f"got {panoramas.dtype} {panoramas.shape}"
                )
            set_(self, "panoramas", panoramas)
        try:
            meta = json.loads(json.dumps(dict(self.meta or {})))
        except (TypeError, ValueError) as error:
            raise ValueError(f"meta must be JSON-serialisable: {error}") from None
        set_(self, "meta", meta)

    def _infer_n(self) -> int:
        candidates = {}
        if self.odometry is not None:
            candidates["odometry"] = np.shape(self.odometry)[0] + 1 if np.ndim(self.odometry) >= 1 else None
        for name in ("signatures", "labels", "true_poses", "panoramas"):
            value = getattr(self, name)
            if value is not None:
                candidates[name] = np.shape(value)[0] if np.ndim(value) >= 1 else None
        if not candidates:
            raise ValueError("a dataset needs at least one of odometry, signatures, labels or true_poses")
        for name, count in candidates.items():
            if count is None:
                raise ValueError(f"{name} must be an array with one row per detection")
        counts = set(candidates.values())
        if len(counts) > 1:
            detail = ", ".join(f"{name} implies N={count}" for name, count in candidates.items())
            raise ValueError(f"mismatched lengths: {detail}")
        n = counts.pop()
        if n < 1:
            raise ValueError("a dataset needs N >= 1 detections, got N=0")
        return n

    @property
    def n(self) -> int:
        """Number of detections N."""
        return self._infer_n()

    def without_panoramas(self) -> "Dataset":
        """The same dataset with the (large) panoramas dropped."""
        return self.replace(panoramas=None)

    def replace(self, **changes) -> "Dataset":
        """A validated copy with some fields replaced."""
        fields = {name: getattr(self, name) for name in _ARRAY_FIELDS}
        fields["meta"] = self.meta
        fields.update(changes)
        return Dataset(**fields)

    def head(self, count: int) -> "Dataset":
        """The first ``count`` detections (used to replay a run incrementally)."""
        if not 1 <= count <= self.n:
            raise ValueError(f"head count must be in [1, {self.n}], got {count}")
        fields = {}
        for name in _ARRAY_FIELDS:
            value = getattr(self, name)
            if value is None:
                fields[name] = None
            elif name in ("odometry", "odometry_cov"):
                fields[name] = value[: count - 1]
            else:
                fields[name] = value[:count]
        return Dataset(meta=self.meta, **fields)

    # -- persistence -------------------------------------------------------------------------

    def save(self, path) -> Path:
        """Write the dataset as one compressed ``.npz`` file, atomically."""
        path = Path(path)
        if path.suffix != ".npz":
            raise ValueError(f"dataset files end in .npz, got {path.name!r}")
        arrays = {name: getattr(self, name) for name in _ARRAY_FIELDS if getattr(self, name) is not None}
        arrays["meta"] = np.array(json.dumps(self.meta, sort_keys=True))

        def write(handle):
            np.savez_compressed(handle, **arrays)

        atomic_write(path, write)
        return path

    @classmethod
    def load(cls, path) -> "Dataset":
        """Read and validate a dataset written by :meth:`save`."""
        path = Path(path)
        if not path.is_file():
            raise FileNotFoundError(f"no dataset file at {path}")
        try:
            loaded = np.load(path, allow_pickle=False)
            if not isinstance(loaded, np.lib.npyio.NpzFile):
                raise ValueError("it holds a single array (.npy), not the named arrays of a dataset (.npz)")
            with loaded as archive:
                contents = {name: archive[name] for name in archive.files}
        except (OSError, ValueError, EOFError, KeyError, NotImplementedError, zipfile.BadZipFile, zlib.error) as error:
            # a truncated, foreign or damaged file: BadZipFile, zlib.error, EOFError or (an unknown compression
            # method in a damaged zip header) NotImplementedError from deep inside numpy
            raise ValueError(f"{path} is not a readable dataset file ({type(error).__name__}: {error})") from None
        unknown = set(contents) - set(_ARRAY_FIELDS) - {"meta"}
        if unknown:
            raise ValueError(f"{path} has unknown fields {sorted(unknown)}")
        try:
            meta = json.loads(str(contents.pop("meta"))) if "meta" in contents else {}
        except json.JSONDecodeError as error:
            raise ValueError(f"{path}: its meta is not valid JSON ({error})") from None
        if not isinstance(meta, dict):
            raise ValueError(f"{path}: its meta must be a JSON object, got {type(meta).__name__}")
        try:
            return cls(meta=meta, **contents)
        except ValueError as error:
            raise ValueError(f"{path}: {error}") from None

    @classmethod
    def from_csv(cls, odometry=None, signatures=None, labels=None, meta=None) -> "Dataset":
        """Import a robot log from plain text.

        ``odometry``: a CSV with one row ``dx,dy,dtheta`` per step (N-1 rows);
        ``signatures``: a CSV with one row of K numbers per detection (N rows);
        ``labels``: optional CSV with one integer per line. A first line of
        names only is a header and skipped (a byte-order mark is ignored); any
        other cell that is not a number is a ``ValueError`` naming file, line
        and cell.
        """
        if odometry is None and signatures is None:
            raise ValueError("from_csv needs an odometry file, a signatures file, or both")
        odometry_rows = _read_csv("odometry", odometry, width=3) if odometry is not None else None
        signature_rows = _read_csv("signatures", signatures) if signatures is not None else None
        label_rows = None
        if labels is not None:
            label_rows = _read_csv("labels", labels, width=1)[:, 0]
        return cls(odometry=odometry_rows, signatures=signature_rows, labels=label_rows, meta=meta or {})

    def __repr__(self) -> str:
        present = [name for name in _ARRAY_FIELDS if getattr(self, name) is not None]
        return f"Dataset(n={self.n}, fields={present})"


def atomic_write(path, write) -> None:
    """Call ``write(handle)`` on a temporary file beside ``path``, then rename it into place.

    A crash or an exception leaves the previous file (or none) untouched.
    """
    path = Path(path)
    folder = path.parent if str(path.parent) else Path(".")
    if not folder.is_dir():
        raise ValueError(f"cannot write {path}: folder {folder} does not exist")
    descriptor, temporary = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=folder)
    try:
        with os.fdopen(descriptor, "wb") as handle:
            write(handle)
            handle.flush()
            os.fsync(handle.fileno())
        os.chmod(temporary, 0o666 & ~_current_umask())  # mkstemp creates 0600; give the usual mode
        os.replace(temporary, path)
    except BaseException:
        Path(temporary).unlink(missing_ok=True)
        raise


def _current_umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def _validated_labels(labels, n: int) -> np.ndarray:
    array = np.asarray(labels)
    if array.ndim != 1 or array.shape[0] != n:
        raise ValueError(f"labels must have shape ({n},), got {array.shape}")
    if array.dtype.kind == "f":
        if not np.all(np.isfinite(array)) or not np.all(array == np.round(array)):
            raise ValueError("labels must be integers")
    elif array.dtype.kind not in "iu":
        raise ValueError(f"labels must be integers, got dtype {array.dtype}")
    # checked before the cast: 1e20 and 2e20 would both become -2**63, one place
    if array.size and (np.any(array < -_INT64_LIMIT) or np.any(array >= _INT64_LIMIT)):
        worst = array.flat[int(np.argmax(np.abs(array.astype(float))))]
        raise ValueError(f"labels must fit in 64-bit integers (|label| < 2**63), got {worst!r}")
    return array.astype(np.int64)


_INT64_LIMIT = 2.0 ** 63


def _validated_covariances(covariances, n: int) -> np.ndarray:
    array = finite_array("odometry_cov", covariances, ndim=3)
    if array.shape != (n - 1, 3, 3):
        raise ValueError(f"odometry_cov must have shape ({n - 1}, 3, 3), got {array.shape}")
    if not np.allclose(array, np.swapaxes(array, 1, 2), rtol=1e-9, atol=1e-12):
        step = int(np.argmax(np.abs(array - np.swapaxes(array, 1, 2)).max(axis=(1, 2))))
        raise ValueError(f"odometry_cov[{step}] is not symmetric")
    if len(array):
        eigenvalues = np.linalg.eigvalsh(array)
        bad = np.flatnonzero(eigenvalues.min(axis=1) <= 0.0)
        if bad.size:
            raise ValueError(
                f"odometry_cov[{int(bad[0])}] is not positive definite "
                f"(smallest eigenvalue {eigenvalues[bad[0]].min():.3g})"
            )
    return array


def _number(cell: str) -> float | None:
    try:
        return float(cell)
    except ValueError:
        return None


def _read_csv(name: str, source, width: int | None = None) -> np.ndarray:
    path = Path(source)
    if not path.is_file():
        raise ValueError(f"{name}: no file at {path}")
    try:
        text_lines = path.read_text(encoding="utf-8-sig").splitlines()  # -sig: a spreadsheet's byte-order mark
    except UnicodeDecodeError as error:
        raise ValueError(f"{name}: {path} is not UTF-8 text ({error.reason} at byte {error.start})") from None
    rows = []
    for line_number, line in enumerate(text_lines, start=1):
        text = line.strip()
        if not text or text.startswith("#"):
            continue
        cells = [cell.strip() for cell in text.split(",")]
        numbers = [_number(cell) for cell in cells]
        if any(number is None for number in numbers):
            if not rows and line_number == 1 and all(number is None for number in numbers):
                continue  # a header line: names only (a row with a typo such as 3O is not one)
            bad = next(cell for cell, number in zip(cells, numbers) if number is None)
            raise ValueError(f"{name}: {path}:{line_number}: not a row of numbers: {bad!r} is not a number, in {text!r}")
        rows.append(numbers)
        if width is not None and len(cells) != width:
            raise ValueError(f"{name}: {path}:{line_number}: expected {width} columns, got {len(cells)}")
        if len(rows[-1]) != len(rows[0]):
            raise ValueError(f"{name}: {path}:{line_number}: {len(rows[-1])} columns, earlier rows have {len(rows[0])}")
    if not rows:
        raise ValueError(f"{name}: {path} holds no rows")
    return np.array(rows, dtype=float)
