"""Stitch the eight mast views into one 360-degree cylindrical panorama (docs/model.md §5, §4).

Each pinhole view (focal length f pixels, principal point at the image
centre) is warped onto a cylinder of radius f with OpenCV's ``remap``: the
cylinder column at angle phi and height h comes from image point
``(cx + f tan(phi), cy + h / cos(phi))``. Each camera contributes the central
45 degrees of its slightly wider view, and the strips are joined in order of
decreasing bearing (cam_0, cam_7, ..., cam_1), so panorama column c sees
bearing ``pi/8 - 2 pi (c + 0.5) / W`` in the robot frame and turning the robot
shifts the panorama circularly, which is what makes the Fourier signature
rotation-invariant.

    >>> import numpy as np
    >>> rig = RigConfig()
    >>> views = [np.full((rig.image_height, rig.image_width, 3), 30 * k, np.uint8) for k in range(CAMERA_COUNT)]
    >>> panorama = CylindricalStitcher(rig).stitch(views)      # (H, 8 * strip_width, 3) uint8
    >>> panorama.shape[0] == rig.image_height, panorama.dtype == np.uint8
    (True, True)
"""

from __future__ import annotations

import math

import cv2
import numpy as np

from ptm_bench.simulation.robot import CAMERA_COUNT, RigConfig

__all__ = ["CylindricalStitcher", "add_pixel_noise"]


class CylindricalStitcher:
    """Precomputed cylindrical remap for one rig; ``stitch`` joins eight views into a panorama."""

    def __init__(self, rig: RigConfig):
        self.rig = rig
        focal = rig.focal_px
        sector = 2 * math.pi / CAMERA_COUNT
        self.strip_width = int(round(focal * sector))
        self.height = rig.image_height
        columns = np.arange(self.strip_width) + 0.5
        angles = (columns - self.strip_width / 2) * sector / self.strip_width
        rows = np.arange(self.height) + 0.5 - self.height / 2
        cx, cy = rig.image_width / 2 - 0.5, rig.image_height / 2 - 0.5
        self.map_x = np.broadcast_to(cx + focal * np.tan(angles), (self.height, self.strip_width)).astype(np.float32)
        self.map_y = (cy + rows[:, None] / np.cos(angles)[None, :]).astype(np.float32)

    @property
    def width(self) -> int:
        """Panorama width in pixels (eight strips)."""
        return CAMERA_COUNT * self.strip_width

    def stitch(self, views) -> np.ndarray:
        """The (H, W, 3) uint8 panorama from the eight views ``cam_0``..``cam_7``."""
        if len(views) != CAMERA_COUNT:
            raise ValueError(f"views: expected {CAMERA_COUNT} camera images, got {len(views)}")
        expected = (self.rig.image_height, self.rig.image_width, 3)
        order = [0] + list(range(CAMERA_COUNT - 1, 0, -1))
        strips = []
        for index in order:
            view = np.asarray(views[index])
            if view.shape != expected or view.dtype != np.uint8:
                raise ValueError(f"views[{index}]: expected a uint8 image of shape {expected}, got {view.dtype} {view.shape}")
            strips.append(cv2.remap(view, self.map_x, self.map_y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE))
        return np.concatenate(strips, axis=1)


def add_pixel_noise(image: np.ndarray, sigma: float, rng: np.random.Generator) -> np.ndarray:
    """Add Gaussian pixel noise of standard deviation ``sigma`` (grey levels) and round back to uint8."""
    if sigma < 0:
        raise ValueError(f"pixel noise sigma must be >= 0, got {sigma}")
    if sigma == 0:
        return image
    noisy = image.astype(np.float32) + rng.normal(0.0, sigma, size=image.shape).astype(np.float32)
    return np.clip(np.rint(noisy), 0, 255).astype(np.uint8)
