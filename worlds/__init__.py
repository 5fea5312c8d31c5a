"""The preset floors, one TOML file each (format: docs/model.md §5 and ``ptm_bench.world.floorplan``).

This folder is installed as the package ``ptm_bench.world.presets`` so that the
presets ship inside the wheel; ``ptm-bench worlds`` lists them.
"""
