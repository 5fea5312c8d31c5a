"""Benchmarks behind ``ptm-bench speed``: one module per section, each returning rows for ``results/speed.csv``."""
