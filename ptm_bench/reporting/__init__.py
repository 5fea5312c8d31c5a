"""Reporting: ``summary.md``, its tables and figures, from the tables :mod:`ptm_bench.evaluation` writes."""
