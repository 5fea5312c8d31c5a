"""Boundary checks shared by the library: counts, numbers, flags, seeds, finite arrays, instances.

Every public entry point validates its inputs with these helpers so that a bad
value fails loudly with a message naming the field, instead of producing a
silently wrong probability. The contract, everywhere in :mod:`ptm`: a value of
the wrong type (a string or None for a number, a float for a flag, an iterator
of the wrong things) raises ``TypeError``, a value of the right type that is
out of range (negative, non-finite, not whole, too large to compute with)
raises ``ValueError``; both name the argument.

    >>> from ptm._validation import positive
    >>> positive("rate", 2.0)
    2.0
    >>> positive("rate", "2")
    Traceback (most recent call last):
    ...
    TypeError: rate must be a number, got '2'
"""

from __future__ import annotations

import math
import numbers

import numpy as np


def count(name: str, value, minimum: int, maximum: int | None = None) -> int:
    """``value`` as an int: ``TypeError`` naming ``name`` unless it is an integer or a whole float (not a bool),
    ``ValueError`` naming it unless it is finite, whole, at least ``minimum`` and at most ``maximum``."""
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, numbers.Real):
        raise TypeError(f"{name} must be an integer >= {minimum}, got {value!r}")
    if not isinstance(value, numbers.Integral) and not (math.isfinite(value) and float(value).is_integer()):
        raise ValueError(f"{name} must be an integer >= {minimum}, got {value!r}")
    if int(value) < minimum:
        raise ValueError(f"{name} must be an integer >= {minimum}, got {value!r}")
    if maximum is not None and int(value) > maximum:
        raise ValueError(f"{name} must be an integer <= {maximum:,}, got {value!r}")
    return int(value)


def number(name: str, value) -> float:
    """``value`` as a float, NaN and infinity included: ``TypeError`` naming ``name`` unless it is a real
    number (not a bool, not a string), ``ValueError`` for an integer beyond the range of floats."""
    if isinstance(value, np.ndarray) and value.ndim == 0 and value.dtype.kind in "iuf":
        value = value.item()
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, numbers.Real):
        raise TypeError(f"{name} must be a number, got {value!r}")
    try:
        return float(value)
    except OverflowError:
        raise ValueError(f"{name} must be a finite number, got {value!r}") from None


def positive(name: str, value, within: tuple[float, float] | None = None) -> float:
    """``value`` as a float (:func:`number`), or ``ValueError`` unless finite, > 0 and in the closed interval
    ``within`` where one is given."""
    result = number(name, value)
    if not math.isfinite(result) or result <= 0.0:
        raise ValueError(f"{name} must be a finite positive number, got {value!r}")
    _check_within(name, value, result, within)
    return result


def non_negative(name: str, value, within: tuple[float, float] | None = None) -> float:
    """``value`` as a float (:func:`number`), or ``ValueError`` unless finite, >= 0 and in ``within``."""
    result = number(name, value)
    if not math.isfinite(result) or result < 0.0:
        raise ValueError(f"{name} must be a finite non-negative number, got {value!r}")
    _check_within(name, value, result, within)
    return result


def _check_within(name: str, value, number_or_array, within: tuple[float, float] | None) -> None:
    if within is not None and (np.any(number_or_array < within[0]) or np.any(number_or_array > within[1])):
        raise ValueError(f"{name} must lie in [{within[0]:g}, {within[1]:g}], got {value!r}")


def share(name: str, value) -> float:
    """``value`` as a float (:func:`number`), or ``ValueError`` unless it lies in [0, 1]."""
    result = number(name, value)
    if not 0.0 <= result <= 1.0:
        raise ValueError(f"{name} must be a number in [0, 1], got {value!r}")
    return result


def flag(name: str, value) -> bool:
    """``value`` as a bool: ``TypeError`` naming ``name`` unless it is True or False."""
    if not isinstance(value, (bool, np.bool_)):
        raise TypeError(f"{name} must be True or False, got {value!r}")
    return bool(value)


def seed_sequence(name: str, value) -> np.random.SeedSequence:
    """``value`` (None, a non-negative int, a sequence of them, or a SeedSequence) as a SeedSequence:
    ``TypeError`` naming ``name`` for another type, ``ValueError`` for a negative int."""
    if isinstance(value, np.random.SeedSequence):
        return value
    if isinstance(value, (bool, np.bool_)):
        raise TypeError(f"{name} must be None, a non-negative integer or a SeedSequence, got {value!r}")
    try:
        return np.random.SeedSequence(value)
    except TypeError:
        raise TypeError(f"{name} must be None, a non-negative integer or a SeedSequence, got {value!r}") from None
    except ValueError:
        raise ValueError(f"{name} must be a non-negative integer, got {value!r}") from None


def instance(name: str, value, kind: type):
    """``value`` itself: ``TypeError`` naming ``name`` unless it is a ``kind`` (named as ``ptm.<kind>``)."""
    if not isinstance(value, kind):
        raise TypeError(f"{name} must be a ptm.{kind.__name__}, got {type(value).__name__} {value!r:.60}")
    return value


def positive_array(name: str, value, length: int | None = None, within: tuple[float, float] | None = None
                   ) -> np.ndarray:
    """A scalar or 1-D array of finite positive floats (broadcast later by the caller), each in the closed
    interval ``within`` where one is given."""
    array = _float_array(name, value)
    if array.ndim > 1:
        raise ValueError(f"{name} must be a scalar or a 1-D array, got shape {array.shape}")
    if length is not None and array.ndim == 1 and array.shape[0] != length:
        raise ValueError(f"{name} has length {array.shape[0]}, expected {length}")
    if not np.all(np.isfinite(array)) or np.any(array <= 0.0):
        raise ValueError(f"{name} must be finite and positive, got {value!r}")
    _check_within(name, value, array, within)
    return array


def finite_array(name: str, value, ndim: int | None = None) -> np.ndarray:
    """A float array with no NaN or infinity, optionally of a fixed number of dimensions; complex is refused."""
    array = _float_array(name, value)
    if ndim is not None and array.ndim != ndim:
        raise ValueError(f"{name} must have {ndim} dimensions, got shape {array.shape}")
    bad = ~np.isfinite(array)
    if bad.any():
        where = tuple(int(i) for i in np.argwhere(bad)[0])
        raise ValueError(f"{name} contains a non-finite value {array[where]!r} at index {where}")
    return array


def _float_array(name: str, value) -> np.ndarray:
    """``value`` as a float array: ``TypeError`` naming ``name`` for None, a string or a mapping in place of
    the array, ``ValueError`` for entries that are not real numbers (an array read from a file is data)."""
    if value is None or isinstance(value, (str, bytes, dict)):
        raise TypeError(f"{name} must be a number or an array of numbers, got {value!r:.80}")
    try:
        is_complex = np.iscomplexobj(value)
        array = np.asarray(value, dtype=complex if is_complex else float)
    except (TypeError, ValueError, OverflowError):
        raise ValueError(f"{name} must hold numbers only, got {value!r:.80}") from None
    if is_complex:
        raise ValueError(f"{name} must be real numbers, got a complex array (a cast would drop its imaginary part)")
    return array
