"""Datasets for sweep cells: resolve the world, generate with the simulator, cache on disk.

A dataset is identified by (world, aliasing, noise, seed, generator options,
number of Fourier components); the simulator is deterministic in these
(SPEC §5), so a cached file is exactly what generation would give. Several
model variants and the calibration of every cell of one condition share one
dataset, so each is generated once per machine. Files are written atomically
(two processes racing write the same bytes), without the panoramas. With
``components`` set, the signatures keep K Fourier components (SPEC §4)
instead of the generator's default.

    >>> dataset = dataset_for("nested_loops", aliasing=0.0, noise=1.0, seed=3, cache_dir="results/exp3/datasets")
    >>> dataset.n, dataset.meta["min_place_spacing"]
    >>> resolve_world({"generator": "corridor_grid", "name": "g", "rows": 2, "cols": 3, "loops": 1, "place_density": 0.8}, seed=0)
"""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

import ptm

__all__ = ["dataset_for", "resolve_world"]


def resolve_world(world_spec, seed: int):
    """A ``Floorplan``: a preset or file by name, or a procedural corridor grid (world seed = ``seed`` unless given)."""
    from . import floorplan

    if isinstance(world_spec, str):
        return floorplan.load_world(world_spec)
    params = {key: value for key, value in world_spec.items() if key not in ("generator", "name")}
    params.setdefault("seed", seed)
    return floorplan.corridor_grid(**params)


def dataset_for(world_spec, aliasing: float, noise: float, seed: int, generator_options=None,
                cache_dir=None, components: int | None = None) -> ptm.Dataset:
    """The dataset of one condition and seed, from ``cache_dir`` if it was generated before."""
    generator_options = dict(generator_options or {})
    identity = {"world": world_spec, "aliasing": aliasing, "noise": noise, "seed": seed,
                "options": generator_options, "components": components}
    digest = hashlib.sha256(json.dumps(identity, sort_keys=True).encode()).hexdigest()[:12]
    name = world_spec if isinstance(world_spec, str) else world_spec["name"]
    path = Path(cache_dir) / f"{Path(name).stem}_a{aliasing:g}_n{noise:g}_s{seed}_{digest}.npz" if cache_dir else None
    if path is not None and path.is_file():
        return ptm.Dataset.load(path)

    from .generate import generate_dataset

    if components is not None:
        generator_options["signature_k"] = int(components)
    world = resolve_world(world_spec, seed)
    dataset = generate_dataset(world, aliasing, noise, seed, images=False, progress=False, **generator_options)
    if path is not None:
        path.parent.mkdir(parents=True, exist_ok=True)
        dataset.save(path)
    return dataset
