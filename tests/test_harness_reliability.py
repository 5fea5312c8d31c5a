"""The harness under misuse (issue 10): bad config values, other experiments' tables, concurrent runs,
killed and interrupted sweeps, unwritable outputs, dead schedulers, corrupted files.

Cell functions here are tiny fakes (tests/sweep_fakes.py), so every test takes seconds.
"""

import pytest

from ptm_bench.evaluation import experiment, settings

BASE = '[sweep]\nworlds = ["nested_loops"]\nseeds = [0]\n'


def load(tmp_path, text, name="tiny.toml"):
    path = tmp_path / name
    path.write_text(text)
    return experiment.load_experiment(path)


# -- config values are checked at load, before any simulation ---------------------------------------------------

@pytest.mark.parametrize("bad, message", [
    (BASE + '[inference]\nn_samples = "100"\n', r"inference\.n_samples must be a positive integer, got '100'"),
    (BASE + '[inference]\nn_samples = 0\n', r"inference\.n_samples must be a positive integer"),
    (BASE + '[inference]\nchains = 2.5\n', r"inference\.chains must be a positive integer"),
    (BASE + '[inference]\nmoves = "fast"\n', r"inference\.moves must be one of 'auto', 'default', 'paper', 'guided', "
                                              r"got 'fast'"),
    (BASE + '[inference]\nburn_in = 1.5\n', r"inference\.burn_in must be a non-negative integer, got 1\.5"),
    (BASE + '[inference]\ntemperatures = [0.5, 1.0]\n', r"inference\.temperatures must be a list of inverse temperatures"),
    (BASE + '[inference]\nprior_rate = -1\n', r"inference\.prior_rate must be a positive number"),
    (BASE + '[odometry]\nmax_penalty = -5\n', r"odometry\.max_penalty must be a non-negative number, got -5"),
    (BASE + '[odometry]\nsigma_xy = "0.1"\n', r"odometry\.sigma_xy must be a positive number"),
    (BASE + '[appearance]\ncomponents = true\n', r"appearance\.components must be a positive integer"),
    (BASE + '[[variants]]\nname = "v"\nmodels = ["odometry"]\ninference = { burn_in = -1 }\n',
     r"variants\['v'\]\.inference\.burn_in must be a non-negative integer"),
    (BASE + '[appearance]\nmodel = "joint"\nevidence = "paper_eq19"\n',
     r"appearance\.evidence = 'paper_eq19' needs appearance\.model = 'independent'"),
    (BASE + '[[variants]]\nname = "v"\nmodels = ["appearance"]\nappearance = { model = "joint", outliers = true }\n',
     r"variants\['v'\]\.appearance\.outliers = true exists for appearance\.model = 'independent'"),
    (BASE + '[sweep.generator_options]\ncolour = 3\n', r"sweep\.generator_options\.colour is an unknown key"),
    (BASE + '[sweep.generator_options]\nmiss_rate = "0.1"\n', r"sweep\.generator_options\.miss_rate must be a float"),
    ('name = "../../elsewhere"\n' + BASE, r"name must be a folder name .* got '\.\./\.\./elsewhere'"),
    ('name = "a/b"\n' + BASE, r"name must be a folder name"),
    ('name = ".."\n' + BASE, r"name must be a folder name"),
])
def test_bad_config_values_are_refused_at_load_naming_the_key(tmp_path, bad, message):
    with pytest.raises(ValueError, match=message):
        load(tmp_path, bad)


def test_good_values_and_generator_options_still_load(tmp_path):
    config = load(tmp_path, 'name = "ok_1.2"\n' + BASE + '[sweep.generator_options]\nmiss_rate = 0\nroute = "main"\n'
                  '[inference]\nn_samples = 10\n[odometry]\nmax_penalty = 0\n[appearance]\nmodel = "joint"\n')
    assert config.name == "ok_1.2"
    assert config.settings.inference.n_samples == 10 and config.settings.odometry.max_penalty == 0.0
    assert config.settings.appearance.outliers is False  # "auto": the joint model has no outlier visits
    assert config.variants[0].appearance.outliers is False and config.variants[0].inference.n_samples == 10


@pytest.mark.parametrize("section, key", [(section, key) for section, keys in settings.REMOVED_KEYS.items()
                                          for key in keys])
def test_a_removed_key_is_refused_with_its_path_and_the_tag(tmp_path, section, key):
    """The keys that pinned old modes were removed; a config that sets one is told so, in a section and in a
    variant, not that the key is unknown."""
    for text, path in [(BASE + f"[{section}]\n{key} = 1\n", f"{section}.{key}"),
                       (BASE + f'[[variants]]\nname = "v"\nmodels = ["odometry"]\n{section} = {{ {key} = 1 }}\n',
                        f"variants['v'].{section}.{key}")]:
        with pytest.raises(ValueError) as refused:
            load(tmp_path, text)
        assert str(refused.value).startswith(f"{tmp_path / 'tiny.toml'}: {path} was removed; it pinned an old mode (")
        assert str(refused.value).endswith("see the tag results-2026-12-06")


@pytest.mark.parametrize("text, path", [
    ('colour = 1\n' + BASE, "colour"),
    (BASE + "colour = 1\n", "sweep.colour"),
    (BASE + "[inference]\ncolour = 1\n", "inference.colour"),
    (BASE + "[odometry]\ncolour = 1\n", "odometry.colour"),
    (BASE + "[appearance]\ncolour = 1\n", "appearance.colour"),
    (BASE + "[sweep.generator_options]\ncolour = 1\n", "sweep.generator_options.colour"),
    (BASE + '[[variants]]\nname = "v"\nmodels = ["odometry"]\ncolour = 1\n', "variants['v'].colour"),
    (BASE + '[[variants]]\nmodels = ["odometry"]\ninference = { colour = 1 }\n', "variants[0].inference.colour"),
    (BASE.replace('["nested_loops"]', '[{ generator = "corridor_grid", name = "g", rows = 2, cols = 2, loops = 1, '
                                      'place_density = 0.5, colour = 1 }]'), "sweep.worlds[0].colour"),
    (BASE.replace('["nested_loops"]', '[{ dataset = "a.npz", name = "a", calibration = ["b.npz"], colour = 1 }]'),
     "sweep.worlds[0].colour"),
], ids=["top", "sweep", "inference", "odometry", "appearance", "generator_options", "variant", "variant section",
        "generated world", "recorded world"])
def test_an_unknown_key_is_refused_at_every_level_with_its_path(tmp_path, text, path):
    with pytest.raises(ValueError) as refused:
        load(tmp_path, text)
    assert str(refused.value).startswith(f"{tmp_path / 'tiny.toml'}: {path} is an unknown key")


def test_defaults_has_the_29_keys_of_the_typed_records_and_the_samplers_defaults():
    """DEFAULTS is read off the settings records; the sampler settings a config leaves unset are those the library
    would take itself (``ptm.SamplerOptions``, ``ptm.tempered_mcmc``)."""
    import dataclasses
    import inspect

    import ptm

    assert sum(len(keys) for keys in settings.DEFAULTS.values()) == 29
    assert all(list(settings.DEFAULTS[name]) == [item.name for item in dataclasses.fields(record)]
               for name, record in settings.SECTIONS.items())
    assert experiment.DEFAULTS is settings.DEFAULTS
    library = ptm.SamplerOptions()
    inference = settings.InferenceSettings()
    assert (inference.burn_in, inference.chains, inference.max_doublings, inference.moves) == (
        library.burn_in, library.chains, library.max_doublings, library.moves)
    temperatures = inspect.signature(ptm.tempered_mcmc).parameters["temperatures"].default
    assert inference.temperatures == tuple(temperatures)


def test_settings_records_are_frozen_picklable_and_json_in_a_cells_definition(tmp_path):
    import dataclasses
    import json
    import pickle

    config = load(tmp_path, BASE + '[[variants]]\nname = "v"\nmodels = ["appearance", "odometry"]\n'
                                   'odometry = { max_penalty = 50 }\n')
    (variant,) = config.variants
    assert variant.models == ("odometry", "appearance") and variant.odometry.max_penalty == 50.0
    with pytest.raises(dataclasses.FrozenInstanceError):
        variant.odometry.max_penalty = 10.0
    assert pickle.loads(pickle.dumps(variant)) == variant
    assert json.loads(json.dumps(dataclasses.asdict(variant)))["odometry"]["max_penalty"] == 50.0
    same = load(tmp_path, BASE + '[[variants]]\nname = "v"\nmodels = ["odometry", "appearance"]\n'
                                 'odometry = { max_penalty = 50.0 }\n', name="same.toml")
    assert same.variants == config.variants  # 50 and 50.0 are one setting


# -- the sweep engine: tables of other experiments, locks, killed and interrupted runs ---------------------------

import os  # noqa: E402
import re  # noqa: E402
import signal  # noqa: E402
import subprocess  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

from ptm_bench.cli import main  # noqa: E402
from ptm_bench.cli.run import failure_report  # noqa: E402
from ptm_bench.evaluation import sweep  # noqa: E402
from ptm_bench.evaluation.datacache import dataset_for, dataset_path  # noqa: E402

TESTS = Path(__file__).resolve().parent
REPOSITORY = TESTS.parent


def cells_of(name, seeds=range(3), **extra):
    return [{"cell_id": f"seed={seed}", "experiment": name, "seed": seed, **extra} for seed in seeds]


def alive(pid: int) -> bool:
    """Running (a zombie, ended but not yet reaped, counts as gone)."""
    try:
        return Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0] != "Z"
    except (FileNotFoundError, IndexError):
        return False


def wait_for(condition, timeout=60.0):
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if condition():
            return True
        time.sleep(0.1)
    return False


def test_a_table_of_another_experiment_is_never_overwritten(tmp_path):
    path = tmp_path / "cells.csv"
    sweep.run_sweep(cells_of("exp1_penalty"), dict, path, workers=1, progress=False)
    before = path.read_bytes()
    for fresh in (False, True):
        with pytest.raises(ValueError, match="holds the table of experiment exp1_penalty, not of demo"):
            sweep.run_sweep(cells_of("demo"), dict, path, workers=1, fresh=fresh, progress=False)
    assert path.read_bytes() == before
    (tmp_path / "notes.csv").write_text("a,b\n1,2\n")  # a CSV that is no sweep table at all
    with pytest.raises(ValueError, match="no cell_id column"):
        sweep.run_sweep(cells_of("demo"), dict, tmp_path / "notes.csv", workers=1, progress=False)
    (tmp_path / "broken.csv").write_bytes(b"cell_id,x\n\"unterminated\n")
    with pytest.raises(ValueError, match="broken.csv is not a readable sweep table"):
        sweep.read_table(tmp_path / "broken.csv")


def test_a_fresh_sweep_recomputes_its_own_experiment_and_drops_its_old_rows(tmp_path):
    path = tmp_path / "cells.csv"
    sweep.run_sweep(cells_of("demo", seeds=[0, 1]), dict, path, workers=1, progress=False)
    table = sweep.run_sweep(cells_of("demo", seeds=[5]), dict, path, workers=1, fresh=True, progress=False)
    assert list(table["cell_id"]) == ["seed=5"]


def test_the_demo_refuses_an_out_holding_another_experiments_table(tmp_path, capsys):
    path = tmp_path / "cells.csv"
    sweep.run_sweep(cells_of("exp1_penalty"), dict, path, workers=1, progress=False)
    before = path.read_bytes()
    assert main(["demo", "--world", "short_loop", "--out", str(tmp_path)]) == 2
    assert "holds the table of experiment exp1_penalty" in capsys.readouterr().err
    assert path.read_bytes() == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["cells.csv"]


def test_a_second_run_of_a_table_is_refused_and_a_dead_runs_lock_is_taken_over(tmp_path):
    path = tmp_path / "cells.csv"
    with sweep.table_lock(path) as lock:
        assert lock.read_text().split()[0] == str(os.getpid())
        with pytest.raises(ValueError, match=rf"being written by another run \(pid {os.getpid()} on "):
            sweep.run_sweep(cells_of("t"), dict, path, workers=1, progress=False)
    assert not lock.exists()
    lock.write_text("999999999 elsewhere\n")  # left by a run that was killed: nobody holds it
    table = sweep.run_sweep(cells_of("t"), dict, path, workers=1, progress=False)
    assert len(table) == 3 and not lock.exists()


def test_zero_workers_are_refused():
    with pytest.raises(ValueError, match="workers must be a positive number of processes, got 0"):
        sweep.run_sweep(cells_of("t"), dict, "unused.csv", workers=0, progress=False)


KILLED_SWEEP = """
import sys
sys.path.insert(0, {tests!r})
from ptm_bench.evaluation import sweep
from sweep_fakes import sleepy_cell
if __name__ == "__main__":
    cells = [{{"cell_id": str(i), "experiment": "t", "seed": i, "sleep": 0 if i == 0 else 60, "pid_dir": {folder!r}}}
             for i in range(4)]
    sweep.run_sweep(cells, sleepy_cell, {folder!r} + "/cells.csv", workers=2, progress=False)
"""


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc")
def test_a_sigkilled_sweep_takes_its_workers_along_and_a_rerun_resumes(tmp_path):
    script = tmp_path / "sweep.py"
    script.write_text(KILLED_SWEEP.format(tests=str(TESTS), folder=str(tmp_path)))
    process = subprocess.Popen([sys.executable, str(script)], cwd=tmp_path, stderr=subprocess.PIPE)
    try:
        # cell 0 is finished and two sleeping cells run
        assert wait_for(lambda: len(list(tmp_path.glob("*.pid"))) >= 3 and (tmp_path / "cells.csv").is_file())
        workers = [int(p.stem) for p in tmp_path.glob("*.pid")]
        with pytest.raises(ValueError, match=rf"pid {process.pid} on "):
            sweep.run_sweep(cells_of("t"), dict, tmp_path / "cells.csv", workers=1, progress=False)
        process.kill()
        process.wait()
        assert wait_for(lambda: not any(alive(pid) for pid in workers), timeout=5), "orphaned workers"
        assert b"Traceback" not in process.stderr.read()
    finally:
        process.kill()
        process.wait()
        process.stderr.close()
    table = sweep.read_table(tmp_path / "cells.csv")
    assert table["cell_id"].tolist() == [0] and table["status"].tolist() == ["ok"]
    # the lock of the killed run is taken over; its finished cell is kept
    cells = [{"cell_id": str(i), "experiment": "t", "seed": i} for i in range(4)]
    table = sweep.run_sweep(cells, dict, tmp_path / "cells.csv", workers=2, progress=False)
    assert (table["status"] == "ok").all() and table.loc[0, "slept"] == 0


SEMAPHORE_SWEEP = """
import sys
sys.path.insert(0, {tests!r})
from ptm_bench.evaluation import sweep
from sweep_fakes import semaphore_cell
if __name__ == "__main__":
    cells = [{{"cell_id": str(i), "experiment": "t", "seed": i}} for i in range(16)]
    sweep.run_sweep(cells, semaphore_cell, {folder!r} + "/cells.csv", workers=2, progress=False)
"""


def test_cell_processes_end_normally_and_leave_no_semaphores_behind(tmp_path):
    """A cell process ends through the interpreter's shutdown, never cut short by its watch of the pipe once
    the sweep has read its outcome. Before the fix the resource tracker warned of leaked semaphores after
    3 of 6 runs of the demo, and after 4 of 4 runs of this test."""
    script = tmp_path / "sweep.py"
    script.write_text(SEMAPHORE_SWEEP.format(tests=str(TESTS), folder=str(tmp_path)))
    finished = subprocess.run([sys.executable, str(script)], cwd=tmp_path, capture_output=True, text=True,
                              timeout=120)
    assert finished.returncode == 0, finished.stderr
    assert "leaked semaphore" not in finished.stderr
    assert (sweep.read_table(tmp_path / "cells.csv")["status"] == "ok").all()


RUN_WITH_FAKE_CELLS = """
import sys
sys.path.insert(0, {tests!r})
import ptm_bench.cli.run
from sweep_fakes import {cell}
ptm_bench.cli.run.run_cell = {cell}
from ptm_bench.cli import main
if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
"""

SMALL_CONFIG = 'name = "small"\n[sweep]\nworlds = ["short_loop"]\nseeds = [0, 1, 2]\ncalibration_seeds = [10]\n'


def run_command(tmp_path, cell, *arguments, **options):
    script = tmp_path / "ptm_bench_fake.py"
    script.write_text(RUN_WITH_FAKE_CELLS.format(tests=str(TESTS), cell=cell))
    return subprocess.Popen([sys.executable, str(script), *arguments], cwd=tmp_path, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, **options)


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc")
@pytest.mark.parametrize("stop, status, said", [
    (signal.SIGINT, 130, "interrupted"),         # Ctrl-C: the terminal signals the whole process group
    (signal.SIGHUP, 129, "stopped by SIGHUP"),   # the terminal closes: the same, fork server and cells included
], ids=["ctrl-c", "sighup"])
def test_a_stopped_run_says_how_to_resume_in_one_line_and_leaves_its_table_intact(tmp_path, stop, status, said):
    """Before issue 47 SIGHUP killed the run at once (no word, the lock file left), and every stop left the
    semaphores of the cells it ended to the resource tracker's "leaked semaphore" warning."""
    (tmp_path / "small.toml").write_text(SMALL_CONFIG)
    folder = tmp_path / "out" / "small"
    process = run_command(tmp_path, "semaphore_sleepy_run_cell", "run", "small.toml", "--out", "out", "--workers",
                          "2", "--no-progress", start_new_session=True)
    try:
        assert wait_for(lambda: len(list(folder.glob("*.pid"))) >= 3 and (folder / "cells.csv").is_file())
        workers = [int(p.stem) for p in folder.glob("*.pid")]
        os.killpg(process.pid, stop)
        _, stderr = process.communicate(timeout=30)
    finally:
        process.kill()
    assert process.returncode == status
    assert "Traceback" not in stderr and "leaked" not in stderr and "resource_tracker" not in stderr, stderr
    lines = [line for line in stderr.splitlines() if line.strip()]
    assert lines == [f"ptm-bench run: {said}; every finished cell is in {Path('out/small/cells.csv')}; "
                     "rerun `ptm-bench run small.toml --out out` to resume"]
    assert wait_for(lambda: not any(alive(pid) for pid in workers), timeout=5)
    table = sweep.read_table(folder / "cells.csv")
    assert table["seed"].tolist() == [0] and table["status"].tolist() == ["ok"]
    assert sorted(path.name for path in folder.iterdir() if path.suffix != ".pid") == ["cells.csv"]  # no lock, no .tmp


@pytest.mark.parametrize("stop", [signal.SIGTERM, signal.SIGHUP], ids=["sigterm", "sighup"])
def test_sigterm_and_sighup_stop_a_command_as_ctrl_c_does(tmp_path, monkeypatch, capsys, stop):
    """``kill PID`` (a batch system's time limit) and a closing terminal: one line, exit status 128 + the signal's
    number, the process's handlers restored afterwards. Before issue 47 either killed the run without a word."""
    import ptm_bench.cli.run

    if signal.getsignal(stop) != signal.SIG_DFL:
        pytest.skip(f"{stop.name} has a handler in this process (a test runner's): the command leaves it alone")

    def stopped_sweep(*args, **kwargs):
        os.kill(os.getpid(), stop)
        time.sleep(10)  # the handler raises at once
        raise AssertionError(f"{stop.name} did not stop the command")

    monkeypatch.setattr(ptm_bench.cli.run, "run_sweep", stopped_sweep)
    (tmp_path / "small.toml").write_text(SMALL_CONFIG)
    assert main(["run", str(tmp_path / "small.toml"), "--out", str(tmp_path)]) == 128 + stop
    assert capsys.readouterr().err.strip() == (
        f"ptm-bench run: stopped by {stop.name}; every finished cell is in {tmp_path / 'small' / 'cells.csv'}; "
        f"rerun `ptm-bench run {tmp_path / 'small.toml'} --out {tmp_path}` to resume")
    assert signal.getsignal(stop) == signal.SIG_DFL


def test_failed_cells_are_summarised_with_the_retry_command():
    import pandas as pd

    table = pd.DataFrame({"status": ["ok", "error", "error", "error"],
                          "error": ["", "ValueError: no signal", "ValueError: no signal", "KilledWorker: x"]})
    report = failure_report(table, "ptm-bench run x.toml --out results --retry-failed")
    assert "  2 cells: ValueError: no signal" in report and "  1 cell: KilledWorker: x" in report
    assert report.endswith("rerun only those cells: ptm-bench run x.toml --out results --retry-failed")


# -- the command line: bad options fail at once, naming the option ------------------------------------------------

def test_zero_workers_are_refused_on_the_command_line(tmp_path, capsys):
    for command in (["demo"], ["run", "x.toml"]):
        with pytest.raises(SystemExit) as stop:
            main([*command, "--workers", "0", "--out", str(tmp_path)])
        assert stop.value.code == 2
        assert "--workers: must be a positive integer, got '0'" in capsys.readouterr().err


def test_an_out_that_is_a_file_or_cannot_be_created_is_refused(tmp_path, capsys):
    config = tmp_path / "small.toml"
    config.write_text(SMALL_CONFIG)
    a_file = tmp_path / "a_file"
    a_file.write_text("")
    assert main(["run", str(config), "--out", str(a_file)]) == 2
    assert f"--out {a_file} is a file, not a folder" in capsys.readouterr().err
    assert main(["demo", "--out", str(a_file)]) == 2
    assert "is a file, not a folder" in capsys.readouterr().err
    assert main(["speed", "--section", "core", "--out", str(a_file)]) == 2
    assert "is a file, not a folder" in capsys.readouterr().err
    if sys.platform.startswith("linux"):
        assert main(["run", str(config), "--out", "/proc/ptm_bench_test"]) == 2
        assert "--out /proc/ptm_bench_test: cannot create the folder" in capsys.readouterr().err


def test_speed_refuses_to_overwrite_a_file_that_is_not_its_table(tmp_path, capsys):
    (tmp_path / "speed.csv").write_text("cell_id,gt_mass\nx,1\n")
    assert main(["speed", "--section", "core", "--out", str(tmp_path)]) == 2
    assert "is not a speed table" in capsys.readouterr().err
    assert (tmp_path / "speed.csv").read_text() == "cell_id,gt_mass\nx,1\n"


def test_a_dead_scheduler_is_reported_at_once(tmp_path):
    pytest.importorskip("distributed")
    started = time.monotonic()
    with pytest.raises(ValueError, match=r"scheduler 'tcp://127.0.0.1:1': no Dask scheduler answered within 1 s"):
        sweep.run_sweep(cells_of("t"), dict, tmp_path / "cells.csv", scheduler="tcp://127.0.0.1:1",
                        connect_timeout=1, progress=False)
    assert time.monotonic() - started < 15


@pytest.mark.parametrize("command, promises", [
    ("run", ["OUT/NAME/", "cells.csv", "summary.md", "docs/model.md section 6", "experiment.DEFAULTS", "resumes"]),
    ("demo", ["results/demo", "cells.csv", "summary.md", "docs/model.md section 6", "experiment.DEFAULTS",
              "another experiment's"]),
    ("speed", ["speed.csv", "core", "simulator", "odometry", "evaluation", "docs/model.md section 6"]),
])
def test_help_says_where_output_goes_what_each_section_is_and_where_keys_are_documented(command, promises, capsys):
    with pytest.raises(SystemExit):
        main([command, "--help"])
    text = capsys.readouterr().out
    for promise in promises:
        assert promise in text


# -- corrupted files -------------------------------------------------------------------------------------------

def corrupt(kind: str, path: Path) -> None:
    import json

    import numpy as np

    import ptm

    if kind == "truncated":
        ptm.Dataset(signatures=np.arange(12.0).reshape(4, 3)).save(path)
        path.write_bytes(path.read_bytes()[:-40])
    elif kind == "renamed .npy":
        np.save(path.with_suffix(".npy"), np.arange(4.0))
        path.with_suffix(".npy").rename(path)
    elif kind == "bad meta":
        np.savez(path, signatures=np.arange(12.0).reshape(4, 3), meta=np.array(json.dumps({"a": 1})[:-1]))
    else:
        path.write_bytes(b"not a zip file at all")


@pytest.mark.parametrize("kind", ["truncated", "renamed .npy", "bad meta", "garbage"])
def test_a_corrupted_cached_dataset_is_an_error_naming_the_file(tmp_path, kind):
    path = dataset_path("short_loop", 0.0, 1.0, 0, cache_dir=tmp_path)
    corrupt(kind, path)
    with pytest.raises(ValueError, match=rf"cached dataset {path} is unreadable .*delete it"):
        dataset_for("short_loop", 0.0, 1.0, 0, cache_dir=tmp_path)


def test_the_appearance_check_refuses_an_experiment_folder(tmp_path, capsys):
    (tmp_path / "cells.csv").write_text("cell_id,experiment\nx,exp1_penalty\n")
    (tmp_path / "summary.md").write_text("exp1's summary")
    assert main(["appearance-check", "--runs", "1", "--calibration-runs", "1", "--out", str(tmp_path)]) == 2
    assert "holds an experiment's table" in capsys.readouterr().err
    assert (tmp_path / "summary.md").read_text() == "exp1's summary"


def test_the_demo_refuses_a_folder_with_another_commands_report(tmp_path, capsys):
    (tmp_path / "summary.md").write_text("# Appearance predictive check")
    (tmp_path / "checks.csv").write_text("world,model\noffice,joint\n")
    assert main(["demo", "--world", "short_loop", "--out", str(tmp_path)]) == 2
    assert "holds a summary.md that is not the demo's" in capsys.readouterr().err
    assert (tmp_path / "summary.md").read_text() == "# Appearance predictive check"


# -- issue 47: copies of the scored run, temporary and damaged tables, report paths, names -------------------------

def test_a_recorded_run_calibrated_on_a_copy_of_itself_is_refused_naming_both_files(tmp_path):
    """Before issue 47 only the paths were compared: a copy of the scored run under another name calibrated it."""
    from helpers import square_loop_dataset

    from ptm_bench.evaluation.calibration import calibration_datasets

    scored = square_loop_dataset(0).save(tmp_path / "loop0.npz")
    other = square_loop_dataset(10).save(tmp_path / "loop10.npz")
    copy = square_loop_dataset(0).replace(meta={"source": "a copy"}).save(tmp_path / "copy.npz")
    config = experiment.parse_experiment({
        "sweep": {"worlds": [{"dataset": str(scored), "name": "loop", "calibration": [str(other), str(copy)]}],
                  "seeds": [0]},
        "variants": [{"name": "appearance", "models": ["appearance"]}]})
    (cell,) = experiment.expand_cells(config, tmp_path / "results")
    with pytest.raises(ValueError, match=rf"calibration: .*{copy}.* holds the same run as {scored}"):
        calibration_datasets(cell)


def test_a_killed_runs_temporary_table_is_deleted_by_the_next_run(tmp_path):
    """A SIGKILL between the atomic writer's write and its rename leaves its temporary file; before issue 47 it
    stayed beside the table for good."""
    path = tmp_path / "cells.csv"
    left = tmp_path / ".cells.csv.k1ll3d00.tmp"
    left.write_bytes(b"")
    another = tmp_path / ".summary.md.k1ll3d00.tmp"  # another file's: not the sweep's to delete
    another.write_bytes(b"")
    sweep.run_sweep(cells_of("t"), dict, path, workers=1, progress=False)
    assert not left.exists() and another.exists()


@pytest.mark.parametrize("damage, problem", [
    (lambda line: line.rsplit(",", 2)[0], "a damaged row (4 fields where the header has 6)"),
    (lambda line: line.replace(",ok,", ",okay,"), "a damaged row (status 'okay' is neither 'ok' nor 'error')"),
], ids=["fields-lost", "status"])
def test_a_damaged_row_of_the_table_is_named_by_file_and_line(tmp_path, damage, problem):
    """Before issue 47 a row that lost its last fields read as a failed cell with a blank error."""
    path = tmp_path / "cells.csv"
    sweep.run_sweep(cells_of("t"), dict, path, workers=1, progress=False)
    lines = path.read_text().splitlines()
    assert lines[0] == "cell_id,experiment,seed,status,error,attempts"
    lines[2] = damage(lines[2])
    path.write_text("\n".join(lines) + "\n")
    message = rf"{path}, line 3: {re.escape(problem)}; delete that line and rerun"
    with pytest.raises(ValueError, match=message):
        sweep.read_table(path)
    with pytest.raises(ValueError, match=message):
        sweep.run_sweep(cells_of("t"), dict, path, workers=1, progress=False)


def test_junit_must_be_a_file_in_an_existing_folder_and_is_checked_before_the_sweep(tmp_path, monkeypatch, capsys):
    """Before issue 47 ``--junit DIR`` ran the whole sweep, then failed as it wrote the report: "error: DIR Is a
    directory", exit status 1."""
    import ptm_bench.cli.run
    from sweep_fakes import scored_cell

    monkeypatch.setattr(ptm_bench.cli.run, "run_cell", scored_cell)
    config = tmp_path / "small.toml"
    config.write_text(SMALL_CONFIG + '[checks]\ngt_mass = ">= 0.9"\n')
    arguments = ["run", str(config), "--out", str(tmp_path / "out"), "--workers", "1", "--no-figures",
                 "--no-progress", "--check", "--junit"]
    assert main([*arguments, str(tmp_path)]) == 2
    assert f"--junit {tmp_path} is a folder; --junit needs the path of a file" in capsys.readouterr().err
    assert main([*arguments, str(tmp_path / "missing" / "checks.xml")]) == 2
    assert f"folder {tmp_path / 'missing'} does not exist" in capsys.readouterr().err
    assert not (tmp_path / "out" / "small" / "cells.csv").exists()  # refused before any cell ran


@pytest.mark.parametrize("name", ["two\nlines", "tab\there", "bell\a", "line\u2028separator"])
def test_a_variant_name_with_a_control_character_is_refused_naming_the_variant(tmp_path, name):
    """Before issue 47 a newline in a variant's name was accepted, into every cell id and row of that variant."""
    with pytest.raises(ValueError, match=rf"variants\[{re.escape(repr(name))}\]\.name must be a non-empty string of "
                                         "printable characters"):
        experiment.parse_experiment({"sweep": {"worlds": ["short_loop"], "seeds": [0]},
                                     "variants": [{"name": name, "models": ["appearance"]}]})
