"""Compile a floor plan to MJCF: walls, floor, ceiling, place decor, and the robot (docs/model.md §5).

Like dm_control's mazes, the abstract layout is rasterised onto a grid
(``cell_size`` metres): a cell is free if it lies inside a corridor rectangle
(extended by half a width past each end, so junctions have square corners),
and a wall if it is not free but touches a free cell. Runs of wall cells of
one height are merged into boxes ``wall_<k>``.

What the cameras see is designed so that the aliasing knob means what it
says. Walls, floor and ceiling are one matte grey under ambient light only,
and a haze of that same grey hides everything beyond a few metres: the
corridor layout around a place is invisible. Each place carries the decor of
its palette: four panels ``place_<id>_panel_<j>`` standing at its diagonals
(``Floorplan.decor_radius`` from it, facing it, floor to ceiling), so places
with one palette look alike up to the robot's heading and its position
within the detection radius. Each place also has a floor marker
``place_<id>_marker`` and an invisible site ``place_<id>_site`` whose name is
where ground-truth labels are read from. The base and cameras
``cam_0``..``cam_7`` come from :mod:`ptm_bench.simulation.robot`. Names are deterministic.
The near clipping plane is set in metres (``NEAR_PLANE``), not as MuJoCo's
default share of the model's extent, which put it behind walls the robot
passes close to.

    >>> import numpy as np
    >>> from ptm_bench.world.floorplan import load_world, palette_library
    >>> floor = load_world("short_loop")
    >>> (palette,) = palette_library(1, np.random.default_rng(0))
    >>> model = compile_scene(build_mjcf(floor, {place_id: palette for place_id in floor.places}))
    >>> sorted(place_sites(model))
    [0, 1, 2, 3]
"""

from __future__ import annotations

import math
import re

import numpy as np

from ptm_bench.world.floorplan import PANEL_WIDTH_PER_RADIUS, SECTOR_COUNT, SURROUNDINGS_RGB, Floorplan, Palette
from ptm_bench.simulation.robot import RigConfig, base_mjcf

import mujoco  # noqa: E402  (robot sets MUJOCO_GL before mujoco is first imported)

__all__ = ["AMBIENT", "HAZE", "NEAR_PLANE", "PLACE_SITE", "build_mjcf", "compile_scene", "place_sites", "rasterise"]

PLACE_SITE = re.compile(r"^place_(\d+)_site$")
NEAR_PLANE = 0.03  # [m] near clipping plane of every camera
HAZE = (1.5, 3.0)  # [m] the haze starts to thin the view here and hides everything beyond the second distance
AMBIENT = 0.8  # the only light: even, so that a surface's brightness does not depend on its orientation


def rasterise(floor: Floorplan, cell_size: float):
    """Free-space and wall masks on a grid; returns (origin_xy, free, wall, wall_height)."""
    xmin, ymin, xmax, ymax = floor.bounds()
    origin = np.array([xmin - 2 * cell_size, ymin - 2 * cell_size])
    shape = (int(math.ceil((ymax - ymin) / cell_size)) + 4, int(math.ceil((xmax - xmin) / cell_size)) + 4)
    rows, cols = np.indices(shape)
    centres = np.stack([origin[0] + (cols + 0.5) * cell_size, origin[1] + (rows + 0.5) * cell_size], axis=-1)
    free = np.zeros(shape, dtype=bool)
    height = np.zeros(shape)
    best = np.full(shape, np.inf)
    for corridor in floor.corridors:
        along, across, length = corridor.coordinates(floor.nodes, centres)
        half = corridor.width / 2
        inside = (along >= -half) & (along <= length + half) & (np.abs(across) <= half)
        free |= inside
        distance = np.abs(across) + np.maximum(0.0, np.maximum(-along, along - length))
        closer = distance < best
        best = np.where(closer, distance, best)
        height = np.where(closer, corridor.wall_height, height)
    padded = np.pad(free, 1)
    touches_free = np.zeros(shape, dtype=bool)
    for dr in (-1, 0, 1):
        for dc in (-1, 0, 1):
            touches_free |= padded[1 + dr:1 + dr + shape[0], 1 + dc:1 + dc + shape[1]]
    wall = touches_free & ~free
    return origin, free, wall, height


def build_mjcf(floor: Floorplan, palettes: dict[int, Palette], rig: RigConfig = RigConfig(),
               cell_size: float = 0.25) -> str:
    """The MJCF text of the floor with every place coloured by ``palettes[place_id]``."""
    missing = sorted(set(floor.places) - set(palettes))
    if missing:
        raise ValueError(f"palettes: no palette for places {missing}")
    if cell_size <= 0 or cell_size > min(c.width for c in floor.corridors) / 2:
        raise ValueError(f"cell_size must be in (0, half the narrowest corridor], got {cell_size}")
    origin, _, wall, height = rasterise(floor, cell_size)
    geoms = []
    for index, ((row0, col0, row1, col1), wall_height) in enumerate(_merge_runs(wall, height)):
        centre_x = origin[0] + (col0 + col1 + 1) / 2 * cell_size
        centre_y = origin[1] + (row0 + row1 + 1) / 2 * cell_size
        size = f"{(col1 - col0 + 1) * cell_size / 2:.4f} {(row1 - row0 + 1) * cell_size / 2:.4f} {wall_height / 2:.4f}"
        geoms.append(
            f'<geom name="wall_{index}" type="box" pos="{centre_x:.4f} {centre_y:.4f} {wall_height / 2:.4f}" '
            f'size="{size}" material="surroundings"/>'
        )
    ceiling = max(corridor.wall_height for corridor in floor.corridors)
    geoms.extend(_decor_panels(floor, palettes, ceiling))
    for place_id in sorted(floor.places):
        x, y = floor.places[place_id]
        r, g, b = palettes[place_id].marker
        geoms.append(
            f'<geom name="place_{place_id}_marker" type="cylinder" pos="{x:.4f} {y:.4f} 0.005" '
            f'size="{min(0.4, floor.detection_radius * 0.6):.3f} 0.005" rgba="{r:.4f} {g:.4f} {b:.4f} 1"/>'
        )
        geoms.append(
            f'<site name="place_{place_id}_site" pos="{x:.4f} {y:.4f} 0" size="{floor.detection_radius:.4f}" '
            'group="5" rgba="1 0 0 0.2"/>'
        )
    xmin, ymin, xmax, ymax = floor.bounds()
    half_extent = f"{(xmax - xmin) / 2 + 1:.3f} {(ymax - ymin) / 2 + 1:.3f}"
    floor_pos = f"{(xmin + xmax) / 2:.3f} {(ymin + ymax) / 2:.3f} 0"
    ceiling_pos = f"{(xmin + xmax) / 2:.3f} {(ymin + ymax) / 2:.3f} {ceiling + 0.05:.3f}"
    grey = " ".join(f"{value:.3f}" for value in SURROUNDINGS_RGB)
    haze = " ".join(f"{value * AMBIENT:.4f}" for value in SURROUNDINGS_RGB)
    body, actuators = base_mjcf(rig)
    return f"""<mujoco model="{floor.name}">
  <compiler angle="radian"/>
  <option timestep="0.02" integrator="implicitfast"/>
  <visual>
    <headlight ambient="{AMBIENT} {AMBIENT} {AMBIENT}" diffuse="0 0 0" specular="0 0 0"/>
    <rgba fog="{haze} 1"/>
    <quality shadowsize="0"/>
  </visual>
  <default>
    <geom contype="0" conaffinity="0"/>
  </default>
  <asset>
    <material name="surroundings" rgba="{grey} 1" specular="0" shininess="0"/>
  </asset>
  <worldbody>
    <geom name="floor" type="plane" pos="{floor_pos}" size="{half_extent} 0.1" material="surroundings"/>
    <geom name="ceiling" type="box" pos="{ceiling_pos}" size="{half_extent} 0.05" material="surroundings"/>
    {chr(10).join("    " + geom for geom in geoms)}
    {body}
  </worldbody>
  <actuator>{actuators}
  </actuator>
</mujoco>
"""


def compile_scene(xml: str):
    """A ``mujoco.MjModel`` from MJCF text (errors re-raised as ValueError)."""
    try:
        model = mujoco.MjModel.from_xml_string(xml)
    except ValueError as error:
        raise ValueError(f"the floor did not compile to a MuJoCo model: {error}") from None
    # MJCF gives these distances as shares of the model's extent, known only once compiled
    extent = model.stat.extent
    model.vis.map.znear = NEAR_PLANE / extent
    model.vis.map.fogstart = HAZE[0] / extent
    model.vis.map.fogend = HAZE[1] / extent
    return model


def place_sites(model) -> dict[int, tuple[float, float]]:
    """Place id -> (x, y), read from the ``place_<id>_site`` element names of a compiled model."""
    places = {}
    for site_id in range(model.nsite):
        match = PLACE_SITE.match(model.site(site_id).name)
        if match:
            places[int(match.group(1))] = (float(model.site_pos[site_id, 0]), float(model.site_pos[site_id, 1]))
    return places


def _decor_panels(floor: Floorplan, palettes, height: float, thickness: float = 0.02):
    """Four panels ``place_<id>_panel_<j>`` per place at bearings 45 + 90 j degrees in its frame, facing it."""
    radius = floor.decor_radius
    half_width = PANEL_WIDTH_PER_RADIUS * radius / 2
    geoms = []
    for place_id, (px, py) in sorted(floor.places.items()):
        frame = floor.place_frame(place_id)
        for index in range(SECTOR_COUNT):
            bearing = frame + math.radians(45.0 + 90.0 * index)
            x, y = px + radius * math.cos(bearing), py + radius * math.sin(bearing)
            r, g, b = palettes[place_id].sectors[index]
            geoms.append(
                f'<geom name="place_{place_id}_panel_{index}" type="box" pos="{x:.4f} {y:.4f} {height / 2:.4f}" '
                f'size="{half_width:.4f} {thickness / 2:.4f} {height / 2:.4f}" euler="0 0 {bearing + math.pi / 2:.6f}" '
                f'rgba="{r:.4f} {g:.4f} {b:.4f} 1"/>'
            )
    return geoms


def _merge_runs(wall, height):
    """Boxes of wall cells of one height: horizontal runs of two or more, then vertical runs.

    Yields ((row0, col0, row1, col1), wall_height).
    """
    key = np.round(height * 1000).astype(int)[..., None]
    used = np.zeros(wall.shape, dtype=bool)
    boxes = []
    for row, first, last in _runs_along_rows(wall, key, minimum=2):
        boxes.append(((row, first, row, last), key[row, first, 0]))
        used[row, first:last + 1] = True
    for col, first, last in _runs_along_rows((wall & ~used).T, key.transpose(1, 0, 2), minimum=1):
        boxes.append(((first, col, last, col), key[first, col, 0]))
    for cells, milli_height in boxes:
        yield cells, milli_height / 1000


def _runs_along_rows(mask, key, minimum):
    """(row, first, last) of each maximal run of set cells with equal ``key`` along the rows of ``mask``."""
    for row in range(mask.shape[0]):
        col = 0
        while col < mask.shape[1]:
            if not mask[row, col]:
                col += 1
                continue
            end = col
            while end + 1 < mask.shape[1] and mask[row, end + 1] and np.array_equal(key[row, end + 1], key[row, col]):
                end += 1
            if end - col + 1 >= minimum:
                yield row, col, end
            col = end + 1
