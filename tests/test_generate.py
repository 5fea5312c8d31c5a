"""Dataset generation end to end: reproducibility, ground truth, noise-free odometry, aliasing, bad input, CLI."""


import numpy as np
import pytest

import ptm
from ptm_bench.cli import main
from ptm_bench.world.floorplan import corridor_grid, load_world
from ptm_bench.simulation.generate import build_world, generate_dataset, true_odometry
from ptm_bench.simulation.robot import RigConfig

SMALL = RigConfig(image_height=24, image_width=32)
REQUIRED_META = ("world", "aliasing", "noise", "seed", "min_place_spacing", "detection_radius", "places",
                 "n_palettes", "generator_version", "camera")


def _short(aliasing=0.3, noise=1.0, seed=0, **options):
    return generate_dataset("short_loop", aliasing, noise, seed, images=False, rig=SMALL, **options)


@pytest.fixture(scope="module")
def short_run():
    return _short()


def test_dataset_has_the_contracted_fields(short_run):
    ds = short_run
    assert ds.n == 9
    assert ds.labels.tolist() == [0, 1, 2, 3, 0, 1, 2, 3, 0]
    assert ds.odometry.shape == (8, 3) and ds.odometry_cov.shape == (8, 3, 3)
    assert ds.signatures.shape == (9, 5) and ds.true_poses.shape == (9, 3) and ds.panoramas is None
    assert all(key in ds.meta for key in REQUIRED_META)
    assert ds.meta["places"] == {str(p): list(xy) for p, xy in load_world("short_loop").places.items()}
    assert ds.meta["camera"]["camera_count"] == 8


@pytest.mark.parametrize(
    "world, labels",
    [("office", [0, 4, 1, 2, 5, 3, 0, 4, 1]), ("nested_loops", [0, 1, 2, 3, 4, 5, 0, 1, 6, 7, 2, 3])],
)
def test_presets_give_the_papers_detection_sequences(world, labels):
    # Generation time is a benchmark (`ptm-bench speed --section simulator`), not a test.
    ds = generate_dataset(world, 0.3, 1.0, 0, images=True)  # default eight-camera resolution
    assert ds.labels.tolist() == labels
    assert ds.panoramas.shape == (len(labels), RigConfig().image_height, ds.meta["panorama"]["width"], 3)


def test_same_seed_gives_identical_arrays_and_different_seeds_differ(short_run):
    again = _short()
    for name in ("odometry", "odometry_cov", "signatures", "labels", "true_poses"):
        assert getattr(again, name).tobytes() == getattr(short_run, name).tobytes(), name
    assert again.meta == short_run.meta
    other = _short(seed=1)
    assert not np.array_equal(other.odometry, short_run.odometry)
    assert not np.array_equal(other.signatures, short_run.signatures)
    assert not np.array_equal(other.true_poses, short_run.true_poses)


def test_noise_level_changes_only_the_odometry(short_run):
    louder = _short(noise=2.0)
    for name in ("signatures", "labels", "true_poses"):
        assert np.array_equal(getattr(louder, name), getattr(short_run, name)), name
    assert louder.meta["palette_of_place"] == short_run.meta["palette_of_place"]
    assert not np.array_equal(louder.odometry, short_run.odometry)


def test_noise_zero_gives_the_true_odometry():
    ds = _short(noise=0.0)
    assert np.abs(ds.odometry - true_odometry(ds)).max() < 1e-9


def test_odometry_is_expressed_in_the_earlier_detections_frame(short_run):
    exact = _short(noise=0.0)
    poses = exact.true_poses
    for k in range(1, exact.n):
        c, s = np.cos(poses[k - 1, 2]), np.sin(poses[k - 1, 2])
        dx, dy = poses[k, :2] - poses[k - 1, :2]
        expected = (c * dx + s * dy, -s * dx + c * dy, np.angle(np.exp(1j * (poses[k, 2] - poses[k - 1, 2]))))
        assert exact.odometry[k - 1] == pytest.approx(expected, abs=1e-9)
    # with noise, the error of each row is within a few propagated standard deviations
    error = short_run.odometry - true_odometry(short_run)
    error[:, 2] = np.angle(np.exp(1j * error[:, 2]))
    assert np.all(np.abs(error) < 5 * np.sqrt(np.diagonal(short_run.odometry_cov, axis1=1, axis2=2)))


def test_detections_lie_within_the_radius_of_their_place(short_run):
    radius = short_run.meta["detection_radius"]
    for label, pose in zip(short_run.labels, short_run.true_poses):
        assert np.linalg.norm(pose[:2] - np.array(short_run.meta["places"][str(label)])) <= radius


def test_aliasing_one_shares_one_palette_and_zero_gives_each_place_its_own():
    floor = load_world("nested_loops")
    for aliasing, distinct in ((1.0, 1), (0.0, len(floor.places))):
        model, palette_of_place, palettes = build_world(floor, aliasing, np.random.default_rng(3), SMALL)
        assert len(set(palette_of_place.values())) == len(palettes) == distinct
        looks = {}
        for geom in range(model.ngeom):
            name = model.geom(geom).name
            if name.startswith("place_") and "_panel_" in name:
                looks.setdefault(int(name.split("_")[1]), set()).add(tuple(np.round(model.geom_rgba[geom], 4)))
        sets = [frozenset(colours) for colours in looks.values()]
        assert (len(set(sets)) == 1) == (distinct == 1)


def test_aliasing_makes_distinct_places_look_alike():
    def spread(ds):
        distances = np.linalg.norm(ds.signatures[:, None] - ds.signatures[None], axis=2)
        different = ds.labels[:, None] != ds.labels[None]
        return distances[different].mean()

    assert spread(_short(aliasing=1.0)) < 0.5 * spread(_short(aliasing=0.0))


def test_a_procedural_grid_generates():
    grid = corridor_grid(2, 3, loops=1, place_density=0.7, seed=2)
    ds = generate_dataset(grid, 0.5, 1.0, 0, images=False, rig=SMALL)
    assert ds.n >= len(grid.places)
    assert set(ds.labels.tolist()) <= set(grid.places)


def test_misses_and_false_detections_reach_the_dataset():
    clean = generate_dataset("office", 0.5, 1.0, 0, images=False, rig=SMALL)
    noisy = generate_dataset("office", 0.5, 1.0, 0, images=False, rig=SMALL, miss_rate=0.2, false_rate=0.03)
    false = noisy.meta["detector"]["false_detections"]
    assert false and all(noisy.labels[i] < 0 for i in false)
    assert sorted(noisy.labels[noisy.labels < 0].tolist()) == list(range(-len(false), 0))
    true_visits = noisy.n - len(false)
    assert true_visits < clean.n  # with seed 0 at least one of the nine visits is missed
    places = np.array([clean.meta["places"][key] for key in clean.meta["places"]])
    far = np.linalg.norm(noisy.true_poses[false, None, :2] - places[None], axis=2).min(axis=1)
    assert np.all(far > 2 * noisy.meta["detection_radius"])


def test_images_are_kept_unless_asked_not_to_and_render_reproducibly():
    ds = generate_dataset("short_loop", 0.0, 1.0, 0, images=True, rig=SMALL)
    assert ds.panoramas.shape[:2] == (9, SMALL.image_height) and ds.panoramas.dtype == np.uint8
    again = generate_dataset("short_loop", 0.0, 1.0, 0, images=True, rig=SMALL)
    assert again.panoramas.tobytes() == ds.panoramas.tobytes()


@pytest.mark.parametrize(
    "arguments, message",
    [
        (("atlantis", 0.5, 1.0, 0), "known worlds"),
        (("short_loop", 1.5, 1.0, 0), "aliasing"),
        (("short_loop", 0.5, -1.0, 0), "noise"),
        (("short_loop", 0.5, 1.0, -3), "seed"),
    ],
)
def test_bad_arguments_are_clear_errors(arguments, message):
    with pytest.raises(ValueError, match=message):
        generate_dataset(*arguments, images=False, rig=SMALL)


def test_cli_generate_writes_one_file_and_a_summary(tmp_path, capsys):
    out = tmp_path / "run.npz"
    code = main(["generate", "--world", "short_loop", "--aliasing", "0.5", "--noise", "1", "--seed", "4",
                 "--out", str(out), "--no-images"])
    assert code == 0
    summary = capsys.readouterr().out.strip().splitlines()
    assert len(summary) == 1 and "9 detections" in summary[0]
    ds = ptm.Dataset.load(out)
    assert ds.n == 9 and ds.meta["seed"] == 4 and ds.panoramas is None
    assert sorted(p.name for p in tmp_path.iterdir()) == ["run.npz"]
    figure = tmp_path / "run.png"
    assert main(["show", str(out), "--out", str(figure)]) == 0
    assert figure.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


@pytest.mark.parametrize(
    "change, message",
    [
        ({"--world": "atlantis"}, "known worlds: nested_loops, office, short_loop"),
        ({"--aliasing": "-0.2"}, "aliasing"),
        ({"--noise": "-1"}, "noise"),
        ({"--out": "{tmp}/missing/run.npz"}, "does not exist"),
        ({"--out": "{tmp}/run.txt"}, ".npz"),
    ],
)
def test_cli_bad_input_fails_cleanly_and_leaves_nothing(tmp_path, capsys, change, message):
    options = {"--world": "short_loop", "--aliasing": "0.5", "--noise": "1", "--seed": "0", "--out": "{tmp}/run.npz"}
    options.update(change)
    argv = ["generate"] + [part.format(tmp=tmp_path) for item in options.items() for part in item] + ["--no-images"]
    assert main(argv) == 2
    assert message in capsys.readouterr().err
    assert list(tmp_path.rglob("*")) == []


def test_a_failed_write_leaves_no_half_written_file(tmp_path, monkeypatch):
    def explode(handle, **arrays):
        handle.write(b"partial")
        raise OSError("disk full")

    monkeypatch.setattr(np, "savez_compressed", explode)
    out = tmp_path / "run.npz"
    code = main(["generate", "--world", "short_loop", "--aliasing", "0", "--noise", "1", "--seed", "0",
                 "--out", str(out), "--no-images"])
    assert code == 2
    assert list(tmp_path.iterdir()) == []
