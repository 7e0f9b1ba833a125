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
per axis by ``integral_limit``), ``"pdc"`` (the paper's PD + compensation).

Every function takes arrays with leading batch dimensions; several controllers (for example the three
variants) run as one batch.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np

from ..conventions import G
from ..errors import InputError, SingularityError, as_finite, positive
from ..estimator.momentum import (
    EstimatorDesign,
    EstimatorParams,
    EstimatorState,
    design,
    estimator_step,
)
from ..estimator.momentum import initial_state as estimator_initial_state
from ..model.dynamics import coriolis_matrix_C, inertia_matrix_M, matvec, transpose
from ..model.kinematics import check_euler_regular, euler_rate_matrix_Q, wrap_angle
from ..model.mixer import allocate
from ..model.vehicle import VehicleParams, load_preset
from .attitude_filter import FilterDesign, FilterState, design_filter, filter_step
from .gains import ImpedanceGains
from .signals import ControlOutput, Measurement, Reference
from .thrust import thrust_and_attitude

VARIANTS: dict[str, str] = {
    "pd": "PD (no compensation)",
    "pid": "PID (PD + integral of e_p)",
    "pdc": "PD+C (PD + compensation of the estimated wrench)",
}
#: Integral gain of the paper's PID baseline, Sec. VI.B.
PAPER_KI = 0.5


@dataclass(frozen=True, eq=False)
class ControllerParams:
    """Everything one controller needs; ``vehicle`` is the *nominal* model, never the true plant."""

    vehicle: VehicleParams
    gains: ImpedanceGains
    variant: str = "pdc"
    estimator: EstimatorParams = field(default_factory=EstimatorParams)
    Ts: float = 0.01
    tilt_max: float = float(np.radians(35.0))
    min_lift_accel: float = 0.2 * G
    attitude_filter_wn: float = 20.0
    attitude_filter_zeta: float = 1.0
    integral_limit: float = 3.0

    def __post_init__(self) -> None:
        if self.variant not in VARIANTS:
            raise InputError(f"unknown controller variant {self.variant!r}; choose one of {sorted(VARIANTS)}")
        positive("Ts", self.Ts)
        positive("integral_limit", self.integral_limit)
        positive("min_lift_accel", self.min_lift_accel)
        if not 0.0 < self.tilt_max < np.pi / 2:
            raise InputError(f"tilt_max must be in (0, pi/2) rad, got {self.tilt_max}")
        if self.variant == "pid" and not np.any(self.gains.Ki > 0):
            raise InputError("variant 'pid' needs Ki > 0 on at least one axis (the paper uses Ki = 0.5)")

    @classmethod
    def paper(cls, variant: str = "pdc", vehicle: VehicleParams | None = None, **kw: object) -> ControllerParams:
        """The paper's controller (Sec. VI.A-B) for the nominal Pelican or the given nominal vehicle."""
        vehicle = vehicle or load_preset("pelican")
        Ki = PAPER_KI if variant == "pid" else 0.0
        return cls(vehicle=vehicle, gains=ImpedanceGains.paper(vehicle.inertia, Ki=Ki), variant=variant, **kw)

    def to_dict(self) -> dict:
        return {
            "variant": self.variant,
            "vehicle": self.vehicle.to_dict(),
            "gains": self.gains.to_dict(),
            "estimator": self.estimator.to_dict(),
            "Ts": self.Ts,
            "tilt_max": self.tilt_max,
            "min_lift_accel": self.min_lift_accel,
            "attitude_filter_wn": self.attitude_filter_wn,
            "attitude_filter_zeta": self.attitude_filter_zeta,
            "integral_limit": self.integral_limit,
        }


class ControllerArrays(NamedTuple):
    """Controller parameters as arrays with a common leading batch shape (``()`` for one vehicle)."""

    mass: np.ndarray
    I_B: np.ndarray
    arm_length: np.ndarray
    drag_factor: np.ndarray
    f_max: np.ndarray
    f_min: np.ndarray
    Kp: np.ndarray
    Dp: np.ndarray
    Ki: np.ndarray
    Ko: np.ndarray
    Do: np.ndarray
    compensate: np.ndarray
    tilt_max: np.ndarray
    min_lift_accel: np.ndarray
    integral_limit: np.ndarray
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
    plist = [params] if single else list(params)
    if not plist:
        raise InputError("no controller given")
    p0 = plist[0]
    for p in plist[1:]:
        if (p.Ts, p.attitude_filter_wn, p.attitude_filter_zeta) != (
            p0.Ts,
            p0.attitude_filter_wn,
            p0.attitude_filter_zeta,
        ) or p.estimator.to_dict() != p0.estimator.to_dict():
            raise InputError("controllers in one batch must share Ts, the estimator and the attitude filter")

    def col(fn) -> np.ndarray:
        arr = np.array([fn(p) for p in plist], dtype=float)
        return arr[0] if single else arr

    return ControllerArrays(
        mass=col(lambda p: p.vehicle.mass),
        I_B=col(lambda p: p.vehicle.inertia),
        arm_length=col(lambda p: p.vehicle.arm_length),
        drag_factor=col(lambda p: p.vehicle.drag_factor),
        f_max=col(lambda p: p.vehicle.f_max),
        f_min=col(lambda p: p.vehicle.f_min),
        Kp=col(lambda p: p.gains.Kp),
        Dp=col(lambda p: p.gains.Dp),
        Ki=col(lambda p: p.gains.Ki if p.variant == "pid" else np.zeros(3)),
        Ko=col(lambda p: p.gains.Ko),
        Do=col(lambda p: p.gains.Do),
        compensate=col(lambda p: 1.0 if p.variant == "pdc" else 0.0),
        tilt_max=col(lambda p: p.tilt_max),
        min_lift_accel=col(lambda p: p.min_lift_accel),
        integral_limit=col(lambda p: p.integral_limit),
        est=design(p0.estimator, p0.Ts),
        filt=design_filter(p0.attitude_filter_wn, p0.attitude_filter_zeta, p0.Ts),
        Ts=float(p0.Ts),
    )


class ControllerState(NamedTuple):
    est: EstimatorState
    filt: FilterState
    integral: np.ndarray  # (..., 3) integral of e_p, m s
    thrust_prev: np.ndarray  # (...) command held over the last period (as allocated)
    tau_B_prev: np.ndarray  # (..., 3)


def initial_controller_state(P: ControllerArrays) -> ControllerState:
    bs = P.batch_shape
    z2 = np.zeros(bs + (2,))
    return ControllerState(
        est=estimator_initial_state(P.est, bs),
        filt=FilterState(z2, z2, False),
        integral=np.zeros(bs + (3,)),
        thrust_prev=P.mass * G,
        tau_B_prev=np.zeros(bs + (3,)),
    )


def controller_step(
    P: ControllerArrays, S: ControllerState, meas: Measurement, ref: Reference
) -> tuple[ControllerState, ControlOutput]:
    """One control period: estimator, eqs. (18a), (16), filter, (18b), (14), allocation. Pure function."""
    m = P.mass
    m3 = m[..., None]
    comp = P.compensate[..., None]

    est, w_hat = estimator_step(P.est, S.est, meas.eta, meas.eta_dot, meas.v_W, S.thrust_prev, S.tau_B_prev, m, P.I_B)
    f_hat_W = w_hat[..., :3]
    tau_hat_eta = w_hat[..., 3:]

    # Position impedance (18a), compensation, eq. (16) solved in NED.
    e_p = meas.p_W - ref.p_W
    e_v = meas.v_W - ref.v_W
    mu = ref.a_W - (P.Dp * e_v + P.Kp * e_p + P.Ki * S.integral) / m3
    mu_bar = mu - comp * f_hat_W / m3
    thrust_req, phi_d, theta_d, tilt_limited = thrust_and_attitude(mu_bar, ref.psi, m, P.tilt_max, P.min_lift_accel)

    # Desired attitude: filtered roll/pitch, planned yaw.
    filt, rp_d, rp_d_dot, rp_d_ddot = filter_step(P.filt, S.filt, np.stack([phi_d, theta_d], -1))
    psi = np.broadcast_to(ref.psi, phi_d.shape)
    eta_d = np.concatenate([rp_d, psi[..., None]], -1)
    eta_d_dot = np.concatenate([rp_d_dot, np.broadcast_to(ref.psi_dot, psi.shape)[..., None]], -1)
    eta_d_ddot = np.concatenate([rp_d_ddot, np.broadcast_to(ref.psi_ddot, psi.shape)[..., None]], -1)

    # Attitude impedance (18b) and torque (14).
    eta, eta_dot = meas.eta, meas.eta_dot
    M = inertia_matrix_M(eta, P.I_B)
    C = coriolis_matrix_C(eta, eta_dot, P.I_B)
    Q = euler_rate_matrix_Q(eta)
    e_eta = wrap_angle(eta - eta_d)
    e_eta_dot = eta_dot - eta_d_dot
    damp = P.Do * e_eta_dot + matvec(C, e_eta_dot) + P.Ko * e_eta
    tau_bar = eta_d_ddot - np.linalg.solve(M, damp[..., None])[..., 0]
    QT = transpose(Q)
    tau_B_req = (
        matvec(P.I_B @ Q, tau_bar) + np.linalg.solve(QT, (matvec(C, eta_dot) - comp * tau_hat_eta)[..., None])[..., 0]
    )
    tau_hat_B = np.linalg.solve(QT, tau_hat_eta[..., None])[..., 0]

    alloc = allocate(thrust_req, tau_B_req, P.arm_length, P.drag_factor, P.f_max, P.f_min)

    # PID anti-windup: freeze while saturated or tilt-limited, and bound |Ki int e_p| per axis.
    freeze = (alloc.saturated | tilt_limited)[..., None]
    integral = np.where(freeze, S.integral, S.integral + P.Ts * e_p)
    bound = P.integral_limit[..., None] / np.maximum(P.Ki, 1e-12)
    integral = np.clip(integral, -bound, bound)

    state = ControllerState(est, filt, integral, alloc.thrust, alloc.tau_B)
    out = ControlOutput(
        thrust=alloc.thrust,
        tau_B=alloc.tau_B,
        f_rotor=alloc.f,
        saturated=alloc.saturated,
        thrust_request=thrust_req,
        tau_B_request=tau_B_req,
        f_hat_W=f_hat_W,
        tau_hat_eta=tau_hat_eta,
        tau_hat_B=tau_hat_B,
        eta_d=eta_d,
        eta_d_dot=eta_d_dot,
        mu_bar=mu_bar,
        tilt_limited=tilt_limited,
    )
    return state, out


class Controller:
    """Stateful controller + estimator for use outside the simulator (a flight loop, a ROS node).

    >>> ctrl = Controller(ControllerParams.paper("pdc"))
    >>> out = ctrl.step(Measurement(p, v, eta, eta_dot), Reference(p_d, v_d, a_d, psi_d, 0.0, 0.0))

    :meth:`step` validates its inputs (finite, trailing shape 3, away from the Euler singularity) and
    returns a :class:`ControlOutput`. :meth:`step_arrays` is the low-overhead path for real-time loops:
    flat ``y = [p_W, v_W, eta, eta_dot]`` and ``r = [p_d, v_d, a_d, psi_d, psi_dot_d, psi_ddot_d]`` in,
    a flat output row out (layout ``vtol_impedance.compiled.controller.O_*``), one compiled call.

    ``backend="compiled"`` (default) runs the numba kernels, ``"numpy"`` the reference functions of this
    module; both compute the same numbers.
    """

    def __init__(self, params: ControllerParams | Sequence[ControllerParams], backend: str = "compiled") -> None:
        if backend not in ("compiled", "numpy"):
            raise InputError(f"backend must be 'compiled' or 'numpy', got {backend!r}")
        self.params = params
        self.backend = backend
        self.arrays = compile_controllers(params)
        if backend == "compiled":
            from ..compiled import controller as kernels

            batch = self.arrays if self.arrays.batch_shape else compile_controllers([params])  # type: ignore[list-item]
            self._k = kernels
            self._cp, self._sh = kernels.pack_controller(batch)
            self._n = batch.est.Ad.shape[-1]
            self._out = np.zeros((self._cp.shape[0], kernels.OUT_SIZE))
        self.reset()

    def reset(self) -> None:
        self.state = initial_controller_state(self.arrays)
        if self.backend == "compiled":
            self._cs = self._k.initial_state(self._cp, self._n)

    def step_arrays(self, y: np.ndarray, r: np.ndarray, vehicle: int = 0) -> np.ndarray:
        """One compiled step for ``vehicle`` with flat float64 inputs ``y (12,)`` and ``r (12,)``.

        Returns the output row (a view, overwritten by the next call). Raises :class:`InputError` on a
        non-finite input and :class:`SingularityError` at theta = +-90 deg.
        """
        if self.backend != "compiled":
            raise InputError("step_arrays needs backend='compiled'")
        out = self._out[vehicle]
        status = self._k.checked_step(self._cp[vehicle], self._sh, self._cs[vehicle], y, r, out)
        if status:
            if status == 2:
                raise SingularityError(f"pitch theta = {np.degrees(y[7]):.3f} deg is at the Euler singularity")
            raise InputError(f"non-finite measurement or reference: y = {y}, r = {r}")
        return out

    def step(self, meas: Measurement, ref: Reference) -> ControlOutput:
        bs = self.arrays.batch_shape
        meas = Measurement(*(as_finite(n, v, (3,)) for n, v in zip(Measurement._fields, meas, strict=True)))
        for name, v in zip(Measurement._fields, meas, strict=True):
            if v.shape[:-1] != bs:
                raise InputError(f"measurement {name} has batch shape {v.shape[:-1]}, the controller has {bs}")
        ref = Reference(
            as_finite("p_d", ref.p_W, (3,)),
            as_finite("v_d", ref.v_W, (3,)),
            as_finite("a_d", ref.a_W, (3,)),
            as_finite("psi_d", ref.psi),
            as_finite("psi_dot_d", ref.psi_dot),
            as_finite("psi_ddot_d", ref.psi_ddot),
        )
        check_euler_regular(meas.eta)
        if self.backend == "numpy":
            self.state, out = controller_step(self.arrays, self.state, meas, ref)
            return out
        return self._step_compiled(meas, ref, bs)

    def _step_compiled(self, meas: Measurement, ref: Reference, bs: tuple[int, ...]) -> ControlOutput:
        k = self._k
        B = self._cp.shape[0]
        y = np.concatenate([np.broadcast_to(v, bs + (3,)).reshape(B, 3) for v in meas], -1)
        r = np.concatenate(
            [
                np.broadcast_to(ref.p_W, (B, 3)),
                np.broadcast_to(ref.v_W, (B, 3)),
                np.broadcast_to(ref.a_W, (B, 3)),
                np.broadcast_to(np.stack([ref.psi, ref.psi_dot, ref.psi_ddot], -1), (B, 3)),
            ],
            -1,
        )
        for b in range(B):
            k.controller_step(self._cp[b], self._sh, self._cs[b], y[b], np.ascontiguousarray(r[b]), self._out[b])
        o = self._out.reshape(bs + (k.OUT_SIZE,)).copy()

        def sl(i: int, n: int) -> np.ndarray:
            return o[..., i : i + n]

        return ControlOutput(
            thrust=o[..., k.O_THRUST],
            tau_B=sl(k.O_TAU, 3),
            f_rotor=sl(k.O_F, 4),
            saturated=o[..., k.O_SAT] > 0.5,
            thrust_request=o[..., k.O_THRUST_REQ],
            tau_B_request=sl(k.O_TAU_REQ, 3),
            f_hat_W=sl(k.O_FHAT, 3),
            tau_hat_eta=sl(k.O_TAUHAT_ETA, 3),
            tau_hat_B=sl(k.O_TAUHAT_B, 3),
            eta_d=sl(k.O_ETA_D, 3),
            eta_d_dot=sl(k.O_ETA_D_DOT, 3),
            mu_bar=sl(k.O_MU_BAR, 3),
            tilt_limited=o[..., k.O_TILT] > 0.5,
        )
