"""Integer arguments of the Python API: an integral value, or InputError (never truncated)."""

from __future__ import annotations

import numbers
import operator

from plantdreamer.errors import InputError

__all__ = ["as_int"]


def as_int(name: str, value: object) -> int:
    """``value`` as an int when it is an integer (int, numpy integer, or a float such as 3.0
    that is one); a width of 3.7, a bool or a string is an InputError naming ``name``."""
    if isinstance(value, bool):
        raise InputError(f"{name} must be an integer, got {value!r}")
    if isinstance(value, numbers.Integral):
        return operator.index(value)
    if isinstance(value, numbers.Real) and float(value).is_integer():
        return int(float(value))
    raise InputError(f"{name} must be an integer, got {value!r}")
