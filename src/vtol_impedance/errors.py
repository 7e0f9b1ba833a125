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
    except OverflowError:  # an integer such as 10**400, beyond any float
        raise InputError(f"{name} is beyond any floating-point number, got {_short(value)}") from None
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
    """Raise :class:`InputError` naming any key of ``data`` not in ``valid`` (or ``data`` that is no table)."""
    if not isinstance(data, dict):
        raise InputError(f"{where} must be a table of keys ({', '.join(valid)}), got {_short(data)}")
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
        raise InputError(f"{name} must be in {rng}, got {_short(value)}")
    return int(v) if integer else v


def _type_name(types: type | tuple[type, ...]) -> str:
    types = types if isinstance(types, tuple) else (types,)
    return " or ".join(t.__name__ for t in types)


def instance(name: str, value: Any, types: type | tuple[type, ...]) -> Any:
    """Return ``value`` if it is an instance of ``types``, else raise :class:`InputError` naming the expected type.

    Parameters
    ----------
    name : str
        The argument's name, as the caller knows it.
    value : object
        What was given.
    types : type or tuple of type
        The accepted type(s).

    Returns
    -------
    object
        ``value`` itself.
    """
    if not isinstance(value, types):
        raise InputError(f"{name} must be a {_type_name(types)}, got {type(value).__name__} {_short(value)}")
    return value


def choice(name: str, value: Any, options: tuple[str, ...] | list[str]) -> str:
    """Return ``value`` if it is one of the strings ``options``, else raise :class:`InputError` listing them.

    Parameters
    ----------
    name : str
        The argument's name.
    value : object
        What was given.
    options : sequence of str
        The accepted values.

    Returns
    -------
    str
        ``value``.
    """
    if not isinstance(value, str) or value not in options:
        raise InputError(f"{name} must be one of {', '.join(map(repr, options))}; got {_short(value)}")
    return value


def path_like(name: str, value: Any) -> Any:
    """Return ``value`` as a :class:`pathlib.Path` if it is a non-empty ``str`` or ``os.PathLike``.

    Parameters
    ----------
    name : str
        The argument's name.
    value : object
        What was given.

    Returns
    -------
    pathlib.Path
        The path (not checked for existence).
    """
    import os
    from pathlib import Path

    if isinstance(value, bytes | bool) or not isinstance(value, str | os.PathLike) or str(value) == "":
        raise InputError(f"{name} must be a file or folder path (str or os.PathLike), got {_short(value)}")
    return Path(value)


def per_axis(name: str, value: Any, n: int = 3, lo: float | None = None, lo_open: bool = False) -> np.ndarray:
    """``value`` as a finite float array of shape ``(n,)``: one number for every axis, or ``n`` numbers.

    Parameters
    ----------
    name : str
        The argument's name.
    value : float or array_like
        A scalar (the same for all axes) or ``n`` values.
    n : int
        The number of axes.
    lo : float, optional
        The lower bound of every entry (``lo_open``: strictly above it).
    lo_open : bool
        Whether ``lo`` itself is refused.

    Returns
    -------
    numpy.ndarray
        Shape ``(n,)``.
    """
    arr = as_finite(name, value)
    if arr.shape not in ((), (1,), (n,)):
        raise InputError(f"{name} must be one number or {n} numbers (one per axis), got {_short(value)}")
    out = np.broadcast_to(arr.reshape(-1) if arr.ndim else arr, (n,)).astype(float)
    if lo is not None and not bool(np.all(out > lo if lo_open else out >= lo)):
        raise InputError(f"{name} must be {'>' if lo_open else '>='} {lo} on every axis, got {out.tolist()}")
    return out


def function(name: str, value: Any) -> Any:
    """Return ``value`` if it is callable, else raise :class:`InputError`.

    Parameters
    ----------
    name : str
        The argument's name.
    value : object
        What was given.

    Returns
    -------
    callable
        ``value``.
    """
    if not callable(value):
        raise InputError(f"{name} must be callable, got {type(value).__name__} {_short(value)}")
    return value


def flag(name: str, value: Any) -> bool:
    """Return ``value`` if it is a ``bool`` (or NumPy bool), else raise :class:`InputError`.

    Parameters
    ----------
    name : str
        The argument's name.
    value : object
        What was given.

    Returns
    -------
    bool
        ``value``.
    """
    if not isinstance(value, bool | np.bool_):
        raise InputError(f"{name} must be True or False, got {_short(value)}")
    return bool(value)


def _fits(shape: tuple[int, ...], tail: tuple[int, ...]) -> bool:
    return all(t in (-1, s) for s, t in zip(shape, tail, strict=True))


def batched(name: str, value: Any, tail: tuple[int, ...] = ()) -> np.ndarray:
    """``value`` as a float array with trailing shape ``tail``, for the batched math called every step.

    Checks the type and the shape only: NaN and infinities pass through by IEEE arithmetic, as the
    batch engine relies on them to flag a diverged vehicle without stopping the others. Entry points
    that take a user's values (:class:`~vtol_impedance.runtime.Controller`, the constructors) refuse
    them with :func:`as_finite`.

    Parameters
    ----------
    name : str
        The argument's name.
    value : array_like
        Real numbers.
    tail : tuple of int
        The required trailing shape (leading batch dimensions are free); ``-1`` takes any length.

    Returns
    -------
    numpy.ndarray
        ``value`` as float64 (the same object when it already is one).
    """
    if type(value) is np.ndarray and value.dtype == np.float64:  # the hot path: no conversion
        arr = value
    else:
        if isinstance(value, str | bytes | dict | bool | np.bool_) or value is None:
            raise InputError(f"{name} must be real numbers, got {_short(value)}")
        try:
            raw = np.asarray(value)
            if raw.dtype.kind in "bcSUVO":
                raise InputError(f"{name} must be real numbers, got {_short(value)}")
            arr = raw.astype(float, copy=False)
        except InputError:
            raise
        except (TypeError, ValueError) as exc:
            raise InputError(f"{name} must be real numbers, got {_short(value)} ({exc})") from None
    n = len(tail)
    if n and (arr.ndim < n or (arr.shape[arr.ndim - n :] != tail and not _fits(arr.shape[arr.ndim - n :], tail))):
        raise InputError(f"{name} must have trailing shape {tail}, got shape {arr.shape}")
    return arr
