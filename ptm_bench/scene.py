"""Compile a floor plan to MJCF: walls, floor, place markers and palettes, and the robot (SPEC §5).

Like dm_control's mazes, the abstract layout is rasterised onto a grid
(``cell_size`` metres): a cell is free if it lies inside a corridor rectangle
(extended by half a width past each end, so junctions have square corners),
and a wall if it is not free but touches a free cell. Runs of wall cells with
the same look are merged into boxes. Wall cells within ``zone_radius`` of a
place take the colour of that place's palette sector (the bearing from the
place relative to its layout frame, in four 90-degree sectors) and are named ``place_<id>_wall_<k>``; all
other walls are ``wall_<k>``. Each place also gets a floor marker
``place_<id>_marker``, a pillar prop ``place_<id>_prop`` and an invisible site ``place_<id>_site`` whose name is
where ground-truth labels are read from. The base and cameras ``cam_0``..``cam_7``
come from :mod:`ptm_bench.robot`. Names are deterministic.

    >>> floor = load_world("short_loop")
    >>> xml = build_mjcf(floor, {pid: palette for pid in floor.places})
    >>> model = compile_scene(xml)
"""

from __future__ import annotations

import math
import re

import numpy as np

from .floorplan import SECTOR_COUNT, Floorplan, Palette
from .robot import RigConfig, base_mjcf

import mujoco  # noqa: E402  (robot sets MUJOCO_GL before mujoco is first imported)

__all__ = ["PLACE_SITE", "build_mjcf", "compile_scene", "place_sites", "rasterise"]

PLACE_SITE = re.compile(r"^place_(\d+)_site$")
_WALL_RGB = (0.62, 0.62, 0.64)


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
        a = np.asarray(floor.nodes[corridor.start])
        b = np.asarray(floor.nodes[corridor.end])
        length = float(np.linalg.norm(b - a))
        axis = (b - a) / length
        relative = centres - a
        along = relative @ axis
        across = relative @ np.array([-axis[1], axis[0]])
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
    looks = _wall_looks(floor, origin, wall, cell_size)
    geoms = []
    counters: dict[str, int] = {}
    for (row0, col0, row1, col1), look in _merge_runs(wall, looks, height):
        place_id, sector = look[0], look[1]
        wall_height = look[2]
        prefix = "wall" if place_id < 0 else f"place_{place_id}_wall"
        index = counters.get(prefix, 0)
        counters[prefix] = index + 1
        centre_x = origin[0] + (col0 + col1 + 1) / 2 * cell_size
        centre_y = origin[1] + (row0 + row1 + 1) / 2 * cell_size
        size = f"{(col1 - col0 + 1) * cell_size / 2:.4f} {(row1 - row0 + 1) * cell_size / 2:.4f} {wall_height / 2:.4f}"
        if place_id < 0:
            look_attributes = 'material="wall_mat"'
        else:
            r, g, b = palettes[place_id].sectors[sector]
            look_attributes = f'rgba="{r:.4f} {g:.4f} {b:.4f} 1"'
        geoms.append(
            f'<geom name="{prefix}_{index}" type="box" pos="{centre_x:.4f} {centre_y:.4f} {wall_height / 2:.4f}" '
            f'size="{size}" {look_attributes}/>'
        )
    geoms.extend(_pillars(floor, palettes, origin, looks[0], cell_size))
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
    floor_size = f"{(xmax - xmin) / 2 + 1:.3f} {(ymax - ymin) / 2 + 1:.3f} 0.1"
    floor_pos = f"{(xmin + xmax) / 2:.3f} {(ymin + ymax) / 2:.3f} 0"
    body, actuators = base_mjcf(rig)
    return f"""<mujoco model="{floor.name}">
  <compiler angle="radian"/>
  <option timestep="0.02" integrator="implicitfast"/>
  <visual>
    <headlight ambient="0.45 0.45 0.45" diffuse="0 0 0" specular="0 0 0"/>
    <quality shadowsize="0"/>
  </visual>
  <default>
    <geom contype="0" conaffinity="0"/>
  </default>
  <asset>
    <texture name="floor_tex" type="2d" builtin="checker" rgb1="0.52 0.50 0.46" rgb2="0.40 0.39 0.36" width="64" height="64"/>
    <material name="floor_mat" texture="floor_tex" texrepeat="1 1" texuniform="true"/>
    <texture name="wall_tex" type="2d" builtin="checker" rgb1="{_WALL_RGB[0]} {_WALL_RGB[1]} {_WALL_RGB[2]}" rgb2="0.50 0.52 0.56" width="64" height="64"/>
    <material name="wall_mat" texture="wall_tex" texrepeat="1 1" texuniform="true"/>
  </asset>
  <worldbody>
    <light name="ceiling" directional="true" pos="0 0 10" dir="0 0 -1" diffuse="0.35 0.35 0.35" specular="0 0 0" castshadow="false"/>
    <light name="sun_east" directional="true" pos="0 0 10" dir="0.8 0.3 -0.5" diffuse="0.3 0.3 0.3" specular="0 0 0" castshadow="false"/>
    <light name="sun_north" directional="true" pos="0 0 10" dir="-0.3 0.8 -0.5" diffuse="0.2 0.2 0.2" specular="0 0 0" castshadow="false"/>
    <geom name="floor" type="plane" pos="{floor_pos}" size="{floor_size}" material="floor_mat"/>
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
        return mujoco.MjModel.from_xml_string(xml)
    except ValueError as error:
        raise ValueError(f"the floor did not compile to a MuJoCo model: {error}") from None


def place_sites(model) -> dict[int, tuple[float, float]]:
    """Place id -> (x, y), read from the ``place_<id>_site`` element names of a compiled model."""
    places = {}
    for site_id in range(model.nsite):
        match = PLACE_SITE.match(model.site(site_id).name)
        if match:
            places[int(match.group(1))] = (float(model.site_pos[site_id, 0]), float(model.site_pos[site_id, 1]))
    return places


def _wall_looks(floor: Floorplan, origin, wall, cell_size) -> tuple[np.ndarray, np.ndarray]:
    """Per cell: the place whose zone it is in (-1 for none) and the compass sector seen from that place."""
    rows, cols = np.indices(wall.shape)
    x = origin[0] + (cols + 0.5) * cell_size
    y = origin[1] + (rows + 0.5) * cell_size
    owner = np.full(wall.shape, -1)
    sector = np.zeros(wall.shape, dtype=int)
    nearest = np.full(wall.shape, np.inf)
    for place_id, (px, py) in sorted(floor.places.items()):
        distance = np.hypot(x - px, y - py)
        claim = wall & (distance <= floor.zone_radius) & (distance < nearest)
        nearest = np.where(claim, distance, nearest)
        owner = np.where(claim, place_id, owner)
        bearing = np.arctan2(y - py, x - px) - floor.place_frame(place_id)
        place_sector = np.floor((bearing + math.pi / SECTOR_COUNT) / (2 * math.pi / SECTOR_COUNT)).astype(int) % SECTOR_COUNT
        sector = np.where(claim, place_sector, sector)
    return owner, sector


def _pillars(floor: Floorplan, palettes, origin, owner, cell_size, radius: float = 0.12, height: float = 1.8):
    """A pillar ``place_<id>_prop`` per place, against its zone's wall nearest the palette's prop bearing."""
    geoms = []
    for place_id, (px, py) in sorted(floor.places.items()):
        rows, cols = np.nonzero(owner == place_id)
        if not len(rows):
            continue
        x = origin[0] + (cols + 0.5) * cell_size
        y = origin[1] + (rows + 0.5) * cell_size
        bearing = np.arctan2(y - py, x - px) - floor.place_frame(place_id)
        target = math.radians(palettes[place_id].prop_bearing)
        best = int(np.argmin(np.abs(np.angle(np.exp(1j * (bearing - target))))))
        towards = np.array([px - x[best], py - y[best]])
        towards /= np.linalg.norm(towards)
        cx, cy = np.array([x[best], y[best]]) + towards * (cell_size / 2 + radius)
        r, g, b = palettes[place_id].marker
        geoms.append(
            f'<geom name="place_{place_id}_prop" type="cylinder" pos="{cx:.4f} {cy:.4f} {height / 2:.4f}" '
            f'size="{radius:.3f} {height / 2:.4f}" rgba="{r:.4f} {g:.4f} {b:.4f} 1"/>'
        )
    return geoms


def _merge_runs(wall, looks, height):
    """Boxes of wall cells with identical look: horizontal runs of two or more, then vertical runs.

    Yields ((row0, col0, row1, col1), (place_id, sector, wall_height)).
    """
    owner, sector = looks
    key = np.stack([owner, np.where(owner < 0, 0, sector), np.round(height * 1000).astype(int)], axis=-1)
    used = np.zeros(wall.shape, dtype=bool)
    boxes = []
    for row, first, last in _runs_along_rows(wall, key, minimum=2):
        boxes.append(((row, first, row, last), key[row, first]))
        used[row, first:last + 1] = True
    for col, first, last in _runs_along_rows((wall & ~used).T, key.transpose(1, 0, 2), minimum=1):
        boxes.append(((first, col, last, col), key[first, col]))
    for cells, (place_id, place_sector, milli_height) in boxes:
        yield cells, (int(place_id), int(place_sector), milli_height / 1000)


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
