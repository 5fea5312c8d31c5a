"""Tiny cell functions for the sweep engine's process tests (importable by the fork server and by scripts)."""

import os
import time
from pathlib import Path


def sleepy_cell(cell: dict) -> dict:
    """Write this worker's pid into ``cell["pid_dir"]``, then sleep ``cell["sleep"]`` seconds."""
    Path(cell["pid_dir"], f"{os.getpid()}.pid").write_text(cell["cell_id"])
    time.sleep(cell["sleep"])
    return {"slept": cell["sleep"]}


def sleepy_run_cell(cell: dict) -> dict:
    """A stand-in for ``run_cell`` of ``ptm-bench run``: seed 0 returns at once, the others sleep a minute.

    The worker's pid goes into the experiment's results folder (the parent of its dataset cache).
    """
    return sleepy_cell({**cell, "pid_dir": Path(cell["inputs"]["cache_dir"]).parent, "sleep": 0 if cell["seed"] == 0 else 60})


def failing_cell(cell: dict) -> dict:
    raise ValueError(f"seed {cell['seed']}: no signal")


def scored_cell(cell: dict) -> dict:
    """A stand-in for ``run_cell`` that scores a fixed answer: right on even seeds, one place off on odd ones."""
    from ptm_bench.evaluation import scoring

    answer = (0, 1, 0) if cell["seed"] % 2 == 0 else (0, 1, 1)
    return {**scoring.score(scoring.point_mass(answer), (0, 1, 0)), "wall_s": 0.0}


def semaphore_cell(cell: dict) -> dict:
    """What a real cell does to the process's semaphores: the scoring imports scikit-learn (whose joblib
    names the semaphores it creates), and a tqdm bar, even disabled, creates its lock, a named semaphore the
    process must unlink as it ends."""
    import sklearn.metrics  # noqa: F401
    from tqdm import tqdm

    with tqdm(total=1, disable=True):
        return {"locked": True}


def semaphore_sleepy_run_cell(cell: dict) -> dict:
    """:func:`sleepy_run_cell` holding a named semaphore while it sleeps, as a real cell does (tqdm's lock, see
    :func:`semaphore_cell`): a sweep stopped meanwhile must end it without leaving the semaphore behind."""
    from tqdm import tqdm

    with tqdm(total=1, disable=True):
        return sleepy_run_cell(cell)
