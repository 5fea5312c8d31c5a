"""Packaging: every package is listed, and a built wheel runs outside the checkout with its preset worlds."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import sysconfig
import tomllib
import venv
import zipfile
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
# What a wheel is built from: the build runs in a copy of these, never in the checkout, whose build/ folder
# (left by an earlier build, or an editable install) made setuptools fail with "File exists" in CI.
SOURCES = ("pyproject.toml", "README.md", "ptm", "ptm_bench", "worlds")


def _pip(python, *arguments: str) -> subprocess.CompletedProcess:
    """``python -m pip``, offline and apart from the user's pip configuration and cache (nothing outside the test)."""
    env = {key: value for key, value in os.environ.items() if not key.startswith("PIP_")}
    env["PIP_CONFIG_FILE"] = os.devnull
    return subprocess.run([str(python), "-m", "pip", *arguments, "--no-index", "--no-cache-dir",
                           "--disable-pip-version-check", "--quiet"], env=env, capture_output=True, text=True)


def _declared() -> dict:
    return tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]


def test_every_package_folder_is_listed_in_pyproject():
    found = {".".join(path.parent.relative_to(ROOT).parts)
             for package in ("ptm", "ptm_bench") for path in (ROOT / package).rglob("__init__.py")}
    found.add("ptm_bench.world.presets")  # the worlds/ folder, mapped into the harness
    assert found == set(_declared()["packages"])
    assert _declared()["package-dir"] == {"ptm_bench.world.presets": "worlds"}


@pytest.fixture(scope="module")
def sources(tmp_path_factory) -> Path:
    """A copy of what a wheel is built from (one moment of the checkout, whatever is saved meanwhile)."""
    source = tmp_path_factory.mktemp("source")
    for name in SOURCES:
        if (ROOT / name).is_dir():
            shutil.copytree(ROOT / name, source / name, ignore=shutil.ignore_patterns("__pycache__", "*.egg-info"))
        else:
            shutil.copy2(ROOT / name, source / name)
    return source


@pytest.fixture(scope="module")
def wheel(tmp_path_factory, sources) -> Path:
    out = tmp_path_factory.mktemp("wheel")
    build = _pip(sys.executable, "wheel", str(sources), "--no-deps", "--no-build-isolation", "--wheel-dir", str(out))
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


VERSIONS = ("from ptm_bench.simulation.code_version import code_version; "
            "print(code_version('ptm_bench.evaluation.cell'), code_version('ptm_bench.simulation.generate'))")


@pytest.mark.slow
def test_an_installed_wheel_runs_from_an_empty_folder(wheel, sources, tmp_path):
    """A non-editable install lists and loads the worlds anywhere, and versions its code as the source tree does.

    The environment sees no system site packages: its dependencies are those of the environment running this
    test (its purelib and platlib folders, named in a ``.pth`` file), so nothing comes from the base Python, the
    user's home or the network.
    """
    environment_dir = tmp_path / "venv"
    venv.create(environment_dir, system_site_packages=False, with_pip=True)
    python = environment_dir / "bin" / "python"
    site_packages = subprocess.run([str(python), "-I", "-c", "import sysconfig; print(sysconfig.get_path('purelib'))"],
                                   check=True, capture_output=True, text=True).stdout.strip()
    dependencies = dict.fromkeys(sysconfig.get_path(key) for key in ("purelib", "platlib"))
    (Path(site_packages) / "test_environment.pth").write_text("\n".join(dependencies) + "\n")
    # The environment's own pip: it installs the wheel into the environment and leaves the editable install
    # of this checkout outside it alone ("outside environment"); pip --prefix from here would uninstall it.
    installed = _pip(python, "install", "--no-deps", str(wheel))
    assert installed.returncode == 0, installed.stderr
    empty = tmp_path / "elsewhere"
    empty.mkdir()
    env = {key: value for key, value in os.environ.items() if key not in ("PYTHONPATH",)}
    env["PYTHONNOUSERSITE"] = "1"
    code = ("import os, sys, ptm_bench.world.floorplan as f, ptm; "
            "inside = [os.path.realpath(m.__file__).startswith(os.path.realpath(sys.prefix)) for m in (f, ptm)]; "
            "assert inside == [True, True], (sys.prefix, f.__file__, ptm.__file__); "
            f"print(f.list_worlds(), f.load_world('office').name); {VERSIONS}")
    shown = subprocess.run([str(python), "-I", "-c", code], cwd=empty, env=env, capture_output=True, text=True)
    assert shown.returncode == 0, shown.stderr
    worlds, installed_versions = shown.stdout.strip().splitlines()
    assert worlds.endswith("'nested_loops', 'office', 'short_loop'] office")
    # the same code read from the source tree (its folder first on the path) has the same versions
    from_source = subprocess.run([sys.executable, "-c", VERSIONS], cwd=sources, env=env, capture_output=True,
                                 text=True)
    assert from_source.returncode == 0, from_source.stderr
    assert installed_versions == from_source.stdout.strip() and installed_versions.startswith("sha256:")
    listed = subprocess.run([str(environment_dir / "bin" / "ptm-bench"), "worlds"], cwd=empty, env=env,
                            capture_output=True, text=True)
    assert listed.returncode == 0, listed.stderr
    assert "office" in listed.stdout and "nested_loops" in listed.stdout
