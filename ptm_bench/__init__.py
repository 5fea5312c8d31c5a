"""PTM evaluation harness: simulated worlds, datasets with ground truth, sweeps and scoring.

Data flows one way: world -> simulation -> ``ptm.Dataset`` file -> ``ptm`` ->
PTM -> scoring -> tables and figures. Nothing in ``ptm`` imports this package.

    $ ptm-bench demo
    $ ptm-bench speed
"""

__version__ = "0.1.0"
