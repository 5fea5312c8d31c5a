"""``import ptm`` stays light: numpy, scipy and threadpoolctl only, the heavy packages only inside the functions that need them.

The library is used on robots and in sweep workers; loading MuJoCo, OpenCV,
pandas, matplotlib or ArviZ with it would cost seconds per process and tie
the library to the harness. ArviZ (diagnostics, ``PTM.to_inference_data``),
pandas (``PTM.to_frame``) and networkx (``ptm.export``) are imported where
they are used.
"""

import ast
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
HEAVY = ("mujoco", "cv2", "pandas", "matplotlib", "arviz", "networkx", "ptm_bench")


def module_level_imports(source: str) -> list[tuple[str, int]]:
    """(top-level package, line) of every import executed when the module is imported: anything not
    inside a function body (class bodies and ``if`` blocks run at import time, so they count)."""
    found = []

    def visit(node, in_function):
        for child in ast.iter_child_nodes(node):
            inside = in_function or isinstance(child, (ast.FunctionDef, ast.AsyncFunctionDef, ast.Lambda))
            if not inside and isinstance(child, ast.Import):
                found.extend((alias.name.split(".")[0], child.lineno) for alias in child.names)
            elif not inside and isinstance(child, ast.ImportFrom) and not child.level and child.module:
                found.append((child.module.split(".")[0], child.lineno))
            visit(child, inside)

    visit(ast.parse(source), False)
    return found


def heavy_packages_loaded(extra: str = "") -> list[str]:
    """The heavy packages in sys.modules after importing every module of ptm (and ``extra``) in a fresh interpreter."""
    script = ("import importlib, pkgutil, sys, ptm\n"
              "for info in pkgutil.walk_packages(ptm.__path__, 'ptm.'):\n"
              "    importlib.import_module(info.name)\n"
              f"{extra}\n"
              f"print(' '.join(sorted({{name.split('.')[0] for name in sys.modules}} & set({HEAVY!r}))))\n")
    loaded = subprocess.run([sys.executable, "-c", script], cwd=ROOT, capture_output=True, text=True, check=True)
    return loaded.stdout.split()


def test_import_ptm_loads_no_heavy_package():
    assert heavy_packages_loaded() == []


def test_the_subprocess_check_sees_a_heavy_package():
    """Negative control: the same check after a deliberate ``import pandas`` reports it."""
    pytest.importorskip("pandas")
    assert heavy_packages_loaded("import pandas") == ["pandas"]


@pytest.mark.parametrize("path", sorted((ROOT / "ptm").rglob("*.py")), ids=lambda p: str(p.relative_to(ROOT)))
def test_no_heavy_import_at_module_level(path):
    offenders = [f"{path.relative_to(ROOT)}:{line}: {name}" for name, line in module_level_imports(path.read_text())
                 if name in HEAVY]
    assert not offenders, "heavy packages imported at module level:\n" + "\n".join(offenders)


def test_the_checker_sees_a_module_level_import():
    """Negative control: module-level and class-level imports are caught, an import inside a function is not."""
    probe = ("import numpy as np\nfrom pandas import DataFrame\n"
             "class Frame:\n    import matplotlib.pyplot as plt\n"
             "def later():\n    import arviz\n    return arviz\n")
    assert module_level_imports(probe) == [("numpy", 1), ("pandas", 2), ("matplotlib", 4)]
