"""Generate a ground-truth dataset end to end: floor -> MuJoCo run -> detections -> ``ptm.Dataset`` (docs/model.md §5, §2.2).

The floor's places get ``palette_count(P, aliasing)`` distinct palettes; the
scene is compiled to MJCF; the base drives the route under ``mj_step``; the
detector fires at closest approaches; the odometry motion model turns the
true per-step motion into noisy odometry rows with propagated covariances;
at each detection the eight mast cameras are rendered (with per-visit
lighting gain and pixel noise), stitched into a panorama, and reduced to a
Fourier signature with ``ptm.features.fourier_signature``.

Randomness: ``np.random.SeedSequence(seed)`` is spawned into four independent
streams -- world appearance (palettes), odometry noise, appearance variation
(path jitter, lighting, pixel noise) and the detector -- so changing the noise
level changes neither the route nor the palettes. The controller steers on
the true pose, so the route does not depend on the odometry noise either.

A run whose work -- the route's length over the distance one control period
covers (``ptm_bench.simulation.robot.control_steps``) -- exceeds
``MAX_CONTROL_STEPS`` is refused before anything is built or simulated.

    >>> dataset = generate_dataset("short_loop", aliasing=0.0, noise=1.0, seed=0, images=False)
    >>> dataset.n, dataset.meta["n_palettes"], dataset.signatures.shape
    (9, 4, (9, 5))
"""

from __future__ import annotations

import math
import sys
import time

import numpy as np
from tqdm import tqdm

import ptm
from ptm.se2 import relative_pose, wrap_angle
from ptm.features import fourier_signature

from ptm_bench.simulation.aliasing import signature_auc
from ptm_bench.simulation.code_version import generator_version
from ptm_bench.simulation.detector import detect
from ptm_bench.world.floorplan import Floorplan, assign_palettes, load_world, palette_count, palette_library
from ptm_bench.simulation.odometry_noise import OdometryNoise, detection_odometry, sample_odometry
from ptm_bench.simulation.panorama import CylindricalStitcher, add_pixel_noise
from ptm_bench.simulation.robot import (MAX_CONTROL_STEPS, ControllerConfig, Rig, RigConfig, control_steps, drive,
                                        place_base)
from ptm_bench.simulation.scene import build_mjcf, compile_scene, place_sites

import mujoco  # noqa: E402  (robot has set MUJOCO_GL)

__all__ = ["build_world", "generate_dataset", "true_odometry"]


def generate_dataset(
    world,
    aliasing: float,
    noise: float,
    seed: int,
    images: bool = True,
    progress: bool = False,
    *,
    route: str = "main",
    rig: RigConfig = RigConfig(),
    controller: ControllerConfig = ControllerConfig(),
    odometry: OdometryNoise = OdometryNoise(),
    miss_rate: float = 0.0,
    false_rate: float = 0.0,
    pixel_noise: float = 2.0,
    lighting_variation: float = 0.05,
    signature_k: int = 5,
    cell_size: float = 0.25,
) -> ptm.Dataset:
    """Simulate one run and return its dataset.

    Parameters
    ----------
    world : str, path or Floorplan
        A preset name (``ptm-bench worlds``), a floor TOML file, or a Floorplan.
    aliasing : float in [0, 1]
        0: every place has its own palette; 1: all places share one.
    noise : float >= 0
        The odometry noise level S (0 gives odometry equal to the truth).
    seed : int >= 0
        Root seed; the same seed gives byte-identical arrays.
    images : bool
        Keep the panoramas in the dataset. The cameras are rendered either way,
        because the signatures are computed from them.
    progress : bool
        Show tqdm progress bars on stderr.
    miss_rate, false_rate : float
        Detector miss probability per visit and false detections per metre.
    pixel_noise : float
        Standard deviation of Gaussian pixel noise, in grey levels.
    lighting_variation : float in [0, 1)
        Each visit's lights are scaled by a gain uniform in [1 - v, 1 + v].
    """
    floor = load_world(world)
    palette_count(len(floor.places), aliasing)  # validates aliasing
    odometry = odometry.scaled(noise)  # validates noise
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise ValueError(f"seed must be a non-negative integer, got {seed!r}")
    if not 0.0 <= lighting_variation < 1.0:
        raise ValueError(f"lighting_variation must be in [0, 1), got {lighting_variation!r}")
    steps = control_steps(floor.route_length(route), floor.speed, controller)
    if steps > MAX_CONTROL_STEPS:
        raise ValueError(f"world: driving {floor.name} ({floor.source}), route {route!r} of "
                         f"{floor.route_length(route):.4g} m at {floor.speed:g} m/s, takes about {steps:.3g} control "
                         f"steps of {controller.control_period:g} s, more than MAX_CONTROL_STEPS = {MAX_CONTROL_STEPS} "
                         "(ptm_bench.simulation.robot): raise the world's speed or shorten its route")
    started = time.perf_counter()
    world_stream, odometry_stream, appearance_stream, detector_stream = (
        np.random.default_rng(child) for child in np.random.SeedSequence(int(seed)).spawn(4)
    )

    model, palette_of_place, palettes = build_world(floor, aliasing, world_stream, rig, cell_size)
    places = place_sites(model)  # ground truth comes from the element names

    waypoints = _jittered_waypoints(floor, route, appearance_stream)
    data = mujoco.MjData(model)
    first_leg = waypoints[1] - waypoints[0]
    place_base(model, data, (*waypoints[0], math.atan2(first_leg[1], first_leg[0])))
    with tqdm(total=100, desc=f"driving {floor.name}", unit="%", disable=not progress, leave=False) as bar:
        def report(fraction):
            bar.update(int(100 * fraction) - bar.n)

        trajectory = drive(model, data, waypoints, floor.speed, controller, progress=report)

    try:
        detections = detect(trajectory.poses, places, floor.detection_radius, detector_stream, miss_rate, false_rate)
    except ValueError as error:
        raise ValueError(f"world {floor.name} ({floor.source}): {error}") from None
    if not detections:
        raise ValueError(f"world: the route of {floor.name} passes no place; no detections")
    steps = np.array([detection.step for detection in detections])
    odometry_steps = sample_odometry(trajectory.poses, odometry, odometry_stream)
    odometry_rows, odometry_cov = detection_odometry(odometry_steps, steps)

    rig_renderer = Rig(model, rig)
    stitcher = CylindricalStitcher(rig)
    panoramas, signatures = [], []
    try:
        for detection in tqdm(detections, desc="rendering panoramas", disable=not progress, leave=False):
            gain = 1.0 + lighting_variation * appearance_stream.uniform(-1.0, 1.0)
            panorama = stitcher.stitch(rig_renderer.views(trajectory.qpos[detection.step], light_gain=gain))
            panorama = add_pixel_noise(panorama, pixel_noise, appearance_stream)
            signatures.append(fourier_signature(panorama, k=signature_k))
            if images:
                panoramas.append(panorama)
    finally:
        rig_renderer.close()

    labels = np.array([detection.place_id for detection in detections])
    true_poses = trajectory.poses[steps].copy()
    true_poses[:, 2] = wrap_angle(true_poses[:, 2])
    meta = {
        "world": floor.name,
        "world_source": floor.source,
        "route": route,
        "route_length": floor.route_length(route),
        "aliasing": float(aliasing),
        "aliasing_auc": signature_auc(signatures, labels),
        "noise": float(noise),
        "seed": int(seed),
        "generator_version": generator_version(),  # the simulator's code (ptm_bench.simulation.code_version)
        "min_place_spacing": floor.min_place_spacing,
        "detection_radius": floor.detection_radius,
        "places": {str(place_id): list(xy) for place_id, xy in sorted(places.items())},
        "n_palettes": len(palettes),
        "palette_of_place": {str(place_id): index for place_id, index in sorted(palette_of_place.items())},
        "camera": rig.as_meta(),
        "panorama": {"height": stitcher.height, "width": stitcher.width},
        "signature_k": signature_k,
        "controller": {"control_period": controller.control_period, "timestep": controller.timestep,
                       "lookahead": controller.lookahead, "speed": floor.speed},
        "odometry_model": {**odometry.as_meta(), "scale_error": odometry_steps.scale_error,
                           "heading_drift": odometry_steps.heading_drift},
        "detector": {"miss_rate": miss_rate, "false_rate": false_rate,
                     "false_detections": [i for i, d in enumerate(detections) if d.place_id < 0]},
        "appearance": {"pixel_noise": pixel_noise, "lighting_variation": lighting_variation,
                       "lateral_jitter": floor.lateral_jitter},
        "control_steps": int(len(trajectory.times) - 1),
        "detection_steps": steps.tolist(),
        "images": bool(images),
    }
    dataset = ptm.Dataset(
        odometry=odometry_rows if len(detections) > 1 else None,
        odometry_cov=odometry_cov if len(detections) > 1 else None,
        signatures=np.array(signatures),
        labels=labels,
        true_poses=true_poses,
        panoramas=np.array(panoramas) if images else None,
        meta=meta,
    )
    if progress:
        print(f"generated {floor.name} in {time.perf_counter() - started:.1f} s", file=sys.stderr)
    return dataset


def build_world(floor: Floorplan, aliasing: float, rng: np.random.Generator, rig: RigConfig = RigConfig(),
                cell_size: float = 0.25):
    """The compiled MuJoCo model of ``floor`` at an aliasing level: (model, palette_of_place, palettes)."""
    palette_of_place = assign_palettes(floor, aliasing, rng)
    palettes = palette_library(max(palette_of_place.values()) + 1, rng, floor.palettes)
    model = compile_scene(build_mjcf(floor, {p: palettes[i] for p, i in palette_of_place.items()}, rig, cell_size))
    return model, palette_of_place, palettes


def _jittered_waypoints(floor: Floorplan, route: str, rng: np.random.Generator) -> np.ndarray:
    """Route waypoints each moved by a random offset, uniform in a disc of radius ``lateral_jitter``."""
    points = floor.route_points(route)
    radius = floor.lateral_jitter * np.sqrt(rng.random(len(points)))
    angle = rng.uniform(0.0, 2 * math.pi, len(points))
    return points + np.column_stack([radius * np.cos(angle), radius * np.sin(angle)])


def true_odometry(dataset: ptm.Dataset) -> np.ndarray:
    """The noise-free odometry rows implied by a dataset's true poses (for checks and plots)."""
    return relative_pose(dataset.true_poses[:-1], dataset.true_poses[1:])
