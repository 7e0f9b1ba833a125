"""Exceptions and input checks shared by the package."""

from __future__ import annotations

from typing import Any

import numpy as np


class VtolImpedanceError(Exception):
    """Base class of the package's errors."""


class InputError(VtolImpedanceError, ValueError):
    """A value given by the user is NaN, infinite, of the wrong shape or outside its valid range."""


class SingularityError(VtolImpedanceError, ValueError):
    """The ZYX Euler parametrisation is singular (pitch theta at +-90 deg)."""


class ScenarioError(InputError, KeyError):
    """An unknown scenario, key or malformed scenario file."""

    def __str__(self) -> str:  # KeyError quotes its message; keep it readable
        return str(self.args[0]) if self.args else ""


def as_finite(name: str, value: Any, shape_tail: tuple[int, ...] | None = None) -> np.ndarray:
    """Return ``value`` as a float array, raising :class:`InputError` if it is not finite or mis-shaped.

    ``shape_tail`` is the required trailing shape (leading batch dimensions are free).
    """
    arr = np.asarray(value, dtype=float)
    if shape_tail is not None:
        n = len(shape_tail)
        if arr.ndim < n or tuple(arr.shape[arr.ndim - n :]) != tuple(shape_tail):
            raise InputError(f"{name} must have trailing shape {shape_tail}, got shape {arr.shape}")
    if not np.all(np.isfinite(arr)):
        bad = arr[~np.isfinite(arr)].ravel()[:3]
        raise InputError(f"{name} contains non-finite values ({', '.join(map(str, bad))})")
    return arr


def positive(name: str, value: Any, allow_zero: bool = False) -> np.ndarray:
    """Return ``value`` as a finite float array whose entries are all > 0 (or >= 0)."""
    arr = as_finite(name, value)
    ok = arr >= 0 if allow_zero else arr > 0
    if not np.all(ok):
        bound = ">= 0" if allow_zero else "> 0"
        raise InputError(f"{name} must be {bound}, got {arr.tolist()}")
    return arr
