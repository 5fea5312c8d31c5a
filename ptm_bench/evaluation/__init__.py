"""Evaluation: experiment configs, sweep cells, calibration on held-out runs, baselines and scores.

Turns datasets from :mod:`ptm_bench.simulation` into posteriors with ``ptm``
and scores them against the ground truth; writes tables, never figures.
"""
