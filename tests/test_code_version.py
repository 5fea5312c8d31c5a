"""Versions derived from the code (ptm_bench.simulation.code_version): a change of code in a module's import closure
changes its version, a change of docstrings, comments or layout does not, and neither does a module outside it.

A small fake package in a temporary folder shows the closure rule file by file; the real tree shows it for the two
versions the harness stores (a cell's rows, a dataset's generator) without depending on its exact module list.
"""

import functools
import re
import textwrap

import pytest

from ptm_bench.evaluation import cell as cell_module
from ptm_bench.simulation import code_version as versions

FAKE = {
    "__init__.py": '"""A fake project."""\n',
    "runner.py": '''
        """Runs the core (the module whose version is asked)."""
        from fakeproj import core


        def run():
            from .late import late_value  # a function-level, relative import counts

            return core.value() + late_value()
        ''',
    "core.py": '''
        """The core."""
        import numpy as np  # a third-party module: not the project's code

        import fakeproj.sub.deep


        def value():
            """One, as an array's sum."""
            return int(np.ones(1).sum())  # a comment
        ''',
    "late.py": "def late_value():\n    return 2\n",
    "report.py": "from fakeproj import runner\n\n\ndef report():\n    return runner.run()\n",
    "sub/__init__.py": "",
    "sub/deep.py": "DEPTH = 3\n",
}


@pytest.fixture(autouse=True)
def fresh_versions():
    """Every version computed anew in a test, and none computed from an edited source left for the next test."""
    versions.code_version.cache_clear()
    yield
    versions.code_version.cache_clear()


@pytest.fixture
def fake(tmp_path, monkeypatch):
    """The fake package on the import path; ``fake(path, text)`` rewrites one of its files, and its version."""
    for name, text in FAKE.items():
        path = tmp_path / "fakeproj" / name
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(textwrap.dedent(text).lstrip())
    monkeypatch.syspath_prepend(str(tmp_path))

    def version(path=None, text=None):
        if path is not None:
            (tmp_path / "fakeproj" / path).write_text(textwrap.dedent(text).lstrip())
            versions.code_version.cache_clear()
        return versions.code_version("fakeproj.runner", ("fakeproj",))

    version.source = lambda path: (tmp_path / "fakeproj" / path).read_text()
    return version


def test_the_closure_follows_imports_at_module_and_function_level_with_their_parent_packages(fake):
    assert versions.import_closure("fakeproj.runner", ("fakeproj",)) == (
        "fakeproj", "fakeproj.core", "fakeproj.late", "fakeproj.runner", "fakeproj.sub", "fakeproj.sub.deep")
    assert re.fullmatch(r"sha256:[0-9a-f]{16}", fake())


@pytest.mark.parametrize("path", ["runner.py", "core.py", "late.py", "sub/deep.py", "sub/__init__.py"])
def test_a_change_of_code_in_the_closure_changes_the_version(fake, path):
    before = fake()
    assert fake(path, fake.source(path) + "\nEDITED = True\n") != before


def test_docstrings_comments_and_layout_leave_the_version(fake):
    before = fake()
    edited = (fake.source("core.py").replace('"""The core."""', '"""The core, described at length.\n\nMore."""')
              .replace('"""One, as an array\'s sum."""', "")  # a docstring removed
              .replace("# a comment", "# another comment").replace("return int(", "return int(  # wrapped\n        "))
    assert edited != fake.source("core.py")
    assert fake("core.py", edited) == before
    reformatted = '"""Late, now with a docstring."""\n\n\ndef late_value():\n    return (\n        2\n    )\n'
    assert fake("late.py", reformatted) == before


def test_a_module_outside_the_closure_leaves_the_version(fake):
    before = fake()
    assert fake("report.py", "def report():\n    return None\n") == before
    assert fake("extra.py", "import fakeproj.runner\n") == before


def test_a_version_is_computed_once_per_process(fake, tmp_path):
    before = fake()
    path = tmp_path / "fakeproj" / "core.py"
    path.write_text(path.read_text() + "\nEDITED = True\n")
    assert versions.code_version("fakeproj.runner", ("fakeproj",)) == before
    versions.code_version.cache_clear()
    assert versions.code_version("fakeproj.runner", ("fakeproj",)) != before


def test_an_import_of_a_missing_project_module_or_a_module_that_does_not_parse_is_an_error(fake):
    with pytest.raises(ValueError, match="fakeproj.late does not parse"):
        fake("late.py", "def late_value(:\n")
    with pytest.raises(ValueError, match="no source file for the module fakeproj.gone"):
        fake("late.py", "import fakeproj.gone\n")


# -- the harness's two versions, on the real tree ----------------------------------------------------------------


@pytest.fixture
def frozen_tree(monkeypatch):
    """Each module's source read once: the tree as the test found it, whatever is saved meanwhile."""
    monkeypatch.setattr(versions, "module_source", functools.cache(versions.module_source))


def edited(monkeypatch, module: str, edit):
    """Make ``module``'s source read as ``edit(source)``, as an edit of its file would."""
    read = versions.module_source
    monkeypatch.setattr(versions, "module_source", lambda name: edit(read(name)) if name == module else read(name))
    versions.code_version.cache_clear()


def add_code(source: str) -> str:
    return source + "\n_EDITED = True\n"


def add_prose(source: str) -> str:
    return '# a new comment\n"""A new docstring above the old one."""\n\n\n' + source + "\n\n# the end\n"


def test_a_cells_closure_holds_the_library_and_the_simulator_and_no_later_layer():
    closure = versions.import_closure("ptm_bench.evaluation.cell")
    assert {"ptm", "ptm.sampler", "ptm.posterior", versions.GENERATOR} <= set(closure)
    assert any(name == "ptm.odometry" or name.startswith("ptm.odometry.") for name in closure)
    assert not [name for name in closure if name.startswith(("ptm_bench.cli", "ptm_bench.reporting",
                                                             "ptm_bench.benchmarks"))]
    generator = versions.import_closure(versions.GENERATOR)
    assert set(generator) < set(closure) and "ptm.se2" in generator
    assert not [name for name in generator if name.startswith("ptm_bench.evaluation")]


def test_the_cell_version_follows_the_library_code_and_not_its_prose_nor_the_reports(monkeypatch, frozen_tree):
    version = cell_module.cell_version()
    assert re.fullmatch(r"sha256:[0-9a-f]{16}", version) and version != versions.generator_version()
    edited(monkeypatch, "ptm.sampler", add_prose)
    assert cell_module.cell_version() == version
    edited(monkeypatch, "ptm_bench.reporting.plots", add_code)
    assert cell_module.cell_version() == version
    edited(monkeypatch, "ptm.sampler", add_code)
    assert cell_module.cell_version() != version


def test_the_generator_version_follows_the_simulator_and_not_the_scoring(monkeypatch, frozen_tree):
    generator, cell = versions.generator_version(), cell_module.cell_version()
    edited(monkeypatch, "ptm_bench.evaluation.scoring", add_code)
    assert versions.generator_version() == generator and cell_module.cell_version() != cell
    edited(monkeypatch, "ptm_bench.simulation.robot", add_code)
    assert versions.generator_version() != generator
