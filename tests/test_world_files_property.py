"""Property tests of the world-file boundary (issue 47): any world file parses or raises a ``ValueError`` that
starts with its source, and a floor that parses is bounded and works in the cheap, MuJoCo-free steps of the
pipeline (route, palettes, detector, the drive's work estimate, the rasterised scene and its MJCF).

A valid floor (every kind of table, optional keys set) is mutated: a value replaced by one of the wrong type, a
non-finite or an extreme one, a key deleted or a misspelt one added, at any level; or the file's bytes are
damaged. ``corridor_grid`` gets the same treatment through its arguments.
"""

import json
import math
import tempfile
from pathlib import Path

import numpy as np
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from ptm_bench.simulation.detector import detect
from ptm_bench.simulation.robot import MAX_CONTROL_STEPS, ControllerConfig, RigConfig, control_steps
from ptm_bench.simulation.scene import build_mjcf, rasterise
from ptm_bench.world.floorplan import (MAX_EXTENT, MAX_SPEED, ROBOT_CLEARANCE, Palette, assign_palettes,
                                       corridor_grid, load_world, parse_floorplan, resample_polyline)

SETTINGS = settings(max_examples=100, deadline=None, database=None, suppress_health_check=[HealthCheck.too_slow])
SOURCE = "fuzz.toml"

#: A floor using every table and key a world file may have.
FLOOR = {
    "name": "fuzz",
    "description": "a corridor with a side branch",
    "defaults": {"corridor_width": 2.0, "wall_height": 2.5, "detection_radius": 0.8, "speed": 1.0,
                 "lateral_jitter": 0.2},
    "nodes": {"A": [0.0, 0.0], "B": [6.0, 0.0], "C": [6.0, 6.0]},
    "corridors": [{"from": "A", "to": "B", "width": 2.0, "wall_height": 2.5}, {"from": "B", "to": "C"}],
    "places": [{"id": 0, "node": "A"}, {"id": 1, "at": [6.0, 3.0]}],
    "palettes": [{"sectors": [[0.1, 0.2, 0.3], [0.9, 0.8, 0.7], [0.5, 0.5, 0.5], [0.2, 0.6, 0.4]],
                  "marker": [0.3, 0.3, 0.3]}],
    "routes": {"main": ["A", "B", "C", "B"], "back": ["C", "B"]},
}
DELETE = object()
GREY = Palette(((0.5, 0.5, 0.5),) * 4, (0.5, 0.5, 0.5))

extreme = st.sampled_from([0, -1, 1e-300, 1e-9, 0.3, 0.6, 1e9, 2e7, 1e6, 1e300, MAX_EXTENT, MAX_EXTENT + 1e-9,
                           MAX_SPEED, 2 ** 63 - 1, -(2 ** 63)])
scalars = st.one_of(
    extreme,
    st.floats(allow_nan=True, allow_infinity=True),
    st.integers(min_value=-(2 ** 63), max_value=2 ** 63 - 1),
    st.booleans(),
    st.text(st.characters(blacklist_categories=("Cs",)), max_size=3),  # TOML has no lone surrogates
    st.sampled_from(["A", "B", "C", "main"]),
)
numbers = st.one_of(extreme, st.floats(-MAX_EXTENT - 100, MAX_EXTENT + 100), st.floats(0.0, 5.0),
                    st.floats(allow_nan=True, allow_infinity=True))
values = st.one_of(
    scalars,
    st.lists(scalars, max_size=4),
    st.lists(st.lists(scalars, max_size=3), max_size=3),
    st.dictionaries(st.sampled_from(["from", "to", "id", "node", "at", "x"]), scalars, max_size=3),
    st.just(DELETE),
)


def _paths(value, prefix=()):
    """Every key path of a document, tables and array entries included."""
    yield prefix
    if isinstance(value, dict):
        for key, item in value.items():
            yield from _paths(item, (*prefix, key))
    elif isinstance(value, list):
        for index, item in enumerate(value):
            yield from _paths(item, (*prefix, index))


PATHS = [path for path in _paths(FLOOR) if path]
MISSPELT = [("corridor_widht",), ("defaults", "corridor_widht"), ("corridors", 0, "widht"), ("places", 1, "nmae"),
            ("palettes", 0, "markre"), ("nodes", "D"), ("nodes", "x]"), ("nodes", "n.m[0]"), ("routes", "extra")]


def _at(document, path):
    for key in path:
        document = document[key]
    return document


NUMERIC = [path for path in PATHS if isinstance(_at(FLOOR, path), (int, float))]


def _mutate(document, path, value) -> None:
    """Set (or with DELETE remove) the entry at ``path`` of ``document`` in place, where its parents exist."""
    *parents, last = path
    for key in parents:
        if isinstance(document, dict) and key in document or isinstance(document, list) and isinstance(key, int) \
                and key < len(document):
            document = document[key]
        else:
            return
    if not isinstance(document, (dict, list)) or isinstance(document, list) and not isinstance(last, int):
        return
    if value is DELETE:
        if isinstance(document, dict):
            document.pop(last, None)
        elif last < len(document):
            del document[last]
    elif isinstance(document, dict) or last < len(document):
        document[last] = value


def _toml(value) -> str:
    """``value`` as an inline TOML value."""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, int):
        return str(value)
    if isinstance(value, float):
        return "nan" if math.isnan(value) else ("inf" if value > 0 else "-inf") if math.isinf(value) else repr(value)
    if isinstance(value, str):
        return json.dumps(value, ensure_ascii=False)
    if isinstance(value, list):
        return "[" + ", ".join(_toml(item) for item in value) + "]"
    return "{" + ", ".join(f"{_toml(key)} = {_toml(item)}" for key, item in value.items()) + "}"


def _document_text(document: dict) -> str:
    """A floor file: each top-level key on its own line (arrays of tables as inline arrays)."""
    return "\n".join(f"{json.dumps(key)} = {_toml(value)}" for key, value in document.items()) + "\n"


@st.composite
def world_files(draw):
    holder = {"document": json.loads(json.dumps(FLOOR))}
    for _ in range(draw(st.integers(1, 3))):
        path, value = draw(st.one_of(st.tuples(st.sampled_from(PATHS + MISSPELT), values),
                                     st.tuples(st.sampled_from(NUMERIC), numbers)))
        _mutate(holder, ("document", *path), value)
    return _document_text(holder["document"]) if isinstance(holder["document"], dict) else "document = 1\n"


def _check_cheap_pipeline(floor) -> None:
    """What a parsed floor promises: bounded values, and every MuJoCo-free step of the pipeline runs."""
    points = np.array(list(floor.nodes.values()))
    assert np.all(np.abs(points) <= MAX_EXTENT)
    xmin, ymin, xmax, ymax = floor.bounds()
    assert max(xmax - xmin, ymax - ymin) <= MAX_EXTENT
    assert 0 < floor.speed <= MAX_SPEED and 0 < floor.detection_radius <= MAX_EXTENT
    assert all(2 * ROBOT_CLEARANCE <= c.width <= MAX_EXTENT and 0 < c.wall_height <= MAX_EXTENT
               for c in floor.corridors)
    assert 0 <= floor.lateral_jitter <= min(c.width for c in floor.corridors) / 2 - ROBOT_CLEARANCE
    rng = np.random.default_rng(0)
    for route in floor.routes:
        path, _ = resample_polyline(floor.route_points(route), 0.05)
        assert np.isfinite(floor.route_length(route))
        steps = control_steps(floor.route_length(route), floor.speed, ControllerConfig())
        assert np.isfinite(steps) and steps >= 0
        if steps <= MAX_CONTROL_STEPS:
            detect(np.column_stack([path, np.zeros(len(path))]), floor.places, floor.detection_radius, rng)
    for place_id in floor.places:
        assert np.isfinite(floor.place_frame(place_id))
    palette_of_place = assign_palettes(floor, 0.5, rng)
    assert set(palette_of_place) == set(floor.places)
    if max(xmax - xmin, ymax - ymin) <= 50.0:  # a larger floor rasterises in seconds, not in a fuzz example
        rasterise(floor, 0.25)
        palettes = (*floor.palettes, GREY)  # palette_library adds generated ones: costly, and not the floor's
        build_mjcf(floor, {place: palettes[index % len(palettes)] for place, index in palette_of_place.items()},
                   RigConfig(image_height=8, image_width=8))


@SETTINGS
@given(world_files())
def test_any_world_file_parses_into_a_bounded_floor_or_names_its_source(text):
    try:
        floor = parse_floorplan(text, source=SOURCE)
    except ValueError as error:
        assert str(error).startswith(f"{SOURCE}:") or str(error).startswith(f"{SOURCE} "), str(error)
        return
    _check_cheap_pipeline(floor)


@SETTINGS
@given(world_files(), st.data())
def test_a_damaged_world_file_loads_or_names_its_file(text, data):
    raw = bytearray(text.encode())
    for _ in range(data.draw(st.integers(1, 4))):
        position = data.draw(st.integers(0, len(raw) - 1))
        raw[position:position + data.draw(st.integers(0, 3))] = data.draw(st.binary(max_size=3))
    with tempfile.TemporaryDirectory() as folder:
        path = Path(folder) / "damaged.toml"
        path.write_bytes(bytes(raw))
        try:
            floor = load_world(path)
        except ValueError as error:
            assert str(error).startswith(str(path)), str(error)
            return
    _check_cheap_pipeline(floor)


GRID_ARGUMENTS = ("rows", "cols", "loops", "place_density", "seed", "spacing", "corridor_width", "wall_height",
                  "detection_radius", "speed")
grid_values = st.one_of(extreme, st.floats(allow_nan=True, allow_infinity=True), st.booleans(), st.text(max_size=2),
                        st.none(), st.integers(-3, 6))


@SETTINGS
@given(st.dictionaries(st.sampled_from(GRID_ARGUMENTS), grid_values, max_size=3))
def test_a_grid_of_any_arguments_is_a_bounded_floor_or_a_named_error(changes):
    try:
        floor = corridor_grid(**{"rows": 3, "cols": 3, "loops": 1, "place_density": 0.5, "seed": 0, **changes})
    except (ValueError, TypeError) as error:
        assert any(name in str(error) for name in GRID_ARGUMENTS), str(error)
        return
    _check_cheap_pipeline(floor)
