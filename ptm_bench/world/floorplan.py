"""Floor plans: corridor-and-loop worlds read from TOML, presets, a procedural grid, palettes.

A floor (docs/model.md §5) is a graph of junction nodes joined by straight corridors
(width, wall height), a set of *places* (ids and positions where the landmark
detector fires), appearance *palettes*, and *routes* (node sequences the robot
drives). This module parses and validates the TOML files in ``worlds/``
(errors name the file, the key and its line; an unknown key is refused at every
level, and what a floor may ask for is bounded: :data:`MAX_EXTENT`,
:data:`MAX_SPEED`), generates corridor grids for sweeps, and
implements the aliasing map of docs/model.md §5: P places receive
``C = max(1, round(1 + (1 - a)(P - 1)))`` distinct palettes.

    >>> floor = load_world("nested_loops")
    >>> len(floor.places), round(floor.route_length(), 1)
    (8, 192.0)
    >>> palette_count(len(floor.places), aliasing=0.5)
    5
"""

from __future__ import annotations

import importlib.resources
import math
import numbers
import re
import reprlib
import tomllib
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import scipy.sparse
import scipy.sparse.csgraph

from ptm._validation import count as whole_number, positive
from ptm.features import fourier_signature, grayscale

__all__ = [
    "Corridor",
    "FLOOR_KEYS",
    "Floorplan",
    "MAX_EXTENT",
    "MAX_GRID_NODES",
    "MAX_SPEED",
    "Palette",
    "WORLDS_DIR",
    "resample_polyline",
    "assign_palettes",
    "corridor_grid",
    "list_worlds",
    "load_world",
    "palette_count",
    "palette_library",
    "palette_signature",
    "parse_floorplan",
]

#: The preset floors: the repository's ``worlds/`` folder, installed as the package ``ptm_bench.world.presets``.
WORLDS_DIR = Path(str(importlib.resources.files("ptm_bench.world.presets")))
SECTOR_COUNT = 4  # a place's decor: four panels at its diagonals, one palette colour each
ROBOT_CLEARANCE = 0.3  # [m] a place must leave this much room to the walls; a corridor, this much on each side
#: [m] The most any length of a floor may be: every node lies within MAX_EXTENT of the origin along x and y, the
#: floor spans at most MAX_EXTENT along each (nodes and corridor widths: ``Floorplan.bounds``), and a width, a
#: wall height or the detection radius is at most MAX_EXTENT. The scene compiler rasterises the floor at 0.25 m:
#: at most 2000 x 2000 cells (tens of MB a corridor), where a 2e7 m floor asked for petabytes.
MAX_EXTENT = 500.0
#: [m/s] The fastest a floor may drive its route: the controller (``ptm_bench.simulation.robot``, 0.6 m look-ahead
#: every 0.1 s) keeps the base within 0.15 m of the route's corners up to 3 m/s, misses them by 0.4 m at 5 m/s and
#: loses the route at 15 m/s.
MAX_SPEED = 3.0
#: The most nodes a procedural grid (:func:`corridor_grid`) may have: its route takes one breadth-first search
#: per node, quadratic in their number (64 x 64, the scale benchmark's largest grid at --scale 16: about 3 s).
MAX_GRID_NODES = 4096
# What a camera sees (compiled by ptm_bench.simulation.scene): walls, floor and ceiling are one matte grey,
# evenly lit, fading into a haze of the same grey, so the corridor layout is invisible; a place's
# decor -- four panels at its diagonals, DECOR_RADIUS_PER_WIDTH x the narrowest corridor width
# away, each PANEL_WIDTH_PER_RADIUS x that radius wide -- is all that tells places apart.
SURROUNDINGS_RGB = (0.55, 0.55, 0.55)
SURROUNDINGS_LUMA = 0.55
DECOR_RADIUS_PER_WIDTH = 0.425
PANEL_WIDTH_PER_RADIUS = 1.0
PANEL_HALF_ANGLE_DEG = math.degrees(math.atan(PANEL_WIDTH_PER_RADIUS / 2))


@dataclass(frozen=True)
class Corridor:
    """A straight corridor between two nodes; walls run along both sides."""

    start: str
    end: str
    width: float
    wall_height: float

    def coordinates(self, nodes, points) -> tuple[np.ndarray, np.ndarray, float]:
        """(along, across, length): ``points`` (..., 2) in the corridor's frame, from its start node.

        ``along`` runs from the start node towards the end node (0 to
        ``length`` on the centreline), ``across`` to the left of that axis; the
        corridor's free space is |across| <= width / 2 with -width / 2 <= along <= length + width / 2.
        """
        start, end = np.asarray(nodes[self.start], dtype=float), np.asarray(nodes[self.end], dtype=float)
        length = float(np.linalg.norm(end - start))
        axis = (end - start) / length
        relative = np.asarray(points, dtype=float) - start
        return relative @ axis, relative @ np.array([-axis[1], axis[0]]), length


@dataclass(frozen=True)
class Palette:
    """The decor of a place: RGB colours of its four panels and of its floor marker.

    Panel j stands at bearing 45 + 90 j degrees seen from the place, measured
    from the place's frame (``Floorplan.place_frame``, fixed by the corridor
    layout), facing the place; so the pattern is a property of the place, not
    of the robot's heading, and places with one palette look alike.
    """

    sectors: tuple[tuple[float, float, float], ...]
    marker: tuple[float, float, float]

    def luminance(self) -> np.ndarray:
        """Luma of each panel colour (the quantity the grayscale signature sees)."""
        return grayscale(np.asarray(self.sectors)[None])[0]


@dataclass(frozen=True)
class Floorplan:
    """A validated floor: geometry, places, palettes and routes (docs/model.md §5)."""

    name: str
    nodes: dict[str, tuple[float, float]]
    corridors: tuple[Corridor, ...]
    places: dict[int, tuple[float, float]]
    routes: dict[str, tuple[str, ...]]
    palettes: tuple[Palette, ...] = ()
    detection_radius: float = 1.0
    speed: float = 1.0
    lateral_jitter: float = 0.2
    description: str = ""
    source: str = ""

    @property
    def min_place_spacing(self) -> float:
        """Smallest distance between two distinct places [m] (inf with one place)."""
        points = np.array(list(self.places.values()), dtype=float)
        if len(points) < 2:
            return math.inf
        gaps = np.linalg.norm(points[:, None, :] - points[None, :, :], axis=2)
        return float(gaps[np.triu_indices(len(points), 1)].min())

    @property
    def decor_radius(self) -> float:
        """Distance [m] of a place's decor panels from the place: a fixed share of the narrowest corridor."""
        return DECOR_RADIUS_PER_WIDTH * min(corridor.width for corridor in self.corridors)

    def route_points(self, route: str = "main") -> np.ndarray:
        """The (R, 2) waypoint coordinates of a route."""
        if route not in self.routes:
            raise ValueError(f"route: {self.name} has no route {route!r}; it has {sorted(self.routes)}")
        return np.array([self.nodes[node] for node in self.routes[route]], dtype=float)

    def route_length(self, route: str = "main") -> float:
        """Length of a route's polyline [m]."""
        points = self.route_points(route)
        return float(np.linalg.norm(np.diff(points, axis=0), axis=1).sum())

    def openings(self, point) -> list[float]:
        """Directions [rad] in which corridors leave ``point`` (both ways inside a corridor, outwards at a node)."""
        p = np.asarray(point, dtype=float)
        directions = []
        for corridor in self.corridors:
            along, across, length = corridor.coordinates(self.nodes, p)
            half = corridor.width / 2
            if abs(across) > half or not -half <= along <= length + half:
                continue
            dx, dy = np.subtract(self.nodes[corridor.end], self.nodes[corridor.start])
            heading = math.atan2(dy, dx)
            if along < length - half:
                directions.append(heading)
            if along > half:
                directions.append(heading + math.pi)
        return sorted(math.remainder(d, 2 * math.pi) for d in directions)

    def place_frame(self, place_id: int) -> float:
        """Orientation [rad] of a place's palette frame, fixed by its corridor layout.

        Among the corridor openings at the place, the one from which the other
        openings look the same for congruent layouts is chosen (the rotation
        giving the lexicographically smallest sorted list of relative
        directions), so two places with the same layout and the same palette
        look alike up to a rotation of the robot -- which is what aliasing means.
        """
        openings = self.openings(self.places[place_id])
        if not openings:
            return 0.0

        def relative(reference):
            return tuple(sorted(round(math.degrees((d - reference) % (2 * math.pi)), 3) % 360 for d in openings))

        return min(openings, key=lambda reference: (relative(reference), reference))

    def bounds(self) -> tuple[float, float, float, float]:
        """(xmin, ymin, xmax, ymax) of the free space, walls excluded."""
        points = np.array(list(self.nodes.values()), dtype=float)
        margin = max(corridor.width for corridor in self.corridors) / 2
        return (*(points.min(axis=0) - margin), *(points.max(axis=0) + margin))


def resample_polyline(waypoints, spacing: float) -> tuple[np.ndarray, np.ndarray]:
    """The polyline through ``waypoints`` sampled at most ``spacing`` metres apart, and where its corners landed.

    Returns (points, segment_ends): every segment of non-zero length is cut
    into equal pieces no longer than ``spacing`` (both its ends kept), and
    ``segment_ends[k]`` is the index in ``points`` of the end of the k-th
    such segment (the waypoints themselves, after zero-length segments are dropped).
    """
    waypoints = np.asarray(waypoints, dtype=float)
    segments = np.diff(waypoints, axis=0)
    lengths = np.linalg.norm(segments, axis=1)
    keep = lengths > 1e-9
    counts = np.maximum(1, np.ceil(lengths[keep] / spacing).astype(int))
    pieces = [waypoints[:1]]
    for start, segment, count in zip(waypoints[:-1][keep], segments[keep], counts):
        pieces.append(start + segment * (np.arange(1, count + 1) / count)[:, None])
    return np.concatenate(pieces), np.cumsum(counts)


# -- loading ---------------------------------------------------------------------------------


def list_worlds() -> list[str]:
    """Names of the preset floors in ``worlds/``."""
    return sorted(path.stem for path in WORLDS_DIR.glob("*.toml"))


def load_world(name_or_path) -> Floorplan:
    """A preset by name (``"office"``) or a floor file by path; a Floorplan passes through."""
    if isinstance(name_or_path, Floorplan):
        return name_or_path
    text = str(name_or_path)
    path = Path(text)
    if path.suffix == ".toml" or path.is_file():
        if not path.is_file():
            raise ValueError(f"world: no floor file at {path}")
        return parse_floorplan(_read_text(path), source=str(path))
    known = list_worlds()
    if text not in known:
        raise ValueError(f"world: unknown world {text!r}; known worlds: {', '.join(known)}")
    return parse_floorplan(_read_text(WORLDS_DIR / f"{text}.toml"), source=str(WORLDS_DIR / f"{text}.toml"))


def _read_text(path: Path) -> str:
    """A floor file's text (UTF-8, a byte-order mark allowed); a ``ValueError`` naming the file if it is not text."""
    try:
        return path.read_bytes().decode("utf-8-sig")
    except UnicodeDecodeError as error:
        raise ValueError(f"{path}: not a UTF-8 text file ({error.reason} at byte {error.start})") from None


def parse_floorplan(text: str, source: str = "<string>") -> Floorplan:
    """Parse and validate a floor described in TOML; errors say ``source:line: field: problem``."""
    if not isinstance(text, str):
        raise TypeError(f"text: a floor is TOML text (str), got {type(text).__name__} from {source}")
    try:
        document = tomllib.loads(text)
    except tomllib.TOMLDecodeError as error:
        raise ValueError(f"{source}: malformed TOML: {error}") from None
    reader = _Reader(document, _KeyLines(text), source)
    return reader.floorplan()


class _KeyLines:
    """Line numbers of TOML keys, e.g. ``corridors[2].width`` -> 17, found by a line scan."""

    _HEADER = re.compile(r"^\s*(\[\[?)\s*([A-Za-z0-9_.\-]+)\s*\]\]?")
    _KEY = re.compile(r"^\s*([A-Za-z0-9_\-]+|\"[^\"]*\")\s*=")
    _ENTRY = re.compile(r"(.+)\[\d+\]")

    def __init__(self, text: str):
        self.lines: dict[str, int] = {}
        table = ""
        counts: dict[str, int] = {}
        for number, line in enumerate(text.splitlines(), start=1):
            header = self._HEADER.match(line)
            if header:
                name = header.group(2)
                if header.group(1) == "[[":
                    index = counts.get(name, 0)
                    counts[name] = index + 1
                    table = f"{name}[{index}]"
                else:
                    table = name
                self.lines.setdefault(table, number)
                continue
            key = self._KEY.match(line)
            if key:
                path = f"{table}.{key.group(1).strip(chr(34))}" if table else key.group(1).strip('"')
                self.lines.setdefault(path, number)

    def line(self, path: str) -> int | None:
        """The line of ``path`` or of its closest enclosing table."""
        while path:
            if path in self.lines:
                return self.lines[path]
            entry = self._ENTRY.fullmatch(path)  # an entry of an inline array: the array's line
            path = entry.group(1) if entry else path.rpartition(".")[0]
        return None


#: The keys of each table of a floor file (``[nodes]`` and ``[routes]`` name their own keys); any other is refused.
FLOOR_KEYS = {
    "": ("name", "description", "defaults", "nodes", "corridors", "places", "palettes", "routes"),
    "defaults": ("corridor_width", "wall_height", "detection_radius", "speed", "lateral_jitter"),
    "corridors": ("from", "to", "width", "wall_height"),
    "places": ("id", "node", "at"),
    "palettes": ("sectors", "marker"),
}
_LENGTH = (MAX_EXTENT, "MAX_EXTENT", "m")  # the bound of a length, its name and its unit
_SPEED = (MAX_SPEED, "MAX_SPEED", "m/s")


class _Reader:
    """Typed access to the parsed TOML document with located error messages."""

    def __init__(self, document: dict, key_lines: _KeyLines, source: str):
        self.document = document
        self.key_lines = key_lines
        self.source = source

    def fail(self, path: str, problem: str):
        line = self.key_lines.line(path)
        where = f"{self.source}:{line}" if line else self.source
        raise ValueError(f"{where}: {path}: {problem}")

    def table(self, value, path: str, section: str | None = None) -> dict:
        """``value`` as a table; with a ``section`` of :data:`FLOOR_KEYS`, refusing the keys that section has not."""
        if not isinstance(value, dict):
            kind = f"a [[{section}]] table" if path.endswith("]") else f"a [{path}] table" if path else "a table"
            self.fail(path, f"must be {kind}, got {reprlib.repr(value)}")
        known = FLOOR_KEYS.get(section)
        for key in value:
            if known is not None and key not in known:
                self.fail(f"{path}.{key}" if path else key, f"unknown key (expected one of {', '.join(known)})")
        return value

    def rows(self, key: str, required: bool) -> list[tuple[str, dict]]:
        """The tables of the array of tables ``[[key]]``, each with its path, their keys checked."""
        rows = self.document.get(key, None if required else [])
        if not isinstance(rows, list) or (required and not rows):
            self.fail(key, f"must be {'a non-empty' if required else 'an'} array of [[{key}]] tables, "
                           f"got {reprlib.repr(rows)}")
        return [(f"{key}[{index}]", self.table(row, f"{key}[{index}]", key)) for index, row in enumerate(rows)]

    def number(self, table: dict, key: str, path: str, default: float, least: tuple | None = None,
               most: tuple = _LENGTH) -> float:
        """A finite number, > 0 (``least`` None) or >= ``least = (bound, what it is)``, at most the bound ``most``
        names."""
        if key not in table:
            return float(default)
        value = table[key]
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
            self.fail(path, f"must be a number, got {reprlib.repr(value)}")
        if least is None and value <= 0:
            self.fail(path, f"must be positive, got {value!r}")
        if least is not None and value < least[0]:
            self.fail(path, f"must be at least {least[1]}, got {value!r}")
        bound, name, unit = most
        if value > bound:
            self.fail(path, f"must be at most {name} = {bound:g} {unit}, got {value!r}")
        return float(value)

    def node(self, value, path: str, nodes: dict) -> str:
        """The name of a node of ``[nodes]``."""
        if not isinstance(value, str) or value not in nodes:
            self.fail(path, f"unknown node {reprlib.repr(value)}; nodes are {reprlib.repr(sorted(nodes))}")
        return value

    def point(self, value, path: str) -> tuple[float, float]:
        if (
            not isinstance(value, list)
            or len(value) != 2
            or not all(isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) for v in value)
        ):
            self.fail(path, f"must be a point [x, y] in metres, got {reprlib.repr(value)}")
        if max(abs(v) for v in value) > MAX_EXTENT:
            self.fail(path, f"{value} lies farther than MAX_EXTENT = {MAX_EXTENT:g} m from the origin")
        return float(value[0]), float(value[1])

    def colour(self, value, path: str) -> tuple[float, float, float]:
        if (
            not isinstance(value, list)
            or len(value) != 3
            or not all(isinstance(v, (int, float)) and not isinstance(v, bool) and 0 <= v <= 1 for v in value)
        ):
            self.fail(path, f"must be an RGB colour [r, g, b] in [0, 1], got {reprlib.repr(value)}")
        return float(value[0]), float(value[1]), float(value[2])

    def floorplan(self) -> Floorplan:
        document = self.table(self.document, "", "")
        name = document.get("name")
        if not isinstance(name, str) or not name:
            self.fail("name", f"must be a non-empty string, got {reprlib.repr(name)}")
        description = document.get("description", "")
        if not isinstance(description, str):
            self.fail("description", f"must be a string, got {reprlib.repr(description)}")
        defaults = self.table(document.get("defaults", {}), "defaults", "defaults")
        narrowest = (2 * ROBOT_CLEARANCE, f"2 x ROBOT_CLEARANCE = {2 * ROBOT_CLEARANCE:g} m (room for the robot)")
        width = self.number(defaults, "corridor_width", "defaults.corridor_width", 2.0, least=narrowest)
        height = self.number(defaults, "wall_height", "defaults.wall_height", 2.5)
        radius = self.number(defaults, "detection_radius", "defaults.detection_radius", 1.0)
        speed = self.number(defaults, "speed", "defaults.speed", 1.0, most=_SPEED)
        jitter = self.number(defaults, "lateral_jitter", "defaults.lateral_jitter", 0.2, least=(0.0, "0 m"))

        nodes_table = self.table(document.get("nodes"), "nodes")
        if not nodes_table:
            self.fail("nodes", "must be a table of node = [x, y] entries")
        nodes = {key: self.point(value, f"nodes.{key}") for key, value in nodes_table.items()}

        corridors = []
        for path, row in self.rows("corridors", required=True):
            start, end = (self.node(row.get(key), f"{path}.{key}", nodes) for key in ("from", "to"))
            if not np.linalg.norm(np.subtract(nodes[end], nodes[start])) > 0:  # Corridor.coordinates divides by it
                self.fail(f"{path}.to", f"a corridor must join two nodes at different points, got {start!r} and "
                                        f"{end!r} at {nodes[start]}")
            corridors.append(
                Corridor(
                    start,
                    end,
                    self.number(row, "width", f"{path}.width", width, least=narrowest),
                    self.number(row, "wall_height", f"{path}.wall_height", height),
                )
            )
        self.check_extent(nodes, corridors)
        room = min(corridor.width for corridor in corridors) / 2 - ROBOT_CLEARANCE
        if jitter > room:
            self.fail("defaults.lateral_jitter", f"{jitter:g} m would move the route into the walls: at most half "
                                                 f"the narrowest corridor less ROBOT_CLEARANCE, {room:.3g} m")

        places: dict[int, tuple[float, float]] = {}
        for path, row in self.rows("places", required=True):
            place_id = row.get("id")
            if isinstance(place_id, bool) or not isinstance(place_id, int) or place_id < 0:
                self.fail(f"{path}.id", f"must be a non-negative integer, got {reprlib.repr(place_id)}")
            if place_id in places:
                self.fail(f"{path}.id", f"duplicate place id {place_id}")
            if ("node" in row) == ("at" in row):
                self.fail(path, "give exactly one of node = NAME or at = [x, y]")
            if "node" in row:
                places[place_id] = nodes[self.node(row["node"], f"{path}.node", nodes)]
            else:
                places[place_id] = self.point(row["at"], f"{path}.at")
            clearance = _clearance(places[place_id], nodes, corridors)
            if clearance < ROBOT_CLEARANCE:
                self.fail(path, f"place {place_id} at {places[place_id]} is not inside a corridor")

        palettes = []
        for path, row in self.rows("palettes", required=False):
            sectors = row.get("sectors")
            if not isinstance(sectors, list) or len(sectors) != SECTOR_COUNT:
                self.fail(f"{path}.sectors", f"must list {SECTOR_COUNT} RGB colours, got {reprlib.repr(sectors)}")
            palettes.append(
                Palette(
                    tuple(self.colour(colour, f"{path}.sectors") for colour in sectors),
                    self.colour(row.get("marker"), f"{path}.marker"),
                )
            )

        route_table = self.table(document.get("routes"), "routes")
        if "main" not in route_table:
            self.fail("routes", "must be a table with at least a `main = [node, ...]` route")
        linked = {frozenset((c.start, c.end)) for c in corridors}
        routes = {}
        for route_name, sequence in route_table.items():
            path = f"routes.{route_name}"
            if not isinstance(sequence, list) or len(sequence) < 2:
                self.fail(path, f"must list at least two nodes, got {reprlib.repr(sequence)}")
            for step, node in enumerate(sequence):
                if not isinstance(node, str) or node not in nodes:
                    self.fail(path, f"unknown node {reprlib.repr(node)} at position {step}")
                if step and frozenset((sequence[step - 1], node)) not in linked:
                    self.fail(path, f"no corridor between {sequence[step - 1]!r} and {node!r}")
            routes[route_name] = tuple(sequence)

        floor = Floorplan(
            name=name,
            nodes=nodes,
            corridors=tuple(corridors),
            places=places,
            routes=routes,
            palettes=tuple(palettes),
            detection_radius=radius,
            speed=speed,
            lateral_jitter=jitter,
            description=description,
            source=self.source,
        )
        if 2 * radius >= floor.min_place_spacing:
            self.fail(
                "defaults.detection_radius",
                f"{radius} m is too large: two places are only {floor.min_place_spacing:.2f} m apart "
                "(the radius must be under half the smallest spacing)",
            )
        return floor

    def check_extent(self, nodes: dict, corridors: list) -> None:
        """Refuse a floor wider or longer than :data:`MAX_EXTENT`, its nodes and corridor widths included."""
        points = np.array(list(nodes.values()))
        span = float((points.max(axis=0) - points.min(axis=0)).max()) + max(c.width for c in corridors)
        if span > MAX_EXTENT:
            self.fail("nodes", f"the floor spans {span:.4g} m (its nodes, and the widest corridor), more than "
                               f"MAX_EXTENT = {MAX_EXTENT:g} m")


def _clearance(point, nodes, corridors) -> float:
    """How far ``point`` is inside the free space (negative: outside), from corridor centrelines."""
    best = -math.inf
    for corridor in corridors:
        along, across, length = corridor.coordinates(nodes, point)
        distance = math.hypot(across, max(0.0, -along, along - length))  # to the centreline segment
        best = max(best, corridor.width / 2 - distance)
    return best


# -- aliasing: palettes ------------------------------------------------------------------------


def palette_count(n_places: int, aliasing: float) -> int:
    """docs/model.md §5: ``C = max(1, round(1 + (1 - a)(P - 1)))`` distinct palettes for P places."""
    if isinstance(aliasing, bool) or not isinstance(aliasing, (int, float)) or not 0.0 <= aliasing <= 1.0:
        raise ValueError(f"aliasing must be a number in [0, 1], got {aliasing!r}")
    if n_places < 1:
        raise ValueError(f"n_places must be >= 1, got {n_places}")
    return max(1, math.floor(1 + (1 - aliasing) * (n_places - 1) + 0.5))  # round half up, not to even


def palette_library(count: int, rng: np.random.Generator, given=()) -> tuple[Palette, ...]:
    """``count`` palettes: the ``given`` ones first, then generated ones chosen to look different.

    Candidates are scored by the Fourier signature of their idealised ring of
    sector luminances; each new palette is the candidate farthest from those
    already chosen (greedy farthest-point selection), so distinct palettes
    stay distinguishable by the 5-coefficient signature.
    """
    chosen = list(given)[:count]
    if len(chosen) == count:
        return tuple(chosen)
    levels = np.linspace(0.12, 0.92, 5)
    pool = []
    for _ in range(64 * count):
        luminances = rng.choice(levels, size=SECTOR_COUNT)
        sectors = tuple(_colour_with_luminance(rng, value) for value in luminances)
        marker = _colour_with_luminance(rng, rng.choice(levels))
        pool.append(Palette(sectors, marker))
    pool_signatures = np.array([palette_signature(p) for p in pool])
    chosen_signatures = [palette_signature(p) for p in chosen]
    if not chosen:
        chosen.append(pool[0])
        chosen_signatures.append(pool_signatures[0])
    while len(chosen) < count:
        gaps = np.linalg.norm(pool_signatures[:, None, :] - np.array(chosen_signatures)[None], axis=2).min(axis=1)
        best = int(np.argmax(gaps))
        chosen.append(pool[best])
        chosen_signatures.append(pool_signatures[best])
    return tuple(chosen)


def assign_palettes(floor: Floorplan, aliasing: float, rng: np.random.Generator) -> dict[int, int]:
    """Place id -> palette index, using exactly ``palette_count(P, aliasing)`` distinct palettes.

    A random set of C places receives one palette each; every other place gets
    a uniformly drawn palette among those C.
    """
    place_ids = sorted(floor.places)
    count = palette_count(len(place_ids), aliasing)
    order = rng.permutation(len(place_ids))
    assignment = np.empty(len(place_ids), dtype=int)
    assignment[order[:count]] = np.arange(count)
    assignment[order[count:]] = rng.integers(0, count, size=len(place_ids) - count)
    return {place_id: int(index) for place_id, index in zip(place_ids, assignment)}


def _colour_with_luminance(rng: np.random.Generator, luminance: float) -> tuple[float, float, float]:
    """A random hue scaled so that its luma is ``luminance`` (clipped to the RGB cube)."""
    direction = rng.uniform(0.2, 1.0, size=3)
    rgb = direction * luminance / grayscale(direction[None, None])[0, 0]
    return tuple(float(v) for v in np.clip(rgb, 0.0, 1.0))


def palette_signature(palette: Palette, samples: int = 360) -> np.ndarray:
    """The 5-coefficient Fourier magnitudes of a palette's idealised ring: four panels on the haze."""
    bearings = (np.arange(samples) + 0.5) * 360.0 / samples
    ring = np.full(samples, SURROUNDINGS_LUMA)
    for index, luma in enumerate(palette.luminance()):
        offset = np.abs((bearings - (45.0 + 90.0 * index) + 180.0) % 360.0 - 180.0)
        ring[offset <= PANEL_HALF_ANGLE_DEG] = luma
    return fourier_signature(ring[None, :], k=5)


# -- procedural corridor grids -------------------------------------------------------------------


def corridor_grid(
    rows: int,
    cols: int,
    loops: int,
    place_density: float,
    seed: int,
    spacing: float = 6.0,
    corridor_width: float = 2.0,
    wall_height: float = 2.5,
    detection_radius: float = 1.0,
    speed: float = 1.0,
) -> Floorplan:
    """A random corridor grid for sweeps.

    Nodes sit on a ``rows x cols`` lattice ``spacing`` metres apart. A random
    spanning tree of the lattice is carved, then ``loops`` extra lattice edges
    are opened (each adds one independent cycle). Each node is a place with
    probability ``place_density`` (at least two places). The route visits the
    nodes in depth-first order of the tree, moving between them by shortest
    paths through the whole graph (so loops get closed), and returns home.
    The arguments are bounded as a floor file's values are: at most
    :data:`MAX_GRID_NODES` nodes spanning at most :data:`MAX_EXTENT`, corridors
    at least 2 x ``ROBOT_CLEARANCE`` wide, a speed of at most :data:`MAX_SPEED`.
    """
    for label, value, low in (("rows", rows, 1), ("cols", cols, 1), ("loops", loops, 0)):
        if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < low:
            raise ValueError(f"{label} must be an integer >= {low}, got {value!r}")
    if rows * cols < 2:
        raise ValueError("a corridor grid needs at least two nodes (rows * cols >= 2)")
    if rows * cols > MAX_GRID_NODES:
        raise ValueError(f"rows x cols: a {rows}x{cols} grid has {rows * cols} nodes, more than MAX_GRID_NODES = "
                         f"{MAX_GRID_NODES}")
    positives = {"spacing": spacing, "corridor_width": corridor_width, "wall_height": wall_height,
                 "detection_radius": detection_radius, "speed": speed}
    for label, value in {"place_density": place_density, **positives}.items():
        if isinstance(value, bool) or not isinstance(value, numbers.Real):
            raise TypeError(f"{label} must be a number, got {value!r}")
    if not 0.0 <= place_density <= 1.0:
        raise ValueError(f"place_density must be in [0, 1], got {place_density!r}")
    for label, value in positives.items():
        positive(label, value)  # checked, not converted: the floor keeps the numbers as given
    if corridor_width < 2 * ROBOT_CLEARANCE:
        raise ValueError(f"corridor_width must be at least 2 x ROBOT_CLEARANCE = {2 * ROBOT_CLEARANCE:g} m (room for "
                         f"the robot), got {corridor_width!r}")
    span = spacing * (max(rows, cols) - 1) + corridor_width
    if span > MAX_EXTENT:
        raise ValueError(f"spacing: a {rows}x{cols} grid {spacing:g} m apart, corridors {corridor_width:g} m wide, "
                         f"spans {span:.4g} m, more than MAX_EXTENT = {MAX_EXTENT:g} m")
    if wall_height > MAX_EXTENT:
        raise ValueError(f"wall_height must be at most MAX_EXTENT = {MAX_EXTENT:g} m, got {wall_height!r}")
    if speed > MAX_SPEED:
        raise ValueError(f"speed must be at most MAX_SPEED = {MAX_SPEED:g} m/s, got {speed!r}")
    seed = whole_number("seed", seed, 0)
    if spacing <= 2 * detection_radius or spacing <= corridor_width:
        raise ValueError(f"spacing {spacing} m must exceed the corridor width and twice the detection radius")
    rng = np.random.default_rng(np.random.SeedSequence(seed))
    cells = [(r, c) for r in range(rows) for c in range(cols)]
    present = set(cells)
    lattice = sorted(
        {tuple(sorted((a, b))) for a in cells for b in ((a[0] + 1, a[1]), (a[0], a[1] + 1)) if b in present}
    )
    tree = _random_spanning_tree(cells, lattice, rng)
    spare = [edge for edge in lattice if edge not in tree]
    if loops > len(spare):
        raise ValueError(f"loops: a {rows}x{cols} grid has room for at most {len(spare)} loops, got {loops}")
    extra = [spare[i] for i in sorted(rng.choice(len(spare), size=loops, replace=False))]
    edges = sorted(tree) + extra
    name_of = {cell: f"n{cell[0]}_{cell[1]}" for cell in cells}
    nodes = {name_of[cell]: (cell[1] * spacing, cell[0] * spacing) for cell in cells}
    corridors = tuple(Corridor(name_of[a], name_of[b], corridor_width, wall_height) for a, b in edges)
    is_place = rng.random(len(cells)) < place_density
    if is_place.sum() < 2:
        is_place[rng.choice(len(cells), size=2, replace=False)] = True
    places = {i: nodes[name_of[cell]] for i, cell in enumerate(c for c, flag in zip(cells, is_place) if flag)}
    route = _tour(cells, tree, edges)
    return Floorplan(
        name=f"grid_{rows}x{cols}_loops{loops}_density{place_density:g}_seed{seed}",
        nodes=nodes,
        corridors=corridors,
        places=places,
        routes={"main": tuple(name_of[cell] for cell in route)},
        detection_radius=detection_radius,
        speed=speed,
        description=f"procedural corridor grid ({rows}x{cols}, {loops} loops, density {place_density:g})",
        source="corridor_grid",
    )


def _random_spanning_tree(cells, lattice, rng) -> set:
    """Randomised Kruskal: the minimum spanning tree when the lattice edges are weighted in a random order."""
    index = {cell: k for k, cell in enumerate(cells)}
    order = rng.permutation(len(lattice))  # edge order[k] is considered k-th, so it weighs k + 1
    weights = np.empty(len(lattice))
    weights[order] = np.arange(1, len(lattice) + 1)
    first, second = (np.array([index[edge[side]] for edge in lattice]) for side in (0, 1))
    graph = scipy.sparse.coo_matrix((weights, (first, second)), shape=(len(cells), len(cells)))
    tree = scipy.sparse.csgraph.minimum_spanning_tree(graph).tocoo()
    return {tuple(sorted((cells[a], cells[b]))) for a, b in zip(tree.row, tree.col)}


def _tour(cells, tree, edges) -> list:
    """Depth-first order of the tree, consecutive nodes joined by shortest paths, back to the start.

    Shortest paths are breadth-first through the whole graph, neighbours taken
    in the order of ``cells`` (so ties between equally short paths are broken
    the same way every time).
    """
    index = {cell: k for k, cell in enumerate(cells)}

    def adjacency(pairs):
        rows = [index[a] for a, b in pairs] + [index[b] for a, b in pairs]
        columns = [index[b] for a, b in pairs] + [index[a] for a, b in pairs]
        matrix = scipy.sparse.csr_matrix((np.ones(len(rows)), (rows, columns)), shape=(len(cells), len(cells)))
        matrix.sort_indices()
        return matrix

    order = scipy.sparse.csgraph.depth_first_order(adjacency(sorted(tree)), 0, directed=False,
                                                   return_predecessors=False)
    graph = adjacency(edges)
    route = [0]
    for target in [*order[1:], order[0]]:
        _, predecessors = scipy.sparse.csgraph.breadth_first_order(graph, route[-1], directed=False,
                                                                   return_predecessors=True)
        path = [int(target)]
        while path[-1] != route[-1]:
            path.append(int(predecessors[path[-1]]))
        route.extend(path[-2::-1])
    return [cells[k] for k in route]
