"""Compiled (numba) momentum-based estimator, eqs. (6)-(13): one update shared by the closed loop
(:func:`vtol_impedance.compiled.controller.controller_step`) and a time loop over a flight log.

Mirrors :func:`vtol_impedance.estimator.momentum.estimator_step` (the NumPy definition); the parity tests
in ``tests/test_compiled.py`` and ``tests/test_logs.py`` tie the two.

Layouts: the shared design ``sh`` is ``[Ts, filter wn, filter zeta, filter Ad (4), filter Bd (2), n,
Ad (6 n n), Bd (6 n), C (6 n), CA (6 n), CB (6), lag (6), dv, da, d_att, alpha, gamma, H]`` (the
attitude-filter slots are unused here; the last six are the timing of
:class:`vtol_impedance.estimator.momentum.EstimatorDesign`); the state ``cs`` holds ``x (6 n), q_prev (6),
eta_prev (3), eta_dot_prev (3), started`` from index 0, the held thrust and torque at ``6 n + 21 ..
6 n + 24``, scratch ``x_new (n), w_hat (6), r_dot (6)`` from ``6 n + 25``, then the timing history
``act (4), act_hist (H x 4), eta_hist (H x 3)`` from :func:`timing_offset` (most recent first).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from ..estimator.momentum import EstimatorDesign
from .algebra import _QMC, _beta_ang, _beta_lin, _mv9, _solve9, _t9

SH_N = 9  # where the order n sits in ``sh``; the estimator matrices follow it


def pack_design(des: EstimatorDesign) -> np.ndarray:
    """``sh`` for an estimator alone (attitude-filter slots zero)."""
    return np.concatenate([[des.Ts], np.zeros(8), design_tail(des)])


def design_tail(des: EstimatorDesign) -> np.ndarray:
    """``[n, Ad, Bd, C, CA, CB, lag, dv, da, d_att, alpha, gamma, H]``: the estimator's part of ``sh``."""
    n = des.Ad.shape[-1]
    timing = [des.dv, des.da, des.d_att, des.alpha, des.gamma, float(des.H)]
    return np.concatenate(
        [[float(n)], des.Ad.ravel(), des.Bd.ravel(), des.C.ravel(), des.CA.ravel(), des.CB, des.lag, timing]
    )


@njit(cache=True, inline="always")
def timing_offset(n):
    """Where the timing history (``act``, ``act_hist``, ``eta_hist``) starts in the state."""
    return 7 * n + 37


@njit(cache=True)
def state_length(sh):
    """State length of the estimator alone for the design ``sh`` (the controller state has the same prefix)."""
    n = int(sh[SH_N])
    H = int(sh[sh_offsets(n)[5] + 11])
    return timing_offset(n) + 4 + 7 * H


@njit(cache=True, inline="always")
def _hist_at(cs, start, width, col, d):
    """Column ``col`` of a history of rows of ``width`` (most recent first) at ``d`` rows back, linearly
    interpolated, as :func:`vtol_impedance.estimator.momentum.history_at`."""
    i = int(math.floor(d + 1e-9))
    g = d - i
    a = cs[start + i * width + col]
    return a + g * (cs[start + (i + 1) * width + col] - a)


@njit(cache=True, inline="always")
def _angle_at(cs, start, col, d):
    i = int(math.floor(d + 1e-9))
    g = d - i
    a = cs[start + i * 3 + col]
    diff = cs[start + (i + 1) * 3 + col] - a
    return a + g * ((diff + math.pi) % (2.0 * math.pi) - math.pi)


@njit(cache=True, inline="always")
def rate_offset(n):
    """Where the estimate's rate of change (6) sits in the state, after the estimate itself."""
    return 6 * n + 25 + n + 6


@njit(cache=True, inline="always")
def sh_offsets(n):
    """Where ``Ad, Bd, C, CA, CB, lag`` start in ``sh`` for an order-``n`` estimator."""
    iA = SH_N + 1
    iB = iA + 6 * n * n
    iC = iB + 6 * n
    iCA = iC + 6 * n
    iCB = iCA + 6 * n
    return iA, iB, iC, iCA, iCB, iCB + 6


@njit(cache=True, inline="always")
def estimator_update(sh, cs, m, I, v0, v1, v2, e0, e1, e2, d0, d1, d2):  # noqa: E741
    """One sample of eqs. (8)-(11) (see :mod:`vtol_impedance.estimator.momentum` for the discretisation).

    ``I`` is the nominal inertia as a row-major 9-tuple, ``v`` the world-frame velocity (NED),
    ``e`` the ZYX Euler angles and ``d`` their rates. The command held over the period that just ended is
    read from ``cs[6 n + 21 .. 6 n + 24]``. Returns ``Q, M, C`` at this sample (9-tuples) and the estimate
    ``[f_hat_ext_W; tau_hat_ext_eta]`` (zero at the first sample), also left in ``cs[6 n + 25 + n ..]``,
    and its rate of change after it, in ``cs[6 n + 31 + n ..]``.
    """
    Ts = sh[0]
    n = int(sh[SH_N])
    iA, iB, iC, iCA, iCB, iL = sh_offsets(n)
    iT = iL + 6
    o_q = 6 * n
    iw = o_q + 25
    Q, M, C = _QMC(e0, e1, d0, d1, d2, I)
    qa = _mv9(M, d0, d1, d2)
    q = (m * v0, m * v1, m * v2, qa[0], qa[1], qa[2])
    ir = rate_offset(n)
    for ch in range(6):
        cs[iw + n + ch] = 0.0
        cs[ir + ch] = 0.0
    # timing history: the command held over the period that just ended, through the rotor model
    dv, da, d_att, alpha, gamma = sh[iT], sh[iT + 1], sh[iT + 2], sh[iT + 3], sh[iT + 4]
    H = int(sh[iT + 5])
    ia = timing_offset(n)
    ih = ia + 4
    ie = ih + 4 * H
    if cs[o_q + 12] > 0.5:
        for j in range(H - 1, 0, -1):  # shift the histories by one period
            for c in range(4):
                cs[ih + 4 * j + c] = cs[ih + 4 * (j - 1) + c]
            for c in range(3):
                cs[ie + 3 * j + c] = cs[ie + 3 * (j - 1) + c]
        for c in range(4):
            cmd = cs[o_q + 21 + c]
            cs[ih + c] = cmd + (cs[ia + c] - cmd) * gamma  # mean over the period
            cs[ia + c] = cmd + (cs[ia + c] - cmd) * alpha  # rotor model now
        cs[ie], cs[ie + 1], cs[ie + 2] = e0, e1, e2
        # moment channel on the attitude's window, force channel on the velocity's
        u_prev = _hist_at(cs, ih, 4, 0, dv)
        tp0, tp1, tp2 = _hist_at(cs, ih, 4, 1, da), _hist_at(cs, ih, 4, 2, da), _hist_at(cs, ih, 4, 3, da)
        ea = (_angle_at(cs, ie, 0, d_att + 1.0), _angle_at(cs, ie, 1, d_att + 1.0), _angle_at(cs, ie, 2, d_att + 1.0))
        eb = (_angle_at(cs, ie, 0, d_att), _angle_at(cs, ie, 1, d_att), _angle_at(cs, ie, 2, d_att))
        pe0, pe1 = cs[o_q + 6], cs[o_q + 7]
        pd0, pd1, pd2 = cs[o_q + 9], cs[o_q + 10], cs[o_q + 11]
        Qp, Mp, Cp = _QMC(pe0, pe1, pd0, pd1, pd2, I)
        la = _beta_lin(ea[0], ea[1], ea[2], u_prev, m)
        lb = _beta_lin(eb[0], eb[1], eb[2], u_prev, m)
        aa = _beta_ang(Qp, Cp, tp0, tp1, tp2, pd0, pd1, pd2)
        ab = _beta_ang(Q, C, tp0, tp1, tp2, d0, d1, d2)
        beta = (la[0] + lb[0], la[1] + lb[1], la[2] + lb[2], aa[0] + ab[0], aa[1] + ab[1], aa[2] + ab[2])
        for ch in range(6):
            wbar = (q[ch] - cs[o_q + ch]) / Ts - 0.5 * beta[ch]
            base = ch * n
            for i in range(n):
                s = sh[iB + base + i] * wbar
                row = iA + (ch * n + i) * n
                for j in range(n):
                    s += sh[row + j] * cs[base + j]
                cs[iw + i] = s
            acc = 0.0
            rate = sh[iCB + ch] * wbar
            for i in range(n):
                cs[base + i] = cs[iw + i]
                acc += sh[iC + base + i] * cs[iw + i]
                rate += sh[iCA + base + i] * cs[iw + i]
            cs[iw + n + ch] = acc
            cs[ir + ch] = rate
    else:  # the histories start filled with the present
        for j in range(H):
            for c in range(4):
                cs[ih + 4 * j + c] = cs[o_q + 21 + c]
            cs[ie + 3 * j], cs[ie + 3 * j + 1], cs[ie + 3 * j + 2] = e0, e1, e2
        for c in range(4):
            cs[ia + c] = cs[o_q + 21 + c]
    cs[o_q + 12] = 1.0
    for ch in range(6):
        cs[o_q + ch] = q[ch]
    cs[o_q + 6], cs[o_q + 7], cs[o_q + 8] = e0, e1, e2
    cs[o_q + 9], cs[o_q + 10], cs[o_q + 11] = d0, d1, d2
    wh = iw + n
    return Q, M, C, (cs[wh], cs[wh + 1], cs[wh + 2], cs[wh + 3], cs[wh + 4], cs[wh + 5])


@njit(cache=True)
def estimator_sample(sh, cs, m, I, v_W, eta, eta_dot, thrust_prev, tau_B_prev, restart, out):  # noqa: E741, N803
    """One sample of the estimator with the command held over the period that just ended, for an online
    loop and for :func:`estimate_log`: ``out = [f_hat_ext_W; tau_hat_ext_eta; tau_hat_ext_B]`` (9).

    ``I`` is the nominal inertia as a row-major 9-tuple; where ``restart`` is true the estimator starts
    afresh (its history filled with this command), as at the first sample."""
    n = int(sh[SH_N])
    o_q = 6 * n
    if restart:
        for i in range(cs.shape[0]):
            cs[i] = 0.0
    cs[o_q + 21] = thrust_prev
    cs[o_q + 22], cs[o_q + 23], cs[o_q + 24] = tau_B_prev[0], tau_B_prev[1], tau_B_prev[2]
    Q, M, C, w = estimator_update(
        sh, cs, m, I, v_W[0], v_W[1], v_W[2], eta[0], eta[1], eta[2], eta_dot[0], eta_dot[1], eta_dot[2]
    )
    for c in range(6):
        out[c] = w[c]
    # tau_B = Q^{-T} tau_eta: Q^T x = tau_eta
    out[6], out[7], out[8] = _solve9(_t9(Q), w[3], w[4], w[5])


@njit(cache=True)
def estimate_log(sh, m, I_B, v_W, eta, eta_dot, thrust, tau_B, restart, out):  # noqa: N803
    """The estimator over a uniformly sampled log: ``out[k] = [f_hat_ext_W; tau_hat_ext_eta; tau_hat_ext_B]``.

    ``thrust[k]``, ``tau_B[k]`` are the commands issued at sample ``k`` and held until ``k + 1``. Where
    ``restart[k]`` is true the estimator starts afresh (after a gap), as at ``k = 0``.
    """
    cs = np.zeros(state_length(sh))
    I = (I_B[0, 0], I_B[0, 1], I_B[0, 2], I_B[1, 0], I_B[1, 1], I_B[1, 2], I_B[2, 0], I_B[2, 1], I_B[2, 2])  # noqa: E741
    for k in range(v_W.shape[0]):
        fresh = restart[k] or k == 0  # a segment starts afresh, its history filled with its first command
        j = k if fresh else k - 1
        estimator_sample(sh, cs, m, I, v_W[k], eta[k], eta_dot[k], thrust[j], tau_B[j], fresh, out[k])
