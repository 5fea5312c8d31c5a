"""The import graph follows the architecture: the library's layers and the harness's data flow point one way.

The library ``ptm``, bottom to top: foundation (validation, caches, SE(2), partitions, the dataset, the result
and its diagnostics, features) -> models (the prior and the likelihood terms, the pose graph, export) -> the
posterior -> sampling (the moves, the online mapper, the chain starts, the recorder, the samplers, exact
enumeration) -> the package's own ``__init__``. A module imports its own layer and the layers below it, never a
later one; the sampling layer knows the posterior's protocol (its screen among it), never a particular term. The
import graph of ``ptm`` has no circle, and a module imports the library's modules at module level only, so no
import inside a function hides a circle.

The harness: world -> simulation -> logs -> evaluation -> reporting -> benchmarks -> cli: a module
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
#: The library's layers, bottom to top, by the first name under ``ptm`` (a module or a package); ``ptm`` itself
#: (its ``__init__``) is the top.
LIBRARY_LAYERS = (
    ("foundation", {"_validation", "_npz", "_cache", "_threads", "se2", "partitions", "dataset", "diagnostics",
                    "result", "features"}),
    ("models", {"prior", "gamma_poisson_prior",
                "appearance", "appearance_joint", "appearance_outliers", "tie_normaliser", "pose_graph",
                "odometry", "export"}),
    ("posterior", {"posterior"}),
    ("sampling", {"moves", "online", "smc", "starts", "recorder", "sampler", "tempering", "exact"}),
)


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


# -- the library's layers ---------------------------------------------------------------------------------------


def _library_layer(module: str) -> int | None:
    """The index of ``module``'s layer in ``LIBRARY_LAYERS`` (``len(LIBRARY_LAYERS)`` for ``ptm`` itself), or None."""
    parts = module.split(".")
    if parts[0] != "ptm":
        return None
    if len(parts) == 1:
        return len(LIBRARY_LAYERS)
    return next((index for index, (_, names) in enumerate(LIBRARY_LAYERS) if parts[1] in names), None)


def _resolved(imported: str, modules) -> str | None:
    """The module of ``modules`` that an imported name lives in (the longest dotted prefix that is one), or None."""
    parts = imported.split(".")
    for end in range(len(parts), 0, -1):
        name = ".".join(parts[:end])
        if name in modules:
            return name
    return None


def _library_graph(modules) -> dict[str, set[str]]:
    """module -> the library modules it imports (anywhere in the file), for ``modules`` (name -> path)."""
    graph = {}
    for module, path in modules.items():
        targets = {_resolved(imported, modules) for imported, _ in _imports(module, path)}
        graph[module] = {target for target in targets if target is not None and target != module}
    return graph


def _circle(graph) -> list[str] | None:
    """One circle of ``graph`` (its modules in order, the first repeated at the end), or None."""
    state, stack = {}, []

    def visit(node):
        state[node] = "open"
        stack.append(node)
        for target in sorted(graph.get(node, ())):
            if state.get(target) == "open":
                return stack[stack.index(target):] + [target]
            if target not in state:
                found = visit(target)
                if found:
                    return found
        stack.pop()
        state[node] = "done"
        return None

    for node in sorted(graph):
        if node not in state:
            found = visit(node)
            if found:
                return found
    return None


def _function_level_library_imports(module: str, path: Path, modules) -> list[str]:
    """``path:line: imported`` for every import of a library module inside a function of ``path``."""
    package = module if path.name == "__init__.py" else module.rpartition(".")[0]
    found = []
    for function in ast.walk(ast.parse(path.read_text(), filename=str(path))):
        if not isinstance(function, (ast.FunctionDef, ast.AsyncFunctionDef)):
            continue
        for node in ast.walk(function):
            names = []
            if isinstance(node, ast.Import):
                names = [alias.name for alias in node.names]
            elif isinstance(node, ast.ImportFrom):
                base = node.module or ""
                if node.level:
                    anchor = package.split(".")
                    base = ".".join(anchor[: len(anchor) - (node.level - 1)] + ([base] if base else []))
                names = [f"{base}.{alias.name}" for alias in node.names]
            shown = path.relative_to(ROOT) if path.is_relative_to(ROOT) else path
            found.extend(f"{shown}:{node.lineno}: {name}" for name in names if _resolved(name, modules) is not None)
    return found


def test_every_library_module_sits_in_a_layer():
    stray = [name for name in _modules("ptm") if _library_layer(name) is None]
    assert not stray, f"modules outside the library's layers: {stray}"


def test_library_imports_only_its_own_layer_and_lower_ones():
    modules = _modules("ptm")
    names = [name for name, _ in LIBRARY_LAYERS] + ["package"]
    violations = []
    for module, targets in _library_graph(modules).items():
        own = _library_layer(module)
        for target in sorted(targets):
            layer = _library_layer(target)
            if own is not None and layer is not None and layer > own and target != "ptm":
                violations.append(f"{module} ({names[own]}) imports {target} ({names[layer]})")
            elif target == "ptm" and module != "ptm":
                violations.append(f"{module} imports the package ptm itself")
    assert not violations, "imports against the library's layers:\n" + "\n".join(violations)


def test_the_sampling_layer_knows_no_particular_term():
    """The samplers, moves, starts and the online mapper reach the global terms through the posterior's protocol
    (``Posterior.screen()``), never through a model module."""
    modules = _modules("ptm")
    sampling = LIBRARY_LAYERS[3][1]
    offenders = [f"{module} imports {target}" for module, targets in _library_graph(modules).items()
                 if module.split(".")[1:2] and module.split(".")[1] in sampling
                 for target in targets if _library_layer(target) == 1]
    assert not offenders, "the sampling layer imports a model:\n" + "\n".join(offenders)


def test_the_library_has_no_import_circle():
    assert _circle(_library_graph(_modules("ptm"))) is None, _circle(_library_graph(_modules("ptm")))


def test_the_library_imports_its_own_modules_at_module_level_only():
    modules = _modules("ptm")
    offenders = [line for module, path in modules.items()
                 for line in _function_level_library_imports(module, path, modules)]
    assert not offenders, "library modules imported inside a function:\n" + "\n".join(offenders)


def test_the_library_checks_see_an_upward_import_a_circle_and_a_hidden_import(tmp_path):
    """Negative controls: a foundation module that imports the sampler (inside a function, to dodge the circle
    through the sampler's own imports) breaks the layers, closes a circle, and is an import inside a function."""
    (tmp_path / "ptm").mkdir()
    probe = tmp_path / "ptm" / "partitions.py"
    probe.write_text("def later():\n    from .sampler import mcmc\n")
    modules = {**_modules("ptm"), "ptm.partitions": probe}
    graph = _library_graph(modules)
    assert "ptm.sampler" in graph["ptm.partitions"]
    assert _library_layer("ptm.sampler") > _library_layer("ptm.partitions")
    circle = _circle(graph)
    assert circle is not None and "ptm.partitions" in circle and "ptm.sampler" in circle
    assert _function_level_library_imports("ptm.partitions", probe, modules) == [f"{probe}:2: ptm.sampler.mcmc"]
