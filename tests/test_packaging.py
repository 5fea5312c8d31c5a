"""Packaging: every package is listed, and a built wheel runs outside the checkout with its preset worlds."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import tomllib
import venv
import zipfile
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
# What a wheel is built from: the build runs in a copy of these, never in the checkout, whose build/ folder
# (left by an earlier build, or an editable install) made setuptools fail with "File exists" in CI.
SOURCES = ("pyproject.toml", "README.md", "ptm", "ptm_bench", "worlds")
# One pytest-xdist worker runs these tests, so that the wheel is built once.
pytestmark = pytest.mark.xdist_group("wheel_build")


def _declared() -> dict:
    return tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]


def test_every_package_folder_is_listed_in_pyproject():
    found = {".".join(path.parent.relative_to(ROOT).parts)
             for package in ("ptm", "ptm_bench") for path in (ROOT / package).rglob("__init__.py")}
    found.add("ptm_bench.world.presets")  # the worlds/ folder, mapped into the harness
    assert found == set(_declared()["packages"])
    assert _declared()["package-dir"] == {"ptm_bench.world.presets": "worlds"}


@pytest.fixture(scope="module")
def wheel(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("wheel")
    source = tmp_path_factory.mktemp("source")
    for name in SOURCES:
        if (ROOT / name).is_dir():
            shutil.copytree(ROOT / name, source / name, ignore=shutil.ignore_patterns("__pycache__", "*.egg-info"))
        else:
            shutil.copy2(ROOT / name, source / name)
    build = subprocess.run([sys.executable, "-m", "pip", "wheel", str(source), "--no-deps", "--no-build-isolation",
                            "--wheel-dir", str(out), "--quiet"], capture_output=True, text=True)
    # pip's own words when it fails (once, under a loaded CI run, it failed without them)
    assert build.returncode == 0, f"pip wheel exited with {build.returncode}:\n{build.stdout[-2000:]}" \
                                  f"{build.stderr[-4000:]}"
    (built,) = out.glob("ptm-*.whl")
    return built


@pytest.mark.slow
def test_the_wheel_ships_the_preset_worlds(wheel):
    names = zipfile.ZipFile(wheel).namelist()
    presets = sorted(path.name for path in (ROOT / "worlds").glob("*.toml"))
    assert presets and all(f"ptm_bench/world/presets/{name}" in names for name in presets)
    assert not any(name.startswith(("tests/", "experiments/", "results/")) for name in names)


@pytest.mark.slow
def test_an_installed_wheel_runs_from_an_empty_folder(wheel, tmp_path):
    """A non-editable install (dependencies from this environment) lists and loads the worlds anywhere."""
    environment_dir = tmp_path / "venv"
    venv.create(environment_dir, system_site_packages=True, with_pip=True)
    python = environment_dir / "bin" / "python"
    # The environment's own pip: it installs the wheel into the environment and leaves the editable install
    # of this checkout outside it alone ("outside environment"); pip --prefix from here would uninstall it.
    subprocess.run([str(python), "-m", "pip", "install", "--no-deps", "--no-index", "--quiet", str(wheel)],
                   check=True, capture_output=True)
    empty = tmp_path / "elsewhere"
    empty.mkdir()
    env = {key: value for key, value in os.environ.items() if key not in ("PYTHONPATH",)}
    env["PYTHONNOUSERSITE"] = "1"
    code = ("import ptm_bench.world.floorplan as f, ptm; "
            "assert 'site-packages' in f.__file__ and 'site-packages' in ptm.__file__, (f.__file__, ptm.__file__); "
            "print(f.list_worlds(), f.load_world('office').name)")
    shown = subprocess.run([str(python), "-I", "-c", code], cwd=empty, env=env, capture_output=True, text=True)
    assert shown.returncode == 0, shown.stderr
    assert "'nested_loops', 'office', 'short_loop'] office" in shown.stdout
    listed = subprocess.run([str(environment_dir / "bin" / "ptm-bench"), "worlds"], cwd=empty, env=env,
                            capture_output=True, text=True)
    assert listed.returncode == 0, listed.stderr
    assert "office" in listed.stdout and "nested_loops" in listed.stdout
