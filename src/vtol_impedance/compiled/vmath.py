"""Sine, cosine, arc tangent and arc sine written in arithmetic LLVM can vectorise.

numba's LLVM has no vector math library here (no SVML), so a loop over SIMD lanes that calls ``math.sin`` or
``math.atan2`` stays scalar. These are the same functions as polynomials, selects, ``floor``, ``sqrt`` and
divisions only (no calls, no branches), so a lane loop that uses them compiles to packed instructions. The
truth a control tick reads (:func:`~.plant.observed`) uses them in every engine (the lanes, a vehicle per
thread, MuJoCo's ticks), so there the engines agree to the last bit; the estimators of a block in lanes
(:mod:`.lanes_estimator`) use them too. One at a time the C library is faster (its arc tangent is a table and
a short polynomial, not a series), so code that stays scalar (the sensors, the controller, the estimator of
one vehicle) keeps it: :func:`sin_cos`, :func:`arctan2` and :func:`arcsin` take a literal ``vector`` that
picks which.

Accuracy (``tests/test_vmath.py``, against the C library over a million arguments and the special
values): within 3 units in the last place (``sincos`` for ``|x| <= 1e6`` rad: beyond, the reduction loses
bits, and beyond about 1e22 the result is meaningless; the callers pass angles); NaN gives NaN;
``sincos(-0.0)`` gives ``+0.0`` for the sine. The NumPy definition uses NumPy's own functions: the two
backends part by these last bits, as they already did between two libraries.

How: ``sincos`` reduces ``x`` by the nearest multiple ``k`` of pi/2 with pi/2 split in three parts (Cody and
Waite's reduction: the first two parts have 33 significant bits, so ``k`` times them is exact for ``|k| < 2^20``),
then sums the Taylor series of sine to ``r^17`` and of cosine to ``r^18`` on ``|r| <= pi/4`` (the first term left
out is below 1e-19) and picks the quadrant by selects. ``atan2`` reduces ``a = min/max`` of ``|x|, |y|`` (in [0, 1]) by
``atan(a) = j pi/8 + atan((a - c)/(1 + a c))``, ``c = tan(j pi/8)`` with ``j`` in 0, 1, 2 the nearest, to
``|z| <= tan(pi/16)``, where the Taylor series to ``z^25`` leaves less than 1e-20, then unfolds the octant. The
parts of pi/2 were computed here from pi's digits with exact rational arithmetic.
"""

from __future__ import annotations

import math

import numpy as np

from .jit import kernel

_TWO_OVER_PI = 0.6366197723675814
_PIO2_1 = 1.5707963267341256  # pi/2 = _PIO2_1 + _PIO2_2 + _PIO2_3 to 1e-37
_PIO2_2 = 6.077100506303966e-11
_PIO2_3 = 2.0222662487959506e-21
_PI_4 = 0.7853981633974483
_PI_2 = 1.5707963267948966
_PI = 3.141592653589793
_PI_8 = 0.39269908169872414
_TAN_PI_16 = 0.198912367379658
_TAN_PI_8 = 0.41421356237309503
_TAN_3PI_16 = 0.6681786379192989
_TAN_PI_4 = 1.0

# 1/n! with alternating signs, as the series need them
_S3, _S5, _S7, _S9 = -1.0 / 6.0, 1.0 / 120.0, -1.0 / 5040.0, 1.0 / 362880.0
_S11, _S13, _S15, _S17 = -1.0 / 39916800.0, 1.0 / 6227020800.0, -1.0 / 1307674368000.0, 1.0 / 355687428096000.0
_C4, _C6, _C8, _C10 = 1.0 / 24.0, -1.0 / 720.0, 1.0 / 40320.0, -1.0 / 3628800.0
_C12, _C14, _C16, _C18 = 1.0 / 479001600.0, -1.0 / 87178291200.0, 1.0 / 20922789888000.0, -1.0 / 6402373705728000.0


@kernel(inline="always")
def sincos(x):
    """``(sin x, cos x)``."""
    k = np.floor(x * _TWO_OVER_PI + 0.5)
    r = ((x - k * _PIO2_1) - k * _PIO2_2) - k * _PIO2_3
    w = r * r
    s = r + r * w * (_S3 + w * (_S5 + w * (_S7 + w * (_S9 + w * (_S11 + w * (_S13 + w * (_S15 + w * _S17)))))))
    c8 = _C10 + w * (_C12 + w * (_C14 + w * (_C16 + w * _C18)))
    c = 1.0 - 0.5 * w + w * w * (_C4 + w * (_C6 + w * (_C8 + w * c8)))
    q = k - 4.0 * np.floor(k * 0.25)  # the quadrant, 0 to 3
    odd = q == 1.0 or q == 3.0
    sin_x = c if odd else s
    cos_x = s if odd else c
    sin_x = -sin_x if q >= 2.0 else sin_x
    cos_x = -cos_x if (q == 1.0 or q == 2.0) else cos_x
    return sin_x, cos_x


@kernel(inline="always")
def _atan_taylor(z):
    """``atan z`` for ``|z| <= tan(pi/16)``: its Taylor series to ``z^25`` (the first term left out, ``z^27/27``,
    is below 1e-20)."""
    w = z * z
    p = -1.0 / 25.0
    p = 1.0 / 23.0 + w * p
    p = -1.0 / 21.0 + w * p
    p = 1.0 / 19.0 + w * p
    p = -1.0 / 17.0 + w * p
    p = 1.0 / 15.0 + w * p
    p = -1.0 / 13.0 + w * p
    p = 1.0 / 11.0 + w * p
    p = -1.0 / 9.0 + w * p
    p = 1.0 / 7.0 + w * p
    p = -1.0 / 5.0 + w * p
    p = 1.0 / 3.0 + w * p
    return z - z * w * p


@kernel(inline="always")
def atan2(y, x):
    """The angle of ``(x, y)`` in ``[-pi, pi]``, with ``math.atan2``'s signs (``atan2(+-0, -0) = +-pi``) for
    finite arguments; a NaN or two infinities give NaN."""
    ax, ay = abs(x), abs(y)
    hi, lo = max(ax, ay), min(ax, ay)
    a = lo / hi if hi > 0.0 else 0.0  # in [0, 1]: atan a = j pi/8 + atan((a - c)/(1 + a c)), c = tan(j pi/8)
    c = _TAN_PI_4 if a > _TAN_3PI_16 else (_TAN_PI_8 if a > _TAN_PI_16 else 0.0)
    base = _PI_4 if a > _TAN_3PI_16 else (_PI_8 if a > _TAN_PI_16 else 0.0)
    t = base + _atan_taylor((a - c) / (1.0 + a * c))
    t = _PI_2 - t if ay > ax else t
    t = _PI - t if math.copysign(1.0, x) < 0.0 else t
    t = math.nan if (x != x or y != y) else t  # max and min would drop a NaN
    return math.copysign(t, y)


@kernel(inline="always")
def asin(x):
    """``asin x`` for ``|x| <= 1`` (the callers clamp it)."""
    return atan2(x, math.sqrt((1.0 - x) * (1.0 + x)))


@kernel(inline="always")
def sin_cos(x, vector):
    """``(sin x, cos x)``: :func:`sincos` where ``vector`` (a literal: code in lanes), else the C library's."""
    if vector:
        return sincos(x)
    return math.sin(x), math.cos(x)


@kernel(inline="always")
def arctan2(y, x, vector):
    """:func:`atan2` where ``vector`` (a literal), else the C library's."""
    if vector:
        return atan2(y, x)
    return math.atan2(y, x)


@kernel(inline="always")
def arcsin(x, vector):
    """:func:`asin` where ``vector`` (a literal), else the C library's."""
    if vector:
        return asin(x)
    return math.asin(x)
