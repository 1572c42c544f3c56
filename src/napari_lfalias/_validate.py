"""Checks of parameters at the API boundary (DESIGN section 5).

Each helper raises :class:`~napari_lfalias.errors.ParameterError` with the
parameter's name, the value received and the range expected.
"""

import math
import numbers

import numpy as np

from .errors import ParameterError


def finite_float(name, value):
    """Return ``value`` as a float, or raise if it is not a finite real number."""
    if isinstance(value, bool) or not isinstance(value, numbers.Real):
        raise ParameterError(f"{name} must be a real number, got {value!r}")
    value = float(value)
    if not math.isfinite(value):
        raise ParameterError(f"{name} must be finite, got {value!r}")
    return value


def in_open_interval(name, value, low, high):
    """Return ``value`` as a float, checking ``low < value < high``."""
    value = finite_float(name, value)
    if not low < value < high:
        raise ParameterError(f"{name} must satisfy {low} < {name} < {high}, got {value!r}")
    return value


def positive_float(name, value):
    """Return ``value`` as a float, checking ``value > 0``."""
    value = finite_float(name, value)
    if value <= 0:
        raise ParameterError(f"{name} must be > 0, got {value!r}")
    return value


def non_negative_float(name, value):
    """Return ``value`` as a float, checking ``value >= 0``."""
    value = finite_float(name, value)
    if value < 0:
        raise ParameterError(f"{name} must be >= 0, got {value!r}")
    return value


def integer_at_least(name, value, minimum):
    """Return ``value`` as an int, checking it is a whole number ``>= minimum``."""
    if isinstance(value, bool) or not isinstance(value, numbers.Integral):
        raise ParameterError(f"{name} must be an integer >= {minimum}, got {value!r}")
    value = int(value)
    if value < minimum:
        raise ParameterError(f"{name} must be an integer >= {minimum}, got {value!r}")
    return value


def integer_between(name, value, minimum, maximum):
    """Return ``value`` as an int, checking it is a whole number in ``minimum .. maximum``."""
    if isinstance(value, bool) or not isinstance(value, numbers.Integral) or not minimum <= value <= maximum:
        raise ParameterError(f"{name} must be an integer from {minimum} to {maximum}, got {value!r}")
    return int(value)


def one_of(name, value, choices):
    """Return ``value``, checking it is one of ``choices``."""
    if value not in choices:
        options = ", ".join(repr(c) for c in choices)
        raise ParameterError(f"{name} must be one of {options}; got {value!r}")
    return value


def boolean(name, value):
    """Return ``value`` as a bool, checking it is True or False (a NumPy bool too)."""
    if not isinstance(value, (bool, np.bool_)):
        raise ParameterError(f"{name} must be True or False, got {value!r}")
    return bool(value)


def value_range(name, value):
    """``(low, high)`` as floats from a pair, finite with ``low <= high``, or a :class:`ParameterError` naming ``name``."""
    try:
        low, high = (float(v) for v in value)
    except (TypeError, ValueError):
        raise ParameterError(f"{name} must be a pair (low, high), got {value!r}") from None
    if not (math.isfinite(low) and math.isfinite(high)) or low > high:
        raise ParameterError(f"{name} must be finite with low <= high, got {value!r}")
    return low, high
