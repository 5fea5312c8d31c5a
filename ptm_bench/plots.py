"""The figures of an experiment (SPEC §6), drawn with matplotlib (Agg) and written atomically as PNG.

* :func:`trajectories` — the true path and the dead-reckoned odometry path
  (paper Figs. 9, 12, 15), detections coloured by their true place.
* :func:`top_topologies` — the most probable topologies drawn as graphs over
  the detections (at their dead-reckoned positions), detections of one place joined,
  titled with their probabilities (paper Figs. 10, 13, 14, 17, 18).
* :func:`mass_heatmap` — mean posterior mass on the ground truth over
  aliasing x noise, one panel per model variant.
* :func:`sampler_traces` — log P(T | Z) and the number of places along each chain.

    >>> trajectories(dataset, Path("results/exp3_nested/trajectory.png"), title="nested_loops, seed 0")
    >>> top_topologies(dataset.true_poses, [((0, 1, 0), 0.9), ((0, 1, 2), 0.1)], truth=(0, 1, 0), path=Path("top.png"))
    >>> mass_heatmap(table, Path("results/grid/heatmap.png"))
"""

from __future__ import annotations

import textwrap

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from ptm.dataset import atomic_write  # noqa: E402

from .baselines import dead_reckoning  # noqa: E402

__all__ = ["mass_heatmap", "sampler_traces", "top_topologies", "topology_string", "trajectories"]

_DIGITS = "0123456789abcdefghijklmnopqrstuvwxyz"


def topology_string(labels) -> str:
    """A compact label string, one character per detection (0-9, then a-z); comma-separated past 36 places."""
    labels = [int(label) for label in labels]
    if max(labels) < len(_DIGITS):
        return "".join(_DIGITS[label] for label in labels)
    return ",".join(str(label) for label in labels)

_PLACE_COLOURS = plt.get_cmap("tab20")


def _save(figure, path: Path, tight: bool = True) -> Path:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    if tight:  # not with a colorbar shared by several panels, which tight_layout cannot place
        figure.tight_layout()
    atomic_write(path, lambda handle: figure.savefig(handle, format="png", dpi=110))
    plt.close(figure)
    return path


def trajectories(dataset, path: Path, title: str = "") -> Path:
    """True and dead-reckoned detection positions, numbered in time order and coloured by true place."""
    figure, axes = plt.subplots(figsize=(6.5, 5))
    labels = np.asarray(dataset.labels) if dataset.labels is not None else np.zeros(dataset.n, dtype=int)
    paths = []
    if dataset.true_poses is not None:
        paths.append(("true", dataset.true_poses[:, :2], "-", "o"))
    if dataset.odometry is not None:
        paths.append(("odometry (dead reckoning)", dead_reckoning(dataset.odometry)[:, :2], "--", "s"))
    for name, points, style, marker in paths:
        axes.plot(points[:, 0], points[:, 1], style, color="0.6", lw=1, label=name, zorder=1)
        axes.scatter(points[:, 0], points[:, 1], c=[_PLACE_COLOURS(label % 20) for label in labels],
                     marker=marker, s=60, edgecolors="k", zorder=2)
        for index, (x, y) in enumerate(points):
            axes.annotate(str(index), (x, y), textcoords="offset points", xytext=(4, 4), fontsize=7)
    axes.set_aspect("equal", adjustable="datalim")
    axes.set_xlabel("x [m]")
    axes.set_ylabel("y [m]")
    axes.set_title(title or "detections (colour = true place, number = time order)")
    axes.legend(loc="best", fontsize=8)
    return _save(figure, path)


def top_topologies(positions, topologies, truth, path: Path, title: str = "") -> Path:
    """One panel per topology: detections at ``positions``, members of a set joined, with its probability."""
    positions = np.asarray(positions, dtype=float)[:, :2]
    truth = tuple(truth)
    count = max(1, len(topologies))
    figure, axes_row = plt.subplots(1, count, figsize=(3.2 * count, 3.4), squeeze=False)
    for axes, (labels, probability) in zip(axes_row[0], topologies):
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
    figure, axes_row = plt.subplots(1, len(variants), figsize=(3.4 * len(variants) + 1, 3.4), squeeze=False)
    for axes, variant in zip(axes_row[0], variants):
        means = ok[ok["variant"] == variant].pivot_table(index="aliasing", columns="noise", values=value, aggfunc="mean")
        grid = means.reindex(index=aliasing, columns=noise).to_numpy(dtype=float)
        image = axes.imshow(grid, vmin=0, vmax=1, cmap="viridis", origin="lower", aspect="auto")
        for (row, column), number in np.ndenumerate(grid):
            if np.isfinite(number):
                axes.text(column, row, f"{number:.2f}", ha="center", va="center", fontsize=8,
                          color="w" if number < 0.5 else "k")
        axes.set_xticks(range(len(noise)), [f"{x:g}" for x in noise])
        axes.set_yticks(range(len(aliasing)), [f"{x:g}" for x in aliasing])
        axes.set_xlabel("noise level")
        axes.set_title(variant, fontsize=9)
    axes_row[0, 0].set_ylabel("aliasing")
    figure.colorbar(image, ax=axes_row[0].tolist(), shrink=0.8, label=f"mean {value}")
    figure.suptitle(f"{value} over aliasing x noise (mean over seeds)", fontsize=10)
    return _save(figure, path, tight=False)


def sampler_traces(traces: dict, path: Path, title: str = "") -> Path:
    """Each named trace (``{name: (chains, points) array}``) in its own panel, one line per chain."""
    if not traces:
        raise ValueError("sampler_traces: no traces to draw")
    figure, axes_column = plt.subplots(len(traces), 1, figsize=(7, 2.2 * len(traces)), squeeze=False)
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
