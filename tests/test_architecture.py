"""The import graph follows the architecture: data flows one way through ptm_bench's layers.

world -> simulation -> logs -> evaluation -> reporting -> benchmarks -> cli: a module
may import its own layer and the layers before it, never a later one (every
import counts, also one inside a function). The library ``ptm`` imports
nothing of the harness, never MuJoCo or OpenCV, and no module of either
package uses another module's private names.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
LAYERS = ("world", "simulation", "logs", "evaluation", "reporting", "benchmarks", "cli")


def _modules(package: str) -> dict[str, Path]:
    modules = {}
    for path in sorted((ROOT / package).rglob("*.py")):
        parts = path.relative_to(ROOT).with_suffix("").parts
        name = ".".join(parts[:-1] if parts[-1] == "__init__" else parts)
        modules[name] = path
    return modules


def _imports(module: str, path: Path) -> list[tuple[str, int]]:
    """(imported module or name, line) for every import in the file, relative ones resolved."""
    package = module if path.name == "__init__.py" else module.rpartition(".")[0]
    found = []
    for node in ast.walk(ast.parse(path.read_text(), filename=str(path))):
        if isinstance(node, ast.Import):
            found.extend((alias.name, node.lineno) for alias in node.names)
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                anchor = package.split(".")
                anchor = anchor[: len(anchor) - (node.level - 1)]
                base = ".".join(anchor + ([base] if base else []))
            found.extend((f"{base}.{alias.name}", node.lineno) for alias in node.names)
    return found


def _layer(module: str) -> int | None:
    parts = module.split(".")
    if parts[0] != "ptm_bench" or len(parts) < 2 or parts[1] not in LAYERS:
        return None
    return LAYERS.index(parts[1])


def test_every_harness_module_sits_in_a_layer():
    stray = [name for name in _modules("ptm_bench") if name != "ptm_bench" and _layer(name) is None]
    assert not stray, f"modules outside the layers {LAYERS}: {stray}"


def test_harness_imports_only_earlier_layers():
    violations = []
    for module, path in _modules("ptm_bench").items():
        own = _layer(module)
        for imported, line in _imports(module, path):
            target = _layer(imported)
            if own is not None and target is not None and target > own:
                violations.append(f"{path.relative_to(ROOT)}:{line}: {module} ({LAYERS[own]}) imports "
                                  f"{imported} ({LAYERS[target]})")
    assert not violations, "imports against the data flow:\n" + "\n".join(violations)


@pytest.mark.parametrize("forbidden", ["ptm_bench", "mujoco", "cv2"])
def test_library_never_imports_the_harness_or_the_simulator(forbidden):
    offenders = [f"{path.relative_to(ROOT)}:{line}" for module, path in _modules("ptm").items()
                 for imported, line in _imports(module, path) if imported.split(".")[0] == forbidden]
    assert not offenders, f"ptm imports {forbidden}: {offenders}"


def test_no_private_names_across_modules():
    modules = {**_modules("ptm"), **_modules("ptm_bench")}
    offenders = []
    for module, path in modules.items():
        for imported, line in _imports(module, path):
            owner, _, name = imported.rpartition(".")
            if name.startswith("_") and not name.startswith("__") and owner in modules and owner != module:
                offenders.append(f"{path.relative_to(ROOT)}:{line}: {imported}")
    assert not offenders, "private names imported from another module:\n" + "\n".join(offenders)


def test_the_checker_sees_a_violation(tmp_path):
    """Negative control: a simulation module that imports the reporting layer, relatively, is caught."""
    path = tmp_path / "probe.py"
    path.write_text("def later():\n    from ..reporting.summary import write_summary\n")
    (imported, line), = _imports("ptm_bench.simulation.probe", path)
    assert imported == "ptm_bench.reporting.summary.write_summary" and line == 2
    assert _layer(imported) > _layer("ptm_bench.simulation.probe")
