"""Compiled (numba) per-vehicle kernels of the estimator, eqs. (6)-(13), and controller, eqs. (14)-(20).

These run the same equations as :mod:`vtol_impedance.control.impedance` and
:mod:`vtol_impedance.estimator.momentum` (the NumPy reference backend, which stays the readable
definition and the test oracle); ``tests/test_compiled.py`` proves the two agree. Everything here works
on one vehicle with small fixed-size arrays, so a batch is a ``prange`` loop over vehicles.

Layouts (flat float64 vectors, so that one call passes few arguments):

* controller parameters ``cp`` (:data:`CP_SIZE`), one row per vehicle, see :func:`pack_controller`;
* shared design ``sh``: ``[Ts, filter wn, filter zeta, filter Ad (4), filter Bd (2), n, Ad (6 n n),
  Bd (6 n), C (6 n)]``;
* controller state ``cs`` (:func:`state_size`), measurement ``y = [p_W, v_W, eta, eta_dot]`` (12),
  reference ``r = [p_d, v_d, a_d, psi, psi_dot, psi_ddot]`` (12), output ``o`` (:data:`OUT_SIZE`).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from ..control.impedance import ControllerArrays
from ..conventions import SINGULARITY_COS_EPS, G

# controller parameter row
CP_MASS, CP_I, CP_L, CP_C, CP_FMAX, CP_FMIN = 0, 1, 10, 11, 12, 13
CP_KP, CP_DP, CP_KI, CP_KO, CP_DO = 14, 17, 20, 23, 26
CP_COMP, CP_TILT, CP_LIFT, CP_ILIM = 29, 30, 31, 32
CP_SIZE = 33

# output row
O_THRUST, O_TAU, O_F, O_SAT, O_THRUST_REQ, O_TAU_REQ = 0, 1, 4, 8, 9, 10
O_FHAT, O_TAUHAT_ETA, O_TAUHAT_B, O_ETA_D, O_ETA_D_DOT, O_MU_BAR, O_TILT = 13, 16, 19, 22, 25, 28, 31
OUT_SIZE = 32


def state_size(n: int) -> int:
    """Controller state length for an order-``n`` estimator."""
    return 6 * n + 25


def pack_controller(P: ControllerArrays) -> tuple[np.ndarray, np.ndarray]:
    """``(cp (B, CP_SIZE), sh)`` from compiled NumPy controller arrays with batch shape ``(B,)``."""
    B = P.mass.shape[0]
    cp = np.empty((B, CP_SIZE))
    cp[:, CP_MASS] = P.mass
    cp[:, CP_I : CP_I + 9] = P.I_B.reshape(B, 9)
    cp[:, CP_L] = P.arm_length
    cp[:, CP_C] = P.drag_factor
    cp[:, CP_FMAX] = P.f_max
    cp[:, CP_FMIN] = P.f_min
    cp[:, CP_KP : CP_KP + 3] = P.Kp
    cp[:, CP_DP : CP_DP + 3] = P.Dp
    cp[:, CP_KI : CP_KI + 3] = P.Ki
    cp[:, CP_KO : CP_KO + 3] = P.Ko
    cp[:, CP_DO : CP_DO + 3] = P.Do
    cp[:, CP_COMP] = P.compensate
    cp[:, CP_TILT] = P.tilt_max
    cp[:, CP_LIFT] = P.min_lift_accel
    cp[:, CP_ILIM] = P.integral_limit
    n = P.est.Ad.shape[-1]
    sh = np.concatenate(
        [
            [P.Ts, P.filt.wn, P.filt.zeta],
            P.filt.Ad.ravel(),
            P.filt.Bd.ravel(),
            [float(n)],
            P.est.Ad.ravel(),
            P.est.Bd.ravel(),
            P.est.C.ravel(),
        ]
    )
    return cp, sh


def initial_state(cp: np.ndarray, n: int) -> np.ndarray:
    """Fresh controller states ``(B, state_size(n))``: nothing started, previous thrust = m g."""
    cs = np.zeros((cp.shape[0], state_size(n)))
    cs[:, 6 * n + 21] = cp[:, CP_MASS] * G
    return cs


# ------------------------------------------------------------------ small math


@njit(cache=True, inline="always")
def _mv(A, x, out):  # noqa: ANN001, ANN202
    for i in range(3):
        out[i] = A[i, 0] * x[0] + A[i, 1] * x[1] + A[i, 2] * x[2]


@njit(cache=True, inline="always")
def _mm(A, B, out):  # noqa: ANN001, ANN202
    for i in range(3):
        for j in range(3):
            out[i, j] = A[i, 0] * B[0, j] + A[i, 1] * B[1, j] + A[i, 2] * B[2, j]


@njit(cache=True, inline="always")
def _mtm(A, B, out):  # noqa: ANN001, ANN202
    """``A^T B``."""
    for i in range(3):
        for j in range(3):
            out[i, j] = A[0, i] * B[0, j] + A[1, i] * B[1, j] + A[2, i] * B[2, j]


@njit(cache=True)
def solve3(A, b, out):  # noqa: ANN001, ANN201
    """``A^{-1} b`` for a 3x3 ``A`` by the adjugate (no LAPACK call on the hot path)."""
    c00 = A[1, 1] * A[2, 2] - A[1, 2] * A[2, 1]
    c01 = A[1, 2] * A[2, 0] - A[1, 0] * A[2, 2]
    c02 = A[1, 0] * A[2, 1] - A[1, 1] * A[2, 0]
    det = A[0, 0] * c00 + A[0, 1] * c01 + A[0, 2] * c02
    inv = 1.0 / det
    x0 = c00 * b[0] + (A[0, 2] * A[2, 1] - A[0, 1] * A[2, 2]) * b[1] + (A[0, 1] * A[1, 2] - A[0, 2] * A[1, 1]) * b[2]
    x1 = c01 * b[0] + (A[0, 0] * A[2, 2] - A[0, 2] * A[2, 0]) * b[1] + (A[0, 2] * A[1, 0] - A[0, 0] * A[1, 2]) * b[2]
    x2 = c02 * b[0] + (A[0, 1] * A[2, 0] - A[0, 0] * A[2, 1]) * b[1] + (A[0, 0] * A[1, 1] - A[0, 1] * A[1, 0]) * b[2]
    out[0], out[1], out[2] = x0 * inv, x1 * inv, x2 * inv


@njit(cache=True)
def euler_Q(eta, Q):  # noqa: ANN001, ANN201
    """``Q(eta)`` of eq. (1c) into ``Q``."""
    cf, sf = math.cos(eta[0]), math.sin(eta[0])
    ct, st = math.cos(eta[1]), math.sin(eta[1])
    Q[0, 0], Q[0, 1], Q[0, 2] = 1.0, 0.0, -st
    Q[1, 0], Q[1, 1], Q[1, 2] = 0.0, cf, sf * ct
    Q[2, 0], Q[2, 1], Q[2, 2] = 0.0, -sf, cf * ct


@njit(cache=True)
def euler_Q_dot(eta, eta_dot, Qd):  # noqa: ANN001, ANN201
    cf, sf = math.cos(eta[0]), math.sin(eta[0])
    ct, st = math.cos(eta[1]), math.sin(eta[1])
    df, dt = eta_dot[0], eta_dot[1]
    Qd[0, 0], Qd[0, 1], Qd[0, 2] = 0.0, 0.0, -ct * dt
    Qd[1, 0], Qd[1, 1], Qd[1, 2] = 0.0, -sf * df, cf * ct * df - sf * st * dt
    Qd[2, 0], Qd[2, 1], Qd[2, 2] = 0.0, -cf * df, -sf * ct * df - cf * st * dt


@njit(cache=True)
def rotation_zyx(eta, R):  # noqa: ANN001, ANN201
    cf, sf = math.cos(eta[0]), math.sin(eta[0])
    ct, st = math.cos(eta[1]), math.sin(eta[1])
    cp, sp = math.cos(eta[2]), math.sin(eta[2])
    R[0, 0], R[0, 1], R[0, 2] = cp * ct, cp * st * sf - sp * cf, cp * st * cf + sp * sf
    R[1, 0], R[1, 1], R[1, 2] = sp * ct, sp * st * sf + cp * cf, sp * st * cf - cp * sf
    R[2, 0], R[2, 1], R[2, 2] = -st, ct * sf, ct * cf


@njit(cache=True)
def inertia_M_and_C(eta, eta_dot, I, Q, M, C):  # noqa: ANN001, ANN201, E741
    """``Q(eta)``, ``M = Q^T I Q`` and ``C = Q^T S(I Q eta_dot)^T Q + Q^T I Q_dot`` (the factorisation
    satisfying (7)), written into ``Q``, ``M``, ``C``."""
    Qd = np.empty((3, 3))
    T1 = np.empty((3, 3))
    T2 = np.empty((3, 3))
    euler_Q(eta, Q)
    euler_Q_dot(eta, eta_dot, Qd)
    _mm(I, Q, T1)
    _mtm(Q, T1, M)
    w = np.empty(3)
    _mv(Q, eta_dot, w)
    h = np.empty(3)
    _mv(I, w, h)
    ST = np.empty((3, 3))  # S(h)^T
    ST[0, 0], ST[0, 1], ST[0, 2] = 0.0, h[2], -h[1]
    ST[1, 0], ST[1, 1], ST[1, 2] = -h[2], 0.0, h[0]
    ST[2, 0], ST[2, 1], ST[2, 2] = h[1], -h[0], 0.0
    _mm(ST, Q, T1)
    _mtm(Q, T1, C)
    _mm(I, Qd, T1)
    _mtm(Q, T1, T2)
    for i in range(3):
        for j in range(3):
            C[i, j] += T2[i, j]


@njit(cache=True)
def momentum_rate_known(eta, eta_dot, u, tau_B, m, Q, C, beta):  # noqa: ANN001, ANN201
    """``beta = [-u R e3 + m g; Q^T tau_B + C^T eta_dot]``, eq. (8) without the external wrench,
    for ``Q``, ``C`` already evaluated at ``(eta, eta_dot)``."""
    cf, sf = math.cos(eta[0]), math.sin(eta[0])
    ct, st = math.cos(eta[1]), math.sin(eta[1])
    cp, sp = math.cos(eta[2]), math.sin(eta[2])
    beta[0] = -u * (cp * st * cf + sp * sf)
    beta[1] = -u * (sp * st * cf - cp * sf)
    beta[2] = -u * (ct * cf) + m * G
    for i in range(3):
        beta[3 + i] = (
            Q[0, i] * tau_B[0]
            + Q[1, i] * tau_B[1]
            + Q[2, i] * tau_B[2]
            + C[0, i] * eta_dot[0]
            + C[1, i] * eta_dot[1]
            + C[2, i] * eta_dot[2]
        )


@njit(cache=True)
def mix(f, l, c, tau):  # noqa: ANN001, ANN201, E741
    """Eq. (4); returns ``u`` and writes ``tau``."""
    tau[0] = l * (f[1] - f[3])
    tau[1] = l * (f[2] - f[0])
    tau[2] = c * (f[0] - f[1] + f[2] - f[3])
    return f[0] + f[1] + f[2] + f[3]


@njit(cache=True)
def _yaw_hi(base, yaw, lo_lim, hi_lim):  # noqa: ANN001, ANN202
    """Largest yaw scale in [0, 1] keeping every rotor in [lo_lim, hi_lim], and whether any fits."""
    a_lo, a_hi, ok = 0.0, 1.0, True
    for i in range(4):
        if yaw[i] > 0:
            a_hi = min(a_hi, (hi_lim - base[i]) / yaw[i])
            a_lo = max(a_lo, (lo_lim - base[i]) / yaw[i])
        elif yaw[i] < 0:
            a_hi = min(a_hi, (lo_lim - base[i]) / yaw[i])
            a_lo = max(a_lo, (hi_lim - base[i]) / yaw[i])
        elif base[i] < lo_lim or base[i] > hi_lim:
            ok = False
    return a_hi, ok and a_lo <= a_hi


@njit(cache=True)
def allocate(u, tau, l, c, fmax, fmin, f):  # noqa: ANN001, ANN201, E741
    """Prioritised inverse of eq. (4), as :func:`vtol_impedance.model.mixer.allocate`; returns saturated."""
    tol = 1e-12 * max(abs(fmax), 1.0)
    hi_lim, lo_lim = fmax + tol, fmin - tol
    a = tau[0] / (2.0 * l)
    bb = tau[1] / (2.0 * l)
    rp = np.array([-bb, a, bb, -a])
    spread = rp.max() - rp.min()
    span = fmax - fmin
    rp_scale = span / max(spread, 1e-300) if spread > span else 1.0
    rp *= rp_scale
    ys = tau[2] / (4.0 * c)
    yaw = np.array([ys, -ys, ys, -ys])
    base = u / 4.0 + rp
    hi_keep, ok_keep = _yaw_hi(base, yaw, lo_lim, hi_lim)
    if ok_keep:
        scale = hi_keep
    else:
        coll = min(max(u / 4.0, fmin - rp.min()), fmax - rp.max())
        base = coll + rp
        scale, _ = _yaw_hi(base, yaw, lo_lim, hi_lim)
    scale = min(max(scale, 0.0), 1.0)
    for i in range(4):
        f[i] = min(max(base[i] + scale * yaw[i], fmin), fmax)
    return rp_scale < 1.0 or (not ok_keep) or scale < 1.0 - 1e-9


@njit(cache=True)
def thrust_and_attitude(mu_bar, psi, m, tilt_max, min_lift):  # noqa: ANN001, ANN201
    """Eq. (16) solved in NED with the tilt and lift limits of :func:`vtol_impedance.control.thrust_and_attitude`."""
    vert = G - mu_bar[2]
    vert_c = max(vert, min_lift)
    h_norm = math.sqrt(mu_bar[0] * mu_bar[0] + mu_bar[1] * mu_bar[1])
    h_max = vert_c * math.tan(tilt_max)
    scale = h_max / max(h_norm, 1e-300) if h_norm > h_max else 1.0
    m1 = mu_bar[0] * scale
    m2 = mu_bar[1] * scale
    a = math.sqrt(m1 * m1 + m2 * m2 + vert_c * vert_c)
    cp, sp = math.cos(psi), math.sin(psi)
    phi = math.asin(min(max((m2 * cp - m1 * sp) / a, -1.0), 1.0))
    theta = math.atan2(-(m1 * cp + m2 * sp), vert_c)
    return m * a, phi, theta, (vert < min_lift) or (scale < 1.0)


@njit(cache=True)
def _wrap(a):  # noqa: ANN001, ANN202
    return (a + math.pi) % (2.0 * math.pi) - math.pi


@njit(cache=True)
def controller_step(cp, sh, cs, y, r, o):  # noqa: ANN001, ANN201, C901
    """One control period for one vehicle; updates ``cs`` in place and writes ``o``. Mirrors
    :func:`vtol_impedance.control.impedance.controller_step`."""
    Ts, fwn, fz = sh[0], sh[1], sh[2]
    n = int(sh[9])
    nn = 6 * n * n
    Ad = sh[10 : 10 + nn].reshape((6, n, n))
    Bd = sh[10 + nn : 10 + nn + 6 * n].reshape((6, n))
    Cd = sh[10 + nn + 6 * n : 10 + nn + 12 * n].reshape((6, n))
    m = cp[CP_MASS]
    I = cp[CP_I : CP_I + 9].reshape((3, 3))  # noqa: E741
    comp = cp[CP_COMP]
    # state views
    ex = cs[0 : 6 * n].reshape((6, n))
    o_q = 6 * n
    q_prev = cs[o_q : o_q + 6]
    eta_prev = cs[o_q + 6 : o_q + 9]
    eta_dot_prev = cs[o_q + 9 : o_q + 12]
    i_est_started = o_q + 12
    fx = cs[o_q + 13 : o_q + 15]
    fxd = cs[o_q + 15 : o_q + 17]
    i_filt_started = o_q + 17
    integ = cs[o_q + 18 : o_q + 21]
    i_thrust_prev = o_q + 21
    tau_prev = cs[o_q + 22 : o_q + 25]

    p = y[0:3]
    v = y[3:6]
    eta = y[6:9]
    eta_dot = y[9:12]

    # estimator, eqs. (6)-(13)
    Q = np.empty((3, 3))
    M = np.empty((3, 3))
    C = np.empty((3, 3))
    inertia_M_and_C(eta, eta_dot, I, Q, M, C)
    q = np.empty(6)
    for i in range(3):
        q[i] = m * v[i]
        q[3 + i] = M[i, 0] * eta_dot[0] + M[i, 1] * eta_dot[1] + M[i, 2] * eta_dot[2]
    w_hat = np.zeros(6)
    if cs[i_est_started] > 0.5:
        ba = np.empty(6)
        bb = np.empty(6)
        Qp = np.empty((3, 3))
        Mp = np.empty((3, 3))
        Cp = np.empty((3, 3))
        inertia_M_and_C(eta_prev, eta_dot_prev, I, Qp, Mp, Cp)
        momentum_rate_known(eta_prev, eta_dot_prev, cs[i_thrust_prev], tau_prev, m, Qp, Cp, ba)
        momentum_rate_known(eta, eta_dot, cs[i_thrust_prev], tau_prev, m, Q, C, bb)
        xn = np.empty(n)
        for ch in range(6):
            wbar = (q[ch] - q_prev[ch]) / Ts - 0.5 * (ba[ch] + bb[ch])
            acc = 0.0
            for i in range(n):
                s = Bd[ch, i] * wbar
                for j in range(n):
                    s += Ad[ch, i, j] * ex[ch, j]
                xn[i] = s
            for i in range(n):
                ex[ch, i] = xn[i]
                acc += Cd[ch, i] * xn[i]
            w_hat[ch] = acc
    cs[i_est_started] = 1.0
    q_prev[:] = q
    eta_prev[:] = eta
    eta_dot_prev[:] = eta_dot

    # position impedance (18a), compensation, eq. (16)
    mu_bar = np.empty(3)
    e_p = np.empty(3)
    for i in range(3):
        e_p[i] = p[i] - r[i]
        e_v = v[i] - r[3 + i]
        mu = r[6 + i] - (cp[CP_DP + i] * e_v + cp[CP_KP + i] * e_p[i] + cp[CP_KI + i] * integ[i]) / m
        mu_bar[i] = mu - comp * w_hat[i] / m
    psi_d = r[9]
    thrust_req, phi_d, theta_d, tilt_lim = thrust_and_attitude(mu_bar, psi_d, m, cp[CP_TILT], cp[CP_LIFT])

    # attitude filter on (phi_d, theta_d)
    if cs[i_filt_started] < 0.5:
        fx[0], fx[1] = phi_d, theta_d
        fxd[0], fxd[1] = 0.0, 0.0
        cs[i_filt_started] = 1.0
    uin = (phi_d, theta_d)
    eta_d = np.empty(3)
    eta_d_dot = np.empty(3)
    eta_d_ddot = np.empty(3)
    for i in range(2):
        x0, xd0 = fx[i], fxd[i]
        eta_d[i] = x0
        eta_d_dot[i] = xd0
        eta_d_ddot[i] = fwn * fwn * (uin[i] - x0) - 2.0 * fz * fwn * xd0
        fx[i] = sh[3] * x0 + sh[4] * xd0 + sh[7] * uin[i]
        fxd[i] = sh[5] * x0 + sh[6] * xd0 + sh[8] * uin[i]
    eta_d[2], eta_d_dot[2], eta_d_ddot[2] = psi_d, r[10], r[11]

    # attitude impedance (18b) and torque (14)
    e_eta = np.empty(3)
    e_eta_dot = np.empty(3)
    for i in range(3):
        e_eta[i] = _wrap(eta[i] - eta_d[i])
        e_eta_dot[i] = eta_dot[i] - eta_d_dot[i]
    damp = np.empty(3)
    _mv(C, e_eta_dot, damp)
    for i in range(3):
        damp[i] += cp[CP_DO + i] * e_eta_dot[i] + cp[CP_KO + i] * e_eta[i]
    tau_bar = np.empty(3)
    solve3(M, damp, tau_bar)
    for i in range(3):
        tau_bar[i] = eta_d_ddot[i] - tau_bar[i]
    QT = np.empty((3, 3))
    for i in range(3):
        for j in range(3):
            QT[i, j] = Q[j, i]
    rhs = np.empty(3)
    _mv(C, eta_dot, rhs)
    for i in range(3):
        rhs[i] -= comp * w_hat[3 + i]
    IQ = np.empty((3, 3))
    _mm(I, Q, IQ)
    tau_req = np.empty(3)
    _mv(IQ, tau_bar, tau_req)
    tmp = np.empty(3)
    solve3(QT, rhs, tmp)
    for i in range(3):
        tau_req[i] += tmp[i]
    tau_hat_B = np.empty(3)
    solve3(QT, w_hat[3:6], tau_hat_B)

    f = np.empty(4)
    sat = allocate(thrust_req, tau_req, cp[CP_L], cp[CP_C], cp[CP_FMAX], cp[CP_FMIN], f)
    tau_out = np.empty(3)
    u_out = mix(f, cp[CP_L], cp[CP_C], tau_out)

    # PID anti-windup
    freeze = sat or tilt_lim
    for i in range(3):
        if not freeze:
            integ[i] += Ts * e_p[i]
        bound = cp[CP_ILIM] / max(cp[CP_KI + i], 1e-12)
        integ[i] = min(max(integ[i], -bound), bound)
    cs[i_thrust_prev] = u_out
    tau_prev[:] = tau_out

    o[O_THRUST] = u_out
    o[O_TAU : O_TAU + 3] = tau_out
    o[O_F : O_F + 4] = f
    o[O_SAT] = 1.0 if sat else 0.0
    o[O_THRUST_REQ] = thrust_req
    o[O_TAU_REQ : O_TAU_REQ + 3] = tau_req
    o[O_FHAT : O_FHAT + 3] = w_hat[0:3]
    o[O_TAUHAT_ETA : O_TAUHAT_ETA + 3] = w_hat[3:6]
    o[O_TAUHAT_B : O_TAUHAT_B + 3] = tau_hat_B
    o[O_ETA_D : O_ETA_D + 3] = eta_d
    o[O_ETA_D_DOT : O_ETA_D_DOT + 3] = eta_d_dot
    o[O_MU_BAR : O_MU_BAR + 3] = mu_bar
    o[O_TILT] = 1.0 if tilt_lim else 0.0


@njit(cache=True)
def checked_step(cp, sh, cs, y, r, o):  # noqa: ANN001, ANN201
    """:func:`controller_step` after input checks; returns 0, or 1 for a non-finite input, 2 at the
    Euler singularity (|cos theta| below the threshold of :mod:`vtol_impedance.conventions`)."""
    for i in range(12):
        if not (math.isfinite(y[i]) and math.isfinite(r[i])):
            return 1
    if abs(math.cos(y[7])) < SINGULARITY_COS_EPS:
        return 2
    controller_step(cp, sh, cs, y, r, o)
    return 0
