"""Bad world input (issue 47): unknown keys, wrong types, extreme values and unmeetable requests end in a
``ValueError`` that names the file, the key and the limit -- never a silent default, a raw traceback, a
petabyte allocation or a simulation without end."""

import numpy as np
import pytest

from ptm_bench.cli import main
from ptm_bench.evaluation.experiment import load_experiment
from ptm_bench.simulation import generate
from ptm_bench.simulation.detector import detect
from ptm_bench.simulation.robot import RigConfig
from ptm_bench.world.floorplan import WORLDS_DIR, corridor_grid, load_world, parse_floorplan

SHORT_LOOP = (WORLDS_DIR / "short_loop.toml").read_text()
SMALL = RigConfig(image_height=24, image_width=32)


def _refused(text: str, *fragments: str) -> str:
    """The message of the ValueError parsing ``text`` as ``w.toml`` raises; it names the file and each fragment."""
    with pytest.raises(ValueError) as error:
        parse_floorplan(text, source="w.toml")
    message = str(error.value)
    assert message.startswith("w.toml"), message
    for fragment in fragments:
        assert fragment in message, message
    return message


# -- 1: an unknown key is refused at every level, with its path and line ------------------------------------


@pytest.mark.parametrize("old, new, path, line", [
    ("corridor_width = 1.2", "corridor_widht = 1.2", "defaults.corridor_widht", 8),
    ('from = "A"\nto = "B"', 'from = "A"\nto = "B"\nwidht = 3.0', "corridors[0].widht", 23),
    ('id = 1\nnode = "B"', 'id = 1\nnode = "B"\nnmae = "x"', "places[1].nmae", 43),
    ('name = "short_loop"', 'name = "short_loop"\nspeed = 0.5', "speed", 5),
])
def test_a_typo_in_any_table_of_a_world_is_refused_with_its_path_and_line(old, new, path, line):
    assert old in SHORT_LOOP
    _refused(SHORT_LOOP.replace(old, new, 1), f"w.toml:{line}: {path}: unknown key")


def test_a_typo_in_a_palette_is_refused():
    palette = '\n[[palettes]]\nsectors = [[0.1, 0.1, 0.1], [0.5, 0.5, 0.5], [0.9, 0.9, 0.9], [0.3, 0.3, 0.3]]\n' \
              'marker = [0.2, 0.2, 0.2]\nmarkre = [0.2, 0.2, 0.2]\n'
    _refused(SHORT_LOOP + palette, "palettes[0].markre: unknown key", "expected one of sectors, marker")


# -- 10: values of the wrong type ----------------------------------------------------------------------------


def _without_corridor_tables(text: str) -> str:
    return text.split("[[corridors]]")[0] + "[[places]]" + text.split("[[places]]", 1)[1]


@pytest.mark.parametrize("text, fragments", [
    (_without_corridor_tables(SHORT_LOOP).replace("\n[defaults]", "\ncorridors = [1, 2]\n[defaults]"),
     ("corridors[0]: must be a [[corridors]] table, got 1",)),
    (SHORT_LOOP.replace("\n[defaults]", '\npalettes = "red"\n[defaults]'),
     ("w.toml:7: palettes: must be an array of [[palettes]] tables, got 'red'",)),
    (SHORT_LOOP.replace('main = ["A"', 'main = [["A"]'), ("routes.main: unknown node ['A'] at position 0",)),
    (SHORT_LOOP.replace('from = "A"', 'from = ["A"]', 1), ("corridors[0].from: unknown node ['A']",)),
    (SHORT_LOOP.replace('node = "A"', 'node = {x = 1}', 1), ("places[0].node: unknown node {'x': 1}",)),
    (SHORT_LOOP.replace('description = "short', 'description = ["short').replace('detections)"', 'detections)"]'),
     ("description: must be a string",)),
    (SHORT_LOOP.split("[defaults]")[0] + "defaults = 3\n\n[nodes]" + SHORT_LOOP.split("[nodes]")[1],
     ("w.toml:7: defaults: must be a [defaults] table, got 3",)),
])
def test_a_value_of_the_wrong_type_is_a_value_error_naming_the_file_and_key(text, fragments):
    _refused(text, *fragments)


def test_a_world_of_the_wrong_type_is_a_clear_error_through_the_demo(tmp_path, capsys):
    world = tmp_path / "red.toml"
    world.write_text(SHORT_LOOP.replace("\n[defaults]", '\npalettes = "red"\n[defaults]'))
    assert main(["demo", "--world", str(world), "--out", str(tmp_path / "out"), "--workers", "1"]) == 2
    error = capsys.readouterr().err
    assert f"{world}:7: palettes: must be an array of [[palettes]] tables" in error and "Traceback" not in error


def test_a_string_for_the_worlds_of_a_sweep_names_the_file_and_the_key(tmp_path):
    config = tmp_path / "exp.toml"
    config.write_text('[sweep]\nworlds = "short_loop"\nseeds = [0]\n')
    with pytest.raises(ValueError, match=f"^{config}: sweep.worlds must be a non-empty list") as error:
        load_experiment(config)
    assert "'s'" not in str(error.value)


def test_a_floor_file_that_is_not_text_names_the_file(tmp_path):
    world = tmp_path / "binary.toml"
    world.write_bytes(b"name = \xff\xfe")
    with pytest.raises(ValueError, match=f"^{world}: not a UTF-8 text file"):
        load_world(world)


# -- 11: what a world may ask for is bounded, the limit in the message ---------------------------------------


@pytest.mark.parametrize("old, new, fragment", [
    ("C = [2.0, 2.0]", "C = [2.0, 2e7]", "w.toml:17: nodes.C: [2.0, 20000000.0] lies farther than MAX_EXTENT = 500 m"),
    ("A = [0.0, 0.0]\nB = [2.0, 0.0]", "A = [-300.0, 0.0]\nB = [300.0, 0.0]",
     "nodes: the floor spans 601.2 m (its nodes, and the widest corridor), more than MAX_EXTENT = 500 m"),
    ("corridor_width = 1.2", "corridor_width = 1e6", "w.toml:8: defaults.corridor_width: must be at most MAX_EXTENT"),
    ("corridor_width = 1.2", "corridor_width = 0.1", "defaults.corridor_width: must be at least 2 x ROBOT_CLEARANCE"),
    ("wall_height = 2.2", "wall_height = 1e300", "defaults.wall_height: must be at most MAX_EXTENT = 500 m"),
    ("speed = 0.6", "speed = 1e9", "w.toml:11: defaults.speed: must be at most MAX_SPEED = 3 m/s, got 1000000000.0"),
    ("lateral_jitter = 0.1", "lateral_jitter = 1e300", "defaults.lateral_jitter: must be at most MAX_EXTENT"),
    ("lateral_jitter = 0.1", "lateral_jitter = 2.0", "defaults.lateral_jitter: 2 m would move the route into the"),
    ("A = [0.0, 0.0]", "A = [0.0, 0.0]\nE = [0.0, 0.0]", ""),  # a node on another is fine ...
])
def test_extreme_world_values_are_refused_with_the_limit(old, new, fragment):
    assert old in SHORT_LOOP
    text = SHORT_LOOP.replace(old, new, 1)
    if not fragment:
        parse_floorplan(text)
        text += '\n[[corridors]]\nfrom = "A"\nto = "E"\n'  # ... a corridor between them is not
        fragment = "corridors[4].to: a corridor must join two nodes at different points"
    _refused(text, fragment)


@pytest.mark.parametrize("arguments, error, fragment", [
    ({"spacing": 1e7}, ValueError, "more than MAX_EXTENT = 500 m"),
    ({"rows": 1000, "cols": 1000}, ValueError, "more than MAX_GRID_NODES = 4096"),
    ({"speed": 1e9}, ValueError, "speed must be at most MAX_SPEED"),
    ({"wall_height": 1e300}, ValueError, "wall_height must be at most MAX_EXTENT"),
    ({"corridor_width": 0.01, "spacing": 0.05}, ValueError, "corridor_width must be at least 2 x ROBOT_CLEARANCE"),
    ({"spacing": "6"}, TypeError, "spacing must be a number"),
    ({"seed": "x"}, TypeError, "seed must be an integer"),
])
def test_extreme_grid_arguments_are_refused_with_the_limit(arguments, error, fragment):
    with pytest.raises(error, match=fragment):
        corridor_grid(**{"rows": 3, "cols": 3, "loops": 1, "place_density": 0.5, "seed": 0, **arguments})


# -- 14: the work of a drive is estimated before it is simulated ---------------------------------------------


def test_a_drive_past_the_step_limit_is_refused_before_it_is_simulated(tmp_path, monkeypatch):
    def simulated(*args, **kwargs):
        raise AssertionError("the drive was simulated")

    monkeypatch.setattr(generate, "build_world", simulated)
    monkeypatch.setattr(generate, "drive", simulated)
    world = tmp_path / "crawl.toml"
    world.write_text(SHORT_LOOP.replace("speed = 0.6", "speed = 1e-9"))
    with pytest.raises(ValueError) as error:
        generate.generate_dataset(world, 0.0, 1.0, 0, images=False, rig=SMALL)
    message = str(error.value)
    assert f"driving short_loop ({world})" in message and "1.6e+11 control steps" in message
    assert "MAX_CONTROL_STEPS = 500000" in message


# -- 2: a false-detection rate the route cannot meet is said so ----------------------------------------------


def _line(length=10.0, count=201):
    xs = np.linspace(0.0, length, count)
    return np.column_stack([xs, np.zeros_like(xs), np.zeros_like(xs)])


def test_a_false_rate_on_a_path_that_never_leaves_the_places_is_refused():
    places = {0: (0.0, 0.5), 1: (2.0, 0.5), 2: (4.0, 0.5)}  # every point of the 4 m path is within 2 m of one
    with pytest.raises(ValueError, match=r"false_rate: 1000 per metre cannot be met: the path never runs farther "
                                         r"than twice the detection radius \(2 m\)"):
        detect(_line(4.0, 81), places, 1.0, np.random.default_rng(0), false_rate=1000.0)


@pytest.mark.parametrize("rate", [1000.0, float("inf")])
def test_a_false_rate_above_one_per_step_is_refused(rate):
    with pytest.raises(ValueError, match=r"at most one false detection fires per step, and the path covers up to "
                                         r"0.05 m in one, so the rate is at most 20 per metre"):
        detect(_line(), {0: (0.0, 50.0)}, 1.0, np.random.default_rng(0), false_rate=rate)


def test_generate_names_the_world_whose_route_cannot_meet_the_false_rate():
    with pytest.raises(ValueError, match=r"^world short_loop \(.*short_loop.toml\): false_rate: 1000 per metre "
                                         r"cannot be met: the path never runs farther than twice"):
        generate.generate_dataset("short_loop", 0.0, 1.0, 0, images=False, rig=SMALL, false_rate=1000.0)
