"""The figures of an experiment (docs/model.md §6), drawn with matplotlib (Agg) and written atomically as PNG.

* :func:`trajectories` — the true path, the dead-reckoned odometry path and,
  when given, a topology's optimised map (paper Figs. 9, 12, 15), detections
  coloured by their true place.
* :func:`top_topologies` — the most probable topologies drawn as graphs over
  the detections, each on its own map (the Laplace mode P* of its pose graph,
  :meth:`ptm.odometry.OdometryTerm.mode_poses`, where the caller has an
  odometry model), detections of one place joined, titled with their
  probabilities (paper Figs. 10, 13, 14, 17, 18).
* :func:`mass_heatmap` — mean posterior mass on the ground truth over
  aliasing x noise, one panel per model variant; where the table has the
  measured aliasing (``aliasing_auc``), each aliasing level is labelled with
  its mean AUC over the distinct datasets, e.g. "0.5 (AUC 0.81)".
* :func:`reliability_diagram` — per variant, the observed frequency of "same
  place" against the mean predicted co-assignment probability in each bin of a
  pooled reliability table (:func:`ptm_bench.evaluation.scoring.reliability_table`), the
  diagonal for reference, and the pairs per bin in a lower panel.
* :func:`sampler_traces` — log P(T | Z) and the number of places along each chain.
* :func:`scaling` — per variant, accuracy (ARI, loop-closure average
  precision), agreement between independent chains (their largest
  co-assignment difference) and wall time against the number of detections,
  one point per cell and the mean per world (a sweep over worlds of several
  sizes, e.g. ``experiments/scale.toml``).
* :func:`cost_accuracy` — each method's (posterior variant, threshold baseline,
  peer) mean ARI and mean loop-closure average precision against its mean wall
  time per cell on a log axis, one point per method, or per method and
  condition: whether the posterior is worth its cost.
* :func:`pit_histograms` — per world and appearance model, the histogram of the
  probability integral transform of held-out revisits, one line per signature
  component (flat at 1 when the predictive is calibrated).

    >>> import tempfile, numpy as np, ptm
    >>> folder = Path(tempfile.mkdtemp())
    >>> poses = np.array([[0.0, 0.0, 0.0], [3.0, 0.0, 1.6], [0.1, 0.2, 3.1]])
    >>> dataset = ptm.Dataset(odometry=ptm.se2.relative_pose(poses[:-1], poses[1:]), labels=[0, 1, 0], true_poses=poses)
    >>> trajectories(dataset, folder / "trajectory.png").name
    'trajectory.png'
    >>> top_topologies([poses, poses], [((0, 1, 0), 0.9), ((0, 1, 2), 0.1)], truth=(0, 1, 0),
    ...                path=folder / "top.png").name
    'top.png'
"""

from __future__ import annotations

import textwrap
from pathlib import Path

import matplotlib
import matplotlib.lines
import matplotlib.patches
import matplotlib.ticker
import numpy as np
from matplotlib.figure import Figure

from ptm.dataset import atomic_write
from ptm.se2 import compose, dead_reckoning


__all__ = ["cost_accuracy", "dataset_overview", "mass_heatmap", "pit_histograms", "reliability_diagram",
           "sampler_traces", "scaling", "top_topologies", "topology_string", "trajectories"]

_DIGITS = "0123456789abcdefghijklmnopqrstuvwxyz"


def topology_string(labels) -> str:
    """A compact label string, one character per detection (0-9, then a-z); comma-separated past 36 places."""
    labels = [int(label) for label in labels]
    if max(labels) < len(_DIGITS):
        return "".join(_DIGITS[label] for label in labels)
    return ",".join(str(label) for label in labels)

_PLACE_COLOURS = matplotlib.colormaps["tab20"]


def _save(figure, path: Path, tight: bool = True) -> Path:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    if tight:  # not with a colorbar shared by several panels, which tight_layout cannot place
        figure.tight_layout()
    atomic_write(path, lambda handle: figure.savefig(handle, format="png", dpi=110))
    return path


def _draw_detections(axes, dataset, optimised=None) -> None:
    """True and dead-reckoned detection positions on ``axes``: numbered in time order, coloured by true place.

    The odometry is composed from the first true pose when the dataset has
    true poses (so both paths start together), else from the origin, and so
    is ``optimised``, a (name, (N, 3) poses in the frame of detection 0) pair
    such as a topology's optimised map; the world's places, when the
    dataset's metadata lists them, are drawn as detection-radius discs.
    """
    labels = np.asarray(dataset.labels) if dataset.labels is not None else np.zeros(dataset.n, dtype=int)
    radius = dataset.meta.get("detection_radius", 1.0)
    for place_id, (x, y) in dataset.meta.get("places", {}).items():
        axes.add_patch(matplotlib.patches.Circle((x, y), radius, color="0.9", zorder=0))
        axes.annotate(f"place {place_id}", (x, y), textcoords="offset points", xytext=(0, -14), ha="center",
                      fontsize=6, color="0.5")
    paths = []
    start = (0.0, 0.0, 0.0)
    if dataset.true_poses is not None:
        paths.append(("true", dataset.true_poses[:, :2], "-", "0.6", "o"))
        start = dataset.true_poses[0]
    if dataset.odometry is not None:
        paths.append(("odometry (dead reckoning)", dead_reckoning(dataset.odometry, start)[:, :2], "--", "0.4", "s"))
    if optimised is not None:
        name, poses = optimised
        paths.append((name, compose(start, poses)[:, :2], ":", "k", "^"))
    for name, points, style, colour, marker in paths:
        # the marker only in the legend (markevery=[]): the detections are drawn below, in their place's colour
        axes.plot(points[:, 0], points[:, 1], style, color=colour, lw=1, label=name, zorder=1, marker=marker,
                  markevery=[], markerfacecolor="white", markeredgecolor="k")
        axes.scatter(points[:, 0], points[:, 1], c=[_PLACE_COLOURS(label % 20) for label in labels],
                     marker=marker, s=60, edgecolors="k", zorder=2)
        for index, (x, y) in enumerate(points):
            axes.annotate(str(index), (x, y), textcoords="offset points", xytext=(4, 4), fontsize=7)
    axes.set_aspect("equal", adjustable="datalim")
    axes.set_xlabel("x [m]")
    axes.set_ylabel("y [m]")
    axes.legend(loc="best", fontsize=8)


def trajectories(dataset, path: Path, title: str = "", optimised=None) -> Path:
    """True and dead-reckoned detection positions, numbered in time order and coloured by true place; with
    ``optimised``, a (name, (N, 3) poses) pair in the frame of detection 0, that map too."""
    figure = Figure(figsize=(6.5, 5))
    axes = figure.subplots()
    _draw_detections(axes, dataset, optimised)
    axes.set_title(title or "detections (colour = true place, number = time order)")
    return _save(figure, path)


def dataset_overview(dataset, path: Path) -> Path:
    """``ptm-bench show``: the detections of :func:`trajectories`, and the panorama strip when the file has one."""
    has_panoramas = dataset.panoramas is not None
    figure = Figure(figsize=(10, 9 if has_panoramas else 6), layout="constrained")
    grid = figure.add_gridspec(2 if has_panoramas else 1, 1, height_ratios=[3, 2] if has_panoramas else [1])
    axes = figure.add_subplot(grid[0])
    _draw_detections(axes, dataset)
    meta = dataset.meta
    axes.set_title(f"{meta.get('world', 'dataset')}: {dataset.n} detections, aliasing {meta.get('aliasing', '?')}, "
                   f"noise {meta.get('noise', '?')}, seed {meta.get('seed', '?')} "
                   "(colour = true place, number = time order)", fontsize=9)
    if has_panoramas:
        labels = dataset.labels if dataset.labels is not None else np.arange(dataset.n)
        strip = figure.add_subplot(grid[1])
        strip.imshow(np.concatenate(list(dataset.panoramas), axis=0), aspect="auto", interpolation="nearest")
        height = dataset.panoramas.shape[1]
        strip.set_yticks((np.arange(dataset.n) + 0.5) * height, [f"{i}:{labels[i]}" for i in range(dataset.n)],
                         fontsize=7)
        strip.set_xticks([])
        strip.set_title("panoramas (row = detection index:place)")
    return _save(figure, path, tight=False)


def top_topologies(maps, topologies, truth, path: Path, title: str = "") -> Path:
    """One panel per topology, on its own map: ``maps[i]`` holds the (N, >= 2) positions of the detections
    under ``topologies[i]`` (a (labels, probability) pair); members of a set joined, with its probability."""
    if len(maps) != len(topologies):
        raise ValueError(f"top_topologies: {len(maps)} maps for {len(topologies)} topologies")
    truth = tuple(truth)
    count = max(1, len(topologies))
    figure = Figure(figsize=(3.2 * count, 3.4))
    axes_row = figure.subplots(1, count, squeeze=False)
    for axes, positions, (labels, probability) in zip(axes_row[0], maps, topologies):
        positions = np.asarray(positions, dtype=float)[:, :2]
        labels = np.asarray(labels)
        axes.plot(positions[:, 0], positions[:, 1], "-", color="0.85", lw=1, zorder=0)
        for place in np.unique(labels):
            members = np.flatnonzero(labels == place)
            colour = _PLACE_COLOURS(int(place) % 20)
            for first in members:
                for second in members[members > first]:
                    axes.plot(*positions[[first, second]].T, "-", color=colour, lw=2, zorder=1)
            axes.scatter(*positions[members].T, color=colour, s=40, edgecolors="k", zorder=2)
        for index, (x, y) in enumerate(positions):
            axes.annotate(str(index), (x, y), textcoords="offset points", xytext=(3, 3), fontsize=6)
        marker = " (ground truth)" if tuple(labels) == truth else ""
        axes.set_title(f"p = {probability:.3f}{marker}\n{topology_string(labels)}", fontsize=8)
        axes.set_aspect("equal", adjustable="datalim")
        axes.set_xticks([])
        axes.set_yticks([])
    if title:
        figure.suptitle(textwrap.fill(title, width=max(30, int(14 * count))), fontsize=10)
    return _save(figure, path)


def mass_heatmap(table, path: Path, value: str = "gt_mass") -> Path:
    """Mean ``value`` over seeds on an aliasing (rows) x noise (columns) grid, one panel per variant."""
    ok = table[table["status"] == "ok"]
    variants = list(dict.fromkeys(ok["variant"]))
    if not variants:
        raise ValueError("mass_heatmap: no finished cells to draw")
    aliasing, noise = sorted(ok["aliasing"].unique()), sorted(ok["noise"].unique())
    aliasing_labels = _aliasing_labels(ok, aliasing)
    # Constrained layout leaves room for long "0.5 (AUC 0.81)" tick labels and the shared colorbar.
    figure = Figure(figsize=(3.4 * len(variants) + 1.8, 3.6), layout="constrained")
    axes_row = figure.subplots(1, len(variants), squeeze=False, sharey=True)
    for axes, variant in zip(axes_row[0], variants):
        means = ok[ok["variant"] == variant].pivot_table(index="aliasing", columns="noise", values=value,
                                                         aggfunc="mean")
        grid = means.reindex(index=aliasing, columns=noise).to_numpy(dtype=float)
        image = axes.imshow(grid, vmin=0, vmax=1, cmap="viridis", origin="lower", aspect="auto")
        for (row, column), number in np.ndenumerate(grid):
            if np.isfinite(number):
                axes.text(column, row, f"{number:.2f}", ha="center", va="center", fontsize=8,
                          color="w" if number < 0.5 else "k")
        axes.set_xticks(range(len(noise)), [f"{x:g}" for x in noise])
        axes.set_yticks(range(len(aliasing)), aliasing_labels)
        axes.tick_params(labelleft=axes is axes_row[0, 0])
        axes.set_xlabel("noise level")
        axes.set_title(variant, fontsize=9)
    measured = any("AUC" in label for label in aliasing_labels)
    axes_row[0, 0].set_ylabel("aliasing knob (measured AUC)" if measured else "aliasing")
    figure.colorbar(image, ax=axes_row[0].tolist(), shrink=0.8, label=f"mean {value}")
    figure.suptitle(f"{value} over aliasing x noise (mean over seeds)", fontsize=10)
    return _save(figure, path, tight=False)


def _aliasing_labels(ok, aliasing) -> list[str]:
    """Tick labels of the aliasing levels: "0.5 (AUC 0.81)" where the measured AUC is known, else "0.5"."""
    if "aliasing_auc" not in ok:
        return [f"{level:g}" for level in aliasing]
    # One value per dataset: the variants of a dataset repeat its AUC, and some may have failed.
    datasets = ok.drop_duplicates(subset=[column for column in ("world", "aliasing", "noise", "seed") if column in ok])
    labels = []
    for level in aliasing:
        values = np.asarray(datasets.loc[datasets["aliasing"] == level, "aliasing_auc"], dtype=float)
        values = values[np.isfinite(values)]
        labels.append(f"{level:g} (AUC {values.mean():.2f})" if values.size else f"{level:g}")
    return labels


def reliability_diagram(tables: dict, path: Path, title: str = "") -> Path:
    """Observed frequency vs mean predicted probability per bin, one line per variant, with the pairs per bin.

    ``tables`` maps a variant name to its reliability table, a ``(bins, 3)``
    array of [pairs, sum of predicted probabilities, sum of outcomes] per
    equal-width bin of [0, 1]. Empty bins are left out of the line.
    """
    if not tables:
        raise ValueError("reliability_diagram: no reliability tables to draw")
    figure = Figure(figsize=(6, 6.5))
    top, bottom = figure.subplots(2, 1, sharex=True, gridspec_kw={"height_ratios": [3, 1.3]})
    top.plot([0, 1], [0, 1], ":", color="0.5", lw=1, label="calibrated")
    bins = None
    for index, (variant, table) in enumerate(tables.items()):
        table = np.asarray(table, dtype=float)
        if table.ndim != 2 or table.shape[1] != 3:
            raise ValueError(f"reliability_diagram: the table of {variant!r} must have shape (bins, 3), "
                             f"got {table.shape}")
        bins = table.shape[0]
        counts = table[:, 0]
        filled = counts > 0
        colour = matplotlib.colormaps["tab10"](index % 10)
        top.plot(table[filled, 1] / counts[filled], table[filled, 2] / counts[filled], "o-", color=colour,
                 label=variant, ms=4, lw=1.2)
        edges = np.linspace(0.0, 1.0, bins + 1)
        # Step lines, not bars: several variants' counts stay readable on one log axis.
        bottom.stairs(np.where(filled, counts, np.nan), edges, color=colour, lw=1.2)
    top.set_xlim(0, 1)
    top.set_ylim(-0.02, 1.02)
    top.set_ylabel("observed frequency (same place)")
    top.legend(fontsize=7, loc="best")
    top.set_title(title or f"reliability of co-assignment probabilities ({bins} bins)", fontsize=10)
    bottom.set_yscale("log")
    bottom.yaxis.set_major_locator(matplotlib.ticker.LogLocator(subs=(1.0, 2.0, 5.0)))
    bottom.yaxis.set_major_formatter(matplotlib.ticker.FuncFormatter(lambda value, _: f"{value:g}"))
    bottom.yaxis.set_minor_formatter(matplotlib.ticker.NullFormatter())
    bottom.set_xlabel("predicted probability P(i and j are the same place)")
    bottom.set_ylabel("pairs per bin")
    return _save(figure, path)


def sampler_traces(traces: dict, path: Path, title: str = "") -> Path:
    """Each named trace (``{name: (chains, points) array}``) in its own panel, one line per chain."""
    if not traces:
        raise ValueError("sampler_traces: no traces to draw")
    figure = Figure(figsize=(7, 2.2 * len(traces)))
    axes_column = figure.subplots(len(traces), 1, squeeze=False)
    for axes, (name, trace) in zip(axes_column[:, 0], traces.items()):
        trace = np.atleast_2d(np.asarray(trace, dtype=float))
        for chain, values in enumerate(trace):
            axes.plot(values, lw=0.8, label=f"chain {chain}")
        axes.set_ylabel(name)
    axes_column[-1, 0].set_xlabel("kept sample (thinned for display)")
    axes_column[0, 0].legend(fontsize=7, loc="best")
    if title:
        axes_column[0, 0].set_title(title, fontsize=10)
    return _save(figure, path)


#: The panels of :func:`scaling`: (column, y label, y scale keyword arguments, reference line). Chains that
#: agree exactly have a co-assignment difference of 0, so that panel is logarithmic only above 1e-3.
SCALING_PANELS = (
    ("ari", "ARI of the MAP", {"value": "linear"}, None),
    ("lc_ap", "loop-closure average precision", {"value": "linear"}, None),
    ("diag_coassignment_max_difference", "largest co-assignment difference\nbetween chains (agree: <= 0.05)",
     {"value": "symlog", "linthresh": 1e-3}, 0.05),
    ("wall_s", "wall time per cell [s]", {"value": "log"}, None),
)


def scaling(table, path: Path, title: str = "") -> Path:
    """Accuracy, chain agreement and wall time against the number of detections (``n_measurements``).

    One marker per finished cell, per variant; a line through each variant's means per world. A panel whose
    column no row has (e.g. chain agreement of exact posteriors and baselines) is left empty.
    """
    ok = table[table["status"] == "ok"]
    if not len(ok):
        raise ValueError("scaling: no finished cells to draw")
    figure = Figure(figsize=(11, 7.5))
    panels = figure.subplots(2, 2, squeeze=False).ravel()
    for axes, (column, label, scale, reference) in zip(panels, SCALING_PANELS):
        for colour, (variant, group) in enumerate(ok.groupby("variant", sort=False)):
            values = group[column].astype(float) if column in group else None
            if values is None or not values.notna().any():
                continue
            axes.plot(group["n_measurements"], values, "o", color=f"C{colour}", alpha=0.5, markersize=4)
            means = group.assign(value=values).groupby("world")[["n_measurements", "value"]].mean().sort_values(
                "n_measurements")
            axes.plot(means["n_measurements"], means["value"], "-", color=f"C{colour}", label=variant)
        if reference is not None:
            axes.axhline(reference, color="black", linewidth=0.8, linestyle="--")
        axes.set_yscale(**scale)
        if scale["value"] == "symlog":  # differences are never negative
            axes.set_ylim(bottom=0.0)
        axes.set_xlabel("detections N")
        axes.set_ylabel(label, fontsize=9)
    panels[0].legend(fontsize=7, loc="best")
    if title:
        figure.suptitle(title, fontsize=10)
    return _save(figure, path)


#: Markers of the conditions in :func:`cost_accuracy`, in order; it draws at most this many conditions apart.
CONDITION_MARKERS = "osD^"


def cost_accuracy(points, path: Path, title: str = "") -> Path:
    """Mean ARI and mean loop-closure AP against mean wall time per cell (log x), in two panels.

    ``points`` is a table with ``variant`` (the method), ``ari``, ``lc_ap`` and ``wall_s``, one row per point, and
    optionally ``condition``, a label per row: one colour per method, one marker per condition (at most
    ``len(CONDITION_MARKERS)`` conditions). A value that is NaN, or a wall time that is not positive, is left out
    of its panel.
    """
    if not len(points):
        raise ValueError("cost_accuracy: no points to draw")
    conditions = list(dict.fromkeys(points["condition"])) if "condition" in points else [""]
    if len(conditions) > len(CONDITION_MARKERS):
        raise ValueError(f"cost_accuracy: at most {len(CONDITION_MARKERS)} conditions, got {len(conditions)}")
    methods = list(dict.fromkeys(points["variant"]))
    figure = Figure(figsize=(11, 4.6))
    panels = figure.subplots(1, 2, sharex=True)
    for axes, (column, label) in zip(panels, (("ari", "mean ARI"), ("lc_ap", "mean loop-closure AP"))):
        for _, row in points.iterrows():
            value, wall = float(row[column]), float(row["wall_s"])
            if not (np.isfinite(value) and np.isfinite(wall) and wall > 0):
                continue
            marker = CONDITION_MARKERS[conditions.index(row["condition"] if "condition" in points else "")]
            axes.plot(wall, value, marker, color=f"C{methods.index(row['variant']) % 10}", markersize=7, alpha=0.85)
        axes.set_xscale("log")
        axes.xaxis.set_major_locator(matplotlib.ticker.LogLocator(subs=(1.0, 2.0, 5.0)))
        axes.xaxis.set_major_formatter(matplotlib.ticker.FuncFormatter(lambda value, _: f"{value:g}"))
        axes.xaxis.set_minor_formatter(matplotlib.ticker.NullFormatter())
        axes.set_ylim(-0.05, 1.05)
        axes.set_xlabel("mean wall time per cell [s]")
        axes.set_ylabel(label)
        axes.grid(True, which="major", alpha=0.3)
    handles = [matplotlib.lines.Line2D([], [], marker="o", linestyle="", color=f"C{index % 10}", label=method)
               for index, method in enumerate(methods)]
    if len(conditions) > 1:
        handles += [matplotlib.lines.Line2D([], [], marker=marker, linestyle="", color="0.4", label=condition)
                    for marker, condition in zip(CONDITION_MARKERS, conditions)]
    panels[1].legend(handles=handles, fontsize=7, loc="center left", bbox_to_anchor=(1.02, 0.5))
    if title:
        figure.suptitle(textwrap.fill(title, width=110), fontsize=10)
    return _save(figure, path)


def pit_histograms(pit, path: Path, bins: int = 10) -> Path:
    """One panel per world (rows) and model (columns): density of the PIT values per component.

    ``pit`` is a table with columns world, model, component and pit (values in [0, 1]).
    """
    worlds, models = list(dict.fromkeys(pit["world"])), list(dict.fromkeys(pit["model"]))
    figure = Figure(figsize=(4.2 * len(models), 2.6 * len(worlds)))
    axes = figure.subplots(len(worlds), len(models), squeeze=False, sharex=True, sharey=True)
    edges = np.linspace(0.0, 1.0, bins + 1)
    centres = (edges[:-1] + edges[1:]) / 2
    for row, world in enumerate(worlds):
        for column, model in enumerate(models):
            axis = axes[row, column]
            panel = pit[(pit["world"] == world) & (pit["model"] == model)]
            for component, values in panel.groupby("component")["pit"]:
                density, _ = np.histogram(values, bins=edges, density=True)
                axis.plot(centres, density, marker="o", markersize=3, label=f"component {component}")
            axis.axhline(1.0, color="black", linewidth=0.8, linestyle="--")
            axis.set_title(f"{world}: {model}", fontsize=9)
            if column == 0:
                axis.set_ylabel("density")
            if row == len(worlds) - 1:
                axis.set_xlabel("PIT of a held-out revisit")
    axes[0, -1].legend(fontsize=7)
    return _save(figure, path)
