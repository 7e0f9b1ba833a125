"""Small fixed-size algebra for the compiled kernels: 3x3 matrices as row-major 9-tuples (no heap
allocation), ``Q(eta)``, ``M(eta)``, ``C(eta, eta_dot)`` of eqs. (3b), (7) and the known momentum rate of
eq. (8)."""

from __future__ import annotations

import math

from ..conventions import G
from .jit import kernel


@kernel(inline="always")
def _Q9(f, t):
    cf, sf, ct, st = math.cos(f), math.sin(f), math.cos(t), math.sin(t)
    return (1.0, 0.0, -st, 0.0, cf, sf * ct, 0.0, -sf, cf * ct)


@kernel(inline="always")
def _Qd9(f, t, df, dt):
    cf, sf, ct, st = math.cos(f), math.sin(f), math.cos(t), math.sin(t)
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
def _QMC(e0, e1, d0, d1, d2, I):  # noqa: E741
    """``Q``, ``M = Q^T I Q``, ``C = Q^T S(I Q eta_dot)^T Q + Q^T I Q_dot`` as 9-tuples (eq. (3b), (7))."""
    Q = _Q9(e0, e1)
    Qt = _t9(Q)
    M = _mm9(Qt, _mm9(I, Q))
    w0, w1, w2 = _mv9(Q, d0, d1, d2)
    h0, h1, h2 = _mv9(I, w0, w1, w2)
    ST = (0.0, h2, -h1, -h2, 0.0, h0, h1, -h0, 0.0)
    C1 = _mm9(Qt, _mm9(ST, Q))
    C2 = _mm9(Qt, _mm9(I, _Qd9(e0, e1, d0, d1)))
    C = (
        C1[0] + C2[0],
        C1[1] + C2[1],
        C1[2] + C2[2],
        C1[3] + C2[3],
        C1[4] + C2[4],
        C1[5] + C2[5],
        C1[6] + C2[6],
        C1[7] + C2[7],
        C1[8] + C2[8],
    )
    return Q, M, C


@kernel(inline="always")
def _beta_ang(Q, C, t0, t1, t2, d0, d1, d2):
    """Angular part of eq. (8): ``Q^T tau_B + C^T eta_dot``."""
    a = _mv9(_t9(Q), t0, t1, t2)
    b = _mv9(_t9(C), d0, d1, d2)
    return a[0] + b[0], a[1] + b[1], a[2] + b[2]


@kernel(inline="always")
def _beta_lin(e0, e1, e2, u, m):
    """Linear part of eq. (8): ``-u R(eta) e3 + m g``."""
    cf, sf = math.cos(e0), math.sin(e0)
    ct, st = math.cos(e1), math.sin(e1)
    cp, sp = math.cos(e2), math.sin(e2)
    return -u * (cp * st * cf + sp * sf), -u * (sp * st * cf - cp * sf), -u * (ct * cf) + m * G
