"""Argument types, output checks and the report of the parameters used, shared by the ``ptm-bench`` sub-commands.

They fail at the command line, before any simulation, with a message naming the option:

    >>> positive_int("2")
    2
    >>> positive_int("0")
    Traceback (most recent call last):
    argparse.ArgumentTypeError: must be a positive integer, got '0'
    >>> import tempfile
    >>> with tempfile.NamedTemporaryFile() as file:
    ...     output_folder(Path(file.name), "--out")  # doctest: +ELLIPSIS
    Traceback (most recent call last):
    ValueError: --out ... is a file, not a folder
"""

from __future__ import annotations

import argparse
import os
from pathlib import Path

__all__ = ["RESUME_HINT", "dataset_output", "output_folder", "positive_int", "print_parameters", "report_file"]

#: Attribute of the parsed arguments that a command sets to say how to resume it; printed on Ctrl-C.
RESUME_HINT = "resume_hint"


def positive_int(text: str) -> int:
    """An ``argparse`` type: an integer >= 1 (``--workers 0`` used to mean "all CPUs")."""
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"must be a positive integer, got {text!r}") from None
    if value < 1:
        raise argparse.ArgumentTypeError(f"must be a positive integer, got {text!r}")
    return value


def output_folder(path: Path, option: str) -> Path:
    """Create ``path`` if needed and check that it is a writable folder; ``ValueError`` naming ``option`` if not."""
    path = Path(path)
    if path.exists() and not path.is_dir():
        raise ValueError(f"{option} {path} is a file, not a folder")
    try:
        path.mkdir(parents=True, exist_ok=True)
    except OSError as error:
        raise ValueError(f"{option} {path}: cannot create the folder ({error.strerror or error})") from None
    if not os.access(path, os.W_OK | os.X_OK):
        raise ValueError(f"{option} {path}: the folder is not writable")
    return path


def dataset_output(path) -> Path:
    """The ``--out`` of a command that writes one dataset file: a ``.npz`` path in an existing, writable folder.

    ``ValueError`` naming ``out`` otherwise, before any work is done.
    """
    out = Path(path)
    if out.suffix != ".npz":
        raise ValueError(f"out: dataset files end in .npz, got {out}")
    folder = out.parent if str(out.parent) else Path(".")
    if not folder.is_dir():
        raise ValueError(f"out: folder {folder} does not exist")
    if not os.access(folder, os.W_OK):
        raise ValueError(f"out: folder {folder} is not writable")
    return out


def report_file(path, option: str) -> Path:
    """The path of a report file a command writes (``--junit``): a file in an existing folder, not a folder;
    ``ValueError`` naming ``option`` otherwise, before any work is done."""
    path = Path(path)
    if path.is_dir():
        raise ValueError(f"{option} {path} is a folder; {option} needs the path of a file, e.g. {path / 'checks.xml'}")
    folder = path.parent if str(path.parent) else Path(".")
    if not folder.is_dir():
        raise ValueError(f"{option} {path}: folder {folder} does not exist")
    return path


def print_parameters(used: dict) -> None:
    """One line per parameter in ``used`` (of :func:`ptm_bench.evaluation.models.build_models`): its value, where
    it is a number, and its source."""
    for name, source in used.items():
        if name.startswith("source_"):
            value = used.get(name[len("source_"):])
            shown = f"{value:.3g} " if isinstance(value, (int, float)) and not isinstance(value, bool) else ""
            print(f"  {name[len('source_'):]}: {shown}({source})")
