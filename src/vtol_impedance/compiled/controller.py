"""Compiled (numba) per-vehicle kernels of the estimator, eqs. (6)-(13), and controller, eqs. (14)-(20).

These run the same equations as :mod:`vtol_impedance.control.impedance` and
:mod:`vtol_impedance.estimator.momentum` (the NumPy reference backend, which stays the readable
definition and the test oracle); ``tests/test_compiled.py`` proves the two agree. Everything here works
on one vehicle with small fixed-size arrays, so a batch is a ``prange`` loop over vehicles.

Layouts (flat float64 vectors, so that one call passes few arguments):

* controller parameters ``cp`` (:data:`CP_SIZE`), one row per vehicle, see :func:`pack_controller`;
* shared design ``sh``: ``[Ts, filter wn, filter zeta, filter Ad (4), filter Bd (2)]`` and the estimator's
  part (:func:`vtol_impedance.compiled.estimator.design_tail`);
* controller state ``cs`` (:func:`state_size`), measurement ``y = [p_W, v_W, eta, eta_dot]`` (12),
  reference ``r = [p_d, v_d, a_d, psi, psi_dot, psi_ddot]`` (12), or with ``comply`` appended: 3 for the
  world axes (15) or 6 for the world axes and the Euler angles (18),
  output ``o`` (:data:`OUT_SIZE`).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from ..control.impedance import ControllerArrays
from ..conventions import SINGULARITY_COS_EPS, G
from ..model.vehicle import MAX_ROTORS
from .algebra import _mm9, _mv9, _solve9, _t9
from .estimator import design_tail, estimator_update, rate_offset, sh_offsets, state_length

# controller parameter row: fixed part, then per rotor i: E_pinv row i (4) at CP_ROT + 4 i, then
# E (4 x n, row-major) at CP_ROT + 4 n, f_min (n) at CP_ROT + 8 n, f_max (n) at CP_ROT + 9 n
CP_MASS, CP_I = 0, 1
CP_KP, CP_DP, CP_KI, CP_KO, CP_DO = 10, 13, 16, 19, 22
CP_COMP, CP_TILT, CP_LIFT, CP_ILIM, CP_SHIFT, CP_NR = 25, 26, 27, 28, 29, 30
CP_MD, CP_DD, CP_KD, CP_CEN = 31, 34, 37, 40  # comply impedance (3 each), comply enabled
CP_MOD, CP_DOD, CP_KOD, CP_ROT = 41, 44, 47, 50  # comply attitude impedance (3 each)

# output row; the n rotor forces come last
O_THRUST, O_TAU, O_SAT, O_THRUST_REQ, O_TAU_REQ = 0, 1, 4, 5, 6
O_FHAT, O_TAUHAT_ETA, O_TAUHAT_B, O_ETA_D, O_ETA_D_DOT, O_MU_BAR = 9, 12, 15, 18, 21, 24
O_TILT, O_RP, O_YAW, O_F = 27, 28, 29, 30
#: Output row length large enough for any vehicle (scratch buffers).
OUT_SIZE = O_F + MAX_ROTORS


def cp_size(n_rotors: int) -> int:
    """Controller parameter row length for ``n_rotors`` rotors."""
    return CP_ROT + 10 * n_rotors


def out_size(n_rotors: int) -> int:
    """Output row length for ``n_rotors`` rotors."""
    return O_F + n_rotors


def state_size(sh: np.ndarray) -> int:
    """Controller state length for the shared design ``sh`` (including ``n + 12`` scratch slots)."""
    return int(state_length(sh))


def pack_controller(P: ControllerArrays) -> tuple[np.ndarray, np.ndarray]:
    """``(cp (B, CP_SIZE), sh)`` from compiled NumPy controller arrays with batch shape ``(B,)``."""
    B = P.mass.shape[0]
    nr = P.E.shape[-1]
    cp = np.empty((B, cp_size(nr)))
    cp[:, CP_MASS] = P.mass
    cp[:, CP_I : CP_I + 9] = P.I_B.reshape(B, 9)
    cp[:, CP_KP : CP_KP + 3] = P.Kp
    cp[:, CP_DP : CP_DP + 3] = P.Dp
    cp[:, CP_KI : CP_KI + 3] = P.Ki
    cp[:, CP_KO : CP_KO + 3] = P.Ko
    cp[:, CP_DO : CP_DO + 3] = P.Do
    cp[:, CP_COMP] = P.compensate
    cp[:, CP_TILT] = P.tilt_max
    cp[:, CP_LIFT] = P.min_lift_accel
    cp[:, CP_ILIM] = P.integral_limit
    cp[:, CP_SHIFT] = P.thrust_shift_max
    cp[:, CP_NR] = nr
    cp[:, CP_MD : CP_MD + 3] = P.Md
    cp[:, CP_DD : CP_DD + 3] = P.Dd
    cp[:, CP_KD : CP_KD + 3] = P.Kd
    cp[:, CP_CEN] = P.comply_enable
    cp[:, CP_MOD : CP_MOD + 3] = P.Mo_d
    cp[:, CP_DOD : CP_DOD + 3] = P.Do_d
    cp[:, CP_KOD : CP_KOD + 3] = P.Ko_d
    r0 = CP_ROT
    cp[:, r0 : r0 + 4 * nr] = P.E_pinv.reshape(B, 4 * nr)
    cp[:, r0 + 4 * nr : r0 + 8 * nr] = P.E.reshape(B, 4 * nr)
    cp[:, r0 + 8 * nr : r0 + 9 * nr] = P.f_min.reshape(B, nr)
    cp[:, r0 + 9 * nr : r0 + 10 * nr] = P.f_max.reshape(B, nr)
    sh = np.concatenate(
        [
            [P.Ts, P.filt.wn, P.filt.zeta],
            P.filt.Ad.ravel(),
            P.filt.Bd.ravel(),
            design_tail(P.est),
        ]
    )
    return cp, sh


def initial_state(cp: np.ndarray, sh: np.ndarray) -> np.ndarray:
    """Fresh controller states ``(B, state_size(sh))``: nothing started, previous thrust = m g."""
    cs = np.zeros((cp.shape[0], state_size(sh)))
    cs[:, thrust_prev_index(int(sh[9]))] = cp[:, CP_MASS] * G
    return cs


@njit(cache=True, inline="always")
def thrust_and_attitude(mu_bar, psi, m, tilt_max, min_lift):
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
def _wrap(a):
    return (a + math.pi) % (2.0 * math.pi) - math.pi


@njit(cache=True)
def _allocate(cp, u, t0, t1, t2, o):
    """Prioritised inverse of eq. (4) for any rotor layout, as :func:`vtol_impedance.model.mixer.allocate`.

    Writes the rotor forces to ``o[O_F:]``; returns ``(saturated, rp_scale, yaw_scale)``. Allocation free:
    per-rotor quantities are recomputed from the parameter row ``cp`` where needed.
    """
    n = int(cp[CP_NR])
    r0 = CP_ROT
    iFmin = r0 + 8 * n
    iFmax = r0 + 9 * n
    # 0. full roll/pitch at the requested thrust, with the largest yaw scale that fits, if any does
    a_lo, a_hi, flat_bad = 0.0, 1.0, False
    for i in range(n):
        tol = 1e-12 * max(abs(cp[iFmax + i]), 1.0)
        lo_i, hi_i = cp[iFmin + i] - tol, cp[iFmax + i] + tol
        base = cp[r0 + 4 * i] * u + cp[r0 + 4 * i + 1] * t0 + cp[r0 + 4 * i + 2] * t1
        y = cp[r0 + 4 * i + 3] * t2
        o[O_F + i] = base
        if y > 0:
            a_hi = min(a_hi, (hi_i - base) / y)
            a_lo = max(a_lo, (lo_i - base) / y)
        elif y < 0:
            a_hi = min(a_hi, (lo_i - base) / y)
            a_lo = max(a_lo, (hi_i - base) / y)
        elif base < lo_i or base > hi_i:
            flat_bad = True
    if not flat_bad and a_lo <= a_hi and a_hi >= 0.0:
        ys = min(max(a_hi, 0.0), 1.0)
        for i in range(n):
            f = o[O_F + i] + ys * cp[r0 + 4 * i + 3] * t2
            o[O_F + i] = min(max(f, cp[iFmin + i]), cp[iFmax + i])
        return ys < 1.0 - 1e-9, 1.0, ys
    # 1. feasible collective with equal shares
    u_lo, u_hi = -math.inf, math.inf
    for i in range(n):
        pu = cp[r0 + 4 * i]
        u_lo = max(u_lo, cp[iFmin + i] / pu)
        u_hi = min(u_hi, cp[iFmax + i] / pu)
    u_c = min(max(u, u_lo), u_hi)
    dmax = cp[CP_SHIFT] * u_c
    # 2. roll/pitch: rotor i needs a_i - k b_i <= delta <= c_i - k b_i, |delta| <= dmax
    k = 1.0
    for i in range(n):
        pu_i = cp[r0 + 4 * i]
        a_i = cp[iFmin + i] / pu_i - u_c
        c_i = cp[iFmax + i] / pu_i - u_c
        b_i = (cp[r0 + 4 * i + 1] * t0 + cp[r0 + 4 * i + 2] * t1) / pu_i
        if b_i < 0:
            k = min(k, (dmax - a_i) / -b_i)
        elif b_i > 0:
            k = min(k, (c_i + dmax) / b_i)
        for j in range(n):
            pu_j = cp[r0 + 4 * j]
            b_j = (cp[r0 + 4 * j + 1] * t0 + cp[r0 + 4 * j + 2] * t1) / pu_j
            if b_j - b_i > 0:
                c_j = cp[iFmax + j] / pu_j - u_c
                k = min(k, (c_j - a_i) / (b_j - b_i))
    k = max(k, 0.0)
    d_lo, d_hi = -dmax, dmax
    for i in range(n):
        pu_i = cp[r0 + 4 * i]
        b_i = (cp[r0 + 4 * i + 1] * t0 + cp[r0 + 4 * i + 2] * t1) / pu_i
        d_lo = max(d_lo, cp[iFmin + i] / pu_i - u_c - k * b_i)
        d_hi = min(d_hi, cp[iFmax + i] / pu_i - u_c - k * b_i)
    delta = min(max(0.0, d_lo), max(d_lo, d_hi))
    # 3. yaw with what is left
    ys = 1.0
    for i in range(n):
        base = cp[r0 + 4 * i] * (u_c + delta) + k * (cp[r0 + 4 * i + 1] * t0 + cp[r0 + 4 * i + 2] * t1)
        o[O_F + i] = base
        y = cp[r0 + 4 * i + 3] * t2
        tol = 1e-12 * max(abs(cp[iFmax + i]), 1.0)
        if y > 0:
            ys = min(ys, (cp[iFmax + i] + tol - base) / y)
        elif y < 0:
            ys = min(ys, (cp[iFmin + i] - tol - base) / y)
    ys = min(max(ys, 0.0), 1.0)
    for i in range(n):
        f = o[O_F + i] + ys * cp[r0 + 4 * i + 3] * t2
        o[O_F + i] = min(max(f, cp[iFmin + i]), cp[iFmax + i])
    shift = u_c + delta - u
    sat = k < 1.0 - 1e-9 or ys < 1.0 - 1e-9 or abs(shift) > 1e-9 * max(abs(u), 1.0)
    return sat, k, ys


@njit(cache=True, inline="always")
def _mix_row(cp, o, row):
    """Row ``row`` of ``E f`` for the rotor forces in ``o[O_F:]``."""
    n = int(cp[CP_NR])
    e0 = CP_ROT + 4 * n + row * n
    acc = 0.0
    for i in range(n):
        acc += cp[e0 + i] * o[O_F + i]
    return acc


@njit(cache=True, inline="always")
def _impedance_axis(cp, cs, r, i, m, comp, e, ev, fh, fl, fdot, lead, ig):
    """``mu_bar`` on world axis ``i``: eq. (18a) with compensation, blended with the comply impedance
    (which feeds forward ``fl``, the estimate with its filter delay taken out, and leads its command by
    ``lead`` seconds), as :func:`vtol_impedance.control.impedance.controller_step`."""
    lam = 0.0
    if cp[CP_CEN] > 0.5 and r.shape[0] >= 15:
        lam = min(max(r[12 + i], 0.0), 1.0)
    md = cp[CP_MD + i]
    kp = (1.0 - lam) * cp[CP_KP + i] + lam * m * cp[CP_KD + i] / md
    dp = (1.0 - lam) * cp[CP_DP + i] + lam * m * cp[CP_DD + i] / md
    ff = (1.0 - lam) * comp * fh + lam * (1.0 - m / md) * fl
    mu = r[6 + i] - (dp * ev + kp * e + (1.0 - lam) * cp[CP_KI + i] * cs[ig + i]) / m - ff / m
    acc = (fl - cp[CP_DD + i] * ev - cp[CP_KD + i] * e) / md
    rate = -cp[CP_DD + i] * acc / md + (1.0 / md - 1.0 / m) * fdot
    return mu + lam * lead * rate


@njit(cache=True, inline="always")
def _attitude_axis(cp, sh, cs, r, i, tb, eta_d_ddot, de, ee, th, ilag, ird, la):
    """``tau_bar`` on Euler angle ``i`` blended with ``M_o e'' + D_o e' + K_o e = tau_ext_eta``, and the
    moment (14) cancels; both use the estimate advanced by G's delay and the attitude latency ``la``, as
    :func:`vtol_impedance.control.impedance.controller_step`."""
    lam = min(max(r[15 + i], 0.0), 1.0)
    lead = th + (sh[ilag + 3 + i] + la) * cs[ird + 3 + i]
    comply = eta_d_ddot - (cp[CP_DOD + i] * de + cp[CP_KOD + i] * ee - lead) / cp[CP_MOD + i]
    return (1.0 - lam) * tb + lam * comply, th + lam * (lead - th)


def thrust_prev_index(n: int) -> int:
    """Where the held thrust sits in the controller state (the held torque follows it)."""
    return 6 * n + 21


@njit(cache=True)
def controller_step(cp, sh, cs, y, r, o):
    """One control period for one vehicle; updates ``cs`` in place and writes ``o``. Mirrors
    :func:`vtol_impedance.control.impedance.controller_step`, with no heap allocation."""
    Ts, fwn, fz = sh[0], sh[1], sh[2]
    n = int(sh[9])
    m = cp[CP_MASS]
    I = (cp[1], cp[2], cp[3], cp[4], cp[5], cp[6], cp[7], cp[8], cp[9])  # noqa: E741
    comp = cp[CP_COMP]
    o_q = 6 * n  # state layout: x (6n), q_prev (6), eta_prev (3), eta_dot_prev (3), started, filter (5),
    # integral (3), thrust_prev, tau_prev (3), scratch: x_new (n), w_hat (6), r_dot (6)

    p0, p1, p2, v0, v1, v2 = y[0], y[1], y[2], y[3], y[4], y[5]
    e0, e1, e2, d0, d1, d2 = y[6], y[7], y[8], y[9], y[10], y[11]

    # estimator, eqs. (6)-(13)
    Q, M, C, w = estimator_update(sh, cs, m, I, v0, v1, v2, e0, e1, e2, d0, d1, d2)
    fh0, fh1, fh2, th0, th1, th2 = w
    # the force estimate with G's low-frequency delay taken out (used by "comply"): f_hat + lag f_hat_dot
    ilag = sh_offsets(n)[5]
    ird = rate_offset(n)
    lv, la = Ts * sh[ilag + 6], Ts * sh[ilag + 7]  # the latencies the force and moment channels see
    fl0 = fh0 + (sh[ilag] + lv) * cs[ird]
    fl1 = fh1 + (sh[ilag + 1] + lv) * cs[ird + 1]
    fl2 = fh2 + (sh[ilag + 2] + lv) * cs[ird + 2]
    lead = 2.0 * fz / fwn  # the attitude filter's delay: how late the force follows the command

    # position impedance (18a), compensation, eq. (16)
    ig = o_q + 18
    # per axis, "comply" blends the rejecting law (lam = 0) with M_d e'' + D_d e' + K_d e = f_ext (lam = 1)
    ep0, ep1, ep2 = p0 - r[0], p1 - r[1], p2 - r[2]
    mb0 = _impedance_axis(cp, cs, r, 0, m, comp, ep0, v0 - r[3], fh0, fl0, cs[ird], lead, ig)
    mb1 = _impedance_axis(cp, cs, r, 1, m, comp, ep1, v1 - r[4], fh1, fl1, cs[ird + 1], lead, ig)
    mb2 = _impedance_axis(cp, cs, r, 2, m, comp, ep2, v2 - r[5], fh2, fl2, cs[ird + 2], lead, ig)
    psi_d = r[9]
    thrust_req, phi_d, theta_d, tilt_lim = thrust_and_attitude((mb0, mb1, mb2), psi_d, m, cp[CP_TILT], cp[CP_LIFT])

    # attitude filter on (phi_d, theta_d)
    fi = o_q + 13
    if cs[o_q + 17] < 0.5:
        cs[fi], cs[fi + 1], cs[fi + 2], cs[fi + 3] = phi_d, theta_d, 0.0, 0.0
        cs[o_q + 17] = 1.0
    x0, x1, xd0, xd1 = cs[fi], cs[fi + 1], cs[fi + 2], cs[fi + 3]
    ed0, ed1, edd0, edd1 = x0, x1, xd0, xd1
    eddd0 = fwn * fwn * (phi_d - x0) - 2.0 * fz * fwn * xd0
    eddd1 = fwn * fwn * (theta_d - x1) - 2.0 * fz * fwn * xd1
    cs[fi] = sh[3] * x0 + sh[4] * xd0 + sh[7] * phi_d
    cs[fi + 2] = sh[5] * x0 + sh[6] * xd0 + sh[8] * phi_d
    cs[fi + 1] = sh[3] * x1 + sh[4] * xd1 + sh[7] * theta_d
    cs[fi + 3] = sh[5] * x1 + sh[6] * xd1 + sh[8] * theta_d

    # attitude impedance (18b) and torque (14)
    ee0, ee1, ee2 = _wrap(e0 - ed0), _wrap(e1 - ed1), _wrap(e2 - psi_d)
    de0, de1, de2 = d0 - edd0, d1 - edd1, d2 - r[10]
    ce = _mv9(C, de0, de1, de2)
    k0 = ce[0] + cp[CP_DO] * de0 + cp[CP_KO] * ee0
    k1 = ce[1] + cp[CP_DO + 1] * de1 + cp[CP_KO + 1] * ee1
    k2 = ce[2] + cp[CP_DO + 2] * de2 + cp[CP_KO + 2] * ee2
    s0, s1, s2 = _solve9(M, k0, k1, k2)
    tb0, tb1, tb2 = eddd0 - s0, eddd1 - s1, r[11] - s2
    tc0, tc1, tc2 = th0, th1, th2  # the moment (14) cancels
    if cp[CP_CEN] > 0.5 and r.shape[0] >= 18:  # per Euler angle, "comply" blends in its own law
        tb0, tc0 = _attitude_axis(cp, sh, cs, r, 0, tb0, eddd0, de0, ee0, th0, ilag, ird, la)
        tb1, tc1 = _attitude_axis(cp, sh, cs, r, 1, tb1, eddd1, de1, ee1, th1, ilag, ird, la)
        tb2, tc2 = _attitude_axis(cp, sh, cs, r, 2, tb2, r[11], de2, ee2, th2, ilag, ird, la)
    QT = _t9(Q)
    cd = _mv9(C, d0, d1, d2)
    g0, g1, g2 = _solve9(QT, cd[0] - comp * tc0, cd[1] - comp * tc1, cd[2] - comp * tc2)
    iq = _mv9(_mm9(I, Q), tb0, tb1, tb2)
    tr0, tr1, tr2 = iq[0] + g0, iq[1] + g1, iq[2] + g2
    hb0, hb1, hb2 = _solve9(QT, th0, th1, th2)

    sat, rp_scale, yaw_scale = _allocate(cp, thrust_req, tr0, tr1, tr2, o)
    u_out = _mix_row(cp, o, 0)
    to0, to1, to2 = _mix_row(cp, o, 1), _mix_row(cp, o, 2), _mix_row(cp, o, 3)

    # PID anti-windup
    freeze = sat or tilt_lim
    for i, e in ((0, ep0), (1, ep1), (2, ep2)):
        if not freeze:
            cs[ig + i] += Ts * e
        bound = cp[CP_ILIM] / max(cp[CP_KI + i], 1e-12)
        cs[ig + i] = min(max(cs[ig + i], -bound), bound)
    cs[o_q + 21] = u_out
    cs[o_q + 22], cs[o_q + 23], cs[o_q + 24] = to0, to1, to2

    o[O_THRUST] = u_out
    o[O_TAU], o[O_TAU + 1], o[O_TAU + 2] = to0, to1, to2
    o[O_SAT] = 1.0 if sat else 0.0
    o[O_THRUST_REQ] = thrust_req
    o[O_TAU_REQ], o[O_TAU_REQ + 1], o[O_TAU_REQ + 2] = tr0, tr1, tr2
    o[O_FHAT], o[O_FHAT + 1], o[O_FHAT + 2] = fh0, fh1, fh2
    o[O_TAUHAT_ETA], o[O_TAUHAT_ETA + 1], o[O_TAUHAT_ETA + 2] = th0, th1, th2
    o[O_TAUHAT_B], o[O_TAUHAT_B + 1], o[O_TAUHAT_B + 2] = hb0, hb1, hb2
    o[O_ETA_D], o[O_ETA_D + 1], o[O_ETA_D + 2] = ed0, ed1, psi_d
    o[O_ETA_D_DOT], o[O_ETA_D_DOT + 1], o[O_ETA_D_DOT + 2] = edd0, edd1, r[10]
    o[O_MU_BAR], o[O_MU_BAR + 1], o[O_MU_BAR + 2] = mb0, mb1, mb2
    o[O_TILT] = 1.0 if tilt_lim else 0.0
    o[O_RP] = rp_scale
    o[O_YAW] = yaw_scale


_ROW = "float64[::1]"
#: Largest magnitude accepted per measurement ``y = [p_W (m), v_W (m/s), eta (rad), eta_dot (rad/s)]`` and
#: reference ``r = [p_d (m), v_d (m/s), a_d (m/s^2), psi (rad), psi_dot (rad/s), psi_ddot (rad/s^2)]``:
#: far beyond any multirotor, well inside float64 (a 1e308 would overflow the arithmetic).
PLAUSIBLE = np.array([1e6] * 3 + [1e4] * 3 + [1e3] * 3 + [1e4] * 3)
PLAUSIBLE_REF = np.array([1e6] * 3 + [1e4] * 3 + [1e5] * 3 + [1e3, 1e4, 1e5])


@njit(f"int64({_ROW}, {_ROW}, {_ROW}, {_ROW}, {_ROW}, {_ROW})", cache=True)
def checked_step(cp, sh, cs, y, r, o):
    """:func:`controller_step` after input checks; returns 0, or 1 for a non-finite input, 2 at the
    Euler singularity (|cos theta| below the threshold of :mod:`vtol_impedance.conventions`), 3 for a
    wrong length, 4 for a comply fraction outside [0, 1], 5 for a value beyond :data:`PLAUSIBLE` (finite
    but no vehicle's: it would poison the controller's state). The explicit signature refuses anything
    but C-contiguous float64 arrays at dispatch (a float32 or strided input would otherwise compile a new,
    silently different specialisation)."""
    if y.shape[0] != 12 or (r.shape[0] != 12 and r.shape[0] != 15 and r.shape[0] != 18):
        return 3
    for i in range(12):
        if not (math.isfinite(y[i]) and math.isfinite(r[i])):
            return 1
    for i in range(12):
        if abs(y[i]) > PLAUSIBLE[i] or abs(r[i]) > PLAUSIBLE_REF[i]:
            return 5
    for i in range(12, r.shape[0]):
        if not (0.0 <= r[i] <= 1.0):
            return 4
    if abs(math.cos(y[7])) < SINGULARITY_COS_EPS:
        return 2
    controller_step(cp, sh, cs, y, r, o)
    return 0
