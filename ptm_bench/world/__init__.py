"""World description: floor plans (corridors, places, routes, palettes) read from TOML or generated.

The first layer of the harness: pure geometry, no simulator. The preset floors
are the TOML files of the package ``ptm_bench.world.presets`` (the
repository's ``worlds/`` folder).
"""
