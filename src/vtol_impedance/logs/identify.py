"""Rotor drag, inflow damping and the rotor time constant identified from a flight log, with 95 % intervals.

What the momentum estimator (eqs. (6)-(13)) reports on a log is everything the nominal model misses
(:mod:`vtol_impedance.logs.estimate`). With the thrust taken from the **commands** that is, in world NED,

    f_W = R_WB f_aero_B(v_B) + (u - T) z_B_W + k u z_B_W + b_W + e,    f_aero_B = -D v_B

(the aerodynamic force of :mod:`~vtol_impedance.model.aero`)

with ``D = diag(d_x, d_y, d_z)`` on the body FRD axes (``rotor_drag`` x, y and ``inflow_damping`` of the
vehicle TOML), ``v_B = R_WB^T v_W`` the body velocity, ``u`` the commanded collective thrust (N), ``T``
the thrust the rotors give (``u`` through a first-order lag of time constant ``tau``), ``z_B_W`` the body
z axis in the world (thrust acts along ``-z_B``), ``k`` the share of the commanded thrust the rotors do
not give (a thrust-map error; a mass error looks the same: ``thrust_loss``), ``b_W`` a constant horizontal
force (a steady wind) and ``e`` the rest (sensor noise, gusts, a fan). The fit:

* the estimator is rerun with its own rotor model at ``tau`` (``EstimatorParams.rotor_tau``): its momentum
  residual (:func:`~vtol_impedance.estimator.series.momentum_residual`) then has no lag term, and the
  estimator's discrete filter ``G(z)`` of eqs. (10)-(11) is applied to it (this is the estimate
  ``f_W``) and to each regressor (``R_WB (-v_B,k e_k)``, ``u z_B_W``, a constant), so the filter's lag
  biases nothing. Filtering was measured against fitting the unfiltered residual on the test flight with
  sensor noise: same bias (under 1 %), intervals 5-15 times narrower;
* ``D``, ``k`` and ``b_W`` by linear least squares over the three world components of the airborne samples
  (thrust at least :data:`MIN_THRUST_SHARE` of the weight, a second away from the ground, after the
  estimator settles); ``tau`` by a bounded 1-D search on that fit's residual sum of squares (separable
  least squares, :func:`scipy.optimize.minimize_scalar`).

Confidence intervals: ``cov = s^2 (J^T J)^-1 n / n_eff`` with ``J`` the Jacobian of the residual in
``(d_x, d_y, d_z, b_x, b_y, k, tau)`` (``tau`` by central differences), ``s^2 = RSS / (n - p)`` and ``n_eff``
the effective sample count: the residual is not white (the estimator filters it, gusts are slow), so
``n`` is divided by the integrated autocorrelation time ``1 + 2 sum rho_k`` of the residual (summed while
``rho_k > 0``, the largest over the three components; about 20 samples at the default ``wn`` of
10 rad/s). The interval is ``+- t_{0.975, n_eff - p} sd``. Measured coverage on five simulated flights
with sensor noise (four coefficients each): 18 of 20 intervals hold the truth (a Newey-West covariance
was narrower, 15 of 20), so read them as about 90 % intervals. Assumptions: ``e`` stationary and
independent of the regressors (a disturbance that follows the speed, e.g. a fan the vehicle flies away
from, or a payload off the centre of mass, biases ``D``); the lag the same spinning up and down (one
``tau`` between the two); the drag linear (body quadratic drag is not fitted); the log's velocity and
attitude latencies given (``velocity_delay``, ``attitude_delay`` of the estimator): a latency left out is
read as rotor lag (a 20 ms velocity latency moved a planted 40 ms ``tau`` to 60 ms).

A coefficient the log does not excite is reported as not identifiable instead of a number: a drag axis
whose body speed RMS is under :data:`MIN_SPEED_RMS`, an interval wider than :data:`MAX_REL_CI` of the
value (and wider than :data:`ABS_CI_PER_WEIGHT` m g per m/s), a ``tau`` at the bound of the search.
"""

from __future__ import annotations

import os
from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np

from ..conventions import G
from ..errors import InputError, instance, scalar
from ..estimator.momentum import EstimatorParams, design
from ..estimator.series import causal, momentum_residual
from ..model.aero import aero_force_B
from ..model.kinematics import rotation_zyx
from .estimate import LogEstimate

#: Body speed RMS (m/s) under which a drag axis is not identifiable. Measured: a simulated hover holds
#: 0.003 m/s horizontally (0.17 m/s vertically, from take-off and landing); the sample logs, a 1.2 m move in
#: 3 s, reach 0.09-0.15 m/s, where the fit's intervals span +-2 N per m/s; the 1 m/s test circle 0.55 m/s
#: (intervals +-1-3 %). At 0.2 m/s a drag of 0.2 N per m/s is 0.04 N, five times that flight's residual RMS.
MIN_SPEED_RMS = 0.2
#: A 95 % interval wider than this share of the value (either side) is not an identification...
MAX_REL_CI = 0.5
#: ... unless it is narrower than this share of the weight per m/s (a drag known to be near zero is known):
#: 0.5 % of the weight per m/s is a third of the stand-in drag the scenarios fly (0.18 N per m/s on the
#: 1.2 kg Pelican, 1.5 % of its weight per m/s).
ABS_CI_PER_WEIGHT = 0.005
#: Search range of the rotor time constant, s: small multirotor rotors spin up in 10-100 ms.
TAU_BOUNDS = (0.0, 0.25)
#: Samples whose thrust is under this share of the weight are left out (on the ground, or landing).
MIN_THRUST_SHARE = 0.8
#: The sum of the integrated autocorrelation time stops at the first autocorrelation at or below this (the
#: initial positive sequence; 0.05 instead gave 3 intervals of 20 missing the truth, 0 gave 2: module docstring).
RHO_CUTOFF = 0.0


@dataclass(frozen=True)
class Coefficient:
    """One identified coefficient: ``value`` and its 95 % interval ``ci95``, both ``None`` when the log does
    not identify it (``reason`` says why). ``key`` is the vehicle TOML key (``rotor_drag[0]``: its x entry)."""

    key: str
    unit: str
    value: float | None
    ci95: tuple[float, float] | None
    identifiable: bool
    reason: str = ""
    excitation: float = 0.0

    def text(self) -> str:
        if not self.identifiable or self.value is None or self.ci95 is None:
            return f"{self.key}: not identifiable from this log ({self.reason})"
        return f"{self.key}: {self.value:.4g} {self.unit} (95 % CI {self.ci95[0]:.4g} .. {self.ci95[1]:.4g})"


@dataclass
class Identification:
    """The fit of :func:`identify` (module docstring): the four coefficients; the nuisance terms
    ``bias_W_N`` (constant horizontal force, world NED x and y, N) and ``thrust_loss`` (share of the
    commanded thrust missing); the residual's RMS (N, per world component) and ``r2`` (share of the
    estimate's variance the fit explains); the samples used and ``n_eff`` (effective independent samples,
    per component)."""

    rotor_drag_x: Coefficient
    rotor_drag_y: Coefficient
    inflow_damping: Coefficient
    rotor_tau: Coefficient
    bias_W_N: tuple[float, float]
    thrust_loss: float
    rms_residual_N: float
    r2: float
    samples: int
    n_eff: float
    span_s: tuple[float, float]
    mass_kg: float
    notes: list[str] = field(default_factory=list)

    @property
    def coefficients(self) -> tuple[Coefficient, ...]:
        return (self.rotor_drag_x, self.rotor_drag_y, self.inflow_damping, self.rotor_tau)

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)

    def toml_snippet(self) -> str:
        """Vehicle TOML keys to paste (only what the log identifies); ``rotor_tau`` is a plant/estimator
        setting, not a vehicle key, and goes in as a comment."""
        dx, dy, dz, tau = self.coefficients
        lines = [
            f"# identified from a flight log ({self.samples} samples, {self.span_s[0]:.2f}-{self.span_s[1]:.2f} s)"
        ]
        if dx.identifiable and dy.identifiable:
            lines.append(
                f"rotor_drag = [{max(dx.value or 0.0, 0.0):.4g}, {max(dy.value or 0.0, 0.0):.4g}]  # N per m/s"
            )
        else:
            lines.append("# rotor_drag: not identifiable from this log")
        if dz.identifiable:
            lines.append(f"inflow_damping = {max(dz.value or 0.0, 0.0):.4g}  # N per m/s")
        else:
            lines.append("# inflow_damping: not identifiable from this log")
        if tau.identifiable:
            lines.append(
                f"# rotor time constant {tau.value:.4g} s: estimate --rotor-tau, scenario plant.rotor_tau_up/down"
            )
        return "\n".join(lines) + "\n"


def _acf_time(r: np.ndarray) -> float:
    """Integrated autocorrelation time ``1 + 2 sum rho_k`` of ``r`` (summed while ``rho_k >= RHO_CUTOFF``)."""
    r = r - r.mean()
    n = len(r)
    var = float(r @ r)
    if n < 4 or var <= 0:
        return 1.0
    spec = np.fft.rfft(r, 2 * n)
    acf = np.fft.irfft(spec * np.conj(spec))[:n] / var
    below = np.flatnonzero(acf[1:] < RHO_CUTOFF)
    k = int(below[0]) if len(below) else n - 1
    return max(1.0, 1.0 + 2.0 * float(np.sum(acf[1 : k + 1])))


def _bounds(tau_bounds: Any) -> tuple[float, float]:
    try:
        a, b = tau_bounds
    except (TypeError, ValueError):
        raise InputError(f"tau_bounds must be two times in seconds (low, high), got {tau_bounds!r}") from None
    lo, hi = scalar("tau_bounds[0] (s)", a, lo=0.0), scalar("tau_bounds[1] (s)", b, lo=0.0, hi=10.0)
    if not hi > lo:
        raise InputError(f"tau_bounds must be (low, high) with high > low, got {tau_bounds!r}")
    return lo, hi


def identify(est: LogEstimate, *, tau_bounds: tuple[float, float] = TAU_BOUNDS) -> Identification:
    """Fit rotor drag, inflow damping and the rotor time constant to an estimate on a log (module docstring).

    ``est`` must have its thrust from the commands (``thrust_from="commands"``): measured rotor speeds carry
    no command lag, so ``tau`` is then reported not identifiable."""
    instance("est", est, LogEstimate)
    lo, hi = _bounds(tau_bounds)
    fl = est.flight
    m = float(est.info["mass_kg"])
    thrust = np.asarray(est.thrust_N, dtype=float)
    n = len(fl.t)
    pdict = dict(est.info.get("estimator") or EstimatorParams().to_dict())
    params0 = EstimatorParams(**pdict)
    from_rotors = est.info.get("thrust_coefficient") is not None
    notes: list[str] = []

    R = rotation_zyx(fl.eta)  # R_WB
    v_B = np.einsum("nji,nj->ni", R, fl.v_W)
    # samples used: airborne, the estimator settled after each start (5 time constants of its slowest pole)
    settle = params0.settling_s()
    since = np.zeros(n)
    starts = np.flatnonzero(fl.restart)
    for i, s in enumerate(starts):
        e = starts[i + 1] if i + 1 < len(starts) else n
        since[s:e] = fl.t[s:e] - fl.t[s]
    air = thrust >= MIN_THRUST_SHARE * m * G
    # a second on each side of a ground contact: the ground reaction is not in the model
    k_air = int(round(fl.rate_hz))
    air_ok = air.copy()
    for j in np.flatnonzero(~air):
        air_ok[max(0, j - k_air) : j + k_air + 1] = False
    use = air_ok & (since >= settle)
    if fl.bridged is not None:
        use &= ~fl.bridged
    n_use = int(use.sum())
    if n_use < 200:
        raise InputError(
            f"the log has {n_use} airborne samples after the estimator settles (thrust >= {MIN_THRUST_SHARE:g} m g, "
            f"{settle:.2f} s after each start); identification needs at least 200 (2 s at 100 Hz)"
        )

    # regressors: the estimator's filter applied to the per-period mean of each term (w_bar_k is the mean
    # over (t_{k-1}, t_k], momentum_residual)
    def filtered(x_W: np.ndarray) -> np.ndarray:
        mean = 0.5 * (x_W + np.concatenate([x_W[:1], x_W[:-1]]))
        return causal(des0, np.column_stack([mean, np.zeros_like(mean)]), fl.restart)[:, :3]

    des0 = design(params0, fl.Ts)
    cols = []
    for k in range(3):
        e_k = np.zeros(3)
        e_k[k] = 1.0
        cols.append(filtered(np.einsum("nij,nj->ni", R, aero_force_B(v_B, e_k, np.zeros(3)))))
    # a constant horizontal force (a steady wind; a vertical constant is the thrust column's near hover: the
    # two together were collinear on the sample logs, 64 % thrust loss against -7 N)
    for k in range(2):
        c = np.zeros((n, 3))
        c[:, k] = 1.0
        cols.append(filtered(c))
    # a thrust map or mass error: a force along the thrust axis in proportion to the thrust
    cols.append(filtered(thrust[:, None] * R[:, :, 2]))
    X = np.stack([c[use].reshape(-1) for c in cols], axis=1)  # (3 n_use, 6)
    zeros_tau = np.zeros((n, 3))
    I_any = np.eye(3) * 1e-2  # the force channel does not use the inertia

    def y_of(tau: float) -> np.ndarray:
        pd = dict(pdict)
        pd.update(rotor_tau=float(tau), poles=params0.poles)
        des = design(EstimatorParams(**pd), fl.Ts)
        w = momentum_residual(fl.v_W, fl.eta, fl.eta_dot, thrust, zeros_tau, m, I_any, fl.Ts, des, fl.restart)
        return causal(des, w, fl.restart)[:, :3][use].reshape(-1)

    def solve(tau: float) -> tuple[np.ndarray, np.ndarray]:
        y = y_of(tau)
        beta = np.linalg.lstsq(X, y, rcond=None)[0]
        return beta, y - X @ beta

    from scipy.optimize import minimize_scalar
    from scipy.stats import t as student_t

    if from_rotors:
        tau_hat = 0.0
        notes.append("thrust from measured rotor speeds: no command lag to fit (rotor_tau not identifiable)")
    else:
        res = minimize_scalar(lambda s: float(np.sum(solve(s)[1] ** 2)), bounds=(lo, hi), method="bounded",
                              options={"xatol": 1e-5})  # fmt: skip
        tau_hat = float(res.x)
    beta, r = solve(tau_hat)
    y = X @ beta + r
    J = -X
    p = X.shape[1]
    if not from_rotors:
        h = 1e-3
        a, b = max(lo, tau_hat - h), min(hi, tau_hat + h)
        dr = (y_of(b) - y_of(a)) / (b - a)  # r = y(tau) - X beta: only y depends on tau
        J = np.column_stack([J, dr])
        p += 1
    N3 = len(r)
    tau_int = max(_acf_time(r.reshape(-1, 3)[:, i]) for i in range(3))
    n_eff = N3 / tau_int
    s2 = float(r @ r) / max(N3 - p, 1)
    cov = s2 * np.linalg.pinv(J.T @ J) * (N3 / n_eff)
    sd = np.sqrt(np.maximum(np.diag(cov), 0.0))
    tq = float(student_t.ppf(0.975, max(n_eff - p, 1.0)))
    weight = m * G
    names = (("rotor_drag[0]", "x"), ("rotor_drag[1]", "y"), ("inflow_damping", "z"))
    out = []
    for k, (key, ax) in enumerate(names):
        rms = float(np.sqrt(np.mean(v_B[use, k] ** 2)))
        val, half = float(beta[k]), tq * float(sd[k])
        reason = ""
        if rms < MIN_SPEED_RMS:
            reason = (
                f"the body {ax} speed RMS is {rms:.3g} m/s, under {MIN_SPEED_RMS:g} m/s: the log does not excite it"
            )
        elif half > MAX_REL_CI * abs(val) and half > ABS_CI_PER_WEIGHT * weight:
            reason = f"the 95 % interval +-{half:.3g} N per m/s is wider than {100 * MAX_REL_CI:.0f} % of {val:.3g}"
        ok = not reason
        out.append(Coefficient(key, "N per m/s", val if ok else None, (val - half, val + half) if ok else None, ok,
                               reason, rms))  # fmt: skip
    if from_rotors:
        tau_c = Coefficient("rotor_tau", "s", None, None, False, "thrust from measured rotor speeds (no lag in it)")
    else:
        half = tq * float(sd[-1])
        reason = ""
        if tau_hat > hi - 0.01 * (hi - lo) or (lo > 0 and tau_hat < lo + 0.01 * (hi - lo)):
            reason = f"the fit ends at the bound of the search {lo:g}-{hi:g} s"
        elif half > MAX_REL_CI * tau_hat:
            reason = f"the 95 % interval +-{half:.3g} s is wider than {100 * MAX_REL_CI:.0f} % of {tau_hat:.3g} s"
        ok = not reason
        du = float(np.std(np.diff(thrust[use]) * fl.rate_hz))
        tau_c = Coefficient("rotor_tau", "s", tau_hat if ok else None,
                            (tau_hat - half, tau_hat + half) if ok else None, ok, reason, du)  # fmt: skip
    y3 = y.reshape(-1, 3)
    y_c = (y3 - y3.mean(0)).reshape(-1)
    r2 = 1.0 - float(r @ r) / max(float(y_c @ y_c), 1e-300)
    return Identification(
        out[0], out[1], out[2], tau_c, (float(beta[3]), float(beta[4])), float(beta[5]),  # type: ignore[arg-type]
        float(np.sqrt(np.mean(r**2))), r2, n_use, float(n_eff / 3.0), (float(fl.t[0]), float(fl.t[-1])), m, notes,
    )  # fmt: skip


def identify_file(
    path: str | os.PathLike[str],
    *,
    vehicle: Any = None,
    mass: float | None = None,
    tau_bounds: tuple[float, float] = TAU_BOUNDS,
    **estimate_options: Any,
) -> Identification:
    """Read, check and estimate a log (:func:`~vtol_impedance.logs.pipeline.estimate_file`, thrust from the
    commands and the estimator without a rotor model unless given) and :func:`identify` on it."""
    from .pipeline import estimate_file

    _bounds(tau_bounds)  # before the log is read
    estimate_options.setdefault("thrust_from", "commands")
    params = estimate_options.pop("params", None) or EstimatorParams()
    est = estimate_file(path, mass, None, params, vehicle=vehicle, **estimate_options)
    ident = identify(est, tau_bounds=tau_bounds)
    ident.notes[:0] = [f"thrust: {est.info.get('thrust')}"] + list(est.warnings)
    return ident


__all__ = [
    "ABS_CI_PER_WEIGHT",
    "Coefficient",
    "Identification",
    "MAX_REL_CI",
    "MIN_SPEED_RMS",
    "TAU_BOUNDS",
    "identify",
    "identify_file",
]
