"""The sweep engine: run many independent cells, one tidy table row each, resumably (docs/model.md §6).

A *cell* is a dict with a unique ``"cell_id"`` and the plain values (strings,
numbers, booleans) that identify it — world, aliasing, noise, seed, model
variant — plus anything else its cell function needs. ``cell_fn(cell)``
returns a dict of results. The table row of a cell is its plain values, the
results, and ``status`` (``ok`` or ``error``) with ``error`` (the message).

* The table (CSV) is rewritten atomically after every finished cell, rows in
  the order of the cell list, so an interrupted sweep loses at most the cells
  that were running, and a rerun skips every cell already in the table
  (``retry_failed=True`` reruns the ones that ended in an error).
* A cell may carry a plain ``"definition"`` value, a digest of everything
  of its config (``ptm_bench.evaluation.experiment.expand_cells`` makes one from the
  settings, calibration seeds and generator options). A row is
  reused only while its definition matches: edit a config and the cells it
  changes are recomputed, the rest are not. Rows of a table written before
  definitions existed are reused unverified; the returned table counts both
  kinds in ``table.attrs``.
* A cell that raises is recorded with its error and the sweep goes on. A cell whose result carries a
  non-empty ``"warning"`` (``run_cell`` writes one when independent chains disagree) is reported on
  stderr as it finishes, and the number of such rows once the table is complete (``table.attrs["warned"]``).
* Locally every cell runs in its own process (at most ``workers`` at a
  time), forked from a clean fork server rather than from this process (a
  fork of a process that has started MuJoCo's EGL renderer or a thread pool
  can deadlock), so a worker that dies — killed, out of memory, a crash in C
  code — is known by cell: the cell is retried up to ``max_attempts`` times, then
  recorded as failed. Never lost.
* With ``scheduler`` (a Dask distributed address) cells become Dask tasks;
  Dask reschedules the tasks of a lost worker and reports ``KilledWorker``
  after too many losses, which is recorded as the cell's error.
* One run writes a table at a time: ``cells.csv.lock`` beside it names the
  pid and host of the run that holds it (an advisory ``flock``, released by
  the kernel when that process ends however it ends, so the lock of a killed
  run is taken over), and a second run of the same table is refused. A table
  of another experiment (its ``experiment`` column) is never overwritten.
  The temporary tables a killed run left mid-write are deleted by the next run.
  A damaged row of the table is an error naming its line (:func:`read_table`).
* A cell process dies with the sweep: killed, even by SIGKILL, the sweep
  takes its workers with it; on Ctrl-C (or SIGTERM, SIGHUP: ``ptm-bench`` turns them
  into the same interrupt) the workers ignore the terminal's signals and the sweep ends them,
  each through its interpreter's shutdown, so the table holds every finished cell and a rerun resumes.

Cell functions are deterministic in their cell's seeds, so the table is the
same on a process pool and on a cluster, apart from the columns :data:`TIMING_COLUMNS` matches.
Any picklable function that returns a dict is a cell function (``dict`` itself here; the
experiments use :func:`ptm_bench.evaluation.cell.run_cell`):

    >>> import tempfile
    >>> folder = Path(tempfile.mkdtemp())
    >>> cells = [{"cell_id": f"seed={seed}", "experiment": "doc", "seed": seed} for seed in range(3)]
    >>> table = run_sweep(cells, dict, folder / "cells.csv", workers=2, progress=False)
    >>> print(table[["cell_id", "status", "attempts"]].to_string(index=False))
    cell_id status  attempts
     seed=0     ok         1
     seed=1     ok         1
     seed=2     ok         1
    >>> len(run_sweep(cells, dict, folder / "cells.csv", progress=False))  # resumed: nothing left to run
    3

On a cluster, ``run_sweep(cells, run_cell, path, scheduler="tcp://10.0.0.5:8786")``.
"""

from __future__ import annotations

import contextlib
import csv
import fcntl
import glob
import multiprocessing
import multiprocessing.connection
import multiprocessing.forkserver
import os
import re
import select
import signal
import socket
import sys
import threading
import time
import traceback
from collections import deque
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path

import pandas as pd
from tqdm import tqdm

from ptm.dataset import atomic_write

__all__ = ["TIMING_COLUMNS", "comparable", "read_table", "run_sweep", "table_lock"]

#: Column names that measure the machine, not the result: they differ between two runs of one config.
TIMING_COLUMNS = re.compile(r"(wall_s|_per_s|seconds|_ms|_ms_mean|attempts)$")

_PLAIN_TYPES = (str, int, float, bool, type(None))
_BOOKKEEPING_COLUMNS = ("status", "error", "attempts")  # written last, after the cell's values and results
_PRELOADED_MODULES = ["numpy", "scipy.optimize", "pandas", "ptm", "ptm_bench.evaluation.cell"]

CellFn = Callable[[dict], dict]


def read_table(path) -> pd.DataFrame:
    """The table of a sweep, or an empty frame if it has not started.

    A damaged row (a field too few or too many, or a ``status`` other than ``ok`` and ``error``) is a
    ``ValueError`` naming the file and the line, never a row of blank values.
    """
    path = Path(path)
    if not path.is_file():
        return pd.DataFrame()
    try:
        _check_rows(path)
        return pd.read_csv(path, keep_default_na=True)
    except (pd.errors.ParserError, pd.errors.EmptyDataError, UnicodeDecodeError, csv.Error) as error:
        raise ValueError(f"{path} is not a readable sweep table ({type(error).__name__}: {error}); "
                         "move it away to start the sweep afresh") from None


def _check_rows(path: Path) -> None:
    """``ValueError`` naming the line of the first row whose fields do not match the header."""
    csv.field_size_limit(max(csv.field_size_limit(), path.stat().st_size))  # a field may be a long JSON value
    with open(path, newline="", encoding="utf-8-sig") as handle:
        reader = csv.reader(handle, strict=True)  # strict: a quote left open is an error, not a field to the end
        header = next(reader, [])
        status = header.index("status") if "status" in header else None
        for record in reader:
            if not record:  # a blank line, which pandas skips too
                continue
            if len(record) != len(header):
                problem = f"{len(record)} fields where the header has {len(header)}"
            elif status is not None and record[status] not in ("ok", "error"):
                problem = f"status {record[status]!r} is neither 'ok' nor 'error'"
            else:
                continue
            raise ValueError(f"{path}, line {reader.line_num}: a damaged row ({problem}); delete that line and "
                             "rerun to compute its cell again")


def comparable(table: pd.DataFrame) -> pd.DataFrame:
    """The table without its timing columns, for comparing two runs of one config."""
    timing = [column for column in table.columns if TIMING_COLUMNS.search(column)]
    return table.drop(columns=timing).reset_index(drop=True)


def run_sweep(
    cells: Sequence[dict],
    cell_fn: CellFn,
    table_path,
    *,
    workers: int | None = None,
    scheduler: str | None = None,
    max_attempts: int = 2,
    retry_failed: bool = False,
    fresh: bool = False,
    progress: bool = True,
    connect_timeout: float = 5.0,
) -> pd.DataFrame:
    """Run every cell not yet in the table at ``table_path``; return the full table.

    ``workers``: local processes at a time (default: the number of CPUs);
    ``max_attempts``: local runs of a cell whose process died before it is recorded as failed;
    ``scheduler``: a Dask distributed scheduler address, used instead of local processes
    (``connect_timeout`` seconds to answer, else ``ValueError``);
    ``fresh``: recompute every cell and drop the table's other rows (only of a table of the same experiment).

    A table another run holds (:func:`table_lock`), or one whose ``experiment`` column names
    another experiment than the cells', raises ``ValueError`` before any cell runs.
    """
    table_path = Path(table_path)
    if workers is not None and (isinstance(workers, bool) or not isinstance(workers, int) or workers < 1):
        raise ValueError(f"workers must be a positive number of processes, got {workers!r}")
    with table_lock(table_path):
        return _run_locked(cells, cell_fn, table_path, workers=workers, scheduler=scheduler, max_attempts=max_attempts,
                           retry_failed=retry_failed, fresh=fresh, progress=progress, connect_timeout=connect_timeout)


def _run_locked(cells, cell_fn, table_path: Path, *, workers, scheduler, max_attempts, retry_failed, fresh, progress,
                connect_timeout) -> pd.DataFrame:
    cell_ids = [_cell_id(cell) for cell in cells]
    if len(set(cell_ids)) != len(cell_ids):
        duplicate = next(cell_id for cell_id in cell_ids if cell_ids.count(cell_id) > 1)
        raise ValueError(f"cell_id {duplicate!r} appears twice in the sweep")
    if max_attempts < 1:
        raise ValueError(f"max_attempts must be >= 1, got {max_attempts}")

    _remove_stale_temporaries(table_path)
    previous = read_table(table_path)
    rows: dict[str, dict] = {}
    if len(previous):
        if "cell_id" not in previous.columns:
            raise ValueError(f"{table_path} has no cell_id column: not a sweep table; refusing to overwrite it")
        _check_same_experiment(previous, cells, table_path)
        for row in ([] if fresh else previous.to_dict(orient="records")):
            if retry_failed and row.get("status") != "ok":
                continue
            rows[str(row["cell_id"])] = row
    changed = [cell_id for cell, cell_id in zip(cells, cell_ids)
               if cell_id in rows and _recorded_definition(rows[cell_id]) not in (None, cell.get("definition"))]
    unverified = sum(1 for cell, cell_id in zip(cells, cell_ids)
                     if cell_id in rows and "definition" in cell and _recorded_definition(rows[cell_id]) is None)
    for cell_id in changed:
        del rows[cell_id]
    pending = [cell for cell, cell_id in zip(cells, cell_ids) if cell_id not in rows]

    if scheduler is None:
        outcomes = _local_outcomes(pending, cell_fn, workers or os.cpu_count() or 1, max_attempts)
    else:
        outcomes = _dask_outcomes(pending, cell_fn, scheduler, connect_timeout)
    order = {cell_id: index for index, cell_id in enumerate(cell_ids)}
    # closed on the way out, also on an interrupt: its workers end before the lock is released
    with contextlib.closing(outcomes), tqdm(total=len(cells), initial=len(cells) - len(pending), unit="cell",
                                            disable=not progress) as bar:
        for cell, outcome in outcomes:
            rows[_cell_id(cell)] = _row(cell, outcome)
            _write_table(table_path, rows, order)
            if outcome.get("warning"):
                bar.write(f"warning: {_cell_id(cell)}: {outcome['warning']}", file=sys.stderr)
            bar.update(1)
    if not pending or fresh:
        _write_table(table_path, rows, order)
    table = read_table(table_path)
    warnings = _warnings(table)
    if len(warnings):
        print(f"{len(warnings)} of {len(table)} cells warn (column 'warning' of {table_path}), e.g. "
              f"{warnings.iloc[0]}", file=sys.stderr)
    table.attrs.update(recomputed_changed=len(changed), reused_unverified=unverified, warned=len(warnings))
    return table


def _warnings(table: pd.DataFrame) -> pd.Series:
    """The table's non-empty ``warning`` values (a cell function's message about its result, e.g. chains that
    disagree)."""
    if "warning" not in table.columns:
        return pd.Series([], dtype=str)
    values = table["warning"].astype("string").fillna("")
    return values[values != ""]


@contextlib.contextmanager
def table_lock(table_path):
    """Hold ``TABLE.lock`` (its holder's pid and host inside) while writing the table; refuse if another run holds it.

    The lock is an advisory ``flock`` on that file: the kernel releases it when
    its process ends, also by SIGKILL, so a lock left by a dead run is taken
    over. Raises ``ValueError`` naming the holder's pid.

        >>> import tempfile
        >>> path = Path(tempfile.mkdtemp()) / "cells.csv"
        >>> with table_lock(path):  # doctest: +ELLIPSIS
        ...     with table_lock(path):
        ...         pass
        Traceback (most recent call last):
        ValueError: ...cells.csv is being written by another run (pid ...
    """
    table_path = Path(table_path)
    folder = table_path.parent
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except FileExistsError:
        raise ValueError(f"output folder {folder} is a file, not a folder") from None
    except OSError as error:
        raise ValueError(f"cannot create output folder {folder}: {error.strerror or error}") from None
    if not os.access(folder, os.W_OK):
        raise ValueError(f"output folder {folder} is not writable")
    lock_path = table_path.with_name(table_path.name + ".lock")
    while True:
        try:
            descriptor = os.open(lock_path, os.O_RDWR | os.O_CREAT, 0o644)
        except OSError as error:
            raise ValueError(f"cannot create the lock {lock_path}: {error.strerror or error}") from None
        try:
            fcntl.flock(descriptor, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            holder = os.pread(descriptor, 200, 0).decode(errors="replace").strip() or "unknown"
            os.close(descriptor)
            raise ValueError(f"{table_path} is being written by another run (pid {holder.replace(' ', ' on ')}, "
                             f"lock {lock_path}); wait for it to end, or write elsewhere with --out") from None
        try:
            same_file = os.fstat(descriptor).st_ino == os.stat(lock_path).st_ino
        except FileNotFoundError:
            same_file = False
        if same_file:
            break
        os.close(descriptor)  # the holder removed the file as we opened it: lock the new one
    try:
        os.ftruncate(descriptor, 0)
        os.pwrite(descriptor, f"{os.getpid()} {socket.gethostname()}\n".encode(), 0)
        yield lock_path
    finally:
        lock_path.unlink(missing_ok=True)  # still locked by us, so no other run holds this file
        os.close(descriptor)


def _remove_stale_temporaries(table_path: Path) -> None:
    """Delete the temporary tables (``.NAME.*.tmp`` of ``atomic_write``) that a killed run left beside the table;
    called under the table's lock, so no run is writing one."""
    for temporary in table_path.parent.glob(f".{glob.escape(table_path.name)}.*.tmp"):
        temporary.unlink(missing_ok=True)


def _check_same_experiment(previous: pd.DataFrame, cells: Sequence[dict], table_path: Path) -> None:
    """Refuse to touch a table written for another experiment (e.g. ``demo --out results/exp1_penalty``)."""
    ours = {str(cell["experiment"]) for cell in cells if "experiment" in cell}
    if not ours:
        return
    theirs = set(previous["experiment"].dropna().astype(str)) if "experiment" in previous.columns else {"(none)"}
    if theirs - ours:
        raise ValueError(f"{table_path} holds the table of experiment {', '.join(sorted(theirs))}, not of "
                         f"{', '.join(sorted(ours))}; refusing to overwrite it: choose another output folder")


def _recorded_definition(row: dict) -> str | None:
    """The definition a table row was computed under; None for a row written before definitions existed."""
    definition = row.get("definition")
    return definition if isinstance(definition, str) else None


def _cell_id(cell: dict) -> str:
    if "cell_id" not in cell:
        raise ValueError(f"a sweep cell needs a 'cell_id', got keys {sorted(cell)}")
    return str(cell["cell_id"])


def _row(cell: dict, outcome: dict) -> dict:
    row = {key: value for key, value in cell.items() if isinstance(value, _PLAIN_TYPES)}
    row.update(outcome)
    return row


def _write_table(path: Path, rows: dict[str, dict], order: dict[str, int]) -> None:
    # Cells of this sweep in their list order; rows of cells no longer listed are kept, after them.
    ordered = sorted(rows.items(), key=lambda item: (order.get(item[0], len(order)), item[0]))
    table = pd.DataFrame([row for _, row in ordered])
    bookkeeping = [column for column in _BOOKKEEPING_COLUMNS if column in table.columns]
    table = table[[column for column in table.columns if column not in bookkeeping] + bookkeeping]
    atomic_write(path, lambda handle: handle.write(table.to_csv(index=False).encode()))


def _succeeded(result: dict, attempts: int) -> dict:
    if not isinstance(result, dict):
        raise TypeError(f"a cell function must return a dict, got {type(result).__name__}")
    return {**result, "status": "ok", "error": "", "attempts": attempts}


def _failed(message: str, attempts: int) -> dict:
    return {"status": "error", "error": message, "attempts": attempts}


def _guarded(cell_fn: CellFn, cell: dict) -> dict:
    """Run one cell; an exception becomes the cell's error instead of stopping the sweep."""
    try:
        return _succeeded(cell_fn(cell), attempts=1)
    except Exception as error:  # noqa: BLE001 - any failure of one cell is recorded, not raised
        last = traceback.extract_tb(error.__traceback__)[-1]
        where = f"{Path(last.filename).name}:{last.lineno}"
        return _failed(f"{type(error).__name__}: {error} ({where})", attempts=1)


# -- local: one process per cell, from the fork server ---------------------------------------------------------


def _child(cell_fn: CellFn, cell: dict, connection) -> None:
    finishing = _die_with_sweep(connection)
    outcome = _guarded(cell_fn, cell)
    # From here on the pipe closes by design (the sweep closes its end once it has read the outcome, this
    # process closes its own): the watch must not end the process. Were the sweep gone, send would raise.
    finishing.set()
    connection.send(outcome)
    connection.close()


def _die_with_sweep(connection) -> threading.Event:
    """Make this cell process end with the sweep's process, and leave Ctrl-C to the sweep; returns the event
    to set once the cell's outcome is ready to send.

    The sweep holds the only read end of ``connection``'s pipe; when its
    process ends, also by SIGKILL, the pipe loses its reader and ``poll``
    reports an error on the write end here. A thread waits for that and ends
    the process, so no orphan runs on to die on a broken pipe. (The parent
    process of a cell is the fork server, which outlives it, so a parent-death
    signal would not fire.) SIGINT (Ctrl-C) and SIGHUP (the terminal closing)
    reach the whole process group; the sweep ends its workers itself, so a
    worker ignores them. The sweep ends a worker with SIGTERM, which exits it
    through the interpreter's shutdown (:func:`_exit_normally`). Once the event is
    set, a closed pipe (the sweep has read the outcome, or this process closed
    its end) ends the watch instead: an ``os._exit`` then would cut the
    interpreter's shutdown short, before it unlinks its semaphores, and the
    resource tracker would warn about them after the sweep.
    """
    finishing = threading.Event()
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGHUP, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, _exit_normally)
    if not hasattr(select, "poll"):
        return finishing
    poller = select.poll()
    poller.register(connection.fileno(), 0)  # no events asked for: POLLERR / POLLHUP are always reported

    def watch() -> None:
        while not any(events & (select.POLLERR | select.POLLHUP | select.POLLNVAL) for _, events in poller.poll()):
            pass
        if not finishing.is_set():
            os._exit(1)

    threading.Thread(target=watch, name="watch-sweep", daemon=True).start()
    return finishing


def _exit_normally(signum, frame) -> None:
    """A cell process's SIGTERM handler: exit through the interpreter's shutdown, which unlinks the semaphores the
    cell created (ended by the signal's default action, it would leave them, and the resource tracker would warn
    of leaked semaphores after an interrupted sweep)."""
    sys.exit(128 + signum)


#: Seconds a cell process has to exit after the sweep's SIGTERM before it is killed (a cell inside a long call
#: into C code runs no Python signal handler until it returns).
END_GRACE_S = 5.0


def _end(processes) -> None:
    """End the running cell processes: SIGTERM to each (:func:`_exit_normally`), SIGKILL to any still running
    :data:`END_GRACE_S` seconds later."""
    processes = list(processes)
    for process in processes:
        process.terminate()
    deadline = time.monotonic() + END_GRACE_S
    for process in processes:
        process.join(max(0.0, deadline - time.monotonic()))
        if process.exitcode is None:
            process.kill()
            process.join()


_BLAS_THREAD_VARIABLES = ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS")


def _start_fork_server() -> None:
    """Start the fork server, and with it multiprocessing's resource tracker, with SIGHUP blocked, as they keep it.

    A terminal that closes sends SIGHUP to its whole process group. The sweep then ends its cell processes,
    which unlink their semaphores through the resource tracker as they exit; a tracker ended by the same
    SIGHUP would make each of them warn and start another.
    """
    blocked = signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGHUP})
    try:
        multiprocessing.forkserver.ensure_running()
    finally:
        signal.pthread_sigmask(signal.SIG_SETMASK, blocked)


def _local_outcomes(cells, cell_fn, workers: int, max_attempts: int) -> Iterator[tuple[dict, dict]]:
    if workers < 1:
        raise ValueError(f"workers must be >= 1, got {workers}")
    if not cells:  # a resumed sweep with nothing left to run starts no fork server
        return
    context = multiprocessing.get_context("forkserver")
    # One process per core already: a cell's BLAS must not start threads of its own. Threaded BLAS on
    # the small matrices of a cell oversubscribes the cores (an odometry evaluation on office took 28 ms
    # with two cells running, 11 ms with single-threaded BLAS). The fork server, started below, inherits
    # this environment; a value the user set is kept.
    for variable in _BLAS_THREAD_VARIABLES:
        os.environ.setdefault(variable, "1")
    # The fork server is a fresh interpreter that never renders; forking cells from it is safe
    # (unlike forking this process, which may have started MuJoCo's EGL renderer) and, with the
    # heavy modules preloaded there, much cheaper than spawning a new interpreter per cell.
    context.set_forkserver_preload(_PRELOADED_MODULES)
    _start_fork_server()
    queue = deque((cell, 1) for cell in cells)
    running: dict = {}
    try:
        while queue or running:
            while queue and len(running) < workers:
                cell, attempt = queue.popleft()
                receiver, sender = context.Pipe(duplex=False)
                process = context.Process(target=_child, args=(cell_fn, cell, sender), name=f"cell-{_cell_id(cell)}")
                process.start()
                sender.close()
                running[receiver] = (process, cell, attempt)
            for receiver in multiprocessing.connection.wait(list(running)):
                process, cell, attempt = running.pop(receiver)
                try:
                    outcome = receiver.recv()
                except EOFError:
                    outcome = None
                receiver.close()
                process.join()
                if outcome is not None:
                    yield cell, {**outcome, "attempts": attempt}
                elif attempt < max_attempts:
                    queue.append((cell, attempt + 1))
                else:
                    yield cell, _failed(f"worker died (exit code {process.exitcode}) on every one of {attempt} "
                                        "attempts", attempt)
    finally:
        _end(process for process, _, _ in running.values())


# -- Dask distributed -------------------------------------------------------------------------


def _dask_outcomes(cells, cell_fn, scheduler: str, connect_timeout: float) -> Iterator[tuple[dict, dict]]:
    # Exceptions inside a cell are caught by _guarded; a lost worker is retried by the scheduler
    # itself (its ``distributed.scheduler.allowed-failures`` setting) before it reports KilledWorker.
    try:
        from distributed import Client, as_completed
    except ImportError:
        raise ValueError("--scheduler needs Dask distributed: pip install 'ptm[dask]'") from None
    if not cells:
        return
    try:
        client = Client(scheduler, timeout=f"{connect_timeout}s")
    except (OSError, TimeoutError, ValueError) as error:  # refused, unreachable, or not an address
        raise ValueError(f"scheduler {scheduler!r}: no Dask scheduler answered within {connect_timeout:g} s "
                         f"({type(error).__name__}: {error})") from None
    with client:
        futures = {
            client.submit(_guarded, cell_fn, cell, key=f"ptm-cell-{_cell_id(cell)}", pure=False): cell
            for cell in cells
        }
        for future in as_completed(futures):
            cell = futures[future]
            try:
                outcome = future.result()
            except Exception as error:  # noqa: BLE001 - a lost worker (KilledWorker) or a scheduler failure
                outcome = _failed(f"{type(error).__name__}: {error}", attempts=1)
            yield cell, outcome
