"""How every kernel is compiled: cached on disk (see the package docstring), with NumPy's floating-point
error model (a division by zero gives inf or NaN, which the engine's divergence check catches, instead of
a Python exception from inside a kernel) and IEEE arithmetic except that a multiply followed by an add
may be fused into one FMA instruction (``fastmath={"contract"}``: one rounding instead of two, never
less accurate; it makes the plant's RK4 step about a fifth faster on this machine, see the README's
performance section). No other fast-math flag: NaN and infinity keep their meaning, which the failure
checks rely on."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from numba import njit

FLAGS: dict[str, Any] = {"cache": True, "error_model": "numpy", "fastmath": {"contract"}}


def kernel(signature: Any = None, **options: Any) -> Callable:
    """``numba.njit`` with :data:`FLAGS` (and ``options``: ``inline``, ``parallel``)."""
    if signature is not None:
        return njit(signature, **FLAGS, **options)
    return njit(**FLAGS, **options)
