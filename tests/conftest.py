"""Test configuration: headless rendering, single-threaded BLAS, nothing written outside the test's own folders,
and the shared helpers on the import path."""

import os
import sys
import tempfile
from pathlib import Path

os.environ.setdefault("MUJOCO_GL", "egl")
# pytest-xdist already runs one worker per core: a worker's BLAS must not start threads of its own (as in the
# harness's sweep, ptm_bench.evaluation.sweep). Threaded OpenBLAS on the small matrices of the pose-graph fits
# oversubscribes the cores: one exact enumeration of the 7-detection loop in test_odometry_proposal took 60 s
# with two busy cores, 14.5 s single-threaded. Set before numpy is imported (pytest loads this file first, and
# xdist's workers inherit it); a value the user set is kept.
for variable in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(variable, "1")
# matplotlib's font cache goes to a temporary folder, not the user's home (a test stays inside its environment)
os.environ.setdefault("MPLCONFIGDIR", tempfile.mkdtemp(prefix="ptm-tests-matplotlib-"))
sys.path.insert(0, str(Path(__file__).parent))
