"""Small fixed-size algebra for the compiled kernels: 3x3 matrices as row-major 9-tuples (no heap
allocation), ``Q(eta)``, ``M(eta)``, ``C(eta, eta_dot)`` of eqs. (3b), (7) and the known momentum rate of
eq. (8)."""

from __future__ import annotations

import math

import numpy as np

from ..conventions import G
from .jit import kernel
from .vmath import sin_cos


@kernel(inline="always")
def mod_2pi(w):
    """``w % (2 pi)`` in ``[0, 2 pi)`` with the same bits as the ``%`` operator, without its ``fmod`` call
    in the usual case of one turn at most (there ``fmod`` is exact and so is ``w -+ 2 pi``)."""
    two_pi = 2.0 * math.pi
    if w >= two_pi:
        return w - two_pi if w < 2.0 * two_pi else w % two_pi
    if w < 0.0:
        return w + two_pi if w >= -two_pi else w % two_pi
    return w


_INV_TWO_PI = 0.5 / math.pi


@kernel(inline="always")
def turn(w, vector):
    """:func:`mod_2pi`; where ``vector`` (a literal: code in lanes) as selects, with ``w - 2 pi floor(w / 2 pi)``
    (``fmod``'s value to rounding; ``w / 2 pi`` taken as a product with ``1 / 2 pi``: a packed division costs
    the lanes as much as a dozen products, and this value is discarded but beyond one turn) in place of the
    call beyond one turn either side, which is never reached there (a difference of two wrapped angles)."""
    if not vector:
        return mod_2pi(w)
    two_pi = 2.0 * math.pi
    far = w - two_pi * np.floor(w * _INV_TWO_PI)
    up = w - two_pi if w < 2.0 * two_pi else far
    down = w + two_pi if w >= -two_pi else far
    return up if w >= two_pi else (down if w < 0.0 else w)


@kernel(inline="always")
def _Q9(f, t, vector):
    (sf, cf), (st, ct) = sin_cos(f, vector), sin_cos(t, vector)
    return (1.0, 0.0, -st, 0.0, cf, sf * ct, 0.0, -sf, cf * ct)  # eq. (1c)


@kernel(inline="always")
def _Qd9(f, t, df, dt, vector):
    (sf, cf), (st, ct) = sin_cos(f, vector), sin_cos(t, vector)
    return (0.0, 0.0, -ct * dt, 0.0, -sf * df, cf * ct * df - sf * st * dt, 0.0, -cf * df, -sf * ct * df - cf * st * dt)


@kernel(inline="always")
def _mm9(A, B):
    return (
        A[0] * B[0] + A[1] * B[3] + A[2] * B[6],
        A[0] * B[1] + A[1] * B[4] + A[2] * B[7],
        A[0] * B[2] + A[1] * B[5] + A[2] * B[8],
        A[3] * B[0] + A[4] * B[3] + A[5] * B[6],
        A[3] * B[1] + A[4] * B[4] + A[5] * B[7],
        A[3] * B[2] + A[4] * B[5] + A[5] * B[8],
        A[6] * B[0] + A[7] * B[3] + A[8] * B[6],
        A[6] * B[1] + A[7] * B[4] + A[8] * B[7],
        A[6] * B[2] + A[7] * B[5] + A[8] * B[8],
    )


@kernel(inline="always")
def _m9(M):
    """A 3x3 array as a row-major 9-tuple."""
    return (M[0, 0], M[0, 1], M[0, 2], M[1, 0], M[1, 1], M[1, 2], M[2, 0], M[2, 1], M[2, 2])


@kernel(inline="always")
def _v3(v):
    """The first three entries of ``v`` as a tuple."""
    return (v[0], v[1], v[2])


@kernel(inline="always")
def _t9(A):
    return (A[0], A[3], A[6], A[1], A[4], A[7], A[2], A[5], A[8])


@kernel(inline="always")
def _mv9(A, x0, x1, x2):
    return (
        A[0] * x0 + A[1] * x1 + A[2] * x2,
        A[3] * x0 + A[4] * x1 + A[5] * x2,
        A[6] * x0 + A[7] * x1 + A[8] * x2,
    )


@kernel(inline="always")
def _solve9(A, b0, b1, b2):
    """``A^{-1} b`` for a 3x3 ``A`` (row-major 9-tuple) by the adjugate: no LAPACK call on the hot path."""
    c00 = A[4] * A[8] - A[5] * A[7]
    c01 = A[5] * A[6] - A[3] * A[8]
    c02 = A[3] * A[7] - A[4] * A[6]
    inv = 1.0 / (A[0] * c00 + A[1] * c01 + A[2] * c02)
    x0 = c00 * b0 + (A[2] * A[7] - A[1] * A[8]) * b1 + (A[1] * A[5] - A[2] * A[4]) * b2
    x1 = c01 * b0 + (A[0] * A[8] - A[2] * A[6]) * b1 + (A[2] * A[3] - A[0] * A[5]) * b2
    x2 = c02 * b0 + (A[1] * A[6] - A[0] * A[7]) * b1 + (A[0] * A[4] - A[1] * A[3]) * b2
    return x0 * inv, x1 * inv, x2 * inv


@kernel(inline="always")
def _AQ(A, cf, sf, ct, st):
    """``A Q(eta)`` for a 3x3 ``A``, using the zeros of ``Q`` (its first column is ``e1``)."""
    return (
        A[0], A[1] * cf - A[2] * sf, -A[0] * st + A[1] * sf * ct + A[2] * cf * ct,
        A[3], A[4] * cf - A[5] * sf, -A[3] * st + A[4] * sf * ct + A[5] * cf * ct,
        A[6], A[7] * cf - A[8] * sf, -A[6] * st + A[7] * sf * ct + A[8] * cf * ct,
    )  # fmt: skip


@kernel(inline="always")
def _QtA(A, cf, sf, ct, st):
    """``Q(eta)^T A`` for a 3x3 ``A``, using the zeros of ``Q``."""
    return (
        A[0], A[1], A[2],
        cf * A[3] - sf * A[6], cf * A[4] - sf * A[7], cf * A[5] - sf * A[8],
        -st * A[0] + sf * ct * A[3] + cf * ct * A[6],
        -st * A[1] + sf * ct * A[4] + cf * ct * A[7],
        -st * A[2] + sf * ct * A[5] + cf * ct * A[8],
    )  # fmt: skip


@kernel(inline="always")
def _QMC(e0, e1, d0, d1, d2, I, vector):  # noqa: E741
    """``Q``, ``M = Q^T I Q``, ``C = Q^T (S(I Q eta_dot)^T Q + I Q_dot)`` as 9-tuples (eq. (3b), (7)).

    The products use the zeros of ``Q`` and ``Q_dot`` (:func:`_Q9`, :func:`_Qd9`): about half the
    arithmetic of dense 3x3 products. ``vector`` (a literal): the sines of :mod:`.vmath` (code in lanes)."""
    (sf, cf), (st, ct) = sin_cos(e0, vector), sin_cos(e1, vector)
    Q = (1.0, 0.0, -st, 0.0, cf, sf * ct, 0.0, -sf, cf * ct)  # eq. (1c), as _Q9
    M = _QtA(_AQ(I, cf, sf, ct, st), cf, sf, ct, st)  # eq. (3b)
    w0, w1, w2 = d0 - st * d2, cf * d1 + sf * ct * d2, -sf * d1 + cf * ct * d2  # Q eta_dot
    h0, h1, h2 = _mv9(I, w0, w1, w2)
    S = _AQ((0.0, h2, -h1, -h2, 0.0, h0, h1, -h0, 0.0), cf, sf, ct, st)  # S(h)^T Q
    # I Q_dot: Q_dot's first column is zero
    q4, q7 = -sf * d0, -cf * d0
    q2, q5, q8 = -ct * d1, cf * ct * d0 - sf * st * d1, -sf * ct * d0 - cf * st * d1
    IQd = (
        0.0, I[1] * q4 + I[2] * q7, I[0] * q2 + I[1] * q5 + I[2] * q8,
        0.0, I[4] * q4 + I[5] * q7, I[3] * q2 + I[4] * q5 + I[5] * q8,
        0.0, I[7] * q4 + I[8] * q7, I[6] * q2 + I[7] * q5 + I[8] * q8,
    )  # fmt: skip
    C = _QtA(  # C of eq. (3b), satisfying (7)
        (S[0] + IQd[0], S[1] + IQd[1], S[2] + IQd[2], S[3] + IQd[3], S[4] + IQd[4], S[5] + IQd[5], S[6] + IQd[6],
         S[7] + IQd[7], S[8] + IQd[8]),
        cf, sf, ct, st,
    )  # fmt: skip
    return Q, M, C


@kernel(inline="always")
def _beta_ang(Q, C, t0, t1, t2, d0, d1, d2):
    """Angular part of eq. (8): ``Q^T tau_B + C^T eta_dot``."""
    a = _mv9(_t9(Q), t0, t1, t2)
    b = _mv9(_t9(C), d0, d1, d2)
    return a[0] + b[0], a[1] + b[1], a[2] + b[2]  # eq. (8), angular part


@kernel(inline="always")
def _beta_lin(e0, e1, e2, u, m, vector):
    """Linear part of eq. (8): ``-u R(eta) e3 + m g``."""
    (sf, cf), (st, ct), (sp, cp) = sin_cos(e0, vector), sin_cos(e1, vector), sin_cos(e2, vector)
    return -u * (cp * st * cf + sp * sf), -u * (sp * st * cf - cp * sf), -u * (ct * cf) + m * G  # eq. (8), linear part


@kernel()
def triangular_response(T, b, c, z, out):
    """``out[f] += c (z_f I - T)^-1 b`` for an upper-triangular complex ``T (n, n)`` (a Schur form), by back
    substitution at each frequency point ``z (F,)``: the frequency response of a state-space loop
    (:class:`vtol_impedance.robust.margins.FrequencyResponse`). Serial, so the sums are the same whatever
    the machine's thread count."""
    n = T.shape[0]
    x = np.empty(n, dtype=np.complex128)
    for f in range(z.shape[0]):
        zf = z[f]
        for i in range(n - 1, -1, -1):
            s = b[i]
            for j in range(i + 1, n):
                s += T[i, j] * x[j]
            x[i] = s / (zf - T[i, i])
        acc = 0j
        for i in range(n):
            acc += c[i] * x[i]
        out[f] += acc
