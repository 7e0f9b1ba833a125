"""Exceptions and input checks shared by the package."""

from __future__ import annotations

import math
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
    if isinstance(value, str | bytes | dict | bool | np.bool_) or value is None:
        raise InputError(f"{name} must be numeric, got {value!r}")
    try:
        raw = value if isinstance(value, np.ndarray) else np.asarray(value)  # converted once
        if raw.dtype.kind in "bcSUV":  # booleans, complex numbers, text, raw bytes: no silent cast to a real number
            raise InputError(f"{name} must be real numbers, got {_short(value)}")
        arr = np.asarray(raw, dtype=float)
    except InputError:
        raise
    except (TypeError, ValueError) as exc:
        raise InputError(f"{name} must be numeric, got {_short(value)} ({exc})") from None
    if arr.dtype == object:
        raise InputError(f"{name} must be numeric, got {_short(value)}")
    if shape_tail is not None:
        n = len(shape_tail)
        if arr.ndim < n or tuple(arr.shape[arr.ndim - n :]) != tuple(shape_tail):
            raise InputError(f"{name} must have trailing shape {shape_tail}, got shape {arr.shape}")
    if not np.isfinite(arr).all():
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


def check_keys(where: str, data: dict[str, Any], valid: tuple[str, ...] | list[str]) -> None:
    """Raise :class:`InputError` naming any key of ``data`` not in ``valid``."""
    unknown = sorted(set(data) - set(valid))
    if unknown:
        raise InputError(f"{where}: unknown key(s) {unknown}; valid keys: {', '.join(valid)}")


def _short(value: Any, n: int = 80) -> str:
    text = repr(value)
    return text if len(text) <= n else text[: n - 3] + "..."


def scalar(
    name: str,
    value: Any,
    lo: float | None = None,
    hi: float | None = None,
    lo_open: bool = False,
    integer: bool = False,
) -> float:
    """``value`` as one finite float (or int) within ``[lo, hi]`` (``(lo, hi]`` with ``lo_open``).

    Refuses booleans, strings, arrays of more than one value and NaN/inf with an :class:`InputError`
    that names the value and the allowed range.
    """
    if type(value) is float and math.isfinite(value):  # the common case, without an array
        v = value
    else:
        if isinstance(value, bool | np.bool_) or isinstance(value, str | bytes) or value is None:
            raise InputError(f"{name} must be a number, got {value!r}")
        arr = as_finite(name, value)
        if arr.size != 1:
            raise InputError(f"{name} must be a single number, got shape {arr.shape}")
        v = float(arr.reshape(()))
    if integer:
        if not v.is_integer():
            raise InputError(f"{name} must be a whole number, got {value!r}")
    bad = (lo is not None and (v < lo or (lo_open and v == lo))) or (hi is not None and v > hi)
    if bad:
        left = "(" if lo_open else "["
        rng = f"{left}{'-inf' if lo is None else lo}, {'inf' if hi is None else hi}]"
        raise InputError(f"{name} must be in {rng}, got {value!r}")
    return int(v) if integer else v
