"""MJCF builder and mobile base: every floor compiles with deterministic names; the base follows its route."""

import math

import numpy as np
import pytest

from ptm_bench.world.floorplan import corridor_grid, list_worlds, load_world, palette_library, parse_floorplan
from ptm_bench.simulation.robot import ControllerConfig, RigConfig, base_pose, drive, place_base
from ptm_bench.simulation.scene import build_mjcf, compile_scene, place_sites

import mujoco  # noqa: E402


def _one_palette_each(floor):
    library = palette_library(len(floor.places), np.random.default_rng(0))
    return {place_id: library[i] for i, place_id in enumerate(sorted(floor.places))}


def _floors():
    return [load_world(name) for name in list_worlds()] + [corridor_grid(3, 3, loops=2, place_density=0.6, seed=4)]


@pytest.mark.parametrize("floor", _floors(), ids=lambda floor: floor.name)
def test_every_floor_compiles_with_deterministic_names(floor):
    xml = build_mjcf(floor, _one_palette_each(floor))
    assert xml == build_mjcf(floor, _one_palette_each(floor))
    model = compile_scene(xml)
    names = [model.geom(i).name for i in range(model.ngeom)]
    assert any(name.startswith("wall_") for name in names)
    for place_id in floor.places:
        assert f"place_{place_id}_marker" in names
        assert [name for name in names if name.startswith(f"place_{place_id}_panel_")] == [
            f"place_{place_id}_panel_{index}" for index in range(4)]
    assert [model.camera(i).name for i in range(model.ncam)] == [f"cam_{i}" for i in range(8)]
    sites = place_sites(model)
    assert sorted(sites) == sorted(floor.places)
    assert np.allclose([sites[p] for p in sorted(sites)], [floor.places[p] for p in sorted(sites)])


def test_walls_and_decor_leave_the_corridors_free():
    floor = load_world("nested_loops")
    model = compile_scene(build_mjcf(floor, _one_palette_each(floor)))
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    route = floor.route_points()
    samples = np.concatenate([a + (b - a) * np.linspace(0, 1, 50)[:, None] for a, b in zip(route[:-1], route[1:])])
    for geom in range(model.ngeom):
        name = model.geom(geom).name
        centre, size = data.geom_xpos[geom][:2], model.geom_size[geom]
        if name.startswith("wall_"):  # axis-aligned boxes
            gap = np.linalg.norm(np.maximum(np.abs(samples - centre) - size[:2], 0.0), axis=1)
            assert gap.min() >= 0.75, f"{name} intrudes on the route"
        elif "_panel_" in name:  # upright panels, turned to face their place: distance to the panel's segment
            along = data.geom_xmat[geom].reshape(3, 3)[:2, 0]
            offset = np.clip((samples - centre) @ along, -size[0], size[0])
            gap = np.linalg.norm(samples - (centre + offset[:, None] * along), axis=1) - size[1]
            assert gap.min() >= 0.25, f"{name} stands in the way of the route centreline"


def test_cameras_are_45_degrees_apart_on_the_mast():
    floor = load_world("short_loop")
    model = compile_scene(build_mjcf(floor, _one_palette_each(floor), RigConfig()))
    data = mujoco.MjData(model)
    place_base(model, data, (1.0, 0.5, 0.3))
    for index in range(8):
        camera = model.camera(f"cam_{index}").id
        forward = -data.cam_xmat[camera].reshape(3, 3)[:, 2]
        assert forward[2] == pytest.approx(0.0, abs=1e-9)
        assert math.atan2(forward[1], forward[0]) == pytest.approx(math.remainder(0.3 + index * math.pi / 4, 2 * math.pi))
        assert data.cam_xpos[camera][2] == pytest.approx(RigConfig().mast_height)


def test_base_is_driven_along_the_route_by_the_physics():
    floor = load_world("short_loop")
    model = compile_scene(build_mjcf(floor, _one_palette_each(floor)))
    data = mujoco.MjData(model)
    waypoints = floor.route_points()
    place_base(model, data, (*waypoints[0], 0.0))
    trajectory = drive(model, data, waypoints, speed=floor.speed, config=ControllerConfig())
    assert data.time == pytest.approx(trajectory.times[-1]) and data.time > floor.route_length() / floor.speed
    assert np.allclose(trajectory.poses[-1], base_pose(model, data))
    assert np.linalg.norm(trajectory.poses[-1, :2] - waypoints[-1]) < 0.15
    dense = np.concatenate([a + (b - a) * np.linspace(0, 1, 100)[:, None] for a, b in zip(waypoints[:-1], waypoints[1:])])
    off_route = np.linalg.norm(trajectory.poses[:, None, :2] - dense[None], axis=2).min(axis=1)
    assert off_route.max() < 0.5 * 1.2 - 0.2  # inside the 1.2 m corridor with room for the chassis
    mujoco.mj_forward(model, data)
    for place_id in floor.places:
        for index in range(4):
            panel = model.geom(f"place_{place_id}_panel_{index}").id
            centre, half_width = data.geom_xpos[panel][:2], model.geom_size[panel][0]
            along = data.geom_xmat[panel].reshape(3, 3)[:2, 0]
            offset = np.clip((trajectory.poses[:, :2] - centre) @ along, -half_width, half_width)
            clearance = np.linalg.norm(trajectory.poses[:, :2] - (centre + offset[:, None] * along), axis=1).min()
            assert clearance > RigConfig().camera_offset + 0.05, f"the mast cameras would enter place_{place_id}_panel_{index}"
    steps = np.linalg.norm(np.diff(trajectory.poses[:, :2], axis=0), axis=1)
    assert steps.max() <= floor.speed * ControllerConfig().control_period * 1.05
    assert trajectory.poses[-1, 2] == pytest.approx(2 * 2 * math.pi - math.pi / 2, abs=0.2)  # two loops, facing south


def test_bad_palettes_and_cells_are_rejected():
    floor = load_world("short_loop")
    with pytest.raises(ValueError, match="no palette for places"):
        build_mjcf(floor, {})
    with pytest.raises(ValueError, match="cell_size"):
        build_mjcf(floor, _one_palette_each(floor), cell_size=1.0)


def test_the_base_drives_into_a_dead_end_before_turning_back():
    """Pure pursuit alone turned back up to its look-ahead before a dead end, so a place there was
    detected a metre off (or missed); a sharp turn is now driven to and turned on the spot."""
    floor = parse_floorplan("""
name = "dead_end"
[nodes]
A = [0.0, 0.0]
B = [5.0, 0.0]
[[corridors]]
from = "A"
to = "B"
[[places]]
id = 0
node = "B"
[[places]]
id = 1
node = "A"
[routes]
main = ["A", "B", "A"]
""")
    model = compile_scene(build_mjcf(floor, _one_palette_each(floor)))
    data = mujoco.MjData(model)
    waypoints = floor.route_points()
    place_base(model, data, (*waypoints[0], 0.0))
    trajectory = drive(model, data, waypoints, speed=1.0)
    assert np.linalg.norm(trajectory.poses[:, :2] - waypoints[1], axis=1).min() < 0.15
    assert np.linalg.norm(trajectory.poses[-1, :2] - waypoints[-1]) < 0.15
