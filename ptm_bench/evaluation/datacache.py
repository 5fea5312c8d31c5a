"""Datasets for sweep cells: resolve the world, generate with the simulator, cache on disk.

A dataset is identified by (world, aliasing, noise, seed, generator options,
number of Fourier components) and by what the simulator makes of them: the
world's *content* and the simulator's version. :func:`world_identity` gives
both: for a preset name or a floor ``.toml`` path, the SHA-256 of the file's
bytes (resolved as ``ptm_bench.world.floorplan.load_world`` resolves it); for a
procedural world, the generator table itself; and for either, the
simulator's version (:func:`ptm_bench.simulation.code_version.generator_version`,
a digest of the code of every module the generator imports). Editing a world
file or the simulator's code therefore gives a new cache file (a dataset
cached by another version of the simulator is never read again) and, since
``ptm_bench.evaluation.experiment`` puts the same identity into every cell's definition
digest, recomputes the sweep cells that used the old one.

The simulator is deterministic in these (docs/model.md §5), so a cached file is
exactly what generation would give. Several model variants and the
calibration of every cell of one condition share one dataset, so each is
generated once per machine. Files are written atomically (two processes
racing write the same bytes), without the panoramas. With ``components``
set, the signatures keep K Fourier components (docs/model.md §4) instead of the
generator's default.

    >>> path = dataset_path("nested_loops", 0.0, 1.0, 3, cache_dir="results/exp3/datasets")  # where it is cached
    >>> path.parent.as_posix(), path.name.startswith("nested_loops_a0_n1_s3_")
    ('results/exp3/datasets', True)
    >>> sorted(world_identity("nested_loops"))
    ['simulator', 'world', 'world_sha256']

``dataset_for("nested_loops", 0.0, 1.0, 3, cache_dir="results/exp3/datasets")``
simulates the run the first time (seconds) and reads that file afterwards.
"""

from __future__ import annotations

import hashlib
import json
import zipfile
import zlib
from pathlib import Path

import ptm
from ptm_bench.simulation.code_version import generator_version

__all__ = ["dataset_for", "dataset_path", "is_recorded", "load_recorded", "resolve_world", "world_identity"]


def is_recorded(world_spec) -> bool:
    """Whether a world is a recorded dataset file, ``{dataset = "path.npz", name = ..., calibration = [...]}``."""
    return isinstance(world_spec, dict) and "dataset" in world_spec


def load_recorded(path, components: int | None = None) -> ptm.Dataset:
    """A recorded dataset file (a real robot's log made into a dataset); it has the signatures it was made with."""
    if components is not None:
        raise ValueError(f"appearance.components = {components} needs panoramas; the recorded dataset {path} has its "
                         "signatures as imported")
    if not Path(path).is_file():
        raise ValueError(f"world: no recorded dataset file at {path}")
    return ptm.Dataset.load(path)


def resolve_world(world_spec, seed: int):
    """A ``Floorplan``: a preset or file by name, or a procedural corridor grid (world seed = ``seed`` unless given)."""
    from ptm_bench.world import floorplan

    if isinstance(world_spec, str):
        return floorplan.load_world(world_spec)
    params = {key: value for key, value in world_spec.items() if key not in ("generator", "name")}
    params.setdefault("seed", seed)
    return floorplan.corridor_grid(**params)


def world_identity(world_spec) -> dict:
    """What decides a world's datasets besides the condition: its spec, its content, the simulator's version.

    A preset name or floor file is identified by the SHA-256 of the file's
    bytes (a missing or malformed file raises ``ValueError``); a procedural
    world by its generator table, already in the spec — the generator's code
    is part of the simulator and versioned with it.
    """
    if is_recorded(world_spec):  # a recorded run: its bytes and those of its calibration runs decide its rows
        files = [world_spec["dataset"], *world_spec.get("calibration", [])]
        missing = [name for name in files if not Path(name).is_file()]
        if missing:
            raise ValueError(f"world {world_spec.get('name')!r}: no recorded dataset file at {', '.join(missing)}")
        return {"world": world_spec,
                "files_sha256": [hashlib.sha256(Path(name).read_bytes()).hexdigest() for name in files]}
    identity = {"world": world_spec, "simulator": generator_version()}  # read from the code: MuJoCo is not imported
    if isinstance(world_spec, str):
        from ptm_bench.world.floorplan import load_world

        source = Path(load_world(world_spec).source)  # the file floorplan's own lookup reads
        identity["world_sha256"] = hashlib.sha256(source.read_bytes()).hexdigest()
    elif not isinstance(world_spec, dict):
        raise ValueError(f"world: a world is a preset name, a floor .toml path or a generator table, "
                         f"got {world_spec!r}")
    return identity


def dataset_path(world_spec, aliasing: float, noise: float, seed: int, generator_options=None, cache_dir=None,
                 components: int | None = None) -> Path | None:
    """The cache file of one condition and seed (None without ``cache_dir``), named with a digest of the identity."""
    if is_recorded(world_spec):
        return Path(world_spec["dataset"])  # recorded, not generated: the file is the dataset
    if cache_dir is None:
        return None
    identity = {**world_identity(world_spec), "aliasing": aliasing, "noise": noise, "seed": seed,
                "options": dict(generator_options or {}), "components": components}
    digest = hashlib.sha256(json.dumps(identity, sort_keys=True).encode()).hexdigest()[:12]
    name = world_spec if isinstance(world_spec, str) else world_spec["name"]
    return Path(cache_dir) / f"{Path(name).stem}_a{aliasing:g}_n{noise:g}_s{seed}_{digest}.npz"


def _load_cached(path: Path) -> ptm.Dataset:
    """A cached dataset; a truncated or foreign file is a ``ValueError`` naming it (never a silently wrong cache)."""
    try:
        return ptm.Dataset.load(path)
    except (ValueError, OSError, EOFError, KeyError, TypeError, zipfile.BadZipFile, zlib.error) as error:
        raise ValueError(f"cached dataset {path} is unreadable ({type(error).__name__}: {error}); "
                         "delete it and rerun to generate it again") from None


def dataset_for(world_spec, aliasing: float, noise: float, seed: int, generator_options=None,
                cache_dir=None, components: int | None = None) -> ptm.Dataset:
    """The dataset of one condition and seed, from ``cache_dir`` if it was generated before."""
    if is_recorded(world_spec):  # aliasing, noise and seed do not apply to a recorded run
        return load_recorded(world_spec["dataset"], components)
    generator_options = dict(generator_options or {})
    path = dataset_path(world_spec, aliasing, noise, seed, generator_options, cache_dir, components)
    if path is not None and path.is_file():
        return _load_cached(path)

    from ptm_bench.simulation.generate import generate_dataset

    if components is not None:
        generator_options["signature_k"] = int(components)
    world = resolve_world(world_spec, seed)
    dataset = generate_dataset(world, aliasing, noise, seed, images=False, progress=False, **generator_options)
    if path is not None:
        path.parent.mkdir(parents=True, exist_ok=True)
        dataset.save(path)
    return dataset
