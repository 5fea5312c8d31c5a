"""The ``ptm-bench`` command line: one sub-command per harness task.

Each sub-command lives in its own module, which exposes ``register(subparsers)``
adding its parser and setting ``handler`` to a function ``(args) -> int``.

    $ ptm-bench demo
    $ ptm-bench speed --out results
"""

from __future__ import annotations

import argparse
import contextlib
import importlib
import signal
import sys

from ptm_bench.cli.options import RESUME_HINT

#: Signals that stop a command as Ctrl-C does (:func:`_stopped_by_signals`).
STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)

# Modules that register sub-commands, in the order ``--help`` lists them.
COMMAND_MODULES = (
    "ptm_bench.cli.demo",
    "ptm_bench.cli.run",
    "ptm_bench.cli.appearance_check",
    "ptm_bench.cli.speed",
    "ptm_bench.cli.worlds",
    "ptm_bench.cli.generate",
    "ptm_bench.cli.import_carmen",
    "ptm_bench.cli.export",
    "ptm_bench.cli.online",
    "ptm_bench.cli.index",
)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="ptm-bench",
        description="Probabilistic topological maps: simulation, inference, evaluation.",
    )
    subparsers = parser.add_subparsers(dest="command", metavar="COMMAND")
    for module_name in COMMAND_MODULES:
        importlib.import_module(module_name).register(subparsers)
    return parser


def main(argv=None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if not getattr(args, "handler", None):
        parser.print_help()
        return 2
    with _stopped_by_signals():
        try:
            return int(args.handler(args) or 0)
        except (ValueError, FileNotFoundError) as error:  # bad input; a programming error keeps its traceback
            print(f"ptm-bench {args.command}: error: {error}", file=sys.stderr)
            return 2
        except OSError as error:  # the machine refused (a full disk, a permission): no traceback, the file named
            where = f" {error.filename}" if error.filename else ""
            print(f"ptm-bench {args.command}: error:{where} {error.strerror or error}", file=sys.stderr)
            return 1
        except KeyboardInterrupt as error:  # Ctrl-C, SIGTERM, SIGHUP: one line, no traceback; finished work is kept
            number = error.signum if isinstance(error, Stopped) else signal.SIGINT
            how = "interrupted" if number == signal.SIGINT else f"stopped by {signal.Signals(number).name}"
            hint = getattr(args, RESUME_HINT, None)
            print(f"\nptm-bench {args.command}: {how}{f'; {hint}' if hint else ''}", file=sys.stderr)
            return 128 + number


class Stopped(KeyboardInterrupt):
    """A stop signal arrived (``signum``): raised where the command is, so that it unwinds as on Ctrl-C (finished
    work kept, temporary files and locks removed, worker processes ended)."""

    def __init__(self, signum: int):
        super().__init__(signal.Signals(signum).name)
        self.signum = signum


def _stop(signum, frame) -> None:
    """Raise :class:`Stopped`; further stop signals are ignored from here on, so the unwinding completes."""
    for number in STOP_SIGNALS:
        signal.signal(number, signal.SIG_IGN)
    raise Stopped(signum)


@contextlib.contextmanager
def _stopped_by_signals():
    """While a command runs, Ctrl-C (SIGINT), SIGTERM (``kill``, a batch system's time limit) and SIGHUP (the
    terminal closing) stop it with :class:`Stopped`; its exit status is then 128 + the signal's number, as a shell
    reports it. The previous handlers are restored afterwards.

    A shell starts a background command of a script with SIGINT ignored: a later Ctrl-C or ``kill -INT``
    must stop a sweep all the same, so SIGINT is always handled. SIGTERM and SIGHUP are handled only where they
    have their default action: under ``nohup``, which ignores SIGHUP, a run outlives its terminal.
    """
    previous = {number: signal.getsignal(number) for number in STOP_SIGNALS}
    for number, handler in previous.items():
        if number == signal.SIGINT or handler == signal.SIG_DFL:
            signal.signal(number, _stop)
    try:
        yield
    finally:
        for number, handler in previous.items():
            if handler is not None:  # None: a handler installed outside Python, left as it is
                signal.signal(number, handler)


if __name__ == "__main__":
    sys.exit(main())
