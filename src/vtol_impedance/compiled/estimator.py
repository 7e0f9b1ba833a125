"""Compiled (numba) momentum-based estimator, eqs. (6)-(13): one update shared by the closed loop
(:func:`vtol_impedance.compiled.controller.controller_step`), the online :class:`vtol_impedance.Estimator`
and a time loop over a flight log.

Mirrors :func:`vtol_impedance.estimator.momentum.estimator_step` (the NumPy definition); the parity tests
in ``tests/test_compiled.py``, ``tests/test_estimator.py`` and ``tests/test_logs.py`` tie the two. Data
layouts (:mod:`.layouts`): the design ``d`` is a :data:`~.layouts.DESIGN` record, the state ``s`` a
:data:`~.layouts.CONTROLLER_STATE` record (the estimator uses its first fields and the held command
``thrust_prev``, ``tau_B_prev``), the timing history ``h`` an array of :data:`~.layouts.HISTORY` rows,
most recent first.
"""

from __future__ import annotations

import math

import numpy as np

from ..errors import InputError
from ..estimator.momentum import EstimatorDesign
from .algebra import _QMC, _beta_ang, _beta_lin, _mv9, _solve9, _t9, turn
from .jit import kernel
from .layouts import CONTROLLER_STATE, DESIGN, HISTORY, MAX_ORDER, fill


def pack_design(des: EstimatorDesign, **filter_fields: object) -> np.ndarray:
    """A ``(1,)`` :data:`~.layouts.DESIGN` array from an estimator design (and, for a controller, the
    attitude filter's ``filt_*`` fields; zero otherwise)."""
    n = des.Ad.shape[-1]
    if n > MAX_ORDER:
        raise InputError(f"the compiled backend holds estimators up to order {MAX_ORDER}, got {n}; use backend='numpy'")
    out = np.zeros(1, dtype=DESIGN)
    for name in ("Ts", "Ad", "Bd", "C", "CA", "CB", "lag", "dv", "da", "d_att", "alpha", "gamma", "H"):
        fill(out, name, getattr(des, name))
    out["order"] = n
    for name, value in filter_fields.items():
        fill(out, name, value)
    return out


def initial_state(d: np.ndarray, batch: int) -> tuple[np.ndarray, np.ndarray]:
    """Fresh states ``(batch,)`` and timing histories ``(batch, H)`` for the design ``d``."""
    return np.zeros(batch, dtype=CONTROLLER_STATE), np.zeros((batch, int(d[0]["H"])), dtype=HISTORY)


@kernel(inline="always")
def history_split(d):
    """Where ``d`` periods back falls in a history kept most recent first: between rows ``i`` and ``i + 1``,
    at the fraction ``g`` (:func:`vtol_impedance.estimator.momentum.history_at`)."""
    i = int(math.floor(d + 1e-9))
    return i, d - i


@kernel(inline="always")
def lerp(a, b, g):
    """``a`` moved the fraction ``g`` towards ``b``."""
    return a + g * (b - a)


@kernel(inline="always")
def lerp_angle(a, b, g, vector):
    """:func:`lerp` of two angles across the +-pi wrap (``vector``: a literal, code in lanes)."""
    return a + g * (turn(b - a + math.pi, vector) - math.pi)


@kernel(inline="always")
def rotor_model(cmd, act, alpha, gamma):
    """The held command ``cmd`` through the rotor model from its output ``act`` at the period's start:
    ``(its mean over the period, its output at the end)``."""
    return cmd + (act - cmd) * gamma, cmd + (act - cmd) * alpha


@kernel(inline="always")
def residual(q, q_prev, Ts, ea, eb, u_w, t, m, Q_prev, C_prev, dp, Q, C, de, vector):  # noqa: N803
    """The estimator's input ``w_bar`` (6) over the period that ends now: the momentum's change (eq. (6))
    less eq. (8)'s known rate at the period's two ends (the trapezoid). ``ea``, ``eb``: the attitude a period
    apart for the thrust's direction, ``u_w`` the thrust, ``t`` the body moments, ``Q_prev``, ``C_prev``,
    ``dp`` at the previous sample and ``Q``, ``C``, ``de`` now."""
    la = _beta_lin(ea[0], ea[1], ea[2], u_w, m, vector)
    lb = _beta_lin(eb[0], eb[1], eb[2], u_w, m, vector)
    aa = _beta_ang(Q_prev, C_prev, t[0], t[1], t[2], dp[0], dp[1], dp[2])
    ab = _beta_ang(Q, C, t[0], t[1], t[2], de[0], de[1], de[2])
    return (
        (q[0] - q_prev[0]) / Ts - 0.5 * (la[0] + lb[0]),
        (q[1] - q_prev[1]) / Ts - 0.5 * (la[1] + lb[1]),
        (q[2] - q_prev[2]) / Ts - 0.5 * (la[2] + lb[2]),
        (q[3] - q_prev[3]) / Ts - 0.5 * (aa[0] + ab[0]),
        (q[4] - q_prev[4]) / Ts - 0.5 * (aa[1] + ab[1]),
        (q[5] - q_prev[5]) / Ts - 0.5 * (aa[2] + ab[2]),
    )  # eq. (8) over the period


@kernel(inline="always")
def _hist_at(h, col, d):
    """Column ``col`` of the command history ``d`` periods back, linearly interpolated, as
    :func:`vtol_impedance.estimator.momentum.history_at`."""
    i, g = history_split(d)
    return lerp(h[i].act[col], h[i + 1].act[col], g)


@kernel(inline="always")
def _angle_at(h, col, d):
    """The same for the attitude history, across the +-pi wrap."""
    i, g = history_split(d)
    return lerp_angle(h[i].eta[col], h[i + 1].eta[col], g, False)


@kernel(inline="always")
def estimator_update(d, s, h, m, I, v0, v1, v2, e0, e1, e2, de0, de1, de2):  # noqa: E741
    """One sample of eqs. (8)-(11) (see :mod:`vtol_impedance.estimator.momentum` for the discretisation).

    ``I`` is the nominal inertia as a row-major 9-tuple, ``v`` the world-frame velocity (NED), ``e`` the
    ZYX Euler angles and ``de`` their rates; the command held over the period that just ended is
    ``s.thrust_prev``, ``s.tau_B_prev``. Returns ``Q, M, C`` at this sample (9-tuples) and the estimate
    ``[f_hat_ext_W; tau_hat_ext_eta]`` (zero at the first sample), also left in ``s.w_hat`` with its rate
    of change in ``s.r_dot``. :mod:`.lanes_estimator` runs the same sample for a block of vehicles in SIMD lanes.
    """
    n = d.order
    Q, M, C = _QMC(e0, e1, de0, de1, de2, I, False)
    qa = _mv9(M, de0, de1, de2)
    q = (m * v0, m * v1, m * v2, qa[0], qa[1], qa[2])  # eq. (6)
    cmd = (s.thrust_prev, s.tau_B_prev[0], s.tau_B_prev[1], s.tau_B_prev[2])
    for ch in range(6):
        s.w_hat[ch] = 0.0
        s.r_dot[ch] = 0.0
    if s.started:
        for j in range(d.H - 1, 0, -1):  # shift the histories by one period
            h[j] = h[j - 1]
        for c in range(4):  # the held command through the rotor model: its mean over the period, and now
            h[0].act[c], s.act[c] = rotor_model(cmd[c], s.act[c], d.alpha, d.gamma)
        h[0].eta[0], h[0].eta[1], h[0].eta[2] = e0, e1, e2
        # moment channel on the attitude's window, force channel on the velocity's
        u_w = _hist_at(h, 0, d.dv)
        t = (_hist_at(h, 1, d.da), _hist_at(h, 2, d.da), _hist_at(h, 3, d.da))
        da = d.d_att
        ea = (_angle_at(h, 0, da + 1.0), _angle_at(h, 1, da + 1.0), _angle_at(h, 2, da + 1.0))
        eb = (_angle_at(h, 0, da), _angle_at(h, 1, da), _angle_at(h, 2, da))
        dp = s.eta_dot_prev
        w_bar = residual(q, s.q_prev, d.Ts, ea, eb, u_w, t, m, s.Q_prev, s.C_prev, dp, Q, C, (de0, de1, de2), False)
        for ch in range(6):  # eq. (11), discretised: the filter G driven by the momentum residual
            x = s.x[ch]
            for i in range(n):
                acc = d.Bd[ch, i] * w_bar[ch]
                for j in range(n):
                    acc += d.Ad[ch, i, j] * x[j]  # eqs. (11), (12): G(s), exact ZOH
                s.x_new[i] = acc
            r = 0.0
            rate = d.CB[ch] * w_bar[ch]
            for i in range(n):
                x[i] = s.x_new[i]
                r += d.C[ch, i] * x[i]
                rate += d.CA[ch, i] * x[i]
            s.w_hat[ch] = r  # eq. (11): the estimate
            s.r_dot[ch] = rate
    else:  # the histories start filled with the present
        for j in range(d.H):
            for c in range(4):
                h[j].act[c] = cmd[c]
            h[j].eta[0], h[j].eta[1], h[j].eta[2] = e0, e1, e2
        for c in range(4):
            s.act[c] = cmd[c]
    s.started = True
    for ch in range(6):
        s.q_prev[ch] = q[ch]
    for i in range(9):  # kept for the next sample's eq. (8), which needs them at this one
        s.Q_prev[i] = Q[i]
        s.C_prev[i] = C[i]
    s.eta_dot_prev[0], s.eta_dot_prev[1], s.eta_dot_prev[2] = de0, de1, de2
    w = s.w_hat
    return Q, M, C, (w[0], w[1], w[2], w[3], w[4], w[5])


@kernel()
def estimator_sample(d, s, h, m, I, v_W, eta, eta_dot, thrust_prev, tau_B_prev, restart, out):  # noqa: E741, N803
    """One sample of the estimator with the command held over the period that just ended, for an online
    loop and for :func:`estimate_log`: ``out = [f_hat_ext_W; tau_hat_ext_eta; tau_hat_ext_B]`` (9).

    ``I`` is the nominal inertia as a row-major 9-tuple; where ``restart`` is true the estimator starts
    afresh (its history filled with this command), as at the first sample."""
    if restart:
        s.started = False
        for ch in range(6):
            for i in range(d.order):
                s.x[ch, i] = 0.0
    s.thrust_prev = thrust_prev
    for i in range(3):
        s.tau_B_prev[i] = tau_B_prev[i]
    Q, M, C, w = estimator_update(
        d, s, h, m, I, v_W[0], v_W[1], v_W[2], eta[0], eta[1], eta[2], eta_dot[0], eta_dot[1], eta_dot[2]
    )
    for c in range(6):
        out[c] = w[c]
    # tau_B = Q^{-T} tau_eta: Q^T x = tau_eta
    out[6], out[7], out[8] = _solve9(_t9(Q), w[3], w[4], w[5])


@kernel()
def sample_one(d, s, h, m, I, v_W, eta, eta_dot, thrust_prev, tau_B_prev, restart, out):  # noqa: E741, N803
    """:func:`estimator_sample` called from Python: ``d``, ``s`` are ``(1,)`` arrays, ``h`` is ``(1, H)``."""
    estimator_sample(d[0], s[0], h[0], m, I, v_W, eta, eta_dot, thrust_prev, tau_B_prev, restart, out)


@kernel()
def estimate_log(d, m, I_B, v_W, eta, eta_dot, thrust, tau_B, restart, out):  # noqa: N803
    """The estimator over a uniformly sampled log: ``out[k] = [f_hat_ext_W; tau_hat_ext_eta; tau_hat_ext_B]``.

    ``d`` is a ``(1,)`` :data:`~.layouts.DESIGN` array; ``thrust[k]``, ``tau_B[k]`` are the commands issued
    at sample ``k`` and held until ``k + 1``. Where ``restart[k]`` is true the estimator starts afresh
    (after a gap), as at ``k = 0``.
    """
    s = np.zeros(1, dtype=CONTROLLER_STATE)
    h = np.zeros(d[0].H, dtype=HISTORY)
    I = (I_B[0, 0], I_B[0, 1], I_B[0, 2], I_B[1, 0], I_B[1, 1], I_B[1, 2], I_B[2, 0], I_B[2, 1], I_B[2, 2])  # noqa: E741
    for k in range(v_W.shape[0]):
        fresh = restart[k] or k == 0  # a segment starts afresh, its history filled with its first command
        j = k if fresh else k - 1
        estimator_sample(d[0], s[0], h, m, I, v_W[k], eta[k], eta_dot[k], thrust[j], tau_B[j], fresh, out[k])


def run_log(
    des: EstimatorDesign,
    mass: float,
    I_B: np.ndarray,  # noqa: N803
    v_W: np.ndarray,  # noqa: N803
    eta: np.ndarray,
    eta_dot: np.ndarray,
    thrust: np.ndarray,
    tau_B: np.ndarray,  # noqa: N803
    restart: np.ndarray,
) -> np.ndarray:
    """:func:`estimate_log` from plain arrays: ``(N, 9)``."""
    c = np.ascontiguousarray
    out = np.empty((len(v_W), 9))
    estimate_log(
        pack_design(des), float(mass), c(I_B, dtype=float), c(v_W, dtype=float), c(eta, dtype=float),
        c(eta_dot, dtype=float), c(thrust, dtype=float), c(tau_B, dtype=float), c(restart, dtype=np.bool_), out,
    )  # fmt: skip
    return out
