"""Momentum-based estimator of external generalized forces, eqs. (6)-(13) of Ruggiero et al. (2014).

Continuous-time idea (eq. (12)): the estimate ``r = [f_hat_ext_W; tau_hat_ext_eta]`` obeys
``r = G(s) [f_ext_W; tau_ext_eta]`` with ``G_i(s) = wn^2 / (s^2 + 2 zeta wn s + wn^2)`` (eq. (10)).
It needs only ``eta``, ``eta_dot``, ``p_dot`` (never the position), the commanded thrust and body
torque, and the nominal ``m`` and ``I_B``; ``M(eta)`` is never inverted.

Discrete-time realisation (what runs at the control rate ``Ts``)
-----------------------------------------------------------------
Eq. (8) gives ``q_dot = beta + w`` with ``w = [f_ext_W; tau_ext_eta]`` and ``beta`` the known part
(:func:`~vtol_impedance.model.dynamics.momentum_rate_known`). Over one period the *average* wrench is
therefore measured without differentiating anything but the momentum itself:

    w_bar_k = (q_k - q_{k-1}) / Ts - (beta(eta_{k-1}, u_{k-1}) + beta(eta_k, u_{k-1})) / 2

(trapezoidal integral of ``beta`` with the command ``u_{k-1}, tau_{k-1}`` that was held over the period).
``w_bar_k`` then drives a state-space realisation of ``G(s)`` discretised exactly with a zero-order
hold on ``w_bar``. This is the paper's eq. (11) with the two integrals evaluated exactly for a wrench
that is constant over each period: a constant wrench is recovered with zero error, a step
is followed exactly at the sample instants by the step response of ``G(s)``, and the discretisation
is stable for every ``wn * Ts`` (the eigenvalues are ``exp(p_i Ts)``). What ``Ts`` does limit is
resolution: a bandwidth near the Nyquist rate passes the differenced measurement noise straight
through, so ``|p| Ts > 0.5`` warns and ``|p| Ts >= pi`` is refused.

Timing (beyond the paper)
-------------------------
On a real vehicle the inputs are not simultaneous: motion capture reports the velocity ``d_v`` seconds
late (20 ms over WiFi in the paper's setup), the IMU the attitude ``d_a`` late, and the rotors produce
the commanded thrust and torque only after their spin-up lag. Read at face value, the momentum change
of a period is then compared with the attitude and command of another period: a rolling vehicle seems
pushed sideways (about 1 N per rad of roll for the paper's Pelican) and the rotor lag and inertia error
come back as a moment a quarter period late. That is enough to take the last degrees of phase margin
from the paper's loop (see :mod:`vtol_impedance.robust`). With ``EstimatorParams(velocity_delay,
attitude_delay, rotor_tau)`` the estimator aligns what it compares:

* the commands go through a first-order model of the rotors (time constant ``rotor_tau``, exact for
  commands held over each period): ``a_bar_j = c_j + (a_j - c_j) (tau/Ts)(1 - exp(-Ts/tau))`` is the
  mean actuator output over period ``j``;
* the moment channel integrates over ``[t_{k-1} - d_a, t_k - d_a]``, the window its rates belong to,
  with the actuator mean over that window (linear interpolation of ``a_bar`` at ``d_a / Ts`` periods);
* the force channel integrates over the velocity's window ``[t_{k-1} - d_v, t_k - d_v]``, with the
  actuator mean there and the attitude at its two ends, interpolated in the attitude history at
  ``(d_v - d_a) / Ts`` periods (attitude older than the velocity is not extrapolated: that lag is
  clamped at zero).

With the defaults (all zero) this is exactly the scheme above.

Order n (the paper: "with small modifications to (11), any order"): ``G(s)`` is any all-pole filter of
unit DC gain, ``G(s) = prod(-p_i) / prod(s - p_i)``; ``order=1`` is the classic first-order momentum
observer of De Luca et al., ``order=2`` with ``(wn, zeta)`` is eq. (10), and higher orders use a
binomial or Butterworth prototype or user poles.
"""

from __future__ import annotations

import functools
import warnings
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np
import scipy.linalg

from ..errors import InputError, as_finite, batched, instance, positive, scalar
from ..model.dynamics import generalized_momentum, momentum_rate_angular, momentum_rate_linear
from ..model.kinematics import wrap_angle

_PROTOTYPES = ("zeta", "binomial", "butterworth")


#: Longest measurement delay or rotor time constant the estimator aligns to, s (it keeps that much history).
MAX_DELAY_S = 1.0


class EstimatorBandwidthWarning(UserWarning):
    """The estimator bandwidth is not well below the sampling rate."""


def _six(name: str, value: float | np.ndarray) -> np.ndarray:
    arr = positive(name, value)
    if arr.shape not in ((), (1,), (6,)):
        raise InputError(f"{name} must be one number or 6 (one per channel), got shape {arr.shape}")
    return np.broadcast_to(arr, (6,)).astype(float)


@dataclass(frozen=True, eq=False)
class EstimatorParams:
    """Design of the estimator filters ``G_i(s)``, one per wrench component (fx, fy, fz, tx, ty, tz).

    Parameters
    ----------
    wn : float or array_like, shape (6,)
        Natural frequency (order 2 with ``prototype="zeta"``) or bandwidth of the prototype, rad/s;
        a scalar or six values. Paper: 10 rad/s for all six.
    zeta : float or array_like, shape (6,)
        Damping of eq. (10) (used by ``prototype="zeta"``, order 2). Paper: 1.
    order : int
        Filter order n >= 1.
    prototype : {"zeta", "binomial", "butterworth"}
        ``"zeta"`` (order 2, eq. (10)), ``"binomial"`` (n poles at ``-wn``) or ``"butterworth"``.
    poles : array_like, shape (n,) or (6, n), optional
        Explicit poles, all with negative real part; complex poles must come in conjugate pairs.
        Overrides ``wn`` and ``prototype``.
    velocity_delay, attitude_delay : float
        Age (s) of the velocity and of the attitude and its rates when they reach the estimator; the
        force channel is evaluated on the velocity's time window and the moment channel on the
        attitude's (module docstring, "Timing"). 0 (default): taken as simultaneous, as in the paper.
    rotor_tau : float
        Time constant (s) of the first-order rotor model the commands pass through before they enter
        eq. (8); 0 (default): the commands are taken as produced at once, as in the paper.

    References
    ----------
    Ruggiero et al. 2014, eqs. (10)-(13).
    """

    wn: np.ndarray | float = 10.0
    zeta: np.ndarray | float = 1.0
    order: int = 2
    prototype: str = "zeta"
    poles: np.ndarray | None = None
    velocity_delay: float = 0.0
    attitude_delay: float = 0.0
    rotor_tau: float = 0.0

    def __post_init__(self) -> None:
        for name in ("velocity_delay", "attitude_delay", "rotor_tau"):
            object.__setattr__(self, name, scalar(f"estimator {name}", getattr(self, name), lo=0.0, hi=MAX_DELAY_S))
        object.__setattr__(self, "wn", _six("estimator wn", self.wn))
        object.__setattr__(self, "zeta", _six("estimator zeta", self.zeta))
        if isinstance(self.order, bool | np.bool_) or not isinstance(self.order, int | np.integer) or self.order < 1:
            raise InputError(f"estimator order must be an integer >= 1, got {self.order!r}")
        if self.prototype not in _PROTOTYPES:
            raise InputError(f"estimator prototype must be one of {_PROTOTYPES}, got {self.prototype!r}")
        if self.prototype == "zeta" and self.order != 2 and self.poles is None:
            raise InputError(
                "prototype 'zeta' is the second-order filter of eq. (10); use order=2 or "
                "prototype='binomial'/'butterworth' for other orders"
            )
        if self.poles is not None:
            p = np.asarray(self.poles, dtype=complex)
            p = np.broadcast_to(p, (6, p.shape[-1])).copy()
            if p.shape[-1] != self.order:
                raise InputError(f"{p.shape[-1]} poles given for an order-{self.order} estimator")
            if not np.all(np.isfinite(p)) or np.any(p.real >= 0):
                raise InputError(f"estimator poles must be finite with negative real part, got {p[0]}")
            object.__setattr__(self, "poles", p)

    @classmethod
    def from_gains(cls, K1: np.ndarray | float, K2: np.ndarray | float) -> EstimatorParams:
        """From the gains of eq. (11) via eq. (13): ``k1 k2 = wn^2``, ``k1 = 2 zeta wn``."""
        k1 = _six("K1", K1)
        k2 = _six("K2", K2)
        wn = np.sqrt(k1 * k2)  # eq. (13a)
        return cls(wn=wn, zeta=k1 / (2.0 * wn), order=2, prototype="zeta")  # eq. (13b)

    @property
    def K1(self) -> np.ndarray:
        """Diagonal of ``K1`` in eq. (11) (order 2): ``2 zeta wn``."""
        return 2.0 * self.zeta * self.wn  # eq. (13b)

    @property
    def K2(self) -> np.ndarray:
        """Diagonal of ``K2`` in eq. (11) (order 2): ``wn / (2 zeta)``."""
        return self.wn / (2.0 * self.zeta)  # eqs. (13a), (13b)

    def settling_s(self) -> float:
        """Five time constants of the slowest channel's slowest pole, ``5 / min |Re p|``, s: how long the
        estimate takes to reach a step (a lightly damped pole's time constant is ``1 / |Re p|``, not
        ``1 / |p|``)."""
        return 5.0 / float(np.min(np.abs(np.real(self.channel_poles()))))

    def channel_poles(self) -> np.ndarray:
        """Continuous-time poles, shape ``(6, order)``."""
        if self.poles is not None:
            return np.asarray(self.poles)
        n = self.order
        wn = self.wn[:, None]
        if self.prototype == "zeta":
            z = self.zeta[:, None].astype(complex)
            root = np.sqrt(z * z - 1.0)
            return np.concatenate([wn * (-z + root), wn * (-z - root)], -1)  # the poles of eq. (10)
        if self.prototype == "binomial":
            return -wn * np.ones((6, n))
        k = np.arange(1, n + 1)
        unit = np.exp(1j * np.pi * (2 * k + n - 1) / (2 * n))
        return wn * unit[None, :]

    def to_dict(self) -> dict:
        return {
            "wn": self.wn.tolist(),
            "zeta": self.zeta.tolist(),
            "order": int(self.order),
            "prototype": self.prototype,
            "poles": None if self.poles is None else [[str(c) for c in row] for row in self.poles],
            "velocity_delay": self.velocity_delay,
            "attitude_delay": self.attitude_delay,
            "rotor_tau": self.rotor_tau,
        }


class EstimatorDesign(NamedTuple):
    """Discrete matrices of the estimator filters: ``x_k = Ad x_{k-1} + Bd w_bar_k``, ``r_k = C x_k``.

    ``CA``, ``CB`` give the estimate's rate of change ``r_dot_k = CA x_k + CB w_bar_k`` (the continuous
    filter's derivative; ``CB = 0`` from order 2 on), and ``lag`` the filter's delay at low frequency,
    ``-G'(0) = sum_i 1/(-p_i)`` (``2 zeta / wn`` for eq. (10)): ``r + lag r_dot`` is the estimate with that
    delay taken out, to first order.

    ``lead`` (6,) s: how late the estimate is at low frequency: ``lag`` plus the latency of the
    measurement each channel is evaluated on (``dv Ts`` for the force, ``da Ts`` for the moment); the
    comply law advances the estimate by it.

    Timing (module docstring): ``dv``, ``da`` are the velocity and attitude delays in periods, ``d_att``
    the attitude lag of the force channel ``max(dv - da, 0)``; ``alpha = exp(-Ts/rotor_tau)`` and
    ``gamma = (rotor_tau/Ts)(1 - alpha)`` the rotor model (both 0 without one); ``H`` the history length.
    """

    Ad: np.ndarray  # (6, n, n)
    Bd: np.ndarray  # (6, n)
    C: np.ndarray  # (6, n)
    Ts: float
    CA: np.ndarray | None = None  # (6, n)
    CB: np.ndarray | None = None  # (6,)
    lag: np.ndarray | None = None  # (6,) s
    dv: float = 0.0
    da: float = 0.0
    d_att: float = 0.0
    alpha: float = 0.0
    gamma: float = 0.0
    H: int = 3

    @property
    def lead(self) -> np.ndarray:
        return self.lag + self.Ts * np.repeat([self.dv, self.da], 3)


@functools.lru_cache(maxsize=256)
def _channel(poles: tuple[complex, ...], Ts: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, float]:
    """One channel's ``Ad, Bd, C, CA, CB``: the filter with these poles in companion form, discretised
    exactly for a zero-order-hold input. Kept for reuse (expm is most of a design's time; a sweep or a
    batch designs the same filter many times); the arrays are read-only."""
    n = len(poles)
    coeffs = np.real(np.poly(np.array(poles)))  # s^n + a1 s^(n-1) + ... + an
    A = np.zeros((n, n))
    A[:-1, 1:] = np.eye(n - 1)
    A[-1, :] = -coeffs[1:][::-1]
    aug = np.zeros((n + 1, n + 1))
    aug[:n, :n] = A * Ts
    aug[n - 1, n] = Ts
    E = scipy.linalg.expm(aug)  # eq. (12) over one period, input held
    C = np.zeros(n)
    C[0] = coeffs[-1]
    out = E[:n, :n], E[:n, n], C, C @ A
    for arr in out:
        arr.flags.writeable = False
    return (*out, float(C[n - 1]) if n == 1 else 0.0)  # B = e_n: only order 1 feeds w straight into r_dot


def design(params: EstimatorParams, Ts: float) -> EstimatorDesign:
    """Exact zero-order-hold discretisation of ``G_i(s)`` for the sampling period ``Ts`` (s)."""
    instance("params", params, EstimatorParams)
    Ts = scalar("Ts", Ts, lo=0.0, lo_open=True)
    poles = params.channel_poles()
    worst = float(np.max(np.abs(poles)) * Ts)
    if worst >= np.pi:
        raise InputError(
            f"estimator bandwidth too high for the control period: |p| * Ts = {worst:.3f} >= pi "
            f"(Ts = {Ts} s, max |p| = {np.max(np.abs(poles)):.1f} rad/s); lower wn or raise the rate"
        )
    if worst > 0.5:
        warnings.warn(
            f"estimator |p| * Ts = {worst:.3f} > 0.5: the bandwidth is close to the sampling rate, "
            "so measurement noise is barely filtered; consider a lower wn or a faster control rate",
            EstimatorBandwidthWarning,
            stacklevel=2,
        )
    n = params.order
    Ad = np.empty((6, n, n))
    Bd = np.empty((6, n))
    C = np.zeros((6, n))
    CA = np.zeros((6, n))
    CB = np.zeros(6)
    lag = np.real(np.sum(1.0 / -poles, axis=1))
    for i in range(6):
        Ad[i], Bd[i], C[i], CA[i], CB[i] = _channel(tuple(complex(p) for p in poles[i]), Ts)
    dv, da = params.velocity_delay / Ts, params.attitude_delay / Ts
    alpha = float(np.exp(-Ts / params.rotor_tau)) if params.rotor_tau > 0 else 0.0
    gamma = params.rotor_tau / Ts * (1.0 - alpha) if params.rotor_tau > 0 else 0.0
    H = int(np.floor(max(dv, da, max(dv - da, 0.0) + 1.0) + 1e-9)) + 2
    return EstimatorDesign(Ad, Bd, C, Ts, CA, CB, lag, dv, da, max(dv - da, 0.0), alpha, gamma, H)


class EstimatorState(NamedTuple):
    """Filter state ``x (..., 6, n)``, the previous sample's momentum, attitude and rates, the estimate's
    rate of change ``r_dot (..., 6)`` at the last sample, and the timing history: the rotor model's
    output ``act (..., 4)`` (thrust, body torque) now, its mean over each past period ``act_hist
    (..., H, 4)`` and the past attitudes ``eta_hist (..., H, 3)``, most recent first."""

    x: np.ndarray
    q_prev: np.ndarray
    eta_prev: np.ndarray
    eta_dot_prev: np.ndarray
    started: bool
    r_dot: np.ndarray | None = None
    act: np.ndarray | None = None
    act_hist: np.ndarray | None = None
    eta_hist: np.ndarray | None = None


def initial_state(des: EstimatorDesign, batch_shape: tuple[int, ...] = ()) -> EstimatorState:
    """The estimator's state before the first sample: filters at rest, no estimate yet.

    Parameters
    ----------
    des : EstimatorDesign
        The discretised filters, from :func:`design`.
    batch_shape : tuple of int
        Leading batch dimensions, ``()`` for one vehicle.

    Returns
    -------
    EstimatorState
        Zero filter states ``(*batch_shape, 6, n)``; the first :func:`estimator_step` only records the
        momentum and returns a zero wrench.
    """
    instance("des", des, EstimatorDesign)
    if not isinstance(batch_shape, tuple) or not all(isinstance(b, int | np.integer) and b >= 0 for b in batch_shape):
        raise InputError(f"batch_shape must be a tuple of whole numbers >= 0, got {batch_shape!r}")
    n = des.Ad.shape[-1]
    z3 = np.zeros(batch_shape + (3,))
    z6 = np.zeros(batch_shape + (6,))
    return EstimatorState(
        np.zeros(batch_shape + (6, n)),
        z6,
        z3,
        z3,
        False,
        z6,
        np.zeros(batch_shape + (4,)),
        np.zeros(batch_shape + (des.H, 4)),
        np.zeros(batch_shape + (des.H, 3)),
    )


def history_at(hist: np.ndarray, d: float, angles: bool = False) -> np.ndarray:
    """The history ``hist (..., H, k)`` (most recent first) at ``d`` periods back, linearly interpolated.

    For per-period means of a held signal this is also the mean over a window ``d`` periods back.
    ``angles``: interpolate across the +-pi wrap.
    """
    i = int(np.floor(d + 1e-9))
    g = d - i
    a, b = hist[..., i, :], hist[..., i + 1, :]
    return a + g * (wrap_angle(b - a) if angles else b - a)


def estimator_step(
    des: EstimatorDesign,
    state: EstimatorState,
    eta: np.ndarray,
    eta_dot: np.ndarray,
    v_W: np.ndarray,
    thrust_prev: np.ndarray,
    tau_B_prev: np.ndarray,
    mass: np.ndarray,
    I_B: np.ndarray,
) -> tuple[EstimatorState, np.ndarray]:
    """One update at the control rate.

    Eqs. (6)-(13): the momentum ``q = [m v_W; M(eta) eta_dot]`` (6) against the integral of its known
    rate ``beta`` (8), filtered by ``G(s)`` (10)-(13) discretised exactly at the control period (see
    :doc:`/guide/estimator`).

    Parameters
    ----------
    des : EstimatorDesign
        The discretised filters and timing, from :func:`design`.
    state : EstimatorState
        The state returned by the previous call (or :func:`initial_state`).
    eta, eta_dot : ndarray, shape (..., 3)
        Measured ZYX Euler angles (rad) and their rates (rad/s) at this sample.
    v_W : ndarray, shape (..., 3)
        Measured velocity of the body origin, world NED frame, m/s.
    thrust_prev : ndarray, shape (...)
        Collective thrust ``u`` held over the period that just ended, N.
    tau_B_prev : ndarray, shape (..., 3)
        Body torque held over the same period, FRD, N m.
    mass : ndarray, shape (...)
        Nominal mass, kg.
    I_B : ndarray, shape (..., 3, 3)
        Nominal inertia about the centre of mass, body frame, kg m^2.

    Returns
    -------
    state : EstimatorState
        The new state.
    wrench_hat : ndarray, shape (..., 6)
        ``[f_hat_ext_W; tau_hat_ext_eta]``: the external force (world NED, N) and the external
        generalised moment in Euler-angle coordinates (N m); zero at the first call.

    References
    ----------
    Ruggiero et al. 2014, eqs. (6)-(13).
    """
    instance("des", des, EstimatorDesign)
    instance("state", state, EstimatorState)
    eta = batched("eta", eta, (3,))
    q = generalized_momentum(v_W, eta, eta_dot, mass, I_B)  # eq. (6)
    cmd = np.concatenate([batched("thrust_prev", thrust_prev)[..., None], batched("tau_B_prev", tau_B_prev, (3,))], -1)
    if not state.started:  # the history starts filled with the present
        act_hist = np.broadcast_to(cmd[..., None, :], cmd.shape[:-1] + (des.H, 4)).copy()
        eta_hist = np.broadcast_to(eta[..., None, :], eta.shape[:-1] + (des.H, 3)).copy()
        zero = np.zeros(q.shape)
        return EstimatorState(state.x, q, eta, eta_dot, True, zero, cmd, act_hist, eta_hist), zero
    # The command held over the period that just ended, through the rotor model: its mean over the period.
    a_bar = cmd + (state.act - cmd) * des.gamma
    act = cmd + (state.act - cmd) * des.alpha
    act_hist = np.concatenate([a_bar[..., None, :], state.act_hist[..., :-1, :]], -2)
    eta_hist = np.concatenate([eta[..., None, :], state.eta_hist[..., :-1, :]], -2)
    # Moment channel on the attitude's window, force channel on the velocity's (module docstring).
    tau_w = history_at(act_hist, des.da)[..., 1:]
    u_w = history_at(act_hist, des.dv)[..., 0]
    eta_a = history_at(eta_hist, des.d_att + 1.0, angles=True)
    eta_b = history_at(eta_hist, des.d_att, angles=True)
    beta_lin = momentum_rate_linear(eta_a, u_w, mass) + momentum_rate_linear(eta_b, u_w, mass)  # eq. (8), both ends
    # eq. (8), both ends of the period
    beta_ang = momentum_rate_angular(state.eta_prev, state.eta_dot_prev, tau_w, I_B) + momentum_rate_angular(
        eta, eta_dot, tau_w, I_B
    )
    w_bar = (q - state.q_prev) / des.Ts - 0.5 * np.concatenate([beta_lin, beta_ang], -1)  # eq. (8) over the period
    x = np.einsum("cij,...cj->...ci", des.Ad, state.x) + des.Bd * w_bar[..., None]  # eqs. (11), (12): G(s)
    r = np.einsum("ci,...ci->...c", des.C, x)  # eq. (11): r = [f_hat_ext_W; tau_hat_ext_eta]
    r_dot = np.einsum("ci,...ci->...c", des.CA, x) + des.CB * w_bar
    return EstimatorState(x, q, eta, eta_dot, True, r_dot, act, act_hist, eta_hist), r


def check_inputs(eta: np.ndarray, eta_dot: np.ndarray, v_W: np.ndarray) -> None:
    """Raise a clear error on non-finite or mis-shaped measurements."""
    as_finite("eta", eta, (3,))
    as_finite("eta_dot", eta_dot, (3,))
    as_finite("v_W", v_W, (3,))
