"""Input checks shared by every public entry point.

Each helper raises :class:`ValueError` naming the parameter, what was expected and what came,
so that bad input is rejected before any solver runs.
"""

from __future__ import annotations

import numbers
from collections.abc import Sequence

import numpy as np


def positive_float(name: str, value: object) -> float:
    """Return ``value`` as a float if it is finite and > 0, else raise ``ValueError``."""
    number = finite_float(name, value)
    if number <= 0.0:
        raise ValueError(f"{name} must be a finite number > 0, got {value!r}")
    return number


def nonnegative_float(name: str, value: object) -> float:
    """Return ``value`` as a float if it is finite and >= 0, else raise ``ValueError``."""
    number = finite_float(name, value)
    if number < 0.0:
        raise ValueError(f"{name} must be a finite number >= 0, got {value!r}")
    return number


def finite_float(name: str, value: object) -> float:
    """Return ``value`` as a float if it is a finite real number, else raise ``ValueError``."""
    if isinstance(value, bool) or not isinstance(value, numbers.Real):
        raise ValueError(f"{name} must be a real number, got {value!r}")
    number = float(value)
    if not np.isfinite(number):
        raise ValueError(f"{name} must be finite, got {value!r}")
    return number


def boolean(name: str, value: object) -> bool:
    """Return ``value`` if it is ``True`` or ``False``, else raise ``ValueError``."""
    if not isinstance(value, bool):
        raise ValueError(f"{name} must be True or False, got {value!r}")
    return value


def positive_int(name: str, value: object, minimum: int = 1) -> int:
    """Return ``value`` if it is an integer >= ``minimum`` (bools rejected), else raise."""
    if isinstance(value, bool) or not isinstance(value, numbers.Integral):
        raise ValueError(f"{name} must be an integer >= {minimum}, got {value!r}")
    if int(value) < minimum:
        raise ValueError(f"{name} must be an integer >= {minimum}, got {value!r}")
    return int(value)


def vector(
    name: str,
    value: object,
    length: int,
    *,
    positive: bool = False,
    nonnegative: bool = False,
) -> tuple[float, ...]:
    """Return ``value`` as a tuple of ``length`` finite floats, checking the sign if asked."""
    try:
        array = np.asarray(value, dtype=float)
    except (TypeError, ValueError) as error:
        raise ValueError(f"{name} must be {length} real numbers, got {value!r}") from error
    if array.shape != (length,):
        raise ValueError(f"{name} must have shape ({length},), got shape {array.shape}: {value!r}")
    if not np.all(np.isfinite(array)):
        raise ValueError(f"{name} must be finite, got {value!r}")
    if positive and np.any(array <= 0.0):
        raise ValueError(f"{name} must be > 0 element-wise, got {value!r}")
    if nonnegative and np.any(array < 0.0):
        raise ValueError(f"{name} must be >= 0 element-wise, got {value!r}")
    return tuple(float(v) for v in array)


def finite_array(name: str, value: object, shape: Sequence[int]) -> np.ndarray:
    """Return ``value`` as a float array of exactly ``shape`` with finite entries."""
    try:
        array = np.array(value, dtype=float)
    except (TypeError, ValueError) as error:
        raise ValueError(f"{name} must be a real array of shape {tuple(shape)}, got {value!r}") from error
    if array.shape != tuple(shape):
        raise ValueError(f"{name} must have shape {tuple(shape)}, got shape {array.shape}")
    if not np.all(np.isfinite(array)):
        raise ValueError(f"{name} must be finite (no NaN or inf), got {array!r}")
    return array


def choice(name: str, value: object, allowed: Sequence[str]) -> str:
    """Return ``value`` if it is one of ``allowed``, else raise naming the valid options."""
    if value not in allowed:
        raise ValueError(f"{name} must be one of {sorted(allowed)}, got {value!r}")
    return str(value)
