"""Calibration that transfers (issue 44, item 1): a cell's held-out runs drive other floors than the scored one.

By default (``sweep.calibration = "other_floors"``) a preset is calibrated on the other presets and generated
grids, a generated grid on grids of other sizes and seeds; ``"same_floor"`` keeps the old protocol. A held-out
run with the scored run's content is refused whatever its name; the sources and ``summary.md`` name the floors.
The runs are hand-made square loops put into the cache where the cells look for them, so nothing is simulated.
"""

import copy
import json
import shutil

import pandas as pd
import pytest

from ptm_bench.evaluation import calibration, datacache, scoring
from ptm_bench.evaluation.experiment import expand_cells, parse_experiment
from ptm_bench.evaluation.held_out import content_hash
from ptm_bench.reporting.summary import write_summary
from ptm_bench.world.floorplan import WORLDS_DIR, load_world

from helpers import square_loop_dataset

SEEDS = [1000, 1001, 1002, 1003, 1004]
CONFIG = {"name": "transfer", "baselines": ["greedy_odometry"],
          "sweep": {"worlds": ["office"], "seeds": [0], "calibration_seeds": SEEDS},
          "variants": [{"name": "odometry", "models": ["odometry"]}]}
GRID = {"generator": "corridor_grid", "name": "grid3x3", "rows": 3, "cols": 3, "loops": 2, "place_density": 0.6}


def cells(tmp_path, **sweep):
    config = copy.deepcopy(CONFIG)
    config["sweep"].update(sweep)
    return expand_cells(parse_experiment(config, source="test"), tmp_path)


def layout(floor):
    return floor.nodes, floor.corridors, floor.places, floor.routes


def cache_runs(cell, scored=None):
    """Hand-made runs in the cache: the scored run (``scored``, else loop 0) and one loop per held-out run."""
    inputs = cell["inputs"]
    held_out = calibration.held_out_floors(inputs["world_spec"], inputs["calibration"], inputs["calibration_seeds"])
    runs = [(inputs["world_spec"], cell["seed"], scored or square_loop_dataset(0))]
    runs += [(spec, seed, square_loop_dataset(seed)) for _, spec, seed in held_out]
    for world, seed, run in runs:
        path = datacache.dataset_path(world, cell["aliasing"], cell["noise"], seed, inputs["generator_options"],
                                      inputs["cache_dir"], None)
        path.parent.mkdir(parents=True, exist_ok=True)
        run.save(path)
    return held_out


def test_by_default_a_preset_is_calibrated_on_other_presets_and_generated_grids(tmp_path):
    cell = cells(tmp_path)[0]
    assert cell["inputs"]["calibration"] == "other_floors"
    held_out = cache_runs(cell)
    assert [(name, seed) for name, _, seed in held_out] == [
        ("nested_loops", 1000), ("short_loop", 1001), ("grid3x3", 1002), ("grid4x4", 1003), ("nested_loops", 1004)]
    office = layout(load_world("office"))
    assert all(layout(datacache.resolve_world(spec, seed)) != office for _, spec, seed in held_out)
    runs = calibration.calibration_datasets(cell)
    assert [run.meta[calibration.HELD_OUT_FLOOR] for run in runs] == [name for name, _, _ in held_out]
    rate, source = calibration.prior_rate(None, 9, runs)
    assert "on 5 held-out runs [nested_loops, short_loop, grid3x3, grid4x4] x N=9 = 4," in source
    assert calibration.floors_in(source) == ["nested_loops", "short_loop", "grid3x3", "grid4x4"]


def test_a_floor_file_is_never_calibrated_on_a_preset_of_its_layout_whatever_its_name(tmp_path):
    renamed = tmp_path / "my_office.toml"
    renamed.write_text((WORLDS_DIR / "office.toml").read_text().replace('name = "office"', 'name = "my_office"'))
    names = [name for name, _ in calibration.other_floors(str(renamed))]
    assert names == ["nested_loops", "short_loop", "grid3x3", "grid4x4"]  # office's layout is left out


def test_a_generated_grid_is_calibrated_on_grids_of_other_sizes_and_seeds():
    scored = {**GRID, "seed": 7}  # a world seed fixed in the table is not the held-out runs' seed
    held_out = calibration.held_out_floors(scored, "other_floors", [10, 11, 12])
    assert [(name, spec["rows"], spec["cols"], seed) for name, spec, seed in held_out] == [
        ("grid4x3", 4, 3, 10), ("grid3x4", 3, 4, 11), ("grid4x3", 4, 3, 12)]
    assert all("seed" not in spec and spec["loops"] == 2 for _, spec, _ in held_out)
    floor = layout(datacache.resolve_world(scored, 0))
    assert all(layout(datacache.resolve_world(spec, seed)) != floor for _, spec, seed in held_out)


def test_same_floor_keeps_the_old_held_out_runs_and_is_another_cell(tmp_path):
    default, old = cells(tmp_path), cells(tmp_path, calibration="same_floor")
    assert all(new["definition"] != before["definition"] for new, before in zip(default, old))
    cell = old[0]
    assert calibration.held_out_floors("office", "same_floor", SEEDS) == [("office", "office", seed) for seed in SEEDS]
    cache_runs(cell)
    runs = calibration.calibration_datasets(cell)
    assert [content_hash(run) for run in runs] == [content_hash(square_loop_dataset(seed)) for seed in SEEDS]
    assert calibration.described(runs) == "5 held-out runs [office]"


def test_a_cells_definition_follows_the_floors_its_held_out_runs_drive(tmp_path, monkeypatch):
    before = [cell["definition"] for cell in cells(tmp_path)]
    assert [cell["definition"] for cell in cells(tmp_path)] == before
    grid3x3, grid4x4 = calibration.CALIBRATION_GRIDS
    monkeypatch.setattr(calibration, "CALIBRATION_GRIDS", ({**grid3x3, "loops": 1}, grid4x4))  # as a floor edited
    assert all(new["definition"] != old for new, old in zip(cells(tmp_path), before))


def test_an_unknown_calibration_protocol_is_refused_naming_the_key():
    config = copy.deepcopy(CONFIG)
    config["sweep"]["calibration"] = "nearby"
    with pytest.raises(ValueError, match=r"sweep\.calibration must be one of 'other_floors', 'same_floor', got "
                                         r"'nearby'"):
        parse_experiment(config, source="test")


def test_a_held_out_run_with_the_scored_runs_content_is_refused(tmp_path):
    cell = cells(tmp_path)[0]
    cache_runs(cell, scored=square_loop_dataset(1002))  # the grid3x3 run at seed 1002 is a copy of the scored run
    with pytest.raises(ValueError, match=r"held-out run 2 \(grid3x3 at seed 1002\) holds the same run as the scored "
                                         r"run of office\|a=0\|noise=1\|seed=0\|odometry"):
        calibration.calibration_datasets(cell)


def test_a_copy_of_the_scored_log_under_another_name_is_refused(tmp_path):
    scored, other = tmp_path / "scored.npz", tmp_path / "other.npz"
    square_loop_dataset(0).save(scored)
    square_loop_dataset(1).save(other)
    shutil.copy(scored, tmp_path / "renamed.npz")
    world = {"dataset": str(scored), "name": "scored", "calibration": [str(other), str(tmp_path / "renamed.npz")]}
    cell = cells(tmp_path, worlds=[world])[0]
    with pytest.raises(ValueError, match=r"held-out run 1 \(.*renamed\.npz\) holds the same run"):
        calibration.calibration_datasets(cell)
    world["calibration"] = [str(other)]
    (run,) = calibration.calibration_datasets(cells(tmp_path, worlds=[world])[0])
    assert run.meta[calibration.HELD_OUT_FLOOR] == "other"


@pytest.mark.parametrize("protocol, says", [("other_floors", "floors other than the scored one"),
                                            ("same_floor", "the scored floor itself")])
def test_the_summary_names_the_floors_each_parameter_was_calibrated_on(tmp_path, protocol, says):
    experiment = parse_experiment({**copy.deepcopy(CONFIG), "sweep": {**CONFIG["sweep"], "calibration": protocol}},
                                  source="test")
    floors = "nested_loops, short_loop" if protocol == "other_floors" else "office"
    rows = []
    for cell in expand_cells(experiment, tmp_path):
        row = {key: value for key, value in cell.items() if isinstance(value, (str, int, float))}
        row.update(scoring.score(scoring.point_mass((0, 1, 0)), (0, 1, 0)), status="ok", error="", wall_s=1.0,
                   top5=json.dumps([[[0, 1, 0], 1.0]]), true_labels=json.dumps([0, 1, 0]),
                   source_sigma_topology="sensor spec: detection radius 1 m / sqrt 2")
        if cell["method"] == "baseline":
            row["source_threshold"] = f"calibrated: best mean ARI on 2 held-out runs [{floors}]"
        else:
            row["source_prior_rate"] = f"calibrated: rate for E[places] = 0.5 places/detection on 2 held-out runs " \
                                       f"[{floors}] x N=3 = 1.5"
            row["source_penalty_radius"] = f"calibrated: 0.75 x 2 m, the closest detections of different places on " \
                                           f"2 held-out runs [{floors}]"
        rows.append(row)
    text = write_summary(experiment, pd.DataFrame(rows), tmp_path, figures=False).read_text()
    section = text[text.index("## Calibration floors and logs"):]
    assert f'`sweep.calibration = "{protocol}"`: a simulated world on {says}' in section
    assert f"| office | prior_rate, penalty_radius, threshold | {floors} |" in section
    assert "sigma_topology" not in section.split("## Where the parameters came from")[0]  # a sensor spec, no floors


def scaled(dataset, factor):
    """The same run on a floor ``factor`` times larger: positions and odometry translations scaled."""
    odometry, poses = dataset.odometry.copy(), dataset.true_poses.copy()
    odometry[:, :2] *= factor
    poses[:, :2] *= factor
    return dataset.replace(odometry=odometry, true_poses=poses, odometry_cov=None)


@pytest.mark.parametrize("scale", [0.25, 1.0, 6.0])
def test_the_penalty_radius_follows_the_scored_floors_own_spacing_not_the_held_out_floors(scale):
    """A floor calibrated on one of another scale gets the radius of its own spacing: the held-out runs give a
    dimensionless ratio (closest places / route spacing), the scored run's odometry its scale."""
    from ptm_bench.evaluation.models import build_models
    from ptm_bench.evaluation.settings import Variant

    held_out = [square_loop_dataset(seed) for seed in (1, 2)]                   # 2 m squares
    scored = scaled(square_loop_dataset(0), scale)
    same_floor = calibration.penalty_radius(None, 0.75, [scaled(run, scale) for run in held_out])[0]
    variant = Variant("odometry", models=("odometry",))
    batch = build_models(variant, scored, held_out).used
    assert batch["penalty_radius"] == pytest.approx(same_floor, rel=0.05), (batch["penalty_radius"], same_floor)
    assert batch["source_penalty_radius"].endswith("m, this run's route spacing")
    online = build_models(variant, scored, held_out, online=True).used  # the run's spacing is known only at its end
    assert online["penalty_radius"] == pytest.approx(calibration.penalty_radius(None, 0.75, held_out)[0])


def test_a_run_that_never_moves_between_detections_cannot_scale_the_radius():
    still = square_loop_dataset(0)
    still = still.replace(odometry=still.odometry * 0.0)
    with pytest.raises(ValueError, match="route spacing: the median distance between consecutive detections is 0"):
        calibration.penalty_radius(None, 0.75, [square_loop_dataset(1)], still)
