"""Floor files: presets, validation errors with field and line, the aliasing map, procedural grids."""

import math

import numpy as np
import pytest

from ptm_bench.world.floorplan import (
    assign_palettes,
    corridor_grid,
    list_worlds,
    load_world,
    palette_count,
    palette_library,
    palette_signature,
    parse_floorplan,
)

MINIMAL = """\
name = "tiny"

[defaults]
corridor_width = 2.0
detection_radius = 0.8

[nodes]
A = [0.0, 0.0]
B = [6.0, 0.0]
C = [6.0, 6.0]

[[corridors]]
from = "A"
to = "B"

[[corridors]]
from = "B"
to = "C"

[[places]]
id = 0
node = "A"

[[places]]
id = 1
at = [6.0, 3.0]

[routes]
main = ["A", "B", "C"]
"""


def test_presets_load_with_the_papers_sizes():
    assert set(list_worlds()) >= {"short_loop", "office", "nested_loops"}
    short, office, nested = (load_world(name) for name in ("short_loop", "office", "nested_loops"))
    assert 12 <= short.route_length() <= 20
    assert 180 <= office.route_length() <= 220
    assert nested.route_length() > 100
    for floor in (short, office, nested):
        assert 2 * floor.detection_radius < floor.min_place_spacing


def test_minimal_floor_parses():
    floor = parse_floorplan(MINIMAL)
    assert floor.name == "tiny"
    assert floor.places == {0: (0.0, 0.0), 1: (6.0, 3.0)}
    assert floor.routes["main"] == ("A", "B", "C")
    assert floor.min_place_spacing == pytest.approx(math.hypot(6.0, 3.0))
    assert floor.route_length() == pytest.approx(12.0)


def test_unknown_world_lists_the_known_ones():
    with pytest.raises(ValueError, match="known worlds: .*nested_loops.*office.*short_loop"):
        load_world("atlantis")


@pytest.mark.parametrize(
    "old, new, field, line",
    [
        ('to = "B"', 'to = "Z"', "corridors[0].to", 14),
        ("corridor_width = 2.0", "corridor_width = -2.0", "defaults.corridor_width", 4),
        ("at = [6.0, 3.0]", "at = [9.0, 3.0]", "places[1]", 24),
        ('main = ["A", "B", "C"]', 'main = ["A", "C"]', "routes.main", 29),
        ("detection_radius = 0.8", "detection_radius = 4.0", "defaults.detection_radius", 5),
        ("id = 1", "id = 0", "places[1].id", 25),
    ],
)
def test_semantic_errors_name_the_field_and_the_line(old, new, field, line):
    assert old in MINIMAL
    with pytest.raises(ValueError) as error:
        parse_floorplan(MINIMAL.replace(old, new, 1), source="tiny.toml")
    message = str(error.value)
    assert f"tiny.toml:{line}:" in message and field in message


def test_toml_syntax_error_reports_the_line():
    with pytest.raises(ValueError, match=r"malformed TOML.*line 9"):
        parse_floorplan(MINIMAL.replace("A = [0.0, 0.0]", "A = [0.0, 0.0", 1), source="tiny.toml")


def test_missing_floor_file_is_a_clear_error(tmp_path):
    with pytest.raises(ValueError, match="no floor file"):
        load_world(tmp_path / "nothing.toml")


@pytest.mark.parametrize("places, aliasing, expected", [(8, 0.0, 8), (8, 1.0, 1), (8, 0.5, 5), (1, 0.0, 1), (12, 0.25, 9)])
def test_palette_count_follows_the_spec(places, aliasing, expected):
    assert palette_count(places, aliasing) == expected == max(1, math.floor(1 + (1 - aliasing) * (places - 1) + 0.5))


@pytest.mark.parametrize("aliasing", [-0.1, 1.01, float("nan"), "high"])
def test_aliasing_outside_the_unit_interval_is_rejected(aliasing):
    with pytest.raises(ValueError, match="aliasing"):
        palette_count(5, aliasing)


@pytest.mark.parametrize("aliasing", [0.0, 0.2, 0.5, 0.8, 1.0])
def test_assignment_uses_exactly_the_required_number_of_palettes(aliasing):
    floor = load_world("nested_loops")
    for seed in range(5):
        assignment = assign_palettes(floor, aliasing, np.random.default_rng(seed))
        assert sorted(assignment) == sorted(floor.places)
        assert len(set(assignment.values())) == palette_count(len(floor.places), aliasing)


def test_palette_library_keeps_given_palettes_and_spreads_the_rest():
    given = load_world("office").palettes
    library = palette_library(10, np.random.default_rng(0), given)
    assert library[: len(given)] == given
    ring = np.array([palette_signature(palette) for palette in library])
    gaps = np.linalg.norm(ring[:, None] - ring[None], axis=2)[np.triu_indices(10, 1)]
    assert gaps.min() > 0.01


def test_congruent_corners_share_a_palette_frame_up_to_rotation():
    floor = load_world("short_loop")
    frames = [floor.place_frame(place_id) for place_id in sorted(floor.places)]
    relative_openings = {
        tuple(sorted(round(math.degrees((o - frame) % (2 * math.pi))) % 360 for o in floor.openings(floor.places[p])))
        for p, frame in zip(sorted(floor.places), frames)
    }
    assert relative_openings == {(0, 90)}
    assert len({round(frame, 6) for frame in frames}) == 4


def test_corridor_grid_is_seeded_and_has_the_requested_loops():
    grid = corridor_grid(3, 4, loops=2, place_density=0.5, seed=11)
    assert grid == corridor_grid(3, 4, loops=2, place_density=0.5, seed=11)
    assert grid.routes != corridor_grid(3, 4, loops=2, place_density=0.5, seed=12).routes
    assert len(grid.corridors) == 3 * 4 - 1 + 2
    linked = {frozenset((c.start, c.end)) for c in grid.corridors}
    route = grid.routes["main"]
    assert all(frozenset(pair) in linked for pair in zip(route, route[1:]))
    assert set(route) == set(grid.nodes) and route[0] == route[-1]
    assert len(grid.places) >= 2


def test_corridor_grid_rejects_impossible_loop_counts():
    with pytest.raises(ValueError, match="loops"):
        corridor_grid(2, 2, loops=2, place_density=0.5, seed=0)
