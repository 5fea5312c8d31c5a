"""Boundary checks shared by the library: counts, positive numbers, finite arrays.

Every public entry point validates its inputs with these helpers so that a bad
value fails loudly with a message naming the field, instead of producing a
silently wrong probability.

    >>> from ptm._validation import positive
    >>> positive("rate", 2.0)
    2.0
"""

from __future__ import annotations

import math
import numbers

import numpy as np


def count(name: str, value, minimum: int) -> int:
    """``value`` as an int: ``TypeError`` naming ``name`` unless it is an integer or a whole float (not a bool),
    ``ValueError`` naming it unless it is finite, whole and at least ``minimum``."""
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, numbers.Real):
        raise TypeError(f"{name} must be an integer >= {minimum}, got {value!r}")
    if not isinstance(value, numbers.Integral) and not (math.isfinite(value) and float(value).is_integer()):
        raise ValueError(f"{name} must be an integer >= {minimum}, got {value!r}")
    if int(value) < minimum:
        raise ValueError(f"{name} must be an integer >= {minimum}, got {value!r}")
    return int(value)


def positive(name: str, value) -> float:
    """Return ``value`` as a float, or raise ``ValueError`` unless finite and > 0."""
    try:
        number = float(value)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a positive number, got {value!r}") from None
    if not np.isfinite(number) or number <= 0.0:
        raise ValueError(f"{name} must be a finite positive number, got {value!r}")
    return number


def non_negative(name: str, value) -> float:
    """Return ``value`` as a float, or raise ``ValueError`` unless finite and >= 0."""
    try:
        number = float(value)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a non-negative number, got {value!r}") from None
    if not np.isfinite(number) or number < 0.0:
        raise ValueError(f"{name} must be a finite non-negative number, got {value!r}")
    return number


def share(name: str, value) -> float:
    """Return ``value`` as a float, or raise ``ValueError`` unless it is a probability in [0, 1]."""
    number = non_negative(name, value)
    if number > 1.0:
        raise ValueError(f"{name} must be a probability in [0, 1], got {value!r}")
    return number


def positive_array(name: str, value, length: int | None = None) -> np.ndarray:
    """A scalar or 1-D array of finite positive floats (broadcast later by the caller)."""
    array = np.asarray(value, dtype=float)
    if array.ndim > 1:
        raise ValueError(f"{name} must be a scalar or a 1-D array, got shape {array.shape}")
    if length is not None and array.ndim == 1 and array.shape[0] != length:
        raise ValueError(f"{name} has length {array.shape[0]}, expected {length}")
    if not np.all(np.isfinite(array)) or np.any(array <= 0.0):
        raise ValueError(f"{name} must be finite and positive, got {value!r}")
    return array


def finite_array(name: str, value, ndim: int | None = None) -> np.ndarray:
    """A float array with no NaN or infinity, optionally of a fixed number of dimensions."""
    array = np.asarray(value, dtype=float)
    if ndim is not None and array.ndim != ndim:
        raise ValueError(f"{name} must have {ndim} dimensions, got shape {array.shape}")
    bad = ~np.isfinite(array)
    if bad.any():
        where = tuple(int(i) for i in np.argwhere(bad)[0])
        raise ValueError(f"{name} contains a non-finite value {array[where]!r} at index {where}")
    return array
