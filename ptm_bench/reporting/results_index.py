"""The index of the committed results: one line and one figure per experiment, written to ``docs/results.md``.

For every experiment config ``experiments/<file>.toml`` this module reads the
table its sweep wrote, ``results/<name>/cells.csv`` (``name`` is the config's
``name``, its file name by default), and writes one entry: the config's
``description`` (what the experiment measures), a headline computed from the
table's finished rows -- per variant the mean ground-truth mass, MAP ARI and
loop-closure average precision, whichever of those columns the table has
(docs/model.md §6 defines them) --, a figure from the results folder, and
where the table was produced. That last comes from the table itself where its
rows record a commit (a ``commit`` column); otherwise from the provenance
table of ``results/README.md`` (a Markdown table whose header starts with
``experiment`` and has a ``produced at`` column); otherwise the entry says it
is not recorded. Variants the config names without rows, and rows of variants
the config no longer names, are listed, so an index of old tables says so.
Result folders without a sweep table but with a ``summary.md`` (the appearance
check) and loose files in ``results/`` (``speed.csv``) are listed after the
experiments. The index is a deterministic function of these files, written
atomically.

    >>> import pandas as pd
    >>> table = pd.DataFrame({"variant": ["odometry", "odometry", "appearance"], "gt_mass": [0.2, 0.4, 1.0],
    ...                       "ari": [1.0, 0.5, 1.0], "status": ["ok", "ok", "ok"]})
    >>> variant_means(table)
    {'odometry': {'gt_mass': 0.3, 'ari': 0.75}, 'appearance': {'gt_mass': 1.0, 'ari': 1.0}}

    $ ptm-bench index                      # results/ + experiments/ -> docs/results.md
"""

from __future__ import annotations

import math
import os
import tomllib
from dataclasses import dataclass
from pathlib import Path

import pandas as pd

from ptm.dataset import atomic_write
from ptm_bench.evaluation.experiment import expand_cells, load_experiment

__all__ = ["HEADLINE", "ExperimentEntry", "Freshness", "experiment_entries", "freshness", "provenance_table",
           "render_index", "variant_means", "write_index"]

#: The headline columns of a sweep table with their names in the index, in this order (docs/model.md §6).
HEADLINE = (("gt_mass", "truth mass"), ("ari", "MAP ARI"), ("lc_ap", "loop-closure AP"))
#: The figure an entry shows: the first of these the results folder holds, else its first PNG by name.
FIGURE_PREFERENCE = ("scaling.png", "gt_mass_heatmap.png", "reliability.png", "trajectory.png")
#: A table column that records the commit each row was computed at.
COMMIT_COLUMN = "commit"


@dataclass(frozen=True)
class Freshness:
    """How many of a config's cells the committed table holds as today's code would compute them.

    A row is fresh when its recorded ``definition`` equals the cell's definition now: the settings, the world
    and the versions derived from the source of the code that makes the dataset and runs the cell
    (``ptm_bench.simulation.code_version``). ``stale`` rows were computed by other code or settings,
    ``missing`` cells have no row, ``failed`` rows did not finish.
    """

    cells: int
    fresh: int
    stale: int
    missing: int
    failed: int

    @property
    def all_fresh(self) -> bool:
        return self.fresh == self.cells

    def describe(self) -> str:
        if self.all_fresh:
            return f"all {self.cells} cells fresh at this code"
        return (f"{self.fresh} of {self.cells} cells fresh at this code ({self.stale} computed by other code or "
                f"settings, {self.missing} without a row, {self.failed} failed): rerun with `ptm-bench run`")


def freshness(config: Path, table: pd.DataFrame | None) -> Freshness:
    """Compare the cells ``config`` defines today with the rows of its committed ``table`` (None: no table).

    Recorded worlds name their datasets relative to the repository, so call it from the repository's root.
    """
    cells = expand_cells(load_experiment(config), Path(config).parent)  # cells are only listed, never run
    rows = {} if table is None else dict(zip(table["cell_id"], table.to_dict("records")))
    fresh = stale = missing = failed = 0
    for cell in cells:
        row = rows.get(cell["cell_id"])
        if row is None:
            missing += 1
        elif row.get("definition") != cell["definition"]:
            stale += 1
        elif row.get("status") != "ok":
            failed += 1
        else:
            fresh += 1
    return Freshness(len(cells), fresh, stale, missing, failed)


@dataclass(frozen=True)
class ExperimentEntry:
    """What the index says about one experiment config and its table."""

    name: str
    config: Path
    description: str
    table: Path | None  # None: the config has no table yet
    rows: int  # finished rows
    means: dict  # variant -> {column: mean over its finished rows}
    figure: Path | None
    produced_at: str | None
    unrun_variants: tuple  # variants (and baselines) the config names without rows
    other_variants: tuple  # variants with rows that the config no longer names
    freshness: Freshness


def variant_means(table: pd.DataFrame) -> dict:
    """Variant -> {headline column: mean over the variant's finished rows}, variants in the table's order.

    Rows whose ``status`` is not ``ok`` are left out; a column the table lacks, or whose values are all
    missing for a variant, is left out of that variant's figures.
    """
    if "variant" not in table.columns:
        raise ValueError("the table has no variant column: not a sweep table")
    if "status" in table.columns:
        table = table[table["status"] == "ok"]
    means = {}
    for variant in dict.fromkeys(table["variant"]):
        rows = table[table["variant"] == variant]
        figures = {}
        for column, _ in HEADLINE:
            if column in rows.columns:
                value = pd.to_numeric(rows[column], errors="coerce").mean()
                if not math.isnan(value):
                    figures[column] = round(float(value), 12)
        means[str(variant)] = figures
    return means


def provenance_table(readme: Path) -> dict:
    """Experiment -> where its table was produced, from the provenance table of ``results/README.md``.

    The table is the first Markdown table whose header's first cell is ``experiment`` and that has a
    ``produced at`` column; backticks around an experiment's name are dropped. No such file or table: {}.
    """
    readme = Path(readme)
    if not readme.is_file():
        return {}
    header = None
    found = {}
    for line in readme.read_text(encoding="utf-8").splitlines():
        if not line.lstrip().startswith("|"):
            if found:
                break
            header = None
            continue
        cells = [cell.strip() for cell in line.strip().strip("|").split("|")]
        if header is None:
            lowered = [cell.lower() for cell in cells]
            header = lowered if lowered and lowered[0] == "experiment" and "produced at" in lowered else []
            continue
        if not header or set(line.strip()) <= set("|-: "):
            continue
        column = header.index("produced at")
        if len(cells) > column:
            found[cells[0].strip("`")] = cells[column]
    return found


def _config(path: Path) -> dict:
    try:
        with open(path, "rb") as handle:
            return tomllib.load(handle)
    except tomllib.TOMLDecodeError as error:
        raise ValueError(f"{path}: not a valid TOML file: {error}") from error


def _figure(folder: Path) -> Path | None:
    for name in FIGURE_PREFERENCE:
        if (folder / name).is_file():
            return folder / name
    pictures = sorted(folder.glob("*.png"))
    return pictures[0] if pictures else None


def _produced_at(table: pd.DataFrame, name: str, provenance: dict) -> str | None:
    if COMMIT_COLUMN in table.columns:
        commits = [str(commit) for commit in dict.fromkeys(table[COMMIT_COLUMN].dropna())]
        if commits:
            return "commit " + ", ".join(f"`{commit}`" for commit in commits)
    return provenance.get(name)


def experiment_entries(results_dir: Path, experiments_dir: Path) -> list[ExperimentEntry]:
    """One entry per config in ``experiments_dir``, by experiment name, with its table in ``results_dir``."""
    results_dir, experiments_dir = Path(results_dir), Path(experiments_dir)
    if not experiments_dir.is_dir():
        raise ValueError(f"experiments: no folder {experiments_dir}")
    provenance = provenance_table(results_dir / "README.md")
    entries = []
    for path in sorted(experiments_dir.glob("*.toml")):
        config = _config(path)
        name = str(config.get("name", path.stem))
        # a config without [[variants]] has the harness's default variant: its names are then not compared
        named = [str(variant.get("name")) for variant in config.get("variants", [])]
        named += [str(baseline) for baseline in config.get("baselines", [])] if named else []
        description = str(config.get("description", ""))
        folder = results_dir / name
        figure = _figure(folder) if folder.is_dir() else None
        table_path = folder / "cells.csv"
        if not table_path.is_file():
            entries.append(ExperimentEntry(name, path, description, None, 0, {}, figure, provenance.get(name),
                                           tuple(named), (), freshness(path, None)))
            continue
        table = pd.read_csv(table_path)
        means = variant_means(table)
        finished = table[table["status"] == "ok"] if "status" in table.columns else table
        entries.append(ExperimentEntry(
            name, path, description, table_path, len(finished), means, figure, _produced_at(table, name, provenance),
            unrun_variants=tuple(variant for variant in named if variant not in means),
            other_variants=tuple(variant for variant in means if named and variant not in named),
            freshness=freshness(path, table)))
    return sorted(entries, key=lambda entry: entry.name)


def _link(target: Path, out_dir: Path) -> str:
    return Path(os.path.relpath(Path(target).resolve(), Path(out_dir).resolve())).as_posix()


def _names(variants) -> str:
    return ", ".join(f"`{variant}`" for variant in variants)


def _number(value: float) -> str:
    return f"{value:.3f}"


def _entry_line(entry: ExperimentEntry, out_dir: Path) -> str:
    text = f"**[{entry.name}]({_link(entry.config, out_dir)})**"
    if entry.description:
        text += f" — {entry.description.rstrip('.')}."
    if entry.table is None:
        return text + f" No committed table yet ({entry.freshness.describe()})."
    columns = [(column, label) for column, label in HEADLINE
               if any(column in figures for figures in entry.means.values())]
    if columns:
        parts = []
        for variant, figures in entry.means.items():
            values = " / ".join(_number(figures[column]) if column in figures else "–" for column, _ in columns)
            parts.append(f"`{variant}` {values}")
        text += f" Mean {' / '.join(label for _, label in columns)} over each variant's rows: " + "; ".join(parts) + "."
    table = f"[cells.csv]({_link(entry.table, out_dir)})"
    summary = entry.table.parent / "summary.md"
    if summary.is_file():
        table += f", [summary.md]({_link(summary, out_dir)})"
    text += f" {entry.rows} finished rows ({table})"
    text += f", produced at {entry.produced_at}" if entry.produced_at else "; where it was produced is not recorded"
    text += f"; {entry.freshness.describe()}."
    if entry.unrun_variants:
        text += " Named by the config, without rows: " + _names(entry.unrun_variants) + "."
    if entry.other_variants:
        text += " Rows of variants the config no longer names: " + _names(entry.other_variants) + "."
    return text


def _other_results(results_dir: Path, claimed: set, provenance: dict, out_dir: Path) -> list[str]:
    """Result folders with a summary but no sweep table, and loose CSV files, each with where it was produced."""
    lines = []
    for folder in sorted(path for path in results_dir.iterdir() if path.is_dir()):
        if folder.name in claimed or (folder / "cells.csv").is_file() or not (folder / "summary.md").is_file():
            continue
        line = f"* **{folder.name}**: [summary.md]({_link(folder / 'summary.md', out_dir)})"
        line += f", produced at {provenance[folder.name]}" if folder.name in provenance else ""
        figure = _figure(folder)
        lines.append(line + (f"\n\n  ![{folder.name}: {figure.name}]({_link(figure, out_dir)})" if figure else ""))
    for path in sorted(path for path in results_dir.iterdir() if path.is_file() and path.suffix == ".csv"):
        line = f"* [{path.name}]({_link(path, out_dir)})"
        lines.append(line + (f", produced at {provenance[path.name]}" if path.name in provenance else ""))
    return lines


def render_index(results_dir: Path, experiments_dir: Path, out: Path) -> str:
    """The Markdown text of the index for ``out`` (links are relative to its folder)."""
    results_dir, out_dir = Path(results_dir), Path(out).parent
    model = results_dir.parent / "docs" / "model.md"  # the repository's docs beside its results folder
    entries = experiment_entries(results_dir, experiments_dir)
    lines = ["# Results", "",
             "Generated by `ptm-bench index` from `results/*/cells.csv` and `experiments/*.toml`; do not edit by hand. "
             "Each experiment: what it measures (its config's description), the means of its finished rows per "
             "variant, its figure, and where its table was produced (recorded in the table, else listed in "
             f"[results/README.md]({_link(results_dir / 'README.md', out_dir)})). A table computed its variants "
             "with the settings of the code that produced it: until it is rerun, a variant of today's config may "
             "mean other settings under the same name. Column definitions: "
             f"[docs/model.md §6]({_link(model, out_dir)}#6-evaluation).", ""]
    for entry in entries:
        lines += [f"## {entry.name}", "", _entry_line(entry, out_dir), ""]
        if entry.figure is not None:
            lines += [f"![{entry.name}: {entry.figure.name}]({_link(entry.figure, out_dir)})", ""]
    provenance = provenance_table(results_dir / "README.md")
    claimed = {entry.name for entry in entries}
    others = _other_results(results_dir, claimed, provenance, out_dir) if results_dir.is_dir() else []
    if others:
        lines += ["## Other results", "", *others, ""]
    return "\n".join(lines)


def write_index(results_dir: Path = Path("results"), experiments_dir: Path = Path("experiments"),
                out: Path = Path("docs/results.md")) -> Path:
    """Write the index to ``out`` atomically (a crash leaves the previous file) and return its path."""
    text = render_index(results_dir, experiments_dir, out)
    atomic_write(out, lambda handle: handle.write(text.encode("utf-8")))
    return Path(out)
