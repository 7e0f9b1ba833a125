"""Hierarchical impedance controller, eqs. (14)-(20) of Ruggiero et al. (2014), with the estimate fed forward.

One step at the control rate:

1. estimator update, eqs. (6)-(13) -> ``f_hat_ext_W``, ``tau_hat_ext_eta``;
2. position impedance (18a): ``mu = p_ddot_d - (Dp e_p_dot + Kp e_p [+ Ki int e_p]) / m``;
3. compensation: ``mu_bar = mu - f_hat_ext_W / m`` (PD+C only);
4. thrust and desired roll/pitch from eq. (16) in NED (:mod:`.thrust`), desired yaw from the planner;
5. second-order filter on ``(phi_d, theta_d)`` for ``eta_d``, ``eta_d_dot``, ``eta_d_ddot``;
6. attitude impedance (18b): ``tau_bar = eta_ddot_d - M^{-1}((Do + C) e_eta_dot + Ko e_eta)``;
7. torque (14): ``tau_B = I_B Q tau_bar + Q^{-T}(C eta_dot - tau_hat_ext_eta)`` (no ``tau_hat`` for PD/PID);
8. rotor forces by inverting eq. (4) within the rotor limits (:func:`~vtol_impedance.model.mixer.allocate`).

Baselines of Sec. VI.B: ``"pd"`` (no compensation), ``"pid"`` (PD plus ``Ki int e_p`` with anti-windup:
integration freezes while the allocation or the tilt limit is active, and ``|Ki int e_p|`` is bounded
per axis by ``integral_limit``), ``"pdc"`` (the paper's PD + compensation). ``"comply"`` is PD+C on the
axes that reject and, on the axes that comply (``Reference.comply``), the programmable impedance
``M_d e'' + D_d e' + K_d e = f_ext`` of step 2 (see :class:`~vtol_impedance.control.gains.Impedance`).

Every function takes arrays with leading batch dimensions; several controllers (for example the three
variants) run as one batch.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np

from ..conventions import G
from ..errors import InputError, instance, scalar
from ..estimator.momentum import (
    EstimatorDesign,
    EstimatorParams,
    EstimatorState,
    design,
    estimator_step,
)
from ..estimator.momentum import initial_state as estimator_initial_state
from ..model.dynamics import coriolis_matrix_C, inertia_matrix_M, matvec, transpose
from ..model.kinematics import euler_rate_matrix_Q, wrap_angle
from ..model.mixer import THRUST_SHIFT_MAX, allocate
from ..model.vehicle import VehicleParams, distinct_vehicles, load_preset
from .attitude_filter import FilterDesign, FilterState, design_filter, filter_step
from .gains import Impedance, ImpedanceGains
from .signals import ControlOutput, Measurement, Reference, comply6
from .thrust import thrust_and_attitude

#: Bandwidth of the second-order filter on the desired roll and pitch in the paper's setup, rad/s (the
#: paper does not give it). Chosen by the measurement of ``examples/attitude_filter_bandwidth.py`` with the
#: paper's 8 rad/s attitude loop: below 20 rad/s the compensated loop lags (case B error x3.5 at 15 rad/s),
#: above 30 rad/s torque peaks grow and from 35 rad/s the loop closed through the estimate and the 20 ms
#: motion capture latency oscillates; 25 rad/s sits in the middle of that window. The scenarios' default
#: is designed with the attitude loop for each vehicle (:func:`vtol_impedance.robust.design`).
ATTITUDE_FILTER_WN = 25.0

#: The controller variants by name, with what each does: ``pd``, ``pid``, ``pdc`` (the paper's PD+C) and
#: ``comply`` (impedance, per axis reject or yield).
VARIANTS: dict[str, str] = {
    "pd": "PD (no compensation)",
    "pid": "PID (PD + integral of e_p)",
    "pdc": "PD+C (PD + compensation of the estimated wrench): rejects",
    "comply": "impedance: per axis, rejects like PD+C or yields with the set M_d, D_d, K_d (Reference.comply)",
}
#: How tables and figures name the variants.
DISPLAY_NAMES: dict[str, str] = {"pd": "PD", "pid": "PID", "pdc": "PD+C", "comply": "comply"}
#: Integral gain of the paper's PID baseline, Sec. VI.B.
PAPER_KI = 0.5


@dataclass(frozen=True, eq=False)
class ControllerParams:
    """Everything one controller needs; ``vehicle`` is the *nominal* model, never the true plant.

    ``reference_delay`` (s, default 0) is for whoever samples the reference from a trajectory (the
    simulator's loop, :func:`~vtol_impedance.sim.run_closed_loop`): the error of eq. (18a) compares the
    position and velocity measured ``d`` seconds ago with the reference *of that instant*, ``p_d(t - d)``,
    ``v_d(t - d)``, while the feed-forward ``p_ddot_d`` and the yaw are today's. With ``d`` the
    measurement's latency the loop no longer tracks a trajectory ``d`` late (``v d`` of error: 10 mm on
    the paper's circle at 0.5 m/s and 20 ms); the feedback, and so every margin, is unchanged. A user's
    loop does the same by giving :meth:`vtol_impedance.runtime.Controller.step` that reference."""

    vehicle: VehicleParams
    gains: ImpedanceGains
    variant: str = "pdc"
    estimator: EstimatorParams = field(default_factory=EstimatorParams)
    Ts: float = 0.01
    tilt_max: float = float(np.radians(35.0))
    min_lift_accel: float = 0.2 * G
    attitude_filter_wn: float = ATTITUDE_FILTER_WN
    attitude_filter_zeta: float = 1.0
    integral_limit: float = 3.0
    thrust_shift_max: float = THRUST_SHIFT_MAX
    impedance: Impedance | None = None  # what "comply" yields with; default: M = m, D = Dp, K = Kp
    reference_delay: float = 0.0  # s: the age of the measurement the reference's p_d, v_d are aligned to

    def __post_init__(self) -> None:
        if self.impedance is not None and not isinstance(self.impedance, Impedance):
            raise InputError(f"impedance must be an Impedance, got {type(self.impedance).__name__}")
        if not isinstance(self.variant, str) or self.variant not in VARIANTS:
            raise InputError(f"unknown controller variant {self.variant!r}; choose one of {sorted(VARIANTS)}")
        for name, want in (("vehicle", VehicleParams), ("gains", ImpedanceGains), ("estimator", EstimatorParams)):
            if not isinstance(getattr(self, name), want):
                raise InputError(f"{name} must be a {want.__name__}, got {type(getattr(self, name)).__name__}")
        for name in ("Ts", "integral_limit", "min_lift_accel", "attitude_filter_wn", "attitude_filter_zeta"):
            object.__setattr__(self, name, scalar(name, getattr(self, name), lo=0.0, lo_open=True))
        if self.Ts > 1.0:
            raise InputError(f"Ts = {self.Ts} s is not a control period a multirotor can fly with (at most 1 s)")
        object.__setattr__(self, "thrust_shift_max", scalar("thrust_shift_max", self.thrust_shift_max, lo=0.0, hi=1.0))
        object.__setattr__(self, "tilt_max", scalar("tilt_max", self.tilt_max))
        object.__setattr__(self, "reference_delay", scalar("reference_delay", self.reference_delay, lo=0.0, hi=1.0))
        if not 0.0 < self.tilt_max < np.pi / 2:
            raise InputError(f"tilt_max must be in (0, pi/2) rad, got {self.tilt_max}")
        if self.attitude_filter_wn * self.Ts >= np.pi:
            raise InputError(
                f"attitude_filter_wn * Ts = {self.attitude_filter_wn * self.Ts:.2f} >= pi: the attitude filter "
                f"({self.attitude_filter_wn} rad/s) is too fast for the control period {self.Ts} s"
            )
        if self.variant == "pid" and not np.any(self.gains.Ki > 0):
            raise InputError("variant 'pid' needs Ki > 0 on at least one axis (the paper uses Ki = 0.5)")

    @classmethod
    def paper(cls, variant: str = "pdc", vehicle: VehicleParams | str | None = None, **kw: object) -> ControllerParams:
        """The paper's controller (Sec. VI.A-B) for the nominal Pelican or the given nominal vehicle (a
        :class:`VehicleParams`, or a preset name or vehicle file for :func:`load_preset`).

        For another vehicle the position gains keep the paper's ``Kp/m``, ``Dp/m`` and ``Ki/m`` (the same
        closed-loop poles) and the attitude gains its wn = 8 rad/s, zeta = 1 on that vehicle's inertia
        (:meth:`ImpedanceGains.paper`). They know nothing of the vehicle's motors and latencies: check the
        loop on your plant before flying (:func:`vtol_impedance.robust.linearize`, ``docs/guide/python-api.md``).
        """
        if isinstance(vehicle, str):
            vehicle = load_preset(vehicle)
        elif vehicle is not None and not isinstance(vehicle, VehicleParams):
            raise InputError(f"vehicle must be a VehicleParams or a preset name, got {type(vehicle).__name__}")
        vehicle = vehicle or load_preset("pelican")
        Ki = PAPER_KI if variant == "pid" else 0.0
        gains = ImpedanceGains.paper(vehicle.inertia, Ki=Ki, mass=vehicle.mass)
        return cls(vehicle=vehicle, gains=gains, variant=variant, **kw)

    def to_dict(self, memo: dict[int, dict] | None = None) -> dict:
        """The parameters as plain data (``memo``: as :meth:`VehicleParams.to_dict`)."""
        return {
            "variant": self.variant,
            "vehicle": self.vehicle.to_dict(memo),
            "gains": self.gains.to_dict(),
            "estimator": self._estimator_dict(memo),
            "Ts": self.Ts,
            "tilt_max": self.tilt_max,
            "min_lift_accel": self.min_lift_accel,
            "attitude_filter_wn": self.attitude_filter_wn,
            "attitude_filter_zeta": self.attitude_filter_zeta,
            "integral_limit": self.integral_limit,
            "thrust_shift_max": self.thrust_shift_max,
            "impedance": self.apparent_impedance().to_dict(),
        }

    def _estimator_dict(self, memo: dict[int, dict] | None) -> dict:
        """The estimator's plain data, one dictionary for the controllers of a batch that share it."""
        if memo is None:
            return self.estimator.to_dict()
        key = id(self.estimator)
        if key not in memo:
            memo[key] = self.estimator.to_dict()
        return memo[key]

    def apparent_impedance(self) -> Impedance:
        """The impedance ``comply`` yields with: the set one, or by default the vehicle's own mass with
        the position gains (a plain PD in the steady state). Built once per parameter set."""
        if self.impedance is not None:
            return self.impedance
        cached = self.__dict__.get("_default_impedance")
        if cached is None:
            cached = Impedance(M=self.vehicle.mass, D=self.gains.Dp, K=self.gains.Kp)
            object.__setattr__(self, "_default_impedance", cached)
        return cached


class ControllerArrays(NamedTuple):
    """Controller parameters as arrays with a common leading batch shape (``()`` for one vehicle)."""

    mass: np.ndarray
    I_B: np.ndarray
    E: np.ndarray  # (..., 4, n) effectiveness of the nominal rotors
    E_pinv: np.ndarray  # (..., n, 4)
    f_max: np.ndarray  # (..., n)
    f_min: np.ndarray  # (..., n)
    Kp: np.ndarray
    Dp: np.ndarray
    Ki: np.ndarray
    Ko: np.ndarray
    Do: np.ndarray
    compensate: np.ndarray
    tilt_max: np.ndarray
    min_lift_accel: np.ndarray
    integral_limit: np.ndarray
    thrust_shift_max: np.ndarray
    Md: np.ndarray  # (..., 3) apparent mass of "comply", kg
    Dd: np.ndarray  # (..., 3) N s/m
    Kd: np.ndarray  # (..., 3) N/m
    Mo_d: np.ndarray  # (..., 3) apparent inertia of "comply" per Euler angle, kg m^2
    Do_d: np.ndarray  # (..., 3) N m s/rad
    Ko_d: np.ndarray  # (..., 3) N m/rad
    comply_enable: np.ndarray  # (...) 1 for the "comply" variant
    est: EstimatorDesign
    filt: FilterDesign
    Ts: float

    @property
    def batch_shape(self) -> tuple[int, ...]:
        return self.mass.shape


def compile_controllers(params: ControllerParams | Sequence[ControllerParams]) -> ControllerArrays:
    """Turn one ``ControllerParams`` (batch shape ``()``) or a sequence (batch shape ``(B,)``) into arrays.

    A batch must share the control period, the estimator design and the attitude filter.
    """
    single = isinstance(params, ControllerParams)
    if not single and not (isinstance(params, Sequence) and all(isinstance(p, ControllerParams) for p in params)):
        raise InputError(f"params must be a ControllerParams or a sequence of them, got {params!r:.80}")
    plist = [params] if single else list(params)
    if not plist:
        raise InputError("no controller given")
    p0 = plist[0]
    est0 = p0.estimator.to_dict()
    for p in plist[1:]:
        if (p.Ts, p.attitude_filter_wn, p.attitude_filter_zeta) != (
            p0.Ts,
            p0.attitude_filter_wn,
            p0.attitude_filter_zeta,
        ) or (p.estimator is not p0.estimator and p.estimator.to_dict() != est0):
            raise InputError("controllers in one batch must share Ts, the estimator and the attitude filter")
        if p.vehicle is not p0.vehicle and p.vehicle.n_rotors != p0.vehicle.n_rotors:
            raise InputError(
                f"controllers in one batch must have the same number of rotors, got {p0.vehicle.n_rotors} and "
                f"{p.vehicle.n_rotors}"
            )

    def col(fn) -> np.ndarray:
        arr = np.array([fn(p) for p in plist], dtype=float)
        return arr[0] if single else arr

    # the vehicle's columns once per distinct vehicle (a batch's controllers mostly share one)
    vehicles, rows = distinct_vehicles([p.vehicle for p in plist])

    def vcol(fn) -> np.ndarray:
        arr = np.array([fn(v) for v in vehicles], dtype=float)[rows]
        return arr[0] if single else arr

    imp = {id(p): p.apparent_impedance() for p in plist}

    return ControllerArrays(
        mass=vcol(lambda v: v.mass),
        I_B=vcol(lambda v: v.inertia),
        E=vcol(lambda v: v.geometry.E),
        E_pinv=vcol(lambda v: v.geometry.E_pinv),
        f_max=vcol(lambda v: v.geometry.f_max),
        f_min=vcol(lambda v: v.geometry.f_min),
        Kp=col(lambda p: p.gains.Kp),
        Dp=col(lambda p: p.gains.Dp),
        Ki=col(lambda p: p.gains.Ki if p.variant == "pid" else np.zeros(3)),
        Ko=col(lambda p: p.gains.Ko),
        Do=col(lambda p: p.gains.Do),
        compensate=col(lambda p: 1.0 if p.variant in ("pdc", "comply") else 0.0),
        tilt_max=col(lambda p: p.tilt_max),
        min_lift_accel=col(lambda p: p.min_lift_accel),
        integral_limit=col(lambda p: p.integral_limit),
        thrust_shift_max=col(lambda p: p.thrust_shift_max),
        Md=col(lambda p: imp[id(p)].M),
        Dd=col(lambda p: imp[id(p)].D),
        Kd=col(lambda p: imp[id(p)].K),
        Mo_d=col(lambda p: np.diag(p.vehicle.inertia) if imp[id(p)].M_o is None else imp[id(p)].M_o),
        Do_d=col(lambda p: _or(imp[id(p)].D_o, p.gains.Do)),
        Ko_d=col(lambda p: _or(imp[id(p)].K_o, p.gains.Ko)),
        comply_enable=col(lambda p: 1.0 if p.variant == "comply" else 0.0),
        est=design(p0.estimator, p0.Ts),
        filt=design_filter(p0.attitude_filter_wn, p0.attitude_filter_zeta, p0.Ts),
        Ts=float(p0.Ts),
    )


class ControllerState(NamedTuple):
    """What the batched controllers carry from one period to the next (from
    :func:`initial_controller_state`, returned by :func:`controller_step`): the estimator's state
    ``est``, the attitude filter's ``filt``, the PID ``integral`` of ``e_p`` (``(..., 3)``, m s) and the
    command held over the last period, ``thrust_prev`` (``(...)``, N, as allocated) and ``tau_B_prev``
    (``(..., 3)``, N m, body FRD)."""

    est: EstimatorState
    filt: FilterState
    integral: np.ndarray  # (..., 3) integral of e_p, m s
    thrust_prev: np.ndarray  # (...) command held over the last period (as allocated)
    tau_B_prev: np.ndarray  # (..., 3)


def initial_controller_state(P: ControllerArrays) -> ControllerState:
    """The controllers' state before the first period: no estimate, filter not started, zero PID
    integral, the previous command a hover thrust ``m g`` with zero torque.

    Parameters
    ----------
    P : ControllerArrays
        The controllers' parameters as arrays, from :func:`compile_controllers`.

    Returns
    -------
    ControllerState
        With the batch shape of ``P``; pass it to the first :func:`controller_step`.
    """
    instance("P", P, ControllerArrays)
    bs = P.batch_shape
    z2 = np.zeros(bs + (2,))
    return ControllerState(
        est=estimator_initial_state(P.est, bs),
        filt=FilterState(z2, z2, False),
        integral=np.zeros(bs + (3,)),
        thrust_prev=P.mass * G,
        tau_B_prev=np.zeros(bs + (3,)),
    )


class PositionStage(NamedTuple):
    """What the estimator and the position loop hand to the attitude loop in one period."""

    est: EstimatorState  # the estimator's new state
    f_hat_W: np.ndarray  # (..., 3) eq. (11), world NED, N
    tau_hat_eta: np.ndarray  # (..., 3) eq. (11), Euler coordinates, N m
    thrust_request: np.ndarray  # (...) eq. (16), N
    rp_d: np.ndarray  # (..., 2) desired roll and pitch of eq. (16) before the filter, rad
    tilt_limited: np.ndarray  # (...) the tilt or lift bound of eq. (16) acted
    mu_bar: np.ndarray  # (..., 3) eq. (16), m/s^2
    lam_o: np.ndarray  # (..., 3) comply fraction per Euler angle


def position_step(P: ControllerArrays, S: ControllerState, meas: Measurement, ref: Reference) -> PositionStage:
    """Steps 1-4 of :func:`controller_step`: the estimator, eqs. (6)-(13), the position impedance (18a) with
    the estimate fed forward, and eq. (16) for the thrust and the desired roll and pitch. Pure function."""
    m = P.mass
    m3 = m[..., None]
    comp = P.compensate[..., None]

    # eqs. (6)-(13): the estimate r of eq. (11)
    est, w_hat = estimator_step(P.est, S.est, meas.eta, meas.eta_dot, meas.v_W, S.thrust_prev, S.tau_B_prev, m, P.I_B)
    f_hat_W = w_hat[..., :3]

    # Position impedance (18a), compensation, eq. (16) solved in NED. Per axis, "comply" blends the
    # stiff rejecting law (lam = 0) with M_d e'' + D_d e' + K_d e = f_ext (lam = 1):
    # u/m = a_d - (D_d e' + K_d e) / M_d + (1/M_d - 1/m) f, with f the estimate advanced by G's
    # low-frequency delay and its measurement's latency (f_hat + lead f_hat_dot, EstimatorDesign.lead):
    # without it the delay shows up as damping and mass.
    comply = comply6(ref.comply)
    lam = P.comply_enable[..., None] * np.clip(comply[..., :3], 0.0, 1.0)
    lam_o = P.comply_enable[..., None] * np.clip(comply[..., 3:], 0.0, 1.0)
    Kp = (1.0 - lam) * P.Kp + lam * m3 * P.Kd / P.Md
    Dp = (1.0 - lam) * P.Dp + lam * m3 * P.Dd / P.Md
    f_lead = f_hat_W + P.est.lead[:3] * est.r_dot[..., :3]
    e_p = meas.p_W - ref.p_W
    e_v = meas.v_W - ref.v_W
    mu = ref.a_W - (Dp * e_v + Kp * e_p + (1.0 - lam) * P.Ki * S.integral) / m3  # eq. (18a)
    mu_bar = mu - ((1.0 - lam) * comp * f_hat_W + lam * (1.0 - m3 / P.Md) * f_lead) / m3  # eq. (16): mu - f_hat/m
    # The force follows the command only as fast as the attitude does, about the attitude filter's
    # delay 2 zeta / wn later; comply leads the inertial and force terms of its law by that much:
    # D_d times the impedance's own acceleration, and the force estimate's rate. (Measured on the
    # realistic plant: without this lead a 2 kg apparent mass comes out at 1.5 kg; leading the
    # stiffness term too over-damps by 10 %.)
    lead = 2.0 * P.filt.zeta / P.filt.wn
    acc = (f_lead - P.Dd * e_v - P.Kd * e_p) / P.Md
    rate = -P.Dd * acc / P.Md + (1.0 / P.Md - 1.0 / m3) * est.r_dot[..., :3]
    mu_bar = mu_bar + lam * lead * rate
    # eqs. (16), (20)
    thrust_req, phi_d, theta_d, tilt_limited = thrust_and_attitude(mu_bar, ref.psi, m, P.tilt_max, P.min_lift_accel)
    return PositionStage(
        est, f_hat_W, w_hat[..., 3:], thrust_req, np.stack([phi_d, theta_d], -1), tilt_limited, mu_bar, lam_o
    )


def attitude_step(
    P: ControllerArrays, S: ControllerState, meas: Measurement, ref: Reference, pos: PositionStage
) -> tuple[ControllerState, ControlOutput]:
    """Steps 5-8 of :func:`controller_step`: the filter on the desired roll and pitch, the attitude
    impedance (18b), the torque (14) with the estimated moment fed forward, and the allocation. Pure
    function; ``pos`` is :func:`position_step`'s output for the same period."""
    comp = P.compensate[..., None]
    est, tau_hat_eta, lam_o = pos.est, pos.tau_hat_eta, pos.lam_o

    # Desired attitude: filtered roll/pitch, planned yaw.
    filt, rp_d, rp_d_dot, rp_d_ddot = filter_step(P.filt, S.filt, pos.rp_d)
    psi = np.broadcast_to(ref.psi, rp_d.shape[:-1])
    eta_d = np.concatenate([rp_d, psi[..., None]], -1)
    eta_d_dot = np.concatenate([rp_d_dot, np.broadcast_to(ref.psi_dot, psi.shape)[..., None]], -1)
    eta_d_ddot = np.concatenate([rp_d_ddot, np.broadcast_to(ref.psi_ddot, psi.shape)[..., None]], -1)

    # Attitude impedance (18b) and torque (14).
    eta, eta_dot = meas.eta, meas.eta_dot
    M = inertia_matrix_M(eta, P.I_B)  # eq. (3b)
    C = coriolis_matrix_C(eta, eta_dot, P.I_B)  # eqs. (3b), (7)
    Q = euler_rate_matrix_Q(eta)  # eq. (1c)
    e_eta = wrap_angle(eta - eta_d)
    e_eta_dot = eta_dot - eta_d_dot
    damp = P.Do * e_eta_dot + matvec(C, e_eta_dot) + P.Ko * e_eta  # eq. (18b)
    tau_bar = eta_d_ddot - np.linalg.solve(M, damp[..., None])[..., 0]  # eq. (18b)
    # Per Euler angle, "comply" blends in M_o e'' + D_o e' + K_o e = tau_ext_eta: with (14) cancelling
    # the moment, eta'' = tau_bar, so tau_bar is that law's acceleration. Both use the estimate advanced
    # by G's delay (measured: with the plain estimate in (14) a 0.01 kg m^2 yaw inertia came out at 0.003).
    tau_lead = tau_hat_eta + P.est.lead[3:] * est.r_dot[..., 3:]
    tau_bar_comply = eta_d_ddot - (P.Do_d * e_eta_dot + P.Ko_d * e_eta - tau_lead) / P.Mo_d
    tau_bar = (1.0 - lam_o) * tau_bar + lam_o * tau_bar_comply
    tau_comp = tau_hat_eta + lam_o * (tau_lead - tau_hat_eta)
    QT = transpose(Q)
    tau_B_req = (  # eq. (14)
        matvec(P.I_B @ Q, tau_bar) + np.linalg.solve(QT, (matvec(C, eta_dot) - comp * tau_comp)[..., None])[..., 0]
    )
    tau_hat_B = np.linalg.solve(QT, tau_hat_eta[..., None])[..., 0]

    alloc = allocate(pos.thrust_request, tau_B_req, P.E, P.E_pinv, P.f_min, P.f_max, P.thrust_shift_max)

    # PID anti-windup: freeze while saturated or tilt-limited, and bound |Ki int e_p| per axis.
    e_p = meas.p_W - ref.p_W
    freeze = (alloc.saturated | pos.tilt_limited)[..., None]
    integral = np.where(freeze, S.integral, S.integral + P.Ts * e_p)
    bound = P.integral_limit[..., None] / np.maximum(P.Ki, 1e-12)
    integral = np.clip(integral, -bound, bound)

    state = ControllerState(est, filt, integral, alloc.thrust, alloc.tau_B)
    out = ControlOutput(
        thrust=alloc.thrust,
        tau_B=alloc.tau_B,
        f_rotor=alloc.f,
        saturated=alloc.saturated,
        thrust_request=pos.thrust_request,
        tau_B_request=tau_B_req,
        f_hat_W=pos.f_hat_W,
        tau_hat_eta=tau_hat_eta,
        tau_hat_B=tau_hat_B,
        eta_d=eta_d,
        eta_d_dot=eta_d_dot,
        mu_bar=pos.mu_bar,
        tilt_limited=pos.tilt_limited,
        rp_scale=alloc.rp_scale,
        yaw_scale=alloc.yaw_scale,
    )
    return state, out


def controller_step(
    P: ControllerArrays, S: ControllerState, meas: Measurement, ref: Reference
) -> tuple[ControllerState, ControlOutput]:
    """One control period: estimator, eqs. (18a), (16) (:func:`position_step`), then filter, (18b), (14)
    and allocation (:func:`attitude_step`). Pure function."""
    if type(P) is not ControllerArrays or type(S) is not ControllerState:  # exact types: cheap, every step
        instance("P", P, ControllerArrays)
        instance("S", S, ControllerState)
    if type(meas) is not Measurement or type(ref) is not Reference:
        instance("meas", meas, Measurement)
        instance("ref", ref, Reference)
    return attitude_step(P, S, meas, ref, position_step(P, S, meas, ref))


def _or(value: np.ndarray | None, default: np.ndarray) -> np.ndarray:
    return default if value is None else value
