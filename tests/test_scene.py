"""MJCF builder and mobile base: every floor compiles with deterministic names; the base follows its route."""

import math

import numpy as np
import pytest

from ptm_bench.floorplan import corridor_grid, list_worlds, load_world, palette_library
from ptm_bench.robot import ControllerConfig, RigConfig, base_pose, drive, place_base
from ptm_bench.scene import build_mjcf, compile_scene, place_sites

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
    assert place_sites(model) == pytest.approx(floor.places)


def test_walls_leave_the_corridors_free():
    floor = load_world("nested_loops")
    model = compile_scene(build_mjcf(floor, _one_palette_each(floor)))
    route = floor.route_points()
    samples = np.concatenate([a + (b - a) * np.linspace(0, 1, 50)[:, None] for a, b in zip(route[:-1], route[1:])])
    for geom in range(model.ngeom):
        name = model.geom(geom).name
        if "wall" not in name and "panel" not in name:
            continue
        centre, size = model.geom_pos[geom][:2], model.geom_size[geom]
        half = size[:2] if model.geom_type[geom] == mujoco.mjtGeom.mjGEOM_BOX else size[[0, 0]]
        gap = np.maximum(np.abs(samples - centre) - half, 0.0)
        clearance = 0.75 if "wall" in name else 0.3  # panels stand inside the corridor, beside the route
        assert np.linalg.norm(gap, axis=1).min() >= clearance, f"{name} intrudes on the route"


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
    for place_id in floor.places:
        for index in range(4):
            panel = model.geom(f"place_{place_id}_panel_{index}")
            clearance = np.linalg.norm(trajectory.poses[:, :2] - panel.pos[:2], axis=1).min() - panel.size[0]
            assert clearance > 0.1, f"the mast cameras would enter place_{place_id}_panel_{index}"
    steps = np.linalg.norm(np.diff(trajectory.poses[:, :2], axis=0), axis=1)
    assert steps.max() <= floor.speed * ControllerConfig().control_period * 1.05
    assert trajectory.poses[-1, 2] == pytest.approx(2 * 2 * math.pi - math.pi / 2, abs=0.2)  # two loops, facing south


def test_bad_palettes_and_cells_are_rejected():
    floor = load_world("short_loop")
    with pytest.raises(ValueError, match="no palette for places"):
        build_mjcf(floor, {})
    with pytest.raises(ValueError, match="cell_size"):
        build_mjcf(floor, _one_palette_each(floor), cell_size=1.0)
