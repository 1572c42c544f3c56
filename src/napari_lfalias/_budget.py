"""The memory budget: refuse, before allocating, work whose arrays would not fit.

A small file can declare a huge image (a PNG of zeros compresses 1000:1),
and a parameter can imply a huge array (``n_slopes``, a pyramid level).
Readers and functions call :func:`check` with the bytes they are about to
allocate; beyond the budget they raise the caller's error class naming the
file or parameter, how much it needs and how to raise the budget.

The budget is ``LFALIAS_MEMORY_BUDGET`` (bytes, or with a suffix: ``512M``,
``8G``), else a quarter of the memory the system has available now (Linux
``MemAvailable``; else of the physical memory): what is decoded must leave
room for the work on it (a detection holds a few arrays the size of the
light field's luminance, a reduction more).
"""

from __future__ import annotations

import os
import re

from .errors import ParameterError

__all__ = ["ENV", "memory_budget", "check", "describe_bytes"]

ENV = "LFALIAS_MEMORY_BUDGET"
_UNITS = {"": 1, "K": 2**10, "M": 2**20, "G": 2**30, "T": 2**40}
_AMOUNT = re.compile(r"^\s*(\d+(?:\.\d*)?)\s*([KMGT]?)(?:I?B)?\s*$", re.IGNORECASE)
_FALLBACK = 4 * 2**30
#: The default budget is the available memory divided by this.
_SHARE = 4


def describe_bytes(n):
    """``1536`` -> ``'1.5 KiB'``.

    Examples
    --------
    >>> describe_bytes(3 * 2**30)
    '3.0 GiB'
    """
    n = float(n)
    for unit in ("B", "KiB", "MiB", "GiB", "TiB", "PiB"):
        if n < 1024 or unit == "PiB":
            return f"{n:.0f} {unit}" if unit == "B" else f"{n:.1f} {unit}"
        n /= 1024
    return f"{n:.1f} PiB"  # pragma: no cover - the loop returns


def _available():
    try:
        with open("/proc/meminfo", encoding="ascii") as handle:
            for line in handle:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        pass
    try:
        return os.sysconf("SC_PHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
    except (ValueError, OSError, AttributeError):
        return None


def memory_budget():
    """``(bytes, where it comes from)``: what one allocation may take.

    Raises
    ------
    ParameterError
        If ``LFALIAS_MEMORY_BUDGET`` is set but is not an amount of bytes.
    """
    text = os.environ.get(ENV)
    if text:
        match = _AMOUNT.match(text)
        if match is None:
            raise ParameterError(f"{ENV}={text!r} is not an amount of memory; write bytes, or e.g. 512M or 8G")
        return int(float(match[1]) * _UNITS[match[2].upper()]), f"set by {ENV}"
    available = _available()
    if available is None:
        return _FALLBACK, f"the default when the memory cannot be measured; set {ENV} to change it"
    return available // _SHARE, f"a quarter of the memory available now; set {ENV} to change it"


def check(n_bytes, what, error=ParameterError):
    """Raise ``error`` if allocating ``n_bytes`` for ``what`` would exceed the budget.

    Parameters
    ----------
    n_bytes : int
        What is about to be allocated (Python ints: no overflow).
    what : str
        The start of the message: the file or parameter and what it needs
        the memory for, e.g. ``"n_slopes=10**6: the variance of every slope"``.
    error : type
        The :class:`~napari_lfalias.errors.LightFieldError` to raise.

    Examples
    --------
    >>> check(1024, "a tiny array")
    >>> check(2**60, "n_slopes=10**17: the variances")  # doctest: +ELLIPSIS
    Traceback (most recent call last):
    ...
    napari_lfalias.errors.ParameterError: n_slopes=10**17: the variances need 1024.0 PiB, ...
    """
    n_bytes = int(n_bytes)
    budget, source = memory_budget()
    if n_bytes > budget:
        raise error(f"{what} need {describe_bytes(n_bytes)}, more than the memory budget of "
                    f"{describe_bytes(budget)} ({source})")
