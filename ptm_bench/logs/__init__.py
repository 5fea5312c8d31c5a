"""Recorded robot logs: a CARMEN reader and the turn of a log into a ``ptm.Dataset`` with ground truth.

Reads real logs (``carmen``), fits the odometry noise model of the simulator
to a robot's raw increments against a reference trajectory (``noise_fit``),
and makes topological detections of places on the reference trajectory with
the simulator's detector (``detections``). Depends on :mod:`ptm_bench.world`
and :mod:`ptm_bench.simulation` (detector, odometry noise model) and on
``ptm``; nothing here scores or reports. The shipped logs and their
provenance are in ``ptm_bench/logs/data``.
"""
