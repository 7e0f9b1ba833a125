"""The momentum-based estimator, eqs. (6)-(13), run on a flight log.

Inputs are what the estimator needs and nothing else: world velocity, attitude, body rates, the thrust
and torque (commands, or the rotors' measured speeds), and the nominal mass and inertia (never the
position; the inertia only for the moment: the force channel of eq. (8) does not contain it). Commands
are converted to SI units here: normalised thrust by the hover map ``u_N = m g * u / u_hover`` with
``u_hover`` given, fitted on a hover segment, or from the log: an estimate logged over the flight
(PX4's ``hover_thrust_estimate``, ArduPilot's ``CTUN.ThH``, a CSV ``hover_thrust`` column), used **per
sample** (it follows the battery's sag), else a parameter (``MPC_THR_HOVER``, ``MOT_THST_HOVER``) that
does not hold its firmware default, else fitted on the hover windows found in the log
(:func:`fit_hover_windows`; their spread becomes the uncertainty ``LogEstimate.fz_sd`` of the vertical
force), else the parameter at its default with a warning, else refused;
normalised torque by the rotor geometry (see :mod:`vtol_impedance.logs.ulog`). Measured rotor speeds
give thrust and torque without the rotors' lag (:mod:`vtol_impedance.logs.rotors`).

Before the estimate the converted thrust must carry the weight: over the airborne samples the vertical
balance ``m (g - a_z) = r u cos(phi) cos(theta)`` gives the ratio ``r``; outside [0.5, 2] the log is
refused (a wrong mass, hover thrust, thrust unit or rotor-speed unit), outside [0.8, 1.25] a warning
names the mean vertical external force it implies. A log on the ground (``on_ground``, a bench test) skips
this check: its force is the ground reaction plus the external force.

What the estimate contains: everything the nominal model misses. A thrust map or mass error shows up
as a constant force along the thrust axis, a centre-of-mass offset as a constant moment. The bias
calibration (``quiet_segment``) reports the mean estimate over a stretch the user knows had no external
wrench (a calm hover); ``remove_bias`` subtracts it.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..conventions import SINGULARITY_COS_EPS, G
from ..errors import InputError, positive, scalar
from ..estimator.momentum import EstimatorParams, design
from ..estimator.series import causal, momentum_residual, zero_phase
from ..model.dynamics import body_moment_from_euler, euler_moment_from_body
from ..model.vehicle import check_inertia
from . import rotors
from .frames import ROTOR_SPEED_UNITS
from .timeseries import FlightLog

BACKENDS = ("compiled", "numpy")
THRUST_SOURCES = ("auto", "commands", "rotors")
#: The thrust must carry the weight within these ratios (error outside WEIGHT_ERROR, warning outside
#: WEIGHT_WARN).
WEIGHT_ERROR = (0.5, 2.0)
WEIGHT_WARN = (0.8, 1.25)
#: A hover fit that leaves more than this share of the weight as RMS residual (of 0.25 s averages, so that
#: command noise does not count) is refused: not a hover. It was 3 %, which refused real hovers in gusts:
#: the residual is the vertical force's variation (gusts, the rotors' lag behind the commands), which does
#: not bias the fit (its error is the residual's standard error over the window, a tenth of it over 10 s);
#: what the limit must catch is a balance that fails outright (the ground carrying part of the weight),
#: and the consistency of several windows (:func:`fit_hover_windows`) catches a smaller failure. The
#: same limit as the rotor-speed fit's (:data:`~vtol_impedance.logs.rotors.MAX_FIT_RESIDUAL`).
MAX_HOVER_RESIDUAL = 0.10


@dataclass
class LogEstimate:
    """Estimated external wrench on the log's grid: force in world NED (N), moment in Euler coordinates
    and in body FRD (N m; ``None`` when the log gives no usable torque or no inertia). ``*_zp``:
    zero-phase. ``hover`` is the normalised hover thrust used at each sample (``None`` when the thrust
    was in newtons or came from the rotors). ``fz_sd``: one standard deviation of the vertical force
    ``f_W[:, 2]`` (N) from the uncertainty of a hover thrust fitted on the automatic hover windows (their
    spread, :func:`fit_hover_windows`): ``|thrust_N cos(phi) cos(theta)| sd / hover``; ``None`` when the
    hover thrust was given, logged or fitted on a given segment. With ``info["on_ground"]`` the force is
    the ground reaction plus the external force."""

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
    hover: np.ndarray | None = None
    warnings: list[str] = field(default_factory=list)
    fz_sd: np.ndarray | None = None

    def columns(self) -> dict[str, np.ndarray]:
        """Named columns (SI units in the names) for CSV and Parquet."""
        fl = self.flight
        cols: dict[str, np.ndarray] = {"t_s": self.t, "segment": np.cumsum(fl.restart) - 1}
        cols["restart"] = fl.restart.astype(np.int64)
        bridged = fl.bridged if fl.bridged is not None else np.zeros(len(self.t), bool)
        cols["bridged"] = bridged.astype(np.int64)
        for arr, stem in ((self.f_W, "f{}_W_N"), (self.tau_B, "tau{}_B_Nm"), (self.tau_eta, "tau{}_eta_Nm")):
            if arr is not None:
                cols.update({stem.format(a): arr[:, i] for i, a in enumerate("xyz")})
        for arr, stem in ((self.f_W_zp, "f{}_W_N_zp"), (self.tau_B_zp, "tau{}_B_Nm_zp")):
            if arr is not None:
                cols.update({stem.format(a): arr[:, i] for i, a in enumerate("xyz")})
        if self.fz_sd is not None:
            cols["fz_W_N_hover_sd"] = self.fz_sd
        cols["thrust_N"] = self.thrust_N
        if self.hover is not None:
            cols["hover_thrust"] = self.hover
        cols.update({f"v{a}_W": fl.v_W[:, i] for i, a in enumerate("xyz")})
        cols.update({n: fl.eta[:, i] for i, n in enumerate(("roll", "pitch", "yaw"))})
        cols.update({f"w{a}_B": fl.omega_B[:, i] for i, a in enumerate("xyz")})
        return cols


def _segment(name: str, seg: Any, t: np.ndarray, min_coverage: float = 0.0) -> np.ndarray:
    try:
        a, b = (float(x) for x in seg)
    except (TypeError, ValueError):
        raise InputError(f"{name} must be two times in seconds 'T0,T1', got {seg!r}") from None
    if not (np.isfinite(a) and np.isfinite(b) and a < b):
        raise InputError(f"{name} must have T0 < T1, got {a}, {b}")
    sel = (t >= a) & (t <= b)
    covered = max(0.0, min(b, t[-1]) - max(a, t[0])) / (b - a)
    if sel.sum() < 10 or covered < min_coverage:
        raise InputError(
            f"{name} {a:g}-{b:g} s holds {int(sel.sum())} samples of the log (which covers {t[0]:.2f}-{t[-1]:.2f} s; "
            f"{100 * covered:.0f} % of the segment): it needs at least 10 samples"
            + (f" and {100 * min_coverage:.0f} % of the segment inside the log" if min_coverage else "")
        )
    return sel


def _stationary_ground(flight: FlightLog, sel: np.ndarray, u: np.ndarray) -> str | None:
    """Why the selected samples look like the vehicle on the ground (or ``None``)."""
    speed = np.linalg.norm(flight.v_W, axis=-1)
    if np.max(speed) < 0.2 and np.max(np.abs(flight.omega_B)) < 0.05:
        return "the vehicle never seems to leave the ground in this log (speed below 0.2 m/s, rates below 0.05 rad/s)"
    typical = np.percentile(u, 90)
    if np.max(speed[sel]) < 0.05 and np.mean(u[sel]) < 0.5 * typical:
        return (
            f"the segment looks on the ground: the vehicle is still and its thrust there ({np.mean(u[sel]):.3g}) is "
            f"under half of what it uses in the rest of the log ({typical:.3g})"
        )
    return None


def _balance_fit(
    flight: FlightLog, mass: float, sel: np.ndarray, u: np.ndarray, a_z_all: np.ndarray | None = None
) -> tuple[float, float, float]:
    """``(k, rms, rms of 0.25 s averages)`` of the least-squares vertical balance
    ``k u cos(phi) cos(theta) = m (g - a_z)`` (NED, ``a_z`` from the velocity, or ``a_z_all`` computed once
    for many fits) over the samples ``sel`` (a mask or sample indices); ``k`` in N per unit ``u``,
    residuals in N."""
    sel = np.flatnonzero(sel) if sel.dtype == bool else sel
    if a_z_all is None:
        a_z_all = np.gradient(flight.v_W[:, 2], flight.t)
    a_z = a_z_all[sel]
    uc = u[sel] * np.cos(flight.eta[sel, 0]) * np.cos(flight.eta[sel, 1])
    rhs = mass * (G - a_z)
    k = float(np.dot(uc, rhs) / max(np.dot(uc, uc), 1e-300))
    res = float(np.sqrt(np.mean((k * uc - rhs) ** 2)))
    n = max(1, int(round(0.25 * flight.rate_hz)))
    kern = np.ones(n) / n
    res_avg = float(np.sqrt(np.mean(np.convolve(k * uc - rhs, kern, "valid") ** 2))) if len(sel) > n else res
    return k, res, res_avg


#: The hover thrusts fitted on the two halves of a hover segment or window differ by less than this share:
#: a steady hover's halves agree within 1-2 % even in gusts (a 5 % residual over ten 0.25 s averages per
#: half), a take-off with the ground carrying part of the weight at first differs by 4-9 %.
HOVER_HALVES_SHARE = 0.03


def _halves_change(
    flight: FlightLog, mass: float, sel: np.ndarray, u: np.ndarray, a_z_all: np.ndarray | None = None
) -> float:
    """The hover thrust fitted on the first half of ``sel`` (a mask or indices) over the second's, minus 1."""
    idx = np.flatnonzero(sel) if sel.dtype == bool else sel
    ka = _balance_fit(flight, mass, idx[: len(idx) // 2], u, a_z_all)[0]
    kb = _balance_fit(flight, mass, idx[len(idx) // 2 :], u, a_z_all)[0]
    return kb / ka - 1.0 if ka > 0 and kb > 0 else float("inf")


def fit_hover_thrust(flight: FlightLog, mass: float, segment: Any) -> tuple[float, float]:
    """Normalised hover thrust from a hover segment by least squares on the vertical balance.

    The balance is ``k u cos(phi) cos(theta) = m (g - a_z)`` (NED, ``a_z`` from the velocity); the hover
    thrust is ``m g / k``. A segment on the ground is refused, and so is one the balance does not fit: an
    RMS residual of 0.25 s averages above :data:`MAX_HOVER_RESIDUAL` of the weight, or whose halves differ
    by more than :data:`HOVER_HALVES_SHARE` (a take-off with the ground still carrying part of the weight,
    a landing).

    Parameters
    ----------
    flight : FlightLog
        The resampled log, with a normalised thrust command.
    mass : float
        Nominal mass, kg.
    segment : (float, float)
        The hover, ``(T0, T1)`` in the log's seconds.

    Returns
    -------
    tuple of float
        ``(hover thrust (normalised), rms residual of the balance in N)``.
    """
    from ..errors import instance

    instance("flight", flight, FlightLog)
    mass = scalar("mass", mass, lo=0.0, lo_open=True)
    sel = _segment("hover segment", segment, flight.t, 0.5)
    if flight.thrust is None:
        raise InputError("the log has no thrust command to fit a hover thrust on")
    why = _stationary_ground(flight, sel, flight.thrust)
    if why:
        raise InputError(f"cannot fit a hover thrust on {segment[0]:g}-{segment[1]:g} s: {why}")
    k, res, res_avg = _balance_fit(flight, mass, sel, flight.thrust)
    if not k > 0:
        raise InputError("the hover segment has no positive thrust: cannot fit a hover thrust on it")
    if res_avg > MAX_HOVER_RESIDUAL * mass * G:
        raise InputError(
            f"the hover fit on {segment[0]:g}-{segment[1]:g} s leaves {res_avg:.3g} N RMS on a {mass * G:.3g} N "
            f"vehicle ({100 * res_avg / (mass * G):.1f} % of its weight; a hover in gusts leaves up to about "
            f"{100 * MAX_HOVER_RESIDUAL:.0f} %): the segment is not a hover (a take-off with the ground still "
            "carrying part of the weight, a landing, a manoeuvre?); choose a steady hover"
        )
    d = _halves_change(flight, mass, sel, flight.thrust)
    if abs(d) > HOVER_HALVES_SHARE:
        raise InputError(
            f"the hover fit on {segment[0]:g}-{segment[1]:g} s is not a hover: the balance changes within it (the "
            f"hover thrust of its first half is {100 * d:+.1f} % from its second's; a steady hover's halves agree "
            f"within {100 * HOVER_HALVES_SHARE:.0f} %): the ground carries part of the weight (a take-off, a "
            "landing) or the vehicle manoeuvres; choose a steady hover"
        )
    return mass * G / k, res


#: Automatic hover windows (where the log has no hover thrust estimate and none is given): samples where
#: the vehicle is airborne (thrust above half its 90th percentile), slow (speed below HOVER_MAX_SPEED),
#: calm (0.5 s-averaged acceleration below HOVER_MAX_ACCEL) and level (tilt below HOVER_MAX_TILT_DEG),
#: for at least HOVER_MIN_S without a restart; longer runs are cut into pieces of at most HOVER_PIECE_S, so
#: that a long hover gives several windows, the battery's sag shows in their spread and a take-off joined
#: to a hover stays in its own window.
HOVER_MAX_SPEED = 1.0  # m/s: drag at 1 m/s is about 1 % of a small vehicle's weight
HOVER_MAX_ACCEL = 0.5  # m/s^2
HOVER_MAX_TILT_DEG = 10.0
#: A log with no level hover window (a steady wind tilts every hover: 30 % of the weight tilts it 17 deg)
#: looks again for windows tilted up to this much: the vertical balance holds at any tilt. Fitted there,
#: with a warning: in a wind a rotor's thrust per command grows (translational lift), so the hover thrust
#: may read a few per cent low, and the vertical force by that share of the weight.
HOVER_WINDY_TILT_DEG = 25.0
HOVER_MIN_S = 2.0
HOVER_PIECE_S = 5.0
#: A window's hover thrust is an outlier (named, not used) when it is further from the median of the
#: windows than 3 robust standard deviations (1.4826 MAD) or this share of the median, whichever is larger.
HOVER_OUTLIER_SHARE = 0.02
#: Hover windows whose fits spread by more than this share (one standard deviation) are warned about.
HOVER_SPREAD_WARN = 0.03
#: A log's hover-thrust parameter (used) further than this share from the hover windows' fit is explained
#: in a note: a wrong parameter, or a payload carried in every hover.
HOVER_PARAMETER_SHARE = 0.05


def hover_windows(
    flight: FlightLog, thrust: np.ndarray | None = None, max_tilt_deg: float = HOVER_MAX_TILT_DEG
) -> list[tuple[float, float]]:
    """Spans ``(t0, t1)`` (s, the log's clock) where the vehicle hovers (the criteria of :data:`HOVER_MIN_S`).

    Parameters
    ----------
    flight : FlightLog
        The resampled log.
    thrust : numpy.ndarray, optional
        ``(N,)`` collective thrust in any unit (default: the log's command) for the airborne test.
    max_tilt_deg : float
        The largest tilt of a hover, degrees (:data:`HOVER_WINDY_TILT_DEG` where no level one exists).

    Returns
    -------
    list of tuple of float
        The windows in time order; empty when the vehicle never hovers (or never leaves the ground).
    """
    max_tilt_deg = scalar("max_tilt_deg", max_tilt_deg, lo=0.0, lo_open=True, hi=90.0)  # NaN: no window, silently
    u = flight.thrust if thrust is None else thrust
    if u is None or len(flight.t) < 3:
        return []
    if np.max(np.linalg.norm(flight.v_W, axis=-1)) < 0.2 and np.max(np.abs(flight.omega_B)) < 0.05:
        return []  # never leaves the ground: an idle vehicle is still and level too
    n = max(1, int(round(0.5 * flight.rate_hz)))
    kern = np.ones(n) / n
    a_W = np.gradient(flight.v_W, flight.t, axis=0)
    a_avg = np.stack([np.convolve(a_W[:, i], kern, "same") for i in range(3)], -1)
    tilt = np.degrees(np.arccos(np.clip(np.cos(flight.eta[:, 0]) * np.cos(flight.eta[:, 1]), -1.0, 1.0)))
    ok = (
        (u > 0.5 * np.percentile(u, 90))
        & (np.linalg.norm(flight.v_W, axis=-1) < HOVER_MAX_SPEED)
        & (np.linalg.norm(a_avg, axis=-1) < HOVER_MAX_ACCEL)
        & (tilt < max_tilt_deg)
    )
    ok &= ~flight.restart  # a run never spans a restart
    edges = np.flatnonzero(np.diff(np.concatenate([[0], ok.astype(np.int8), [0]])))
    out = []
    for i0, i1 in zip(edges[::2], edges[1::2], strict=True):
        t0, t1 = float(flight.t[i0]), float(flight.t[i1 - 1])
        if t1 - t0 < HOVER_MIN_S:
            continue
        k = int(np.ceil((t1 - t0) / HOVER_PIECE_S))
        cuts = np.linspace(t0, t1, k + 1)
        out += [(float(a), float(b)) for a, b in zip(cuts[:-1], cuts[1:], strict=True)]
    return out


def fit_hover_windows(flight: FlightLog, mass: float, max_tilt_deg: float = HOVER_MAX_TILT_DEG) -> dict[str, Any]:
    """The normalised hover thrust fitted on every automatic hover window (:func:`hover_windows`).

    Each window is fitted by the vertical balance of :func:`fit_hover_thrust`; a window whose fit leaves
    more than :data:`MAX_HOVER_RESIDUAL` of the weight or whose halves differ by more than
    :data:`HOVER_HALVES_SHARE` is not a hover, one further from the median than
    :data:`HOVER_OUTLIER_SHARE` (or 3 robust standard deviations) is an outlier; the rest are kept.

    Parameters
    ----------
    flight : FlightLog
        The resampled log, with a normalised thrust command.
    mass : float
        Nominal mass, kg.
    max_tilt_deg : float
        The largest tilt of a hover window, degrees (:func:`hover_windows`).

    Returns
    -------
    dict
        ``windows``: one dict per window (``t0_s``, ``t1_s``, ``hover``, ``rms_N``, ``kept``, ``why`` when
        not kept); ``hover``: the median of the kept windows (``None`` when none is kept); ``sd``: its
        uncertainty, one standard deviation (normalised): the robust spread of the kept windows (1.4826 MAD;
        the standard deviation of two), at least the median of their own standard errors
        (``rms of 0.25 s averages / m g * hover / sqrt(length / 0.25 s)``); ``sd_rel``: ``sd / hover``;
        ``second_group`` (when two outliers or more on one side agree within the outlier tolerance): their
        count ``n``, the windows fitted ``of`` and their median ``hover``.
    """
    from ..errors import instance

    instance("flight", flight, FlightLog)
    mass = scalar("mass", mass, lo=0.0, lo_open=True)
    weight = mass * G
    wins = []
    a_z_all = np.gradient(flight.v_W[:, 2], flight.t)
    for t0, t1 in hover_windows(flight, max_tilt_deg=max_tilt_deg):
        sel = np.arange(np.searchsorted(flight.t, t0), np.searchsorted(flight.t, t1, side="right"))
        k, _, res_avg = _balance_fit(flight, mass, sel, flight.thrust, a_z_all)
        w: dict[str, Any] = {"t0_s": t0, "t1_s": t1, "hover": None, "rms_N": res_avg, "kept": False}
        if not k > 0:
            w["why"] = "no positive thrust"
        else:
            w["hover"] = weight / k
            if res_avg > MAX_HOVER_RESIDUAL * weight:
                w["why"] = f"not a hover: the balance leaves {100 * res_avg / weight:.1f} % of the weight"
            elif not 0.02 < w["hover"] < 1.0:
                w["why"] = "hover thrust outside (0.02, 1)"
            elif abs(d := _halves_change(flight, mass, sel, flight.thrust, a_z_all)) > HOVER_HALVES_SHARE:
                w["why"] = (
                    f"not a hover: its halves differ by {100 * d:+.1f} % (the ground carrying part of the weight?)"
                )
            else:
                w["kept"] = True
                w["se"] = float(w["hover"] * res_avg / weight / np.sqrt(max(1.0, (t1 - t0) / 0.25)))
        wins.append(w)
    kept = [w for w in wins if w["kept"]]
    out: dict[str, Any] = {"windows": wins, "hover": None, "sd": None, "sd_rel": None}
    if not kept:
        return out
    h = np.array([w["hover"] for w in kept])
    med = float(np.median(h))
    tol = max(3 * 1.4826 * float(np.median(np.abs(h - med))), HOVER_OUTLIER_SHARE * med)
    for w in kept:
        if abs(w["hover"] - med) > tol:
            w["kept"] = False
            w["why"] = f"outlier: {100 * (w['hover'] / med - 1):+.1f} % from the median of the windows"
    outliers = [w["hover"] for w in wins if w.get("why", "").startswith("outlier")]
    kept = [w for w in wins if w["kept"]]
    # two outliers or more on one side that agree among themselves (within the outlier tolerance) are a
    # second group, not gusts: a payload picked up or dropped, a battery swapped
    side = max(([o for o in outliers if o > med], [o for o in outliers if o < med]), key=len)
    if len(side) >= 2 and max(side) - min(side) <= tol:
        out["second_group"] = {"n": len(side), "of": len(outliers) + len(kept), "hover": float(np.median(side))}
    h = np.array([w["hover"] for w in kept])
    med = float(np.median(h))
    if len(h) >= 3:
        spread = 1.4826 * float(np.median(np.abs(h - med)))
    else:
        spread = float(np.std(h, ddof=1)) if len(h) == 2 else 0.0
    sd = max(spread, float(np.median([w["se"] for w in kept])))
    out.update(hover=med, sd=sd, sd_rel=sd / med)
    return out


def _fit_level_or_windy(flight: FlightLog, mass: float) -> dict[str, Any]:
    """:func:`fit_hover_windows` on level hovers, else on hovers tilted up to :data:`HOVER_WINDY_TILT_DEG`
    (then ``windy``: a steady wind held every hover)."""
    auto = fit_hover_windows(flight, mass)
    if auto["hover"] is None:
        windy = fit_hover_windows(flight, mass, HOVER_WINDY_TILT_DEG)
        if windy["hover"] is not None:
            return windy | {"windy": True}
    return auto


def weight_ratio(flight: FlightLog, thrust_N: np.ndarray, mass: float) -> float:
    """``r`` of ``m (g - a_z) = r u cos(phi) cos(theta)`` over the airborne samples (median, smoothed 0.5 s)."""
    n = max(1, int(round(0.5 * flight.rate_hz)))
    kern = np.ones(n) / n
    a_z = np.convolve(np.gradient(flight.v_W[:, 2], flight.t), kern, "same")
    uc = np.convolve(thrust_N * np.cos(flight.eta[:, 0]) * np.cos(flight.eta[:, 1]), kern, "same")
    air = uc > 0.3 * np.percentile(uc, 95)
    if air.sum() < 10:
        return float("nan")
    return float(np.median(mass * (G - a_z[air]) / uc[air]))


def check_weight(
    flight: FlightLog, thrust_N: np.ndarray, mass: float, what: str, fixes: str
) -> tuple[float, str | None]:
    """``(ratio, warning or None)``; raises outside :data:`WEIGHT_ERROR` (module docstring)."""
    r = weight_ratio(flight, thrust_N, mass)
    if not np.isfinite(r):
        return r, None
    if not WEIGHT_ERROR[0] <= r <= WEIGHT_ERROR[1]:
        raise InputError(
            f"the thrust ({what}) does not carry the weight: while the rotors run it gives {1 / r:.3g} times "
            f"m g = {mass * G:.3g} N. Check {fixes}; or the vehicle was not flying on its own thrust (carried, "
            "on a stand, landed: --on-ground estimates the ground reaction of a log that never leaves the ground)"
        )
    if not WEIGHT_WARN[0] <= r <= WEIGHT_WARN[1]:
        return r, (
            f"the thrust ({what}) gives {1 / r:.3g} times the weight m g = {mass * G:.3g} N in flight: the estimate "
            f"will show a mean vertical force of about {mass * G * (1 / r - 1):+.3g} N (NED, + down). If the vehicle "
            f"carried nothing, check {fixes}"
        )
    return r, None


#: Firmware defaults of the hover-thrust parameters: a log whose parameter still holds one was most likely
#: never tuned (PX4 before 1.12 did not learn it), and it is taken as no value at all.
PARAMETER_DEFAULTS = {"MPC_THR_HOVER": 0.5, "MOT_THST_HOVER": 0.35, "Q_M_THST_HOVER": 0.35}


def _parameter(raw: Any) -> tuple[str, bool] | None:
    """``(name, at its firmware default)`` when the log's constant hover thrust is a parameter
    (``MPC_THR_HOVER``, ``MOT_THST_HOVER``...) rather than a logged estimate or a CSV value, else ``None``."""
    if raw.hover_thrust is None or not str(raw.hover_source).startswith("the parameter"):
        return None
    name = next((n for n in PARAMETER_DEFAULTS if n in str(raw.hover_source)), "")
    default = PARAMETER_DEFAULTS.get(name)
    return name, default is not None and abs(float(raw.hover_thrust) - default) < 1e-6


def _hover_for(
    flight: FlightLog, mass: float, hover_thrust: float | None, hover_segment: Any, on_ground: bool = False
) -> tuple[np.ndarray, str, dict[str, Any]]:
    """The normalised hover thrust per sample, where it came from, and its summary.

    In this order: given; fitted on the given segment; the log's per-sample estimate; a constant the log
    states (a CSV value, one estimate); the log's parameter unless it holds its firmware default
    (:data:`PARAMETER_DEFAULTS`), checked against the automatic hover windows (``summ["windows_fit"]``);
    fitted on the automatic hover windows (:func:`fit_hover_windows`; ``summ["sd"]`` its uncertainty);
    the parameter at its default (``summ["unchecked"]``: a loud warning, and checked against the whole
    flight's balance by the caller); else refused.
    """
    raw = flight.raw
    summ: dict[str, Any] = {"sd": None, "unchecked": False}
    param = _parameter(raw)
    auto = None
    if hover_thrust is not None:
        h = scalar("hover thrust", hover_thrust, lo=0.0, hi=1.0, lo_open=True)
        src = "given"
        arr = np.full(len(flight.t), h)
    elif hover_segment is not None:
        h, res = fit_hover_thrust(flight, mass, hover_segment)
        src = f"fitted on the hover segment {hover_segment[0]:g}-{hover_segment[1]:g} s (rms residual {res:.3g} N)"
        arr = np.full(len(flight.t), h)
    elif flight.hover is not None:
        arr = np.asarray(flight.hover, dtype=float)
        src = f"per sample from {raw.hover.source}" if raw.hover is not None else "per sample from the log"
    elif raw.hover_thrust is not None and param is None:
        arr = np.full(len(flight.t), float(raw.hover_thrust))
        src = raw.hover_source
    elif param is not None and not param[1]:
        arr = np.full(len(flight.t), float(raw.hover_thrust))
        src = raw.hover_source
        if not on_ground:
            auto = _fit_level_or_windy(flight, mass)
            if auto["hover"] is not None:
                summ["windows_fit"] = {"hover": auto["hover"], "sd": auto["sd"], "windy": bool(auto.get("windy"))}
            else:
                src += ", not checked on a hover (the log has no hover window)"
    elif not on_ground and (auto := _fit_level_or_windy(flight, mass))["hover"] is not None:
        kept = [w for w in auto["windows"] if w["kept"]]
        arr = np.full(len(flight.t), auto["hover"])
        src = (
            f"fitted on {len(kept)} automatic hover window(s) of {len(auto['windows'])} (median, spread "
            f"{auto['sd']:.2g} = {100 * auto['sd_rel']:.1f} %)"
        )
        summ.update(sd=auto["sd"], sd_rel=auto["sd_rel"])
        if auto.get("windy"):
            src += f"; no level hover: windows tilted up to {HOVER_WINDY_TILT_DEG:g} deg, a steady wind held"
            summ["windy"] = True
        if "second_group" in auto:
            summ["second_group"] = auto["second_group"]
        if param is not None:
            summ["ignored"] = f"{raw.hover_source} = {float(raw.hover_thrust):.4g}: its firmware default"
    elif param is not None:
        arr = np.full(len(flight.t), float(raw.hover_thrust))
        src = raw.hover_source + (
            ", its firmware default, unchecked: the log has no hover window" if not on_ground else
            ", its firmware default, unchecked (--on-ground)"
        )  # fmt: skip
        summ["unchecked"] = True
    else:
        why = (
            "a log on the ground has no hover to fit it on"
            if on_ground
            else "the log has no hover window to fit it on (airborne, slower than "
            f"{HOVER_MAX_SPEED:g} m/s, calmer than {HOVER_MAX_ACCEL:g} m/s^2, tilted less than "
            f"{HOVER_MAX_TILT_DEG:g} deg, or {HOVER_WINDY_TILT_DEG:g} deg when no level one exists, for {HOVER_MIN_S:g} s)"
            + _windows_refused(auto)
        )
        raise InputError(
            f"normalised thrust needs a hover thrust to become newtons and {why}: give it (--hover-thrust), "
            "a hover segment to fit it on (--hover-segment T0,T1), or a log with a hover thrust estimate"
        )
    if auto is not None:
        summ["windows"] = [{k: v for k, v in w.items() if k != "se"} for w in auto["windows"]]
    lo, hi = float(np.min(arr)), float(np.max(arr))
    if not (0.02 < lo and hi < 1.0):
        raise InputError(f"hover thrust {lo:.4g}..{hi:.4g} is outside (0.02, 1): check the hover segment or the value")
    summ.update(median=float(np.median(arr)), min=lo, max=hi, source=src)
    return arr, src, summ


def _windows_refused(auto: dict[str, Any] | None) -> str:
    """What the automatic hover windows found and why none was kept ("" when there was none)."""
    if not auto or not auto["windows"]:
        return ""
    return "; the windows found were refused: " + "; ".join(
        f"{w['t0_s']:.1f}-{w['t1_s']:.1f} s ({w['why']})" for w in auto["windows"]
    )


def describe_hover_windows(summ: dict[str, Any]) -> list[str]:
    """Lines naming each automatic hover window, its hover thrust and whether it was used (``[]`` when
    the hover thrust did not come from them).

    Parameters
    ----------
    summ : dict
        ``LogEstimate.info["hover_thrust"]``.

    Returns
    -------
    list of str
        One line per window.
    """
    out = []
    for w in summ.get("windows", []):
        h = "-" if w["hover"] is None else f"{w['hover']:.4f}"
        kept = "used" if summ.get("sd") is not None else "consistent; compared with the parameter"
        state = kept if w["kept"] else f"not used: {w['why']}"
        out.append(f"hover window {w['t0_s']:.2f}-{w['t1_s']:.2f} s: hover thrust {h} ({state})")
    return out


#: A hover thrust taken per sample from the autopilot that moves by more than this share within
#: HOVER_LEARN_WINDOW_S is learning a vertical force, not following the battery (which sags by about a
#: tenth over a whole flight): warned about, since the per-sample map then hides that force.
HOVER_LEARN_SHARE = 0.1
HOVER_LEARN_WINDOW_S = 20.0


def _hover_learning(t: np.ndarray, h: np.ndarray, src: str) -> str | None:
    """A warning when the per-sample hover thrust ``h`` moves faster than a battery sags, else ``None``."""
    n = len(h)
    if n < 2 or np.ptp(h) == 0:  # a constant: given, fitted or a parameter
        return None
    k = min(max(int(np.searchsorted(t, t[0] + HOVER_LEARN_WINDOW_S)), 1), n - 1)
    rel = h[k:] / h[:-k] - 1.0
    i = int(np.argmax(np.abs(rel)))
    if abs(rel[i]) <= HOVER_LEARN_SHARE:
        return None
    return (
        f"the hover thrust learnt by the autopilot ({src}) moves from {h[i]:.4g} to {h[i + k]:.4g} "
        f"({rel[i]:+.0%}) between {t[i]:.1f} and {t[i + k]:.1f} s, faster than a battery sags: it is learning a "
        "steady vertical force (a payload, a tether, a push), which the per-sample hover thrust then hides from "
        f"the estimate, or it starts from a value it had not learnt. To see such a force, give a constant: "
        f"--hover-thrust {h[i]:.4g} (its value before, if it had been learnt), or fit one on a hover without "
        "the force (--hover-segment T0,T1)"
    )


def commands_in_si(
    flight: FlightLog,
    mass: float,
    hover_thrust: float | None = None,
    hover_segment: Any = None,
    torque_scale: Any = None,
    *,
    thrust_from: str = "auto",
    thrust_coefficient: float | None = None,
    rotor_geometry: tuple[np.ndarray, np.ndarray] | None = None,
    on_ground: bool = False,
) -> tuple[np.ndarray, np.ndarray | None, dict[str, Any], list[str]]:
    """``(thrust_N, tau_B or None, info, notes)``: the log's thrust and torque in newtons and newton metres.

    ``thrust_from``: ``"commands"``, ``"rotors"`` (measured rotor speeds, module
    :mod:`~vtol_impedance.logs.rotors`) or ``"auto"`` (rotors when the log has their speeds at 20 Hz or
    more). ``info["hover"]`` is the per-sample hover thrust used (normalised commands only).
    ``on_ground``: the vehicle stands on the ground (a bench test): no hover window is looked for and the
    thrust is not checked against the weight (the ground carries the rest).
    """
    from ..errors import choice, instance

    instance("flight", flight, FlightLog)
    mass = scalar("mass", mass, lo=0.0, lo_open=True)
    if hover_thrust is not None:
        scalar("hover_thrust", hover_thrust, lo=0.0, hi=1.0, lo_open=True)
    choice("thrust_from", thrust_from, THRUST_SOURCES)
    raw = flight.raw
    info: dict[str, Any] = {}
    notes: list[str] = []
    weight = mass * G
    if thrust_from not in THRUST_SOURCES:
        raise InputError(f"thrust source must be one of {', '.join(THRUST_SOURCES)}, got {thrust_from!r}")
    have_rotors = flight.rotor_speed is not None
    if thrust_from == "rotors" and not have_rotors:
        raise InputError("thrust from rotor speeds: the log has no rotor speeds (ESC telemetry, CSV rpm1..rpmN)")
    if thrust_from == "commands" and flight.thrust is None:
        raise InputError("thrust from the commands: the log has no thrust command, only rotor speeds")
    use_rotors = have_rotors and uses_rotor_speeds(raw, thrust_from, thrust_coefficient)
    if thrust_coefficient is not None and not use_rotors:
        raise InputError("a thrust coefficient converts rotor speeds; this estimate takes the thrust from the commands")
    geometry = rotor_geometry if rotor_geometry is not None else raw.rotor_geometry
    if on_ground and use_rotors and thrust_coefficient is None:
        raise InputError(
            "--on-ground with rotor speeds needs their thrust coefficient (--thrust-coefficient): a log on the "
            "ground has no flight to calibrate it on (or take the thrust from the commands: --thrust-from commands)"
        )
    if use_rotors:
        w = flight.rotor_speed
        sq = np.sum(w**2, -1)
        air = rotors.airborne_mask(sq)
        unit = raw.meta.get("rotor_speed_unit", "rpm")
        rotors.check_speed_unit(w, air, unit, raw.rotor_speed.source)
        cmd_N = None
        if thrust_coefficient is None and hover_segment is None and flight.thrust is not None:
            cmd_info: dict[str, Any] = {}
            cmd_notes: list[str] = []
            try:  # the commands' own calibration (newtons, or the hover map), to transfer to the rotors
                cmd_N, _ = _thrust_from_commands(flight, mass, hover_thrust, None, cmd_info, cmd_notes)
                # what that calibration rests on (a hover thrust fitted on hover windows absorbs a steady vertical
                # force) and its uncertainty carry over to the rotors matched to it
                notes.extend(f"the commands' calibration: {n}" if not n.startswith("WARNING") else n for n in cmd_notes)
                if "hover_thrust" in cmd_info:
                    info["hover_thrust"] = cmd_info["hover_thrust"]
            except InputError as exc:
                cmd_N = None
                notes.append(
                    f"WARNING: the thrust commands could not calibrate the rotor speeds ({exc}): the thrust "
                    "coefficient is fitted on the vertical balance instead, which absorbs a steady vertical "
                    "force such as a payload's weight (fix the commands, or give --thrust-coefficient)"
                )
        if thrust_coefficient is not None:
            k_T = float(scalar("thrust coefficient", thrust_coefficient, lo=0.0, lo_open=True))
            src = "given"
        elif cmd_N is not None:
            k_T, res = rotors.match_thrust_coefficient(sq, cmd_N, air, flight.rate_hz)
            src = (
                f"matched to the commanded thrust over the {int(air.sum())} airborne samples (0.5 s averages, "
                f"rms difference {res:.3g} N)"
            )
            if res > rotors.MAX_FIT_RESIDUAL * weight:
                raise InputError(
                    f"the rotor speeds do not follow the commanded thrust ({res:.3g} N RMS apart on a {weight:.3g} N "
                    "vehicle): wrong columns or rotor order? give --thrust-coefficient, or --thrust-from commands"
                )
        else:
            sel = air if hover_segment is None else _segment("hover segment", hover_segment, flight.t, 0.5)
            why = _stationary_ground(flight, sel, sq)
            if why and (hover_segment is not None or "never" in why):
                raise InputError(f"cannot fit the thrust coefficient: {why}")
            k_T, res = rotors.fit_thrust_coefficient(flight.t, flight.v_W, flight.eta, sq, mass, sel)
            where = (
                f"the hover segment {hover_segment[0]:g}-{hover_segment[1]:g} s"
                if hover_segment is not None
                else f"the {int(sel.sum())} airborne samples"
            )
            if res > rotors.MAX_FIT_RESIDUAL * weight:
                raise InputError(
                    f"the thrust-coefficient fit on {where} leaves {res:.3g} N RMS (0.5 s averages, after a vertical "
                    f"drag term) on a {weight:.3g} N vehicle: the "
                    "rotor speeds do not follow the vertical balance (wrong columns? give --thrust-coefficient)"
                )
            src = (
                f"fitted on {where} (vertical balance with a drag term, rms residual of 0.5 s averages {res:.3g} N; "
                "it absorbs the mean vertical "
                "external force there)"
            )
        thrust, tau_rotors = rotors.rotor_wrench(w, k_T, geometry)
        info["thrust"] = f"rotor speeds ({raw.rotor_speed.source}) x k_T = {k_T:.4g} N/(rad/s)^2, {src}"
        info["thrust_coefficient"] = k_T
        notes.append(f"thrust from the rotor speeds: k_T = {k_T:.4g} N/(rad/s)^2 ({src})")
        fixes = "the mass, the thrust coefficient and the rotor-speed unit (--rotor-speed-unit)"
        if tau_rotors is None:
            notes.append("no rotor geometry (give --vehicle): the moment comes from the torque commands, if any")
    else:
        tau_rotors = None
        if flight.thrust is None:
            raise InputError("the log has no thrust command")
        if have_rotors:
            notes.append(
                "the log has rotor speeds but the thrust is taken from the commands "
                + ("(--thrust-from commands)" if thrust_from == "commands" else "(rotor speeds below 20 Hz)")
            )
        thrust, fixes = _thrust_from_commands(flight, mass, hover_thrust, hover_segment, info, notes, on_ground)
    if on_ground:
        r, warn = weight_ratio(flight, thrust, mass), None
        notes.append("--on-ground: the thrust is not checked against the weight (the ground carries the rest)")
    else:
        r, warn = check_weight(flight, thrust, mass, info["thrust"], fixes)
    info["weight_ratio"] = None if not np.isfinite(r) else round(1 / r, 4)
    if warn:
        notes.append(f"WARNING: {warn}")
    if tau_rotors is not None:
        if torque_scale is not None:  # not ignored in silence
            raise InputError(
                "a torque scale converts torque commands; this estimate takes the moment from the rotor speeds "
                "through the rotor geometry (leave the scale out, or take the thrust and torque from the commands: "
                "--thrust-from commands)"
            )
        info["torque"] = "rotor speeds x k_T through the rotor geometry"
        return thrust, tau_rotors, info, notes
    tau = _torque_from_commands(flight, raw, info, notes, torque_scale, weight)
    return thrust, tau, info, notes


def uses_rotor_speeds(raw: Any, thrust_from: str, thrust_coefficient: float | None = None) -> bool:
    """Whether the thrust comes from the log's rotor speeds: ``"rotors"``, or ``"auto"`` with a thrust
    coefficient given, rotor speeds at 20 Hz or more, or no thrust command at all."""
    if raw.rotor_speed is None or thrust_from == "commands":
        return False
    return (
        thrust_from == "rotors"
        or thrust_coefficient is not None
        or raw.thrust is None
        or 1.0 / _period(raw.rotor_speed.t) >= 20.0
    )


def _period(t: np.ndarray) -> float:
    d = np.diff(t)
    d = d[d > 0]
    return float(np.median(d)) if len(d) else float("inf")


def _thrust_from_commands(
    flight: FlightLog,
    mass: float,
    hover_thrust: float | None,
    hover_segment: Any,
    info: dict,
    notes: list[str],
    on_ground: bool = False,
) -> tuple[np.ndarray, str]:
    raw = flight.raw
    weight = mass * G
    u = flight.thrust
    if raw.thrust_unit == "N" and (hover_thrust is not None or hover_segment is not None):
        raise InputError("a hover thrust converts normalised thrust; this log's thrust is already in newtons")
    if raw.thrust_unit == "N":
        if np.max(u) < 0 and np.min(u) < -0.2 * weight:
            raise InputError(
                f"thrust declared in newtons is negative (down to {np.min(u):.3g} N): is it the z component of a "
                "thrust vector in FRD (PX4's thrust setpoint z is minus the thrust)? negate the column"
            )
        if np.max(u) < 0.2 * weight:
            raise InputError(
                f"thrust declared in newtons peaks at {np.max(u):.3g} N, under 20 % of the weight "
                f"m g = {weight:.3g} N: "
                "it looks normalised; declare it as normalised thrust (CSV column thrust_norm) with a hover thrust"
            )
        info["thrust"] = "newtons, as logged"
        return u, "the mass and the thrust column's unit"
    if np.max(u) > 1.5:
        raise InputError(
            f"thrust declared normalised reaches {np.max(u):.3g}, above 1: it looks like newtons (CSV column thrust_n)"
            + (" or a percentage (divide by 100)" if np.max(u) <= 100 else "")
        )
    if np.max(u) <= 0:
        raise InputError(
            f"normalised thrust is never positive (at most {np.max(u):.3g}): is it PX4's thrust setpoint z (minus the "
            "thrust)? negate it"
        )
    h, src, summ = _hover_for(flight, mass, hover_thrust, hover_segment, on_ground)
    learning = _hover_learning(flight.t, h, src)
    if learning:
        notes.append("WARNING: " + learning)
    info["hover"] = h
    info["hover_thrust"] = summ
    per = "" if summ["min"] == summ["max"] else f", {summ['min']:.4f}..{summ['max']:.4f} over the log"
    info["thrust"] = f"normalised x m g / hover thrust ({src}; median {summ['median']:.4f}{per})"
    notes.append(f"hover thrust {summ['median']:.4f}{per}: {src}")
    notes.extend(describe_hover_windows(summ))
    if summ["sd"] is not None and summ["sd_rel"] > HOVER_SPREAD_WARN:
        notes.append(
            f"WARNING: the hover windows' fits spread by {100 * summ['sd_rel']:.1f} % (one standard deviation): the "
            f"vertical force is uncertain by about {weight * summ['sd_rel']:.3g} N at hover (column "
            "fz_W_N_hover_sd). Give --hover-thrust, or --hover-segment on a hover you know was calm"
        )
    if summ.get("windy"):
        notes.append(
            "WARNING: the log has no level hover: the hover thrust was fitted on hovers tilted by a steady wind, "
            "where a rotor's thrust per command grows (translational lift): it may read a few per cent low, and "
            "the vertical force by that share of the weight. Give --hover-thrust or --hover-segment on a calm "
            "hover if the log has one"
        )
    if "second_group" in summ:
        g = summ["second_group"]
        r = g["hover"] / summ["median"]
        lo, hi = sorted((weight * abs(r - 1), weight * abs(1 / r - 1)))  # whichever group flew the bare vehicle
        notes.append(
            f"WARNING: {g['n']} of {g['of']} hover windows agree on another hover thrust, {g['hover']:.4f} "
            f"({100 * (g['hover'] / summ['median'] - 1):+.1f} % from the {summ['median']:.4f} used): a payload "
            f"picked up or dropped, or a battery changed, between them? The vertical force is then off by about "
            f"{lo:.2g}-{hi:.2g} N on one side of the change. Give --hover-segment on a hover you trust (or --hover-thrust)"
        )
    if "ignored" in summ:
        notes.append(f"not used: {summ['ignored']} (never tuned?)")
    wf = summ.get("windows_fit")
    if wf is not None:
        d = summ["median"] / wf["hover"] - 1
        tilted = (
            f" (on hovers tilted up to {HOVER_WINDY_TILT_DEG:g} deg by a steady wind: translational lift may make it "
            "a few per cent low)" if wf.get("windy") else ""
        )
        line = (
            f"the hover windows fit a hover thrust of {wf['hover']:.4g}{tilted} (spread {wf['sd']:.2g}); the parameter "
            f"used is {100 * d:+.1f} % from it"
        )
        if abs(d) > HOVER_PARAMETER_SHARE:
            line = (  # a note: someone set the parameter (a default is not used when there are windows)
                f"{line}: either the parameter is wrong (set for another battery or vehicle), or every "
                f"hover carried a steady vertical force of about {weight * -d / (1 + d):+.3g} N (NED, a payload), "
                f"which the estimate shows. If it carried none: --hover-thrust {wf['hover']:.4g}"
            )
        notes.append(line)
    thrust = u * weight / h
    if summ["unchecked"]:
        if not on_ground:
            r = weight_ratio(flight, thrust, mass)
            if np.isfinite(r) and not WEIGHT_WARN[0] <= r <= WEIGHT_WARN[1]:
                raise InputError(
                    f"the log has no hover window to fit the hover thrust on, and its parameter ({src}) "
                    f"= {summ['median']:.4g} gives {1 / r:.3g} times the weight in flight (the whole flight's "
                    f"vertical balance suggests about {summ['median'] / r:.3g}). Give the hover thrust "
                    "(--hover-thrust) or a hover to fit it on (--hover-segment T0,T1)"
                )
        notes.append(
            f"WARNING: the hover thrust {summ['median']:.4g} is the log's parameter at its firmware default, not "
            "checked on a hover ("
            + ("--on-ground" if on_ground else "the log has no hover window")
            + "): the vertical force carries its error (each 1 % of error is 1 % of the thrust); give "
            "--hover-thrust or --hover-segment if you know better"
        )
    return thrust, "the mass and the hover thrust (--hover-thrust, --hover-segment)"


def _torque_from_commands(
    flight: FlightLog, raw: Any, info: dict, notes: list[str], torque_scale: Any, weight: float
) -> np.ndarray | None:
    if raw.torque_unit == "N m" and torque_scale is not None:
        raise InputError("a torque scale converts normalised torque; this log's torques are already in N m")
    if flight.tau_B is None:
        return None
    if raw.torque_unit == "N m":
        info["torque"] = "N m, as logged"
        return flight.tau_B
    if torque_scale is not None:
        k = np.broadcast_to(positive("torque scale", torque_scale), (3,)).astype(float)
        info["torque"] = f"normalised x given scale {k.tolist()} N m"
        return flight.tau_B * k
    if raw.torque_per_unit is not None and "hover" in info:
        c_t = weight / (raw.n_rotors * info["hover"])
        k = raw.torque_per_unit[None, :] * c_t[:, None]
        info["torque"] = f"normalised x {np.round(np.median(k, 0), 4).tolist()} N m from the log's rotor geometry"
        return flight.tau_B * k
    notes.append(
        "torque commands are normalised and the log has no rotor geometry (CA_ROTOR* parameters): "
        "the moment estimate is skipped (give --torque-scale to convert them, or use rotor speeds with --vehicle)"
    )
    return None


def _body_moment(tau_eta: np.ndarray, eta: np.ndarray) -> np.ndarray:
    """``tau_B = Q^{-T} tau_eta`` per sample, NaN where the pitch is at the ZYX singularity (+-90 deg within
    :data:`~vtol_impedance.conventions.SINGULARITY_COS_EPS`): a flip passes through it, and the body moment
    has no Euler-coordinate source there (the Euler-coordinate moment is kept)."""
    regular = np.abs(np.cos(eta[:, 1])) >= SINGULARITY_COS_EPS
    out = np.full(np.shape(tau_eta), np.nan)
    out[regular] = body_moment_from_euler(tau_eta[regular], eta[regular])
    return out


def peak_impulse_response(des: Any) -> np.ndarray:
    """``(6,)``: the largest value of each channel's impulse response (1/s), ``wn / e`` for the paper's G."""
    out = np.zeros(6)
    for i in range(6):
        x = des.Bd[i].copy()
        best, k = 0.0, 0
        while k < 100000:
            y = float(des.C[i] @ x) / des.Ts
            best = max(best, y)
            if k > 10 and y < 1e-3 * best:
                break
            x = des.Ad[i] @ x
            k += 1
        out[i] = best
    return out


def _gap_bounds(flight: FlightLog, thrust: np.ndarray, tau: np.ndarray | None, des: Any) -> None:
    """Add to each bridged gap the bound of the module :mod:`~vtol_impedance.logs.timeseries` docstring:
    ``g_max (E + |dx| T / 4 + dW T / 2)``. The bridge interpolates the thrust ``u`` linearly and the thrust
    axis ``r = R e3`` (nearly) linearly, so the impulse of ``x = u r`` it misses is ``E <= T^3 / 12
    (max|u''| + max|u| max|r''|)``, the curvatures those of quadratics fitted to the second before and the
    second after the gap (the larger); ``dx`` is ``x`` after the gap minus before it. ``bound_f_N`` is the
    bound for a steady wrench, ``bound_f_per_N_change`` what each newton of change inside the gap adds. The
    moment channel likewise with the body torque."""
    bridged = [g for g in flight.gaps if g["action"] == "bridged"]
    if not bridged:
        return
    gmax = peak_impulse_response(des)
    from ..model.kinematics import rotation_zyx

    r = rotation_zyx(flight.eta)[:, :, 2]
    x = thrust[:, None] * r

    def curvature(sig: np.ndarray, sel: np.ndarray) -> float:
        """|second derivative| of a quadratic fitted to the selected samples (robust to noise and steps)."""
        if sel.sum() < 5:
            return 0.0
        tt = flight.t[sel] - flight.t[sel].mean()
        c = np.polyfit(tt, sig.reshape(len(sig), -1)[sel], 2)
        return float(np.linalg.norm(2.0 * c[0]))

    for g in bridged:
        T = g["length_s"]
        sides = [
            (flight.t > g["t0_s"] - 1.0) & (flight.t <= g["t0_s"]),
            (flight.t >= g["t1_s"]) & (flight.t < g["t1_s"] + 1.0),
        ]
        cu = max(curvature(thrust, s) for s in sides)
        cr = max(curvature(r, s) for s in sides)
        near = sides[0] | sides[1]
        if not near.any():
            continue
        E = T**3 / 12.0 * (cu + float(np.max(np.abs(thrust[near]))) * cr)
        k0 = max(int(np.searchsorted(flight.t, g["t0_s"], side="right")) - 1, 0)
        k1 = min(int(np.searchsorted(flight.t, g["t1_s"], side="left")), len(flight.t) - 1)
        dx = float(np.linalg.norm(x[k1] - x[k0]))
        g["bound_f_N"] = float(gmax[:3].max() * (E + dx * T / 4.0))
        g["bound_f_per_N_change"] = float(gmax[:3].max() * T / 2.0)
        if tau is not None:
            ct = max(curvature(tau, s) for s in sides)
            g["bound_tau_Nm"] = float(gmax[3:].max() * T**3 / 12.0 * ct)


#: A stretch of at least this long, s, with the thrust under :data:`GROUND_THRUST_SHARE` of the weight is the
#: vehicle on the ground (before take-off, landed, disarmed between flights).
GROUND_MIN_S = 1.0
GROUND_THRUST_SHARE = 0.2


def _grounded(flight: FlightLog, thrust: np.ndarray, mass: float, info: dict[str, Any], notes: list[str]) -> None:
    """Name the stretches on the ground (:data:`GROUND_THRUST_SHARE`) in ``info["ground_s"]`` and a note: the
    estimate there is the ground's reaction (the thrust carries nothing), which a log of two flights with a
    pause between showed as an external force of -11.8 N and a headline mean of -6.2 N (the summary's
    statistics now leave them out)."""
    low = np.asarray(thrust, float) < GROUND_THRUST_SHARE * mass * G
    edges = np.flatnonzero(np.diff(np.concatenate([[0], low.astype(np.int8), [0]])))
    spans = [(flight.t[a], flight.t[b - 1]) for a, b in zip(edges[::2], edges[1::2], strict=True)
             if flight.t[b - 1] - flight.t[a] >= GROUND_MIN_S]  # fmt: skip
    if not spans:
        return
    info["ground_s"] = [[float(a), float(b)] for a, b in spans]
    where = ", ".join(f"{a:.1f}-{b:.1f} s" for a, b in spans[:4]) + (" ..." if len(spans) > 4 else "")
    notes.append(
        f"the thrust is under {100 * GROUND_THRUST_SHARE:.0f} % of the weight at {where} (on the ground: before "
        "take-off, landed or disarmed): the estimate there is the ground's reaction, not an external force; "
        "the summary's statistics leave these stretches out (the series keeps them)"
    )


def airborne(est: LogEstimate) -> np.ndarray:
    """The samples of ``est`` outside its ground stretches (``info["ground_s"]``): a boolean mask."""
    keep = np.ones(len(est.t), bool)
    for a, b in est.info.get("ground_s", []):
        keep &= ~((est.t >= a) & (est.t <= b))
    return keep


def _settles_within(flight: FlightLog, params: EstimatorParams, notes: list[str]) -> None:
    """A WARNING when the estimator's settling (5 time constants of its slowest pole) is longer than every
    stretch of the log it runs on without a restart: the estimate never reaches the force, and a reader
    would take its near-zero for no force (``--wn 0.01`` on a 20 s log: 0.005 N against a true 1 N)."""
    settle = params.settling_s()
    starts = np.union1d([0], np.flatnonzero(flight.restart))
    ends = np.append(starts[1:], len(flight.t)) - 1
    longest = float(np.max(flight.t[ends] - flight.t[starts]))
    if settle > longest:
        notes.append(
            f"WARNING: the estimator settles in {settle:.3g} s (5 time constants of its slowest pole), longer than "
            f"the longest stretch of the log it runs on without a restart ({longest:.3g} s): the estimate never "
            "reaches the force and reads smaller than it is, near zero for a much slower estimator; raise --wn"
        )


def estimate(
    flight: FlightLog,
    mass: float,
    inertia: Any = None,
    params: EstimatorParams | None = None,
    *,
    zero_phase_too: bool = False,
    quiet_segment: Any = None,
    remove_bias: bool = False,
    hover_thrust: float | None = None,
    hover_segment: Any = None,
    torque_scale: Any = None,
    backend: str = "compiled",
    thrust_from: str = "auto",
    thrust_coefficient: float | None = None,
    rotor_geometry: tuple[np.ndarray, np.ndarray] | None = None,
    on_ground: bool = False,
) -> LogEstimate:
    """Estimate the external wrench along a resampled log (see the module docstring). ``inertia``
    ``None``: the force only. ``on_ground``: a log that never leaves the ground (a bench test); the
    force is then the ground reaction plus the external force (:func:`commands_in_si`)."""
    from ..errors import choice, instance

    instance("flight", flight, FlightLog)
    if params is not None:
        instance("params", params, EstimatorParams)
    if hover_thrust is not None:
        scalar("hover_thrust", hover_thrust, lo=0.0, hi=1.0, lo_open=True)
    choice("backend", backend, BACKENDS)
    mass = float(scalar("mass", mass, lo=0.0, lo_open=True))
    I_B = None if inertia is None else check_inertia(inertia)
    if backend not in BACKENDS:
        raise InputError(f"backend must be one of {', '.join(BACKENDS)}, got {backend!r}")
    params = params or EstimatorParams()
    thrust, tau, info, notes = commands_in_si(
        flight, mass, hover_thrust, hover_segment, torque_scale, thrust_from=thrust_from,
        thrust_coefficient=thrust_coefficient, rotor_geometry=rotor_geometry, on_ground=on_ground,
    )  # fmt: skip
    if info.get("thrust_coefficient") is not None and params.rotor_tau > 0:
        notes.append(f"rotor_tau {params.rotor_tau:g} s ignored: measured rotor speeds carry no command lag")
        d = params.to_dict()
        d.update(rotor_tau=0.0, poles=params.poles)
        params = EstimatorParams(**d)
    hover = info.pop("hover", None)
    des = design(params, flight.Ts)
    if I_B is None:
        if tau is not None:
            notes.append("no inertia given: the force only (the moment needs --inertia or --vehicle)")
        tau = None
    I_use = np.eye(3) * 1e-2 if I_B is None else I_B  # the force channel does not use the inertia
    tau_in = np.zeros_like(flight.v_W) if tau is None else tau
    w = None
    if backend == "numpy" or zero_phase_too:
        w = momentum_residual(
            flight.v_W, flight.eta, flight.eta_dot, thrust, tau_in, mass, I_use, flight.Ts, des, flight.restart
        )
    if backend == "compiled":
        from ..compiled.estimator import run_log

        out = run_log(des, mass, I_use, flight.v_W, flight.eta, flight.eta_dot, thrust, tau_in, flight.restart)
        f_W, tau_eta, tau_B = out[:, :3], out[:, 3:6], _body_moment(out[:, 3:6], flight.eta)
    else:
        r = causal(des, w, flight.restart)
        f_W, tau_eta = r[:, :3], r[:, 3:]
        tau_B = _body_moment(tau_eta, flight.eta)
    f_zp = tau_zp = None
    if zero_phase_too:
        r = zero_phase(des, w, flight.restart)
        f_zp, tau_zp = r[:, :3], _body_moment(r[:, 3:], flight.eta)
    if tau is None:
        tau_eta = tau_B = tau_zp = None
    _gap_bounds(flight, thrust, tau, des)
    _settles_within(flight, params, notes)
    bias = None
    if quiet_segment is not None:
        sel = _segment("quiet segment", quiet_segment, flight.t, 0.5)
        a, b = float(quiet_segment[0]), float(quiet_segment[1])
        if a < flight.t[0] or b > flight.t[-1]:
            notes.append(
                f"WARNING: the quiet segment {a:g}-{b:g} s reaches outside the log "
                f"({flight.t[0]:.2f}-{flight.t[-1]:.2f} s): the bias is measured on the part inside"
            )
        settle = params.settling_s()
        starts = flight.t[flight.restart]
        if np.any((starts <= flight.t[sel][-1]) & (flight.t[sel][0] < starts + settle)):
            notes.append(
                f"WARNING: the quiet segment starts within {settle:.2f} s (5 time constants of the estimator) of the "
                "start of the log or of a restart: the bias includes the estimator's start-up transient"
            )
        if flight.bridged is not None and flight.bridged[sel].any():
            notes.append("WARNING: the quiet segment contains bridged dropouts: the bias there is less certain")
        bias = {"segment_s": [a, b], "f_W_N": f_W[sel].mean(0).tolist()}
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
    fz_sd = None
    sd_rel = (info.get("hover_thrust") or {}).get("sd_rel")
    if sd_rel is not None:
        fz_sd = np.abs(thrust * np.cos(flight.eta[:, 0]) * np.cos(flight.eta[:, 1])) * sd_rel
        info["hover_thrust"]["fz_sd_at_hover_N"] = mass * G * sd_rel
    if not on_ground:
        _grounded(flight, thrust, mass, info, notes)
    if on_ground:
        info["on_ground"] = True
        info["force_meaning"] = "ground reaction plus external force (--on-ground)"
        if np.max(np.linalg.norm(flight.v_W, axis=-1)) >= 0.2 or np.max(np.abs(flight.omega_B)) >= 0.05:
            notes.append(
                "WARNING: --on-ground, but the vehicle moves in this log (speed above 0.2 m/s or rates above "
                "0.05 rad/s): the force is the ground reaction only while it stands on the ground"
            )
    info.update(
        mass_kg=mass,
        inertia_kg_m2=None if I_B is None else I_B.tolist(),
        estimator=params.to_dict(),
        rate_hz=flight.rate_hz,
        samples=len(flight.t),
        segments=int(flight.restart.sum()),
        span_s=[float(flight.t[0]), float(flight.t[-1])],
        zero_phase=bool(zero_phase_too),
        backend=backend,
        max_gap_s=flight.max_gap_s,
        max_gap=flight.max_gap_source,
        gaps=flight.gaps,
        **{k: v for k, v in flight.raw.meta.items()},
    )
    all_notes = flight.notes + notes
    warnings = [n[len("WARNING: ") :] for n in all_notes if n.startswith("WARNING: ")]
    all_notes = [n for n in all_notes if not n.startswith("WARNING: ")]
    return LogEstimate(
        flight.t, f_W, tau_eta, tau_B, f_zp, tau_zp, thrust, flight, bias, info, all_notes, hover, warnings, fz_sd
    )


__all__ = [
    "LogEstimate",
    "airborne",
    "ROTOR_SPEED_UNITS",
    "THRUST_SOURCES",
    "check_inertia",
    "commands_in_si",
    "describe_hover_windows",
    "estimate",
    "fit_hover_thrust",
    "fit_hover_windows",
    "hover_windows",
    "peak_impulse_response",
]
