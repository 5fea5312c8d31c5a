"""``ptm-bench import-carmen``: turn a CARMEN log into a dataset file with ground truth from its reference.

The log's first metres are a calibration drive that measures the robot's
systematic odometry errors and noise level (not scored); places are chosen on
the rest of its reference trajectory, detections fire at the closest approach
within the detection radius, odometry rows are the raw odometry between
detections with the systematic errors the drive tells from zero taken out, and
covariances from a noise model fitted on other logs, widened where the drive
is noisier (ptm_bench.logs.detections). It prints the fitted noise and the
logs it was fitted on, what the drive measured and took out, and the rows'
normalised error against the reference. A shipped log is named by its name.

    $ ptm-bench import-carmen intel --out intel.npz
    $ ptm-bench import-carmen my-robot.log.gz --out mine.npz --place-spacing 4 --detection-radius 1
"""

from __future__ import annotations

import time
from pathlib import Path

from ptm_bench.cli.options import dataset_output
from ptm_bench.logs.carmen import SHIPPED_LOGS
from ptm_bench.logs.detections import (DEFAULT_CALIBRATION_DRIVE, DEFAULT_DETECTION_RADIUS, DEFAULT_PLACE_SPACING,
                                       import_carmen)
from ptm_bench.logs.noise_fit import SIGNIFICANT
from ptm_bench.logs.row_error import row_normalised_error


def register(subparsers) -> None:
    parser = subparsers.add_parser(
        "import-carmen",
        help="turn a CARMEN log into a dataset file (places and labels from its reference trajectory)",
        description="Read a CARMEN log (plain or GMapping-corrected, optionally .gz), choose places on its reference "
                    "trajectory, detect them at closest approach and write a ptm.Dataset .npz file (atomically).",
    )
    parser.add_argument("log", help=f"a log file, or a shipped log's name ({', '.join(SHIPPED_LOGS)})")
    parser.add_argument("--out", required=True, type=Path, help="output .npz path")
    parser.add_argument("--place-spacing", type=float, default=DEFAULT_PLACE_SPACING,
                        help=f"places are more than this far apart [m] (default {DEFAULT_PLACE_SPACING:g})")
    parser.add_argument("--detection-radius", type=float, default=DEFAULT_DETECTION_RADIUS,
                        help=f"a visit is a run of scans within this radius of a place [m] "
                             f"(default {DEFAULT_DETECTION_RADIUS:g}; at most half the spacing)")
    parser.add_argument("--calibration-drive", type=float, default=DEFAULT_CALIBRATION_DRIVE, metavar="M",
                        help=f"the log's first M metres calibrate the robot's odometry (scale, drift) and are not "
                             f"scored; 0: none (default {DEFAULT_CALIBRATION_DRIVE:g})")
    parser.add_argument("--noise-from", nargs="+", metavar="LOG",
                        help="logs to fit the odometry noise on (default: the shipped logs other than this one)")
    parser.set_defaults(handler=_run_import)


def _run_import(args) -> int:
    out = dataset_output(args.out)
    started = time.perf_counter()
    dataset = import_carmen(args.log, place_spacing=args.place_spacing, detection_radius=args.detection_radius,
                            calibration=args.noise_from, calibration_drive=args.calibration_drive)
    try:
        dataset.save(out)
    except OSError as error:
        raise ValueError(f"out: cannot write {out}: {error}") from None
    meta = dataset.meta
    places = len(set(dataset.labels.tolist()))
    print(f"wrote {out}: {meta['world']} ({meta['n_scans']} scans), N = {dataset.n} detections of {places} places, "
          f"{dataset.n - places} revisits, path {meta['path_length']:.0f} m, spacing {meta['place_spacing']:g} m, "
          f"radius {meta['detection_radius']:g} m, laser aliasing AUC {meta['aliasing_auc']:.2f}, "
          f"{time.perf_counter() - started:.1f} s")
    noise = meta["odometry_noise"]
    systematic = (f"a {noise['calibration_drive']:g} m drive misses the rest of its run by"
                  if noise["calibration_drive"] else "the robots' own spread:")
    print(f"odometry noise fitted on {', '.join(noise['fitted_on'])} over {noise['window']:g} m windows: "
          f"alpha1 {noise['alpha1']:.4f} rad/rad, alpha2 {noise['alpha2']:.4f} rad/m, "
          f"alpha3 {noise['alpha3']:.4f} m/m, alpha4 {noise['alpha4']:.4f} m/rad, "
          f"floors {noise['floor_xy']:.4f} m and {noise['floor_theta']:.4f} rad; "
          f"{systematic} scale {noise['scale_sigma']:.4f}, heading drift {noise['drift_sigma']:.4f} rad/m")
    drive = meta["calibration_drive"]
    if drive is not None:
        taken = {True: "taken out", False: f"left in, within {SIGNIFICANT:g} sigma of 0"}
        print(f"calibration drive: the first {drive['metres']:g} m ({drive['scans']} scans, not scored): scale error "
              f"{drive['scale_error']:+.4f} ({taken[drive['scale_applied'] != 0.0]}), heading drift "
              f"{drive['heading_drift']:+.4f} rad/m ({taken[drive['drift_applied'] != 0.0]}); the rows' "
              f"covariances x {drive['noise_level']:.2f}, the drive's noise level against the fit (at least 1)")
    print(f"odometry rows against the reference: mean normalised error {row_normalised_error(dataset):.2f} "
          "(r^T Sigma^-1 r / 3; 1 where the covariances are right)")
    return 0
