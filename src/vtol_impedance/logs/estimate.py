"""The momentum-based estimator, eqs. (6)-(13), run on a flight log.

Inputs are what the estimator needs and nothing else: world velocity, attitude, body rates, the thrust
and torque (commands, or the rotors' measured speeds), and the nominal mass and inertia (never the
position; the inertia only for the moment: the force channel of eq. (8) does not contain it). Commands
are converted to SI units here: normalised thrust by the hover map ``u_N = m g * u / u_hover`` with
``u_hover`` given, fitted on a hover segment, or from the log: an estimate logged over the flight
(PX4's ``hover_thrust_estimate``, ArduPilot's ``CTUN.ThH``, a CSV ``hover_thrust`` column), used **per
sample** (it follows the battery's sag), else a parameter (``MPC_THR_HOVER``, ``MOT_THST_HOVER``);
normalised torque by the rotor geometry (see :mod:`vtol_impedance.logs.ulog`). Measured rotor speeds
give thrust and torque without the rotors' lag (:mod:`vtol_impedance.logs.rotors`).

Before the estimate the converted thrust must carry the weight: over the airborne samples the vertical
balance ``m (g - a_z) = r u cos(phi) cos(theta)`` gives the ratio ``r``; outside [0.5, 2] the log is
refused (a wrong mass, hover thrust, thrust unit or rotor-speed unit), outside [0.8, 1.25] a warning
names the mean vertical external force it implies.

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
#: command noise does not count) is refused: not a hover.
MAX_HOVER_RESIDUAL = 0.03


@dataclass
class LogEstimate:
    """Estimated external wrench on the log's grid: force in world NED (N), moment in Euler coordinates
    and in body FRD (N m; ``None`` when the log gives no usable torque or no inertia). ``*_zp``:
    zero-phase. ``hover`` is the normalised hover thrust used at each sample (``None`` when the thrust
    was in newtons or came from the rotors)."""

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


def fit_hover_thrust(flight: FlightLog, mass: float, segment: Any) -> tuple[float, float]:
    """Normalised hover thrust from a hover segment by least squares on the vertical balance
    ``k u cos(phi) cos(theta) = m (g - a_z)`` (NED, ``a_z`` from the velocity); returns ``(m g / k, rms
    residual in N)``. Refuses a segment on the ground and one the balance does not fit (an RMS residual of
    0.25 s averages above 3 % of the weight: a take-off with the ground still carrying part of the weight,
    a landing, a manoeuvre in ground effect)."""
    from ..errors import instance

    instance("flight", flight, FlightLog)
    mass = scalar("mass", mass, lo=0.0, lo_open=True)
    sel = _segment("hover segment", segment, flight.t, 0.5)
    if flight.thrust is None:
        raise InputError("the log has no thrust command to fit a hover thrust on")
    why = _stationary_ground(flight, sel, flight.thrust)
    if why:
        raise InputError(f"cannot fit a hover thrust on {segment[0]:g}-{segment[1]:g} s: {why}")
    a_z = np.gradient(flight.v_W[:, 2], flight.t)[sel]
    uc = flight.thrust[sel] * np.cos(flight.eta[sel, 0]) * np.cos(flight.eta[sel, 1])
    rhs = mass * (G - a_z)
    k = float(np.dot(uc, rhs) / max(np.dot(uc, uc), 1e-300))
    if not k > 0:
        raise InputError("the hover segment has no positive thrust: cannot fit a hover thrust on it")
    res = float(np.sqrt(np.mean((k * uc - rhs) ** 2)))
    n = max(1, int(round(0.25 * flight.rate_hz)))
    kern = np.ones(n) / n
    res_avg = float(np.sqrt(np.mean(np.convolve(k * uc - rhs, kern, "valid") ** 2))) if sel.sum() > n else res
    if res_avg > MAX_HOVER_RESIDUAL * mass * G:
        raise InputError(
            f"the hover fit on {segment[0]:g}-{segment[1]:g} s leaves {res_avg:.3g} N RMS on a {mass * G:.3g} N "
            f"vehicle ({100 * res_avg / (mass * G):.1f} % of its weight; a hover leaves about 1 %): the segment is "
            "not a hover (a take-off with the ground still carrying part of the weight, a landing, a manoeuvre?); "
            "choose a steady hover"
        )
    return mass * G / k, res


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
            "on a stand, landed)"
        )
    if not WEIGHT_WARN[0] <= r <= WEIGHT_WARN[1]:
        return r, (
            f"the thrust ({what}) gives {1 / r:.3g} times the weight m g = {mass * G:.3g} N in flight: the estimate "
            f"will show a mean vertical force of about {mass * G * (1 / r - 1):+.3g} N (NED, + down). If the vehicle "
            f"carried nothing, check {fixes}"
        )
    return r, None


def _hover_for(
    flight: FlightLog, mass: float, hover_thrust: float | None, hover_segment: Any
) -> tuple[np.ndarray, str, dict[str, Any]]:
    """The normalised hover thrust per sample, where it came from, and its summary."""
    raw = flight.raw
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
    elif raw.hover_thrust is not None:
        arr = np.full(len(flight.t), float(raw.hover_thrust))
        src = raw.hover_source
    else:
        raise InputError(
            "normalised thrust needs a hover thrust to become newtons: give it (--hover-thrust), a hover "
            "segment to fit it on (--hover-segment T0,T1), or a log with a hover thrust estimate or parameter"
        )
    lo, hi = float(np.min(arr)), float(np.max(arr))
    if not (0.02 < lo and hi < 1.0):
        raise InputError(f"hover thrust {lo:.4g}..{hi:.4g} is outside (0.02, 1): check the hover segment or the value")
    summ = {"median": float(np.median(arr)), "min": lo, "max": hi, "source": src}
    return arr, src, summ


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
) -> tuple[np.ndarray, np.ndarray | None, dict[str, Any], list[str]]:
    """``(thrust_N, tau_B or None, info, notes)``: the log's thrust and torque in newtons and newton metres.

    ``thrust_from``: ``"commands"``, ``"rotors"`` (measured rotor speeds, module
    :mod:`~vtol_impedance.logs.rotors`) or ``"auto"`` (rotors when the log has their speeds at 20 Hz or
    more). ``info["hover"]`` is the per-sample hover thrust used (normalised commands only).
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
    if use_rotors:
        w = flight.rotor_speed
        sq = np.sum(w**2, -1)
        air = rotors.airborne_mask(sq)
        unit = raw.meta.get("rotor_speed_unit", "rpm")
        rotors.check_speed_unit(w, air, unit, raw.rotor_speed.source)
        cmd_N = None
        if thrust_coefficient is None and hover_segment is None and flight.thrust is not None:
            try:  # the commands' own calibration (newtons, or the hover map), to transfer to the rotors
                cmd_N, _ = _thrust_from_commands(flight, mass, hover_thrust, None, {}, [])
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
                    f"the thrust-coefficient fit on {where} leaves {res:.3g} N RMS on a {weight:.3g} N vehicle: the "
                    "rotor speeds do not follow the vertical balance (wrong columns? give --thrust-coefficient)"
                )
            src = (
                f"fitted on {where} (vertical balance, rms residual {res:.3g} N; it absorbs the mean vertical "
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
        thrust, fixes = _thrust_from_commands(flight, mass, hover_thrust, hover_segment, info, notes)
    r, warn = check_weight(flight, thrust, mass, info["thrust"], fixes)
    info["weight_ratio"] = None if not np.isfinite(r) else round(1 / r, 4)
    if warn:
        notes.append(f"WARNING: {warn}")
    if tau_rotors is not None:
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
    flight: FlightLog, mass: float, hover_thrust: float | None, hover_segment: Any, info: dict, notes: list[str]
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
    h, src, summ = _hover_for(flight, mass, hover_thrust, hover_segment)
    learning = _hover_learning(flight.t, h, src)
    if learning:
        notes.append("WARNING: " + learning)
    info["hover"] = h
    info["hover_thrust"] = summ
    per = "" if summ["min"] == summ["max"] else f", {summ['min']:.4f}..{summ['max']:.4f} over the log"
    info["thrust"] = f"normalised x m g / hover thrust ({src}; median {summ['median']:.4f}{per})"
    notes.append(f"hover thrust {summ['median']:.4f}{per}: {src}")
    return u * weight / h, "the mass and the hover thrust (--hover-thrust, --hover-segment)"


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
) -> LogEstimate:
    """Estimate the external wrench along a resampled log (see the module docstring). ``inertia``
    ``None``: the force only."""
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
        thrust_coefficient=thrust_coefficient, rotor_geometry=rotor_geometry,
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
    _gap_bounds(flight, thrust, tau, des)
    bias = None
    if quiet_segment is not None:
        sel = _segment("quiet segment", quiet_segment, flight.t, 0.5)
        a, b = float(quiet_segment[0]), float(quiet_segment[1])
        if a < flight.t[0] or b > flight.t[-1]:
            notes.append(
                f"WARNING: the quiet segment {a:g}-{b:g} s reaches outside the log "
                f"({flight.t[0]:.2f}-{flight.t[-1]:.2f} s): the bias is measured on the part inside"
            )
        settle = 5.0 / float(np.min(np.abs(params.channel_poles())))
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
        flight.t, f_W, tau_eta, tau_B, f_zp, tau_zp, thrust, flight, bias, info, all_notes, hover, warnings
    )


__all__ = [
    "LogEstimate",
    "ROTOR_SPEED_UNITS",
    "THRUST_SOURCES",
    "check_inertia",
    "commands_in_si",
    "estimate",
    "fit_hover_thrust",
    "peak_impulse_response",
]
