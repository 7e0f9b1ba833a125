"""The estimator over a whole time series at once (a flight log), causal or zero-phase.

The same discretisation as :func:`~vtol_impedance.estimator.momentum.estimator_step`, written over the
time axis: the per-period residual ``w_bar_k`` of eq. (8) for every ``k`` in one vectorised pass
(:func:`momentum_residual`), then the discrete ``G_i(z)`` of each channel applied to it
(:func:`causal`). The compiled loop :func:`vtol_impedance.compiled.estimator.estimate_log` is the fast
path of the same thing; the tests tie the three together.

Zero-phase (:func:`zero_phase`): the residual filtered forward and backward by the same ``G_i(z)``
(Gustafsson's initial conditions, :func:`scipy.signal.filtfilt`), so the response is ``|G_i|^2`` with no
phase lag. ``w_bar_k`` is the mean wrench over ``(t_{k-1}, t_k]``, i.e. it belongs to ``t_k - Ts/2``; the
zero-phase series is moved back onto the sample times by averaging neighbours, so a ramp comes out
with no lag. It needs the future, so it is for logs only; the causal estimate stays the default because
it is what runs in flight and what the paper shows.
"""

from __future__ import annotations

import numpy as np
import scipy.signal

from ..model.dynamics import generalized_momentum, momentum_rate_angular, momentum_rate_linear
from .momentum import EstimatorDesign


def momentum_residual(
    v_W: np.ndarray,
    eta: np.ndarray,
    eta_dot: np.ndarray,
    thrust: np.ndarray,
    tau_B: np.ndarray,
    mass: float,
    I_B: np.ndarray,
    Ts: float,
    des: EstimatorDesign | None = None,
    restart: np.ndarray | None = None,
) -> np.ndarray:
    """``w_bar (N, 6)``: the mean external wrench ``[f_ext_W; tau_ext_eta]`` over each period.

    ``w_bar_k = (q_k - q_{k-1}) / Ts - (beta(eta_{k-1}, u_{k-1}) + beta(eta_k, u_{k-1})) / 2`` with ``q`` of
    eq. (6) and ``beta`` of eq. (8); ``thrust[k]``, ``tau_B[k]`` are the commands held from ``k`` to ``k + 1``.
    ``w_bar_0 = 0`` (no previous sample). With a design ``des`` whose timing is set (velocity and attitude
    delays, rotor model), the commands pass through the rotor model and each channel is evaluated on its
    own window, exactly as :func:`~vtol_impedance.estimator.momentum.estimator_step` does (before the
    first sample the history holds the first sample). Where ``restart[k]`` is true (after a gap) a new
    segment starts, with nothing carried over from the one before.
    """
    if restart is not None and np.any(restart[1:]):
        w = np.zeros((len(v_W), 6))
        for seg in _segments(np.asarray(restart)):
            w[seg] = momentum_residual(v_W[seg], eta[seg], eta_dot[seg], thrust[seg], tau_B[seg], mass, I_B, Ts, des)
        return w
    m = np.asarray(mass, dtype=float)
    q = generalized_momentum(v_W, eta, eta_dot, m, I_B)
    w = np.zeros(q.shape)
    if len(q) < 2:
        return w
    cmd = np.column_stack([thrust, tau_B])
    dv, da, d_att, alpha, gamma = (0.0,) * 5 if des is None else (des.dv, des.da, des.d_att, des.alpha, des.gamma)
    # the rotor model at each sample, a_{j+1} = alpha a_j + (1 - alpha) c_j from a_0 = c_0, and its mean
    # output over each period
    a = np.empty_like(cmd)
    a[0] = cmd[0]
    a[1:] = scipy.signal.lfilter([1.0 - alpha], [1.0, -alpha], cmd[:-1], axis=0, zi=alpha * cmd[:1])[0]
    a_bar = cmd + (a - cmd) * gamma
    k = np.arange(1, len(q), dtype=float)

    def at(series: np.ndarray, pos: np.ndarray) -> np.ndarray:  # fractional rows, clamped at the start
        pos = np.maximum(pos, 0.0)
        return np.column_stack([np.interp(pos, np.arange(len(series)), series[:, j]) for j in range(series.shape[1])])

    u_w = at(a_bar[:, :1], k - 1.0 - dv)[:, 0]
    tau_w = at(a_bar[:, 1:], k - 1.0 - da)
    unwrapped = np.unwrap(eta, axis=0)
    eta_a = at(unwrapped, k - d_att - 1.0)
    eta_b = at(unwrapped, k - d_att)
    beta_lin = momentum_rate_linear(eta_a, u_w, m) + momentum_rate_linear(eta_b, u_w, m)
    beta_ang = momentum_rate_angular(eta[:-1], eta_dot[:-1], tau_w, I_B) + momentum_rate_angular(
        eta[1:], eta_dot[1:], tau_w, I_B
    )
    w[1:] = np.diff(q, axis=0) / Ts - 0.5 * np.concatenate([beta_lin, beta_ang], -1)
    return w


def transfer_functions(des: EstimatorDesign) -> list[tuple[np.ndarray, np.ndarray]]:
    """``(b, a)`` in powers of ``z^-1`` of each channel's ``x_k = Ad x_{k-1} + Bd w_k``, ``r_k = C x_k``."""
    out = []
    for i in range(6):
        num, den = scipy.signal.ss2tf(des.Ad[i], des.Bd[i][:, None], des.C[i][None, :], np.zeros((1, 1)))
        # r_k = C x_k (not C x_{k-1}): H(z) = z C (zI - Ad)^-1 Bd, one power of z^-1 less
        b = np.append(num[0][1:], 0.0)
        out.append((b, den))
    return out


def _segments(restart: np.ndarray) -> list[slice]:
    starts = np.flatnonzero(restart)
    if len(starts) == 0 or starts[0] != 0:
        starts = np.concatenate([[0], starts])
    ends = np.append(starts[1:], len(restart))
    return [slice(int(a), int(b)) for a, b in zip(starts, ends, strict=True) if b > a]


def causal(des: EstimatorDesign, w_bar: np.ndarray, restart: np.ndarray | None = None) -> np.ndarray:
    """``r (N, 6)``: ``G(z)`` applied to the residual from rest at every segment start (eq. (11))."""
    restart = np.zeros(len(w_bar), bool) if restart is None else restart
    r = np.zeros(w_bar.shape)
    tfs = transfer_functions(des)
    for seg in _segments(restart):
        w = w_bar[seg].copy()
        w[0] = 0.0  # a segment starts without a previous sample
        for i, (b, a) in enumerate(tfs):
            r[seg, i] = scipy.signal.lfilter(b, a, w[:, i])
    return r


def zero_phase(des: EstimatorDesign, w_bar: np.ndarray, restart: np.ndarray | None = None) -> np.ndarray:
    """``r (N, 6)``: ``|G(e^{jw})|^2`` applied to the residual, no lag, on the sample times."""
    restart = np.zeros(len(w_bar), bool) if restart is None else restart
    r = np.full(w_bar.shape, np.nan)
    tfs = transfer_functions(des)
    for seg in _segments(restart):
        w = w_bar[seg][1:]  # w_bar_k belongs to t_k - Ts/2, k >= 1
        if len(w) < 2:
            continue
        z = np.empty(w.shape)
        for i, (b, a) in enumerate(tfs):
            z[:, i] = scipy.signal.filtfilt(b, a, w[:, i], method="gust")
        out = np.empty((len(w) + 1, 6))
        out[0], out[-1] = z[0], z[-1]  # half a period of extrapolation at both ends
        out[1:-1] = 0.5 * (z[:-1] + z[1:])
        r[seg] = out
    return r
