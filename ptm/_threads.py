"""How many threads the BLAS libraries (OpenBLAS, MKL, ...) may use while the library works.

PTM's linear algebra is many small solves and products (3 x 3 blocks, banded factors of a few hundred
variables, Woodbury corrections of rank up to N): a BLAS thread pool hands each of them to its threads and
back, which costs more than it saves at these sizes. :func:`blas_threads` limits the pools for the span of a
``with`` block and restores what the process had after it (threadpoolctl, which finds every BLAS library
loaded, numpy's and scipy's included).

    >>> from ptm._threads import blas_threads
    >>> with blas_threads(1):
    ...     pass
    >>> with blas_threads(None):   # None: leave the process's setting alone
    ...     pass
"""

from __future__ import annotations

import contextlib
import functools

from ._validation import count


def blas_threads(threads: int | None):
    """A context manager that limits every loaded BLAS library to ``threads`` threads (``None``: no limit
    set, the process's own setting stands)."""
    if threads is None:
        return contextlib.nullcontext()
    return _controller().limit(limits=threads, user_api="blas")


def checked_blas_threads(value) -> int | None:
    """``value`` as a thread count >= 1, or None; anything else is a ``ValueError`` naming the field."""
    return None if value is None else count("blas_threads", value, minimum=1)


@functools.cache
def _controller():
    """The process's BLAS libraries, found once (each search walks the loaded shared objects)."""
    from threadpoolctl import ThreadpoolController

    return ThreadpoolController()
