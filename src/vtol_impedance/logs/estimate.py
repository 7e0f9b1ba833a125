"""The momentum-based estimator, eqs. (6)-(13), run on a flight log.

Inputs are what the estimator needs and nothing else: world velocity, attitude, body rates, the thrust
and torque commands, and the nominal mass and inertia (never the position). Commands are converted to
SI units here: normalised thrust by the hover map ``u_N = m g * u / u_hover`` (``u_hover`` given, read
from the log, or fitted on a hover segment), normalised torque by the rotor geometry (see
:mod:`vtol_impedance.logs.ulog`).

What the estimate contains: everything the nominal model misses. A thrust map or mass error shows up
as a constant force along the thrust axis, a centre-of-mass offset as a constant moment. The bias
calibration (``quiet_segment``) reports the mean estimate over a stretch the user knows had no external
wrench (a calm hover); ``remove_bias`` subtracts it.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..conventions import G
from ..errors import InputError, as_finite, positive, scalar
from ..estimator.momentum import EstimatorParams, design
from ..estimator.series import causal, momentum_residual, zero_phase
from ..model.dynamics import body_moment_from_euler, euler_moment_from_body
from .timeseries import FlightLog

BACKENDS = ("compiled", "numpy")


@dataclass
class LogEstimate:
    """Estimated external wrench on the log's grid: force in world NED (N), moment in Euler coordinates
    and in body FRD (N m; ``None`` when the log has no usable torque commands). ``*_zp``: zero-phase."""

    t: np.ndarray
    f_W: np.ndarray
    tau_eta: np.ndarray | None
    tau_B: np.ndarray | None
    f_W_zp: np.ndarray | None
    tau_B_zp: np.ndarray | None
    thrust_N: np.ndarray
    flight: FlightLog
    bias: dict[str, Any] | None
    info: dict[str, Any]
    notes: list[str] = field(default_factory=list)

    def columns(self) -> dict[str, np.ndarray]:
        """Named columns (SI units in the names) for CSV and Parquet."""
        cols: dict[str, np.ndarray] = {"t_s": self.t, "segment": np.cumsum(self.flight.restart) - 1}
        for arr, stem in ((self.f_W, "f{}_W_N"), (self.tau_B, "tau{}_B_Nm"), (self.tau_eta, "tau{}_eta_Nm")):
            if arr is not None:
                cols.update({stem.format(a): arr[:, i] for i, a in enumerate("xyz")})
        for arr, stem in ((self.f_W_zp, "f{}_W_N_zp"), (self.tau_B_zp, "tau{}_B_Nm_zp")):
            if arr is not None:
                cols.update({stem.format(a): arr[:, i] for i, a in enumerate("xyz")})
        cols["thrust_N"] = self.thrust_N
        cols.update({f"v{a}_W": self.flight.v_W[:, i] for i, a in enumerate("xyz")})
        cols.update({n: self.flight.eta[:, i] for i, n in enumerate(("roll", "pitch", "yaw"))})
        return cols


def _segment(name: str, seg: Any, t: np.ndarray) -> np.ndarray:
    try:
        a, b = (float(x) for x in seg)
    except (TypeError, ValueError):
        raise InputError(f"{name} must be two times in seconds 'T0,T1', got {seg!r}") from None
    if not (np.isfinite(a) and np.isfinite(b) and a < b):
        raise InputError(f"{name} must have T0 < T1, got {a}, {b}")
    sel = (t >= a) & (t <= b)
    if sel.sum() < 10:
        raise InputError(
            f"{name} {a:g}-{b:g} s holds {int(sel.sum())} samples of the log (which covers {t[0]:.2f}-{t[-1]:.2f} s);"
            " it needs at least 10"
        )
    return sel


def fit_hover_thrust(flight: FlightLog, mass: float, segment: Any) -> tuple[float, float]:
    """Normalised hover thrust from a hover segment by least squares on the vertical balance
    ``k u cos(phi) cos(theta) = m (g - a_z)`` (NED, ``a_z`` from the velocity); returns ``(m g / k, rms
    residual in N)``."""
    sel = _segment("hover segment", segment, flight.t)
    a_z = np.gradient(flight.v_W[:, 2], flight.t)[sel]
    uc = flight.thrust[sel] * np.cos(flight.eta[sel, 0]) * np.cos(flight.eta[sel, 1])
    rhs = mass * (G - a_z)
    k = float(np.dot(uc, rhs) / max(np.dot(uc, uc), 1e-300))
    if not k > 0:
        raise InputError("the hover segment has no positive thrust: cannot fit a hover thrust on it")
    return mass * G / k, float(np.sqrt(np.mean((k * uc - rhs) ** 2)))


def commands_in_si(
    flight: FlightLog,
    mass: float,
    hover_thrust: float | None = None,
    hover_segment: Any = None,
    torque_scale: Any = None,
) -> tuple[np.ndarray, np.ndarray | None, dict[str, Any], list[str]]:
    """``(thrust_N, tau_B or None, info, notes)``: the logged commands in newtons and newton metres."""
    raw = flight.raw
    info: dict[str, Any] = {}
    notes: list[str] = []
    weight = mass * G
    u = flight.thrust
    if raw.thrust_unit == "N" and (hover_thrust is not None or hover_segment is not None):
        raise InputError("a hover thrust converts normalised thrust; this log's thrust is already in newtons")
    if raw.torque_unit == "N m" and torque_scale is not None:
        raise InputError("a torque scale converts normalised torque; this log's torques are already in N m")
    if raw.thrust_unit == "N":
        if np.max(u) < 0.2 * weight:
            raise InputError(
                f"thrust declared in newtons peaks at {np.max(u):.3g} N, under 20 % of the weight "
                f"m g = {weight:.3g} N: "
                "it looks normalised; declare it as normalised thrust (CSV column thrust_norm) with a hover thrust"
            )
        thrust = u
        info["thrust"] = "newtons, as logged"
    else:
        if np.max(u) > 1.5:
            raise InputError(
                f"thrust declared normalised reaches {np.max(u):.3g}, above 1: it looks like newtons "
                "(CSV column thrust_n)"
            )
        if hover_thrust is not None:
            h = scalar("hover thrust", hover_thrust, lo=0.0, hi=1.0, lo_open=True)
            src = "given"
        elif hover_segment is not None:
            h, res = fit_hover_thrust(flight, mass, hover_segment)
            src = f"fitted on the hover segment {hover_segment[0]:g}-{hover_segment[1]:g} s (rms residual {res:.3g} N)"
        elif raw.hover_thrust is not None:
            h, src = raw.hover_thrust, raw.hover_source
        else:
            raise InputError(
                "normalised thrust needs a hover thrust to become newtons: give it (--hover-thrust), a hover "
                "segment to fit it on (--hover-segment T0,T1), or a log with a hover thrust estimate"
            )
        if not 0.02 < h < 1.0:
            raise InputError(f"hover thrust {h:.4g} is outside (0.02, 1): check the hover segment or the value")
        thrust = u * weight / h
        info["hover_thrust"] = float(h)
        info["thrust"] = f"normalised x m g / hover thrust {h:.4f} ({src})"
        notes.append(f"hover thrust {h:.4f}: {src}")
    tau = None
    if flight.tau_B is not None:
        if raw.torque_unit == "N m":
            tau = flight.tau_B
            info["torque"] = "N m, as logged"
        elif torque_scale is not None:
            k = np.broadcast_to(positive("torque scale", torque_scale), (3,)).astype(float)
            tau = flight.tau_B * k
            info["torque"] = f"normalised x given scale {k.tolist()} N m"
        elif raw.torque_per_unit is not None and "hover_thrust" in info:
            c_t = weight / (raw.n_rotors * info["hover_thrust"])
            k = raw.torque_per_unit * c_t
            tau = flight.tau_B * k
            info["torque"] = f"normalised x {np.round(k, 4).tolist()} N m from the log's rotor geometry"
        else:
            notes.append(
                "torque commands are normalised and the log has no rotor geometry (CA_ROTOR* parameters): "
                "the moment estimate is skipped (give --torque-scale to convert them)"
            )
    return thrust, tau, info, notes


def estimate(
    flight: FlightLog,
    mass: float,
    inertia: Any,
    params: EstimatorParams | None = None,
    *,
    zero_phase_too: bool = False,
    quiet_segment: Any = None,
    remove_bias: bool = False,
    hover_thrust: float | None = None,
    hover_segment: Any = None,
    torque_scale: Any = None,
    backend: str = "compiled",
) -> LogEstimate:
    """Estimate the external wrench along a resampled log (see the module docstring)."""
    mass = float(scalar("mass", mass, lo=0.0, lo_open=True))
    I_B = as_finite("inertia", inertia)
    if I_B.shape == (3,):
        I_B = np.diag(I_B)
    if I_B.shape != (3, 3) or np.any(np.linalg.eigvalsh(0.5 * (I_B + I_B.T)) <= 0):
        raise InputError(f"inertia must be 3 positive values or a positive definite 3x3 matrix, got {inertia!r}")
    if backend not in BACKENDS:
        raise InputError(f"backend must be one of {', '.join(BACKENDS)}, got {backend!r}")
    params = params or EstimatorParams()
    des = design(params, flight.Ts)
    thrust, tau, info, notes = commands_in_si(flight, mass, hover_thrust, hover_segment, torque_scale)
    tau_in = np.zeros_like(flight.v_W) if tau is None else tau
    w = None
    if backend == "numpy" or zero_phase_too:
        w = momentum_residual(
            flight.v_W, flight.eta, flight.eta_dot, thrust, tau_in, mass, I_B, flight.Ts, des, flight.restart
        )
    if backend == "compiled":
        from ..compiled.estimator import run_log

        out = run_log(des, mass, I_B, flight.v_W, flight.eta, flight.eta_dot, thrust, tau_in, flight.restart)
        f_W, tau_eta, tau_B = out[:, :3], out[:, 3:6], out[:, 6:9]
    else:
        r = causal(des, w, flight.restart)
        f_W, tau_eta = r[:, :3], r[:, 3:]
        tau_B = body_moment_from_euler(tau_eta, flight.eta)
    f_zp = tau_zp = None
    if zero_phase_too:
        r = zero_phase(des, w, flight.restart)
        f_zp, tau_zp = r[:, :3], body_moment_from_euler(r[:, 3:], flight.eta)
    if tau is None:
        tau_eta = tau_B = tau_zp = None
    bias = None
    if quiet_segment is not None:
        sel = _segment("quiet segment", quiet_segment, flight.t)
        settle = 5.0 / float(np.min(np.abs(params.channel_poles())))
        starts = flight.t[flight.restart]
        if np.any((starts <= flight.t[sel][0]) & (flight.t[sel][0] < starts + settle)):
            notes.append(
                f"the quiet segment starts within {settle:.2f} s (5 time constants of the estimator) of the start "
                "of the log or of a gap: the bias includes the estimator's start-up transient"
            )
        bias = {"segment_s": [float(quiet_segment[0]), float(quiet_segment[1])], "f_W_N": f_W[sel].mean(0).tolist()}
        if tau_B is not None:
            bias["tau_B_Nm"] = tau_B[sel].mean(0).tolist()
        if remove_bias:
            f_W = f_W - np.asarray(bias["f_W_N"])
            if f_zp is not None:
                f_zp = f_zp - np.nanmean(f_zp[sel], 0)
            if tau_B is not None:
                tau_B = tau_B - np.asarray(bias["tau_B_Nm"])
                tau_eta = euler_moment_from_body(tau_B, flight.eta)
                if tau_zp is not None:
                    tau_zp = tau_zp - np.nanmean(tau_zp[sel], 0)
            bias["removed"] = True
    elif remove_bias:
        raise InputError("removing the bias needs a quiet segment (--quiet-segment T0,T1) to measure it on")
    info.update(
        mass_kg=mass,
        inertia_kg_m2=I_B.tolist(),
        estimator=params.to_dict(),
        rate_hz=flight.rate_hz,
        samples=len(flight.t),
        segments=int(flight.restart.sum()),
        span_s=[float(flight.t[0]), float(flight.t[-1])],
        zero_phase=bool(zero_phase_too),
        backend=backend,
        **{k: v for k, v in flight.raw.meta.items()},
    )
    return LogEstimate(flight.t, f_W, tau_eta, tau_B, f_zp, tau_zp, thrust, flight, bias, info, flight.notes + notes)
