"""The ``ptm-bench`` command line: one sub-command per harness task.

Each sub-command lives in its own module, which exposes ``register(subparsers)``
adding its parser and setting ``handler`` to a function ``(args) -> int``.

    $ ptm-bench demo
    $ ptm-bench speed --out results
"""

from __future__ import annotations

import argparse
import importlib
import signal
import sys

from ptm_bench.cli.options import RESUME_HINT

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
    # A shell starts a background command of a script with SIGINT ignored, and Python then installs no handler:
    # a later Ctrl-C or `kill -INT` would not stop a sweep. Ask for Python's own handler in any case.
    signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        return int(args.handler(args) or 0)
    except (ValueError, FileNotFoundError) as error:  # bad input; a programming error keeps its traceback
        print(f"ptm-bench {args.command}: error: {error}", file=sys.stderr)
        return 2
    except OSError as error:  # the machine refused (a full disk, a permission): no traceback, the file named
        where = f" {error.filename}" if error.filename else ""
        print(f"ptm-bench {args.command}: error:{where} {error.strerror or error}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:  # Ctrl-C: one line, no traceback; what was finished is kept
        hint = getattr(args, RESUME_HINT, None)
        print(f"\nptm-bench {args.command}: interrupted{f'; {hint}' if hint else ''}", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
