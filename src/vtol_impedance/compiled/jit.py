"""How every kernel is compiled: cached on disk (see the package docstring), with NumPy's floating-point
error model (a division by zero gives inf or NaN, which the engine's divergence check catches, instead of
a Python exception from inside a kernel) and IEEE arithmetic except that a multiply followed by an add
may be fused into one FMA instruction (``fastmath={"contract"}``: one rounding instead of two, never
less accurate; it makes the plant's RK4 step about a fifth faster on this machine, see the README's
performance section). No other fast-math flag: NaN and infinity keep their meaning, which the failure
checks rely on.

On a CPU with AVX-512, LLVM's tuning for recent Intel server cores prefers 256-bit vectors, which halves
what the SIMD lanes (:mod:`.lanes`) do per instruction; :func:`_wide_vectors` lifts that preference when
this package is imported (see its docstring and the performance guide for what it changes and measures)."""

from __future__ import annotations

import os
from collections.abc import Callable
from typing import Any

import numba
from numba import njit


def _wide_vectors() -> None:
    """Let LLVM use 512-bit vectors where the host has AVX-512: numba's target features become the host's
    with ``-prefer-256-bit`` (``numba.config.CPU_FEATURES``). Measured on a 2-core AVX-512 machine (Emerald
    Rapids, LLVM 20): one RK4 step of a block's plants 54 -> 32 ns per vehicle, the same results (the
    arithmetic of each lane does not change, only how many lanes one instruction holds).

    Numba has one code generator per process, so this holds for every kernel compiled after the import,
    the user's too. On older AVX-512 cores (Skylake-SP) 512-bit code lowers the clock, which is why LLVM
    prefers 256 bits there: ``VTOL_IMPEDANCE_NARROW_VECTORS=1`` keeps LLVM's choice. It also does nothing
    when ``NUMBA_CPU_FEATURES`` or ``NUMBA_CPU_NAME`` is set (the user's choice stands) or when numba made
    its generator before this package's kernels were imported (any numba function defined first,
    ``numba.typed`` imported first: the kernels then run with narrower vectors). ``vtol_impedance.compiled``
    imports this module before anything else of numba's."""
    if os.environ.get("VTOL_IMPEDANCE_NARROW_VECTORS", "") not in ("", "0"):
        return
    if os.environ.get("NUMBA_CPU_FEATURES") or os.environ.get("NUMBA_CPU_NAME") or numba.config.CPU_FEATURES:
        return
    import llvmlite.binding as ll

    host = ll.get_host_cpu_features().flatten()
    if "+avx512f" in host.split(","):
        numba.config.CPU_FEATURES = host + ",-prefer-256-bit"


_wide_vectors()

FLAGS: dict[str, Any] = {"cache": True, "error_model": "numpy", "fastmath": {"contract"}}


def kernel(signature: Any = None, **options: Any) -> Callable:
    """``numba.njit`` with :data:`FLAGS` (and ``options``: ``inline``, ``parallel``)."""
    if signature is not None:
        return njit(signature, **FLAGS, **options)
    return njit(**FLAGS, **options)
