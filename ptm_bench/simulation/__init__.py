"""Simulation: a floor plan compiled to MuJoCo, driven by the mobile base, turned into a ``ptm.Dataset``.

Scene (MJCF), robot and camera rig, panorama stitching, the odometry noise
model, the landmark detector, end-to-end generation, and the measured
aliasing of a dataset. Depends on :mod:`ptm_bench.world` and on ``ptm`` for
the dataset contract; nothing here scores or reports.
"""
