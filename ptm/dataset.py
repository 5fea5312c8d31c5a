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

import decimal
import json
import math
import numbers
import os
import re
import tempfile
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ._npz import read_npz
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
        contents = read_npz(path, "dataset")
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
        ``labels``: optional CSV with one integer per line, read exactly (any
        integer in [-2**63, 2**63), also as ``1e6`` or ``3.0``). A first line
        of names (a letter first, then letters, digits, ``_``, ``-`` or spaces,
        an optional unit in brackets), one per column, is a header and skipped
        (a byte-order mark is ignored); any other cell that is not a finite
        real number (a label: a whole number in range) is a ``ValueError``
        naming file, line and cell.
        """
        if odometry is None and signatures is None:
            raise ValueError("from_csv needs an odometry file, a signatures file, or both")
        odometry_rows = np.array(_read_csv("odometry", odometry, _real, width=3)) if odometry is not None else None
        signature_rows = np.array(_read_csv("signatures", signatures, _real)) if signatures is not None else None
        label_rows = None
        if labels is not None:
            label_rows = np.array([row[0] for row in _read_csv("labels", labels, _label, width=1)], dtype=np.int64)
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
    if array.dtype.kind in "fO" and all(isinstance(label, numbers.Integral) and not isinstance(label, (bool, np.bool_))
                                        for label in labels):
        # Python integers past int64 turn numpy's array into floats or objects: check them as the integers they are
        array = np.array([_int64_label(int(label), f"labels[{index}] = {label!r}")
                          for index, label in enumerate(labels)])
    if array.dtype.kind == "f":
        if not np.all(np.isfinite(array)) or not np.all(array == np.round(array)):
            raise ValueError("labels must be integers")
        beyond = (array < _INT64.min) | (array >= 2.0 ** 63)  # checked before the cast: 1e20 would wrap round
    elif array.dtype.kind == "u":
        beyond = array > _INT64.max
    elif array.dtype.kind == "i":
        beyond = np.zeros(n, dtype=bool)
    else:
        raise ValueError(f"labels must be integers, got dtype {array.dtype}")
    if beyond.any():
        index = int(np.argmax(beyond))
        _int64_label(array[index].item(), f"labels[{index}] = {array[index].item()!r}")
    return array.astype(np.int64)


_INT64 = np.iinfo(np.int64)


def _int64_label(label, shown: str):
    """``label``, or a ``ValueError`` showing it as ``shown`` unless it fits in a 64-bit integer."""
    if not _INT64.min <= label <= _INT64.max:
        raise ValueError(f"{shown} does not fit in a 64-bit integer (-2**63 <= label < 2**63)")
    return label


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


_NAME = re.compile(r"[^\W\d][\w \-]*(\s*[(\[][^()\[\]]*[)\]])?")  # dx, d theta, dtheta (rad), s_0 [a.u.]


def _is_name(cell: str) -> bool:
    """Whether ``cell`` is a column name: not a number ("nan", "inf") and not a number with a typo ("O.5")."""
    try:
        float(cell)
    except ValueError:
        return _NAME.fullmatch(cell) is not None
    return False


def _real(cell: str) -> float:
    """The finite real number written in ``cell``, or a ``ValueError`` saying why not."""
    try:
        number = float(cell)
    except ValueError:
        try:
            complex(cell)
        except ValueError:
            raise ValueError(f"{cell!r} is not a number") from None
        raise ValueError(f"{cell!r} is a complex number; only real numbers are read (an FFT's abs(), say)") from None
    if not math.isfinite(number):
        raise ValueError(f"{cell!r} is not a finite number")
    return number


def _label(cell: str) -> int:
    """The integer written in ``cell``, read exactly (no float in between), or a ``ValueError`` saying why not."""
    try:
        number = decimal.Decimal(cell)
    except decimal.InvalidOperation:
        raise ValueError(f"{cell!r} is not a number") from None
    if not number.is_finite() or number != number.to_integral_value():
        raise ValueError(f"{cell!r} is not a whole number")
    return int(_int64_label(number, repr(cell)))


def _read_csv(name: str, source, read_cell, width: int | None = None) -> list[list]:
    """The rows of the CSV file ``source`` as lists of ``read_cell(cell)``; a ``ValueError`` names file and line."""
    path = Path(source)
    if not path.is_file():
        raise ValueError(f"{name}: no file at {path}")
    try:
        text_lines = path.read_text(encoding="utf-8-sig").splitlines()  # -sig: a spreadsheet's byte-order mark
    except UnicodeDecodeError as error:
        raise ValueError(f"{name}: {path} is not UTF-8 text ({error.reason} at byte {error.start})") from None
    header, rows = None, []
    for line_number, line in enumerate(text_lines, start=1):
        text = line.strip()
        if not text or text.startswith("#"):
            continue
        cells = [cell.strip() for cell in text.split(",")]
        if line_number == 1 and all(_is_name(cell) for cell in cells):
            header = cells  # names only (a row with a typo such as 3O or O.5 is not one)
            continue
        try:
            rows.append([read_cell(cell) for cell in cells])
        except ValueError as error:
            raise ValueError(f"{name}: {path}:{line_number}: not a row of numbers: {error}, in {text!r}") from None
        if width is not None and len(cells) != width:
            raise ValueError(f"{name}: {path}:{line_number}: expected {width} columns, got {len(cells)}")
        if len(rows[-1]) != len(rows[0]):
            raise ValueError(f"{name}: {path}:{line_number}: {len(rows[-1])} columns, earlier rows have {len(rows[0])}")
    if not rows:
        raise ValueError(f"{name}: {path} holds no rows")
    if header is not None and len(header) != len(rows[0]):
        raise ValueError(f"{name}: {path}:1: the header names {len(header)} columns, the rows have {len(rows[0])}")
    return rows
