"""Rendering: eight views stitched into a panorama; Fourier signatures are rotation-invariant on real renders.

Small images (24 x 32 per camera) keep these fast on a CPU with software EGL.
"""

import math
import os
import subprocess
import sys

import numpy as np
import pytest

from ptm.features import fourier_signature
from ptm_bench.world.floorplan import ROBOT_CLEARANCE, load_world
from ptm_bench.simulation.generate import build_world
from ptm_bench.simulation.panorama import CylindricalStitcher, add_pixel_noise
from ptm_bench.simulation.robot import Rig, RigConfig
from ptm_bench.simulation.scene import NEAR_PLANE

SMALL = RigConfig(image_height=24, image_width=32)


@pytest.fixture(scope="module")
def short_loop_rig():
    floor = load_world("short_loop")
    model, palette_of_place, _ = build_world(floor, 0.0, np.random.default_rng(0), SMALL)
    rig = Rig(model, SMALL)
    yield floor, rig, palette_of_place
    rig.close()


def _panorama(rig, x, y, heading):
    qpos = np.zeros(rig.model.nq)
    qpos[:3] = (x, y, heading)
    return CylindricalStitcher(SMALL).stitch(rig.views(qpos))


def test_panorama_has_eight_strips(short_loop_rig):
    _, rig, _ = short_loop_rig
    stitcher = CylindricalStitcher(SMALL)
    panorama = _panorama(rig, 0.1, 0.05, 0.0)
    assert panorama.shape == (SMALL.image_height, stitcher.width, 3) and panorama.dtype == np.uint8
    assert stitcher.width == 8 * round(SMALL.focal_px * math.pi / 4)
    assert panorama.std() > 5  # the walls, floor and markers give the cameras structure to see


def test_turning_by_45_degrees_shifts_the_panorama_by_one_strip(short_loop_rig):
    _, rig, _ = short_loop_rig
    stitcher = CylindricalStitcher(SMALL)
    before = _panorama(rig, 0.1, 0.05, 0.3).astype(int)
    after = _panorama(rig, 0.1, 0.05, 0.3 + math.pi / 4).astype(int)
    difference = np.abs(after - np.roll(before, stitcher.strip_width, axis=1))
    assert np.mean(difference <= 2) > 0.99


def test_signatures_are_rotation_invariant_and_separate_palettes(short_loop_rig):
    floor, rig, palette_of_place = short_loop_rig
    x, y = floor.places[0]
    same_spot = np.array([fourier_signature(_panorama(rig, x + 0.1, y + 0.05, h)) for h in (0.0, 0.7, 2.0, -2.5, 4.0)])
    others = [p for p in floor.places if palette_of_place[p] != palette_of_place[0]]
    assert others
    elsewhere = np.array([fourier_signature(_panorama(rig, *floor.places[p], 0.0)) for p in others])
    within = np.linalg.norm(same_spot[:, None] - same_spot[None], axis=2).max()
    between = np.linalg.norm(same_spot[:, None] - elsewhere[None], axis=2).min()
    assert within < 0.25 * between, (within, between)


def test_stitcher_rejects_wrong_views():
    stitcher = CylindricalStitcher(SMALL)
    with pytest.raises(ValueError, match="expected 8"):
        stitcher.stitch([np.zeros((24, 32, 3), np.uint8)] * 7)
    with pytest.raises(ValueError, match=r"views\[0\]"):
        stitcher.stitch([np.zeros((24, 30, 3), np.uint8)] * 8)


def test_pixel_noise_has_the_requested_spread():
    image = np.full((64, 640, 3), 128, np.uint8)
    noisy = add_pixel_noise(image, 3.0, np.random.default_rng(0)).astype(float)
    assert noisy.std() == pytest.approx(3.0, rel=0.03) and abs(noisy.mean() - 128) < 0.05


@pytest.mark.skipif(bool(os.environ.get("DISPLAY")), reason="with a display GLFW renders, and there is no error to explain")
def test_mujoco_imported_first_without_mujoco_gl_gets_a_clear_error():
    program = (
        "import mujoco\n"
        "from ptm_bench.world.floorplan import load_world\n"
        "from ptm_bench.simulation.generate import build_world\n"
        "from ptm_bench.simulation.robot import Rig, RigConfig\n"
        "import numpy as np\n"
        "model, _, _ = build_world(load_world('short_loop'), 0.0, np.random.default_rng(0))\n"
        "Rig(model, RigConfig())\n"
    )
    environment = {key: value for key, value in os.environ.items() if key != "MUJOCO_GL"}
    finished = subprocess.run([sys.executable, "-c", program], env=environment, capture_output=True, text=True,
                              timeout=120)
    assert finished.returncode != 0
    assert "set MUJOCO_GL=egl" in finished.stderr


def test_a_wall_beside_the_robot_is_rendered_not_clipped():
    """At the largest lateral offset a place allows (ROBOT_CLEARANCE from the wall), the camera facing the wall
    sees only wall: MuJoCo's default near plane (1 % of the extent, 0.72 m in office) rendered through it."""
    floor = load_world("office")
    model, _, _ = build_world(floor, 0.0, np.random.default_rng(0), SMALL)
    assert model.vis.map.znear * model.stat.extent == pytest.approx(NEAR_PLANE)
    model.mat_rgba[model.material("surroundings").id] = (1.0, 0.0, 0.0, 1.0)  # walls red, haze and clear colour grey
    model.vis.rgba.fog[:3] = (0.0, 0.0, 1.0)
    x, y = floor.nodes["S"]  # the middle of the south corridor: walls at y = +-1 m
    offset = 1.0 - ROBOT_CLEARANCE
    rig = Rig(model, SMALL)
    try:
        qpos = np.zeros(model.nq)
        qpos[:3] = (x + 2.0, y - offset, 0.0)  # heading east: cam_6 (bearing 270 degrees) faces the south wall
        view = rig.views(qpos)[6].astype(int)
    finally:
        rig.close()
    red = (view[..., 0] > 150) & (view[..., 1] < 60) & (view[..., 2] < 60)
    assert red.all(), f"{np.count_nonzero(~red)} of {red.size} pixels are not wall"
