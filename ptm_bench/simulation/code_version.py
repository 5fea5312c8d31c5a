"""Versions derived from the code: a digest of the source of every project module a module can run.

A cached dataset or a table row is fresh while the code that made it is
unchanged (docs/model.md §6, Sweeps: a rerun skips a cell whose definition,
these versions included, did not change). That code is the *static import closure* of the module that makes
it (:data:`GENERATOR`, ``ptm_bench.simulation.generate``, for a dataset;
``ptm_bench.evaluation.cell`` for a cell's row, see
``ptm_bench.evaluation.cell.cell_version``): the module, every project module
(``ptm.*``, ``ptm_bench.*``) it imports — at module level or inside a function,
found by parsing with :mod:`ast`, never by importing — and, transitively, theirs.
Importing ``a.b.c`` runs ``a/__init__.py`` and ``a/b/__init__.py`` too, so
parent packages belong to the closure; ``from a.b import c`` adds ``a.b.c`` when
``c`` is a module. Nothing is listed by hand, so a module that is added, split
or moved is counted from its first import on.

The version is ``"sha256:"`` and 16 hex digits of the SHA-256 over the closure's
module names and, for each, ``ast.dump`` of its syntax tree with every bare
string statement (the docstrings) removed: comments, docstrings and formatting
leave it unchanged, any change of code changes it. ``ast.dump`` is Python's
own, so a new Python version may give new versions (a conservative error: it
recomputes, never reuses). Data files a module reads (a world's ``.toml``) are
not code; ``ptm_bench.evaluation.datacache.world_identity`` hashes those.

Modules are located with :func:`importlib.util.find_spec` from their top-level
package, so an installed wheel (the ``.py`` files in site-packages) gives the
same version as the checkout. Each version is computed once per process.

    >>> version = code_version(GENERATOR)
    >>> version.startswith("sha256:") and len(version) == len("sha256:") + 16
    True
    >>> "ptm.se2" in import_closure(GENERATOR) and "ptm_bench.evaluation.cell" not in import_closure(GENERATOR)
    True
"""

from __future__ import annotations

import ast
import functools
import hashlib
import importlib.util
import json
from pathlib import Path

__all__ = ["GENERATOR", "PROJECT_PACKAGES", "code_version", "generator_version", "import_closure", "module_source"]

#: The top-level packages whose modules count as the project's code (third-party packages are versioned by pip).
PROJECT_PACKAGES = ("ptm", "ptm_bench")
#: The module that generates datasets: its closure decides a dataset's ``generator_version``.
GENERATOR = "ptm_bench.simulation.generate"


def _module_path(name: str) -> Path | None:
    """The source file of a module or package by its dotted name, or None where there is none."""
    top, *rest = name.split(".")
    spec = importlib.util.find_spec(top)  # a top-level name: found without importing anything
    if spec is None:
        return None
    if not spec.submodule_search_locations:
        return Path(spec.origin) if not rest and spec.origin else None
    for folder in spec.submodule_search_locations:
        base = Path(folder).joinpath(*rest)
        for candidate in (base / "__init__.py", base.with_suffix(".py") if rest else None):
            if candidate is not None and candidate.is_file():
                return candidate
    return None


def module_source(name: str) -> str:
    """The source text of a project module by its dotted name (``ValueError`` where it has no ``.py`` file)."""
    path = _module_path(name)
    if path is None:
        raise ValueError(f"code version: no source file for the module {name}")
    return path.read_text(encoding="utf-8")


def _module(name: str, packages: tuple[str, ...]) -> tuple[set[str], str]:
    """The project modules one module imports (anywhere in it, with their parent packages) and its code's digest."""
    path = _module_path(name)
    try:
        tree = ast.parse(module_source(name), filename=str(path))
    except SyntaxError as error:
        raise ValueError(f"code version: the module {name} does not parse ({error})") from None
    package = name if path.name == "__init__.py" else name.rpartition(".")[0]
    named = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            named.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                anchor = package.split(".")[: len(package.split(".")) - (node.level - 1)]
                base = ".".join(anchor + ([base] if base else []))
            if base.split(".")[0] in packages:
                named.add(base)
                named.update(f"{base}.{alias.name}" for alias in node.names
                             if alias.name != "*" and _module_path(f"{base}.{alias.name}") is not None)
        body = getattr(node, "body", None)
        if isinstance(body, list):  # docstrings (and any string left as a note) do not run: they do not count
            node.body = [statement for statement in body
                         if not (isinstance(statement, ast.Expr) and isinstance(statement.value, ast.Constant)
                                 and isinstance(statement.value.value, str))]
    imported = {".".join(parts[:end]) for parts in (module.split(".") for module in named)
                if parts[0] in packages for end in range(1, len(parts) + 1)}
    return imported, hashlib.sha256(ast.dump(tree).encode()).hexdigest()


def _closure(module: str, packages: tuple[str, ...]) -> dict[str, str]:
    """The digest of every module in ``module``'s import closure, by name."""
    parts = module.split(".")
    pending = [".".join(parts[:end]) for end in range(1, len(parts) + 1)]
    digests: dict[str, str] = {}
    while pending:
        name = pending.pop()
        if name not in digests:
            imported, digests[name] = _module(name, packages)
            pending.extend(imported - digests.keys())
    return digests


def import_closure(module: str, packages: tuple[str, ...] = PROJECT_PACKAGES) -> tuple[str, ...]:
    """Every project module that importing ``module`` and calling its functions can run, sorted."""
    return tuple(sorted(_closure(module, packages)))


@functools.cache
def code_version(module: str, packages: tuple[str, ...] = PROJECT_PACKAGES) -> str:
    """``"sha256:<16 hex>"`` of the code in ``module``'s import closure, docstrings, comments and layout aside."""
    digests = _closure(module, packages)
    return "sha256:" + hashlib.sha256(json.dumps(digests, sort_keys=True).encode()).hexdigest()[:16]


def generator_version() -> str:
    """The version of the simulator that writes the datasets: :func:`code_version` of :data:`GENERATOR`."""
    return code_version(GENERATOR)
