"""PTM evaluation harness: simulated worlds, datasets with ground truth, sweeps and scoring.

The sub-packages are layers, and data flows one way through them (each
imports only the layers before it; ``tests/test_architecture.py`` checks it):

    world -> simulation -> ptm.Dataset -> evaluation (ptm -> PTM -> scores) -> reporting -> benchmarks -> cli

* :mod:`ptm_bench.world` — floor plans and the preset worlds;
* :mod:`ptm_bench.simulation` — MuJoCo scene, robot, cameras, odometry noise, detector, dataset generation;
* :mod:`ptm_bench.evaluation` — experiment configs, sweeps, calibration, baselines, scoring;
* :mod:`ptm_bench.reporting` — ``summary.md`` and figures;
* :mod:`ptm_bench.benchmarks` — the sections of ``ptm-bench speed``;
* :mod:`ptm_bench.cli` — every ``ptm-bench`` sub-command.

Nothing in ``ptm`` imports this package.

    $ ptm-bench demo
    $ ptm-bench speed
"""

__version__ = "0.1.0"
