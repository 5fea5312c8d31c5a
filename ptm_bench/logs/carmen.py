"""CARMEN log reader: laser scans with timestamps, raw odometry increments and a reference trajectory.

A CARMEN log is one message per line, whitespace-separated; ``#`` starts a
comment and ``PARAM name value ...`` lines are settings. The reader uses

* ``ODOM x y theta tv rv accel t host t_logger`` -- the odometry pose;
* ``FLASER n r_1 ... r_n x y theta odom_x odom_y odom_theta t host t_logger``
  -- a front laser scan of n ranges [m] taken at pose (x, y, theta);
* ``TRUEPOS x y theta odom_x odom_y odom_theta t host t_logger`` -- a
  reference pose (simulators, ground truth systems);

and skips every other message (``NEFF``, ``SYNC``, ``RLASER``, ...). Each
scan is one time step k of the result.

**Raw odometry** (two forms, detected per scan). In a *plain* log the ODOM
poses are one continuous odometry frame, so scan k's raw increment is
u_k = P_{k-1}^-1 o P_k with P_k the last ODOM pose before scan k. In the
*corrected* form GMapping writes, the ODOM lines between two scans are the
raw odometry integrated from the previous scan's *corrected* pose X_{k-1},
which GMapping re-states in an ODOM line right after each scan; the raw
increment is then u_k = X_{k-1}^-1 o P_k. The reader recognises that
re-anchoring line as the first ODOM line after a FLASER line that repeats the
scan's pose exactly, and uses the anchor it names. (The FLASER line's own
odometry fields repeat X_k in that form: they are not raw odometry.)

**Reference trajectory.** In the corrected form, the scan poses X_k
(GMapping's estimate); otherwise the last TRUEPOS pose at or before each
scan, if the log has TRUEPOS lines; otherwise none.

**Timestamps** are the scans' ``t`` fields. Scan timestamps must increase;
a step back of at most ``time_tolerance`` seconds (the Intel log's logger
steps back four times, by up to 0.86 s) is tolerated and counted in
``CarmenLog.time_reversals``; a larger one is an error naming its line.
Malformed input (a truncated line, a non-number, a log without scans or
without odometry) raises ``ValueError`` naming the file and line.

    >>> log = read_carmen(shipped_log("intel"))          # or a path: read_carmen("my-robot.log.gz")
    >>> log.n_scans, log.form, log.raw_increments.shape, log.reference.shape
    (910, 'corrected', (909, 3), (910, 3))
    >>> log.odometry_poses().shape                        # dead reckoning of the raw increments
    (910, 3)
"""

from __future__ import annotations

import gzip
import math
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from ptm.se2 import dead_reckoning, relative_pose

__all__ = ["CarmenLog", "DATA_DIR", "SHIPPED_LOGS", "read_carmen", "shipped_log"]

#: The logs shipped with the harness (ptm_bench/logs/data, see its README for provenance).
DATA_DIR = Path(__file__).resolve().parent / "data"
SHIPPED_LOGS = ("intel", "aces", "fhw", "acapulco")

_ODOM_FIELDS = 8  # ODOM x y theta tv rv accel t (host and logger time are optional for the reader)
_TRUEPOS_FIELDS = 8  # TRUEPOS x y theta odom_x odom_y odom_theta t


@dataclass(frozen=True)
class CarmenLog:
    """The scans of one CARMEN log, in file order; arrays are indexed by scan k = 0 ... n_scans-1."""

    source: str
    form: str  # "corrected" (GMapping re-anchors the odometry at every scan) or "plain"
    timestamps: np.ndarray  # (n,) seconds, the scans' t fields
    ranges: tuple  # n arrays of laser ranges [m] (a log may change its beam count)
    scan_poses: np.ndarray  # (n, 3) the FLASER line's pose (x, y, theta)
    raw_increments: np.ndarray  # (n-1, 3) raw odometry u_k of scan k in the frame of scan k-1, row k-1
    reference: np.ndarray | None  # (n, 3) reference poses, or None when the log has none
    lines: np.ndarray  # (n,) 1-based line number of each scan's FLASER line
    params: dict = field(default_factory=dict)  # PARAM name -> value (a string)
    time_reversals: int = 0  # scans whose timestamp stepped back by at most time_tolerance

    @property
    def n_scans(self) -> int:
        return len(self.timestamps)

    def odometry_poses(self) -> np.ndarray:
        """(n, 3) poses from composing the raw increments from the first reference pose (the origin without one)."""
        start = self.reference[0] if self.reference is not None else (0.0, 0.0, 0.0)
        return dead_reckoning(self.raw_increments, start=start)

    def reference_increments(self) -> np.ndarray:
        """(n-1, 3) motion between consecutive scans according to the reference, in the earlier scan's frame."""
        if self.reference is None:
            raise ValueError(f"{self.source}: the log has no reference trajectory (no corrected poses, no TRUEPOS)")
        return relative_pose(self.reference[:-1], self.reference[1:])

    def path_length(self) -> float:
        """Length [m] of the reference trajectory (of the dead-reckoned one without a reference)."""
        return float(self._distances().sum())

    def scan_at_path_length(self, metres: float) -> int:
        """The first scan at least ``metres`` along the path (:meth:`path_length`'s trajectory) from the first;
        ``ValueError`` when the whole log is shorter."""
        travelled = np.cumsum(self._distances())
        if not travelled.size or travelled[-1] < metres:
            raise ValueError(f"{self.source}: the log's path is {self.path_length():.1f} m long, shorter than "
                             f"{metres:g} m")
        return int(np.searchsorted(travelled, metres)) + 1

    def segment(self, start: int, stop: int) -> "CarmenLog":
        """Scans ``start .. stop - 1`` as a log of their own (the increments between them; ``params`` and
        ``time_reversals`` those of the whole log)."""
        if not 0 <= start < stop <= self.n_scans:
            raise ValueError(f"a segment of {self.n_scans} scans is 0 <= start < stop <= {self.n_scans}, "
                             f"got {start}, {stop}")
        return replace(self, timestamps=self.timestamps[start:stop], ranges=self.ranges[start:stop],
                       scan_poses=self.scan_poses[start:stop], raw_increments=self.raw_increments[start:stop - 1],
                       reference=None if self.reference is None else self.reference[start:stop],
                       lines=self.lines[start:stop])

    def _distances(self) -> np.ndarray:
        poses = self.reference if self.reference is not None else self.odometry_poses()
        return np.linalg.norm(np.diff(poses[:, :2], axis=0), axis=1)


def shipped_log(name: str) -> Path:
    """The path of a shipped log by name (``intel``, ``aces``, ``fhw``, ``acapulco``)."""
    if name not in SHIPPED_LOGS:
        raise ValueError(f"unknown log {name!r}; shipped logs: {', '.join(SHIPPED_LOGS)}")
    return DATA_DIR / f"{name}-corrected.log.gz"


def resolve_log(name_or_path) -> Path:
    """A shipped log's name or a path to a log file (``ValueError`` when it is neither)."""
    if str(name_or_path) in SHIPPED_LOGS:
        return shipped_log(str(name_or_path))
    path = Path(name_or_path)
    if not path.is_file():
        raise FileNotFoundError(f"no CARMEN log at {path} (shipped logs by name: {', '.join(SHIPPED_LOGS)})")
    return path


def _text_lines(path: Path) -> list[str]:
    try:
        if path.suffix == ".gz":
            with gzip.open(path, "rt", encoding="ascii", errors="replace") as handle:
                return handle.read().splitlines()
        return path.read_text(encoding="ascii", errors="replace").splitlines()
    except EOFError:
        raise ValueError(f"{path}: the gzip stream ends early: truncated log") from None
    except gzip.BadGzipFile as error:
        raise ValueError(f"{path}: not a gzip file: {error}") from None


def _numbers(fields: list[str], count: int, where: str, what: str) -> list[float]:
    if len(fields) < count:
        raise ValueError(f"{where}: {what} needs {count} fields, found {len(fields)} (truncated line?)")
    try:
        values = [float(value) for value in fields[:count]]
    except ValueError:
        raise ValueError(f"{where}: {what} has a field that is not a number: {' '.join(fields[:count])!r}") from None
    if not all(math.isfinite(value) for value in values):
        raise ValueError(f"{where}: {what} has a non-finite number: {' '.join(fields[:count])!r}")
    return values


def read_carmen(path, time_tolerance: float = 1.0) -> CarmenLog:
    """Read a CARMEN log (plain text or ``.gz``); see the module docstring for the rules."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"no CARMEN log at {path}")
    timestamps, ranges, scan_poses, lines, last_odometry, anchors, truepos_at_scan = [], [], [], [], [], [], []
    params: dict[str, str] = {}
    odometry = None  # last ODOM pose
    truepos = None  # last TRUEPOS pose
    scan_pending = False  # the first ODOM line after a scan may re-anchor the odometry at the scan's pose
    anchor = None  # the pose the current stretch of ODOM poses is integrated from (corrected form)
    reversals = 0
    for number, line in enumerate(_text_lines(path), start=1):
        fields = line.split()
        if not fields or fields[0].startswith("#"):
            continue
        where, kind, values = f"{path}:{number}", fields[0], fields[1:]
        if kind == "PARAM":
            if len(values) < 2:
                raise ValueError(f"{where}: PARAM needs a name and a value (truncated line?)")
            params[values[0]] = values[1]
        elif kind == "ODOM":
            pose = _numbers(values, _ODOM_FIELDS - 1, where, "ODOM")[:3]
            if scan_pending and pose == list(scan_poses[-1]):
                anchor = pose  # GMapping re-states the corrected pose: the next raw stretch starts here
            scan_pending = False
            odometry = pose
        elif kind == "TRUEPOS":
            truepos = _numbers(values, _TRUEPOS_FIELDS - 1, where, "TRUEPOS")[:3]
        elif kind == "FLASER":
            count = _numbers(values, 1, where, "FLASER")[0]
            if count != int(count) or count < 0:
                raise ValueError(f"{where}: FLASER beam count must be a non-negative integer, got {values[0]!r}")
            count = int(count)
            numbers = _numbers(values[1:], count + 7, where, f"FLASER with {count} ranges")
            if odometry is None:
                raise ValueError(f"{where}: FLASER before any ODOM line: the log holds no odometry for this scan")
            stamp = numbers[count + 6]
            if timestamps and stamp < timestamps[-1]:
                if timestamps[-1] - stamp > time_tolerance:
                    raise ValueError(f"{where}: scan timestamp {stamp:g} s is earlier than the previous scan's "
                                     f"{timestamps[-1]:g} s (non-monotonic timestamps; tolerance {time_tolerance:g} s)")
                reversals += 1
            timestamps.append(stamp)
            ranges.append(np.array(numbers[:count]))
            scan_poses.append(numbers[count:count + 3])
            lines.append(number)
            last_odometry.append(odometry)
            anchors.append(anchor)
            truepos_at_scan.append(truepos)
            anchor = None
            scan_pending = True
    if not timestamps:
        raise ValueError(f"{path}: no FLASER lines: the log holds no laser scans")
    if len(timestamps) < 2:
        raise ValueError(f"{path}: one laser scan only; a log needs at least two")
    scan_poses = np.array(scan_poses, dtype=float)
    odometry_at_scan = np.array(last_odometry, dtype=float)
    # Scan k's raw stretch starts at the anchor GMapping wrote after scan k-1, else at scan k-1's odometry pose.
    starts = np.array([anchors[k] if anchors[k] is not None else odometry_at_scan[k - 1]
                       for k in range(1, len(timestamps))], dtype=float)
    raw_increments = relative_pose(starts, odometry_at_scan[1:])
    corrected = sum(anchor is not None for anchor in anchors[1:]) >= (len(timestamps) - 1) / 2
    if corrected:
        reference = scan_poses.copy()
    elif all(pose is not None for pose in truepos_at_scan):
        reference = np.array(truepos_at_scan, dtype=float)
    else:
        reference = None
    return CarmenLog(source=str(path), form="corrected" if corrected else "plain",
                     timestamps=np.array(timestamps), ranges=tuple(ranges), scan_poses=scan_poses,
                     raw_increments=raw_increments, reference=reference, lines=np.array(lines), params=params,
                     time_reversals=reversals)
