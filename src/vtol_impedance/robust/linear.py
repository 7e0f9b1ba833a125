"""The sampled closed loop linearised at hover, for any vehicle, controller and sensor timing.

What the model is
-----------------
The closed loop the simulator flies (:func:`vtol_impedance.sim.run_closed_loop`), linearised about a
hover at rest, exactly as it is sampled:

* **controller**: :func:`~vtol_impedance.control.position_step` and
  :func:`~vtol_impedance.control.attitude_step` themselves, differentiated numerically (central
  differences) with respect to their state, the measurement and the desired roll and pitch between the
  two stages. Whatever the controller does (PD, PID, PD+C, comply; the estimator of any order and its
  timing, eqs. (6)-(13); the attitude filter; eqs. (14)-(20)) is in the model because it is the
  controller's own code. States that influence no output (the unused PID integral of PD, the estimator
  of PD) are dropped.
* **plant**: the true plant's :func:`~vtol_impedance.sim.plant.plant_derivative` (true mass, inertia and
  centre of mass with the payload, true rotor geometry, drag factor and rotor drag, a pendulum if any)
  differentiated in minimal coordinates (position, velocity, a body-frame rotation vector, body rate,
  rotor forces, the pendulum bob's horizontal offset and rate), then discretised exactly for commands
  held over each control period (zero-order hold).
* **rotor lag**: the plant's rotors spin up with ``tau_up`` and down with ``tau_down``. That is not
  linear; its describing function is amplitude-independent and has the phase of a first-order lag of
  18.4-18.7 ms for 12.5/25 ms over 2-40 rad/s (:func:`rotor_lag_describing_function`). The model uses a
  first-order lag with the mean ``(tau_up + tau_down) / 2``: it reproduced the growth rate of the
  paper's unstable hover (0.139 s^-1 against 0.148 simulated) better than the describing function's
  18.6 ms (0.121).
* **sensors**: :func:`~vtol_impedance.sim.sensors.measurement` differentiated, read at the sensor
  latencies (rounded to plant steps as the simulator does). A latency ``d = n Ts + delta`` reads the
  state ``Ts - delta`` into period ``k - n - 1``, which the exact discretisation gives from the state and
  the held command of that period: fractional latencies are exact, not rounded to control periods.

What it is not: noise is absent (it does not move the poles); explicit disturbances enter only through
their steady wrench at the operating point (``force_W``, ``torque_B``): a fan's or a wall's dependence
on position is not in the model; saturation (rotor limits, the tilt limit) is assumed inactive at the
operating point and is checked there; the ground is not touched. The result is a discrete
linear time-invariant system at the control period, held in python-control objects.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Any, NamedTuple

import control as ct
import numpy as np
import scipy.linalg

from ..control.impedance import (
    ControllerParams,
    ControllerState,
    attitude_step,
    compile_controllers,
    controller_step,
    initial_controller_state,
    position_step,
)
from ..control.signals import Measurement, Reference
from ..conventions import GRAVITY_W
from ..errors import InputError, as_finite, scalar
from ..model.kinematics import euler_from_rotation, quat_derivative, quat_to_rotation
from ..model.mixer import allocate
from ..sim.plant import (
    N_BODY,
    OMEGA,
    P_COM,
    PEND_R,
    PEND_V,
    QUAT,
    V_COM,
    PlantArrays,
    PlantParams,
    compile_plants,
    initial_state,
    plant_derivative,
)
from ..sim.sensors import SensorParams, latency_steps, measurement

#: Names of the loops broken for margins: the four rotor-command channels (thrust and body torque, before
#: the allocation) and the two attitude references (the desired roll and pitch between eq. (16) and the
#: attitude filter).
LOOPS: tuple[str, ...] = ("thrust", "roll torque", "pitch torque", "yaw torque", "roll reference", "pitch reference")
#: Measurement channels, in the order of ``y``: the body origin's position and velocity (world NED), the
#: attitude (ZYX Euler) and its rates.
MEASUREMENTS: tuple[str, ...] = tuple(f"{q}_{a}" for q in ("p", "v") for a in "xyz") + (
    "phi", "theta", "psi", "phi_dot", "theta_dot", "psi_dot",
)  # fmt: skip
#: The controller's commands before the allocation: thrust (N) and body torque (N m, FRD).
COMMANDS: tuple[str, ...] = ("thrust", "tau_x", "tau_y", "tau_z")
#: The desired roll and pitch eq. (16) computes, and the same signals where the attitude stage takes them.
ATTITUDE_OUT: tuple[str, ...] = ("phi_d", "theta_d")
ATTITUDE_IN: tuple[str, ...] = ("phi_d_in", "theta_d_in")


class TrimError(InputError):
    """The vehicle cannot hover at the requested operating point (beyond its rotors or tilt limit)."""


class LoopSizeError(InputError):
    """The linearised loop would be too large to analyse (latencies of many control periods)."""


#: The most states a linearised loop may have: the sensor latencies become delay lines of six states per
#: control period, and a design's time grows with their number (100 Hz with the default 20 ms: 34
#: states, margins in a second, a design in a few; 250 states, a 0.35 s latency at 100 Hz or 40 ms at
#: 1 kHz, take about a minute on two cores; a 1 s latency at 100 Hz never finished in two minutes).
MAX_LOOP_STATES = 250


def equivalent_rotor_tau(tau_up: float, tau_down: float) -> float:
    """The first-order time constant the linear model uses for a rotor that spins up with ``tau_up`` and
    down with ``tau_down`` (s): their mean (module docstring)."""
    return 0.5 * (scalar("tau_up", tau_up, lo=0.0) + scalar("tau_down", tau_down, lo=0.0))


def rotor_lag_describing_function(tau_up: float, tau_down: float, omega: float, periods: int = 30) -> complex:
    """First harmonic of the asymmetric rotor lag's response to ``sin(omega t)``, relative to the input.

    ``f_dot = (c - f) / tau`` with ``tau = tau_up`` while ``c > f`` and ``tau_down`` otherwise, integrated
    exactly between switches on a fine grid; amplitude-independent (the system is homogeneous).
    """
    tau_up = scalar("tau_up", tau_up, lo=0.0)
    tau_down = scalar("tau_down", tau_down, lo=0.0)
    omega = scalar("omega", omega, lo=0.0, lo_open=True)
    periods = int(scalar("periods", periods, lo=1.0, integer=True))
    n = 4000
    T = 2.0 * np.pi / omega
    dt = T / n
    t = np.arange(n * periods) * dt
    c = np.sin(omega * t)
    f = np.empty_like(c)
    y = 0.0
    for k in range(len(t)):  # exact step of the linear ODE for the branch that is active
        tau = tau_up if c[k] > y else tau_down
        y = c[k] + (y - c[k]) * np.exp(-dt / tau) if tau > 0 else c[k]
        f[k] = y
    last = slice(n * (periods - 1), None)
    first = 2.0 * np.mean(f[last] * np.exp(-1j * omega * t[last]))
    return complex(first / -1j)  # relative to sin: its first harmonic is -1j


# --------------------------------------------------------------------------- flattening


def _leaves(obj: Any) -> list[np.ndarray]:
    if isinstance(obj, tuple):
        return [leaf for child in obj for leaf in _leaves(child)]
    if obj is None or isinstance(obj, bool | np.bool_):
        return []
    return [np.asarray(obj, dtype=float)]


def flatten_state(S: ControllerState, template: ControllerState | None = None) -> np.ndarray:
    """The controller state's numbers as one vector ``(..., n)`` (flags left out); with ``template`` (one
    vehicle's state) the leading axes beyond its shapes are kept as a batch."""
    leaves = _leaves(S)
    if template is None:
        return np.concatenate([leaf.ravel() for leaf in leaves])
    shapes = [leaf.shape for leaf in _leaves(template)]
    batch = np.broadcast_shapes(*(leaf.shape[: leaf.ndim - len(sh)] for leaf, sh in zip(leaves, shapes, strict=True)))
    return np.concatenate(
        [
            np.broadcast_to(leaf, batch + sh).reshape(batch + (int(np.prod(sh)),))
            for leaf, sh in zip(leaves, shapes, strict=True)
        ],
        -1,
    )


def unflatten_state(template: ControllerState, vec: np.ndarray) -> ControllerState:
    """A controller state shaped like ``template`` from ``vec (..., n)``; leading axes become a batch."""
    batch = vec.shape[:-1]
    pos = [0]

    def rebuild(obj: Any) -> Any:
        if isinstance(obj, tuple):
            return type(obj)(*[rebuild(c) for c in obj])
        if obj is None or isinstance(obj, bool | np.bool_):
            return obj
        shape = np.shape(obj)
        size = int(np.prod(shape))
        out = vec[..., pos[0] : pos[0] + size].reshape(batch + shape)
        pos[0] += size
        return out

    return rebuild(template)


def jacobian(fn: Any, x0: np.ndarray, h: np.ndarray | float) -> np.ndarray:
    """Central differences of ``fn`` (batched: called once with every perturbation) at ``x0``."""
    n = x0.size
    if n == 0:
        return np.zeros((np.asarray(fn(x0[None])).shape[-1], 0))
    step = np.broadcast_to(np.asarray(h, dtype=float), (n,))
    X = np.concatenate([x0 + np.diag(step), x0 - np.diag(step)])
    F = fn(X)
    return ((F[:n] - F[n:]) / (2.0 * step[:, None])).T


# --------------------------------------------------------------------------- plant coordinates


class _Coordinates:
    """Minimal coordinates of the plant state about ``x_base``: position and velocity of the centre of
    mass (world), a rotation vector in the body frame, body rate, rotor forces (unless lagless) and the
    pendulum bob's horizontal offset and rate from its joint."""

    def __init__(self, PA: PlantArrays, x_base: np.ndarray, lagless: bool) -> None:
        self.PA, self.x_base, self.lagless = PA, x_base, lagless
        self.n = PA.spins.shape[-1]
        self.pend = float(PA.pend_m) > 0.0
        self.size = 12 + (0 if lagless else self.n) + (4 if self.pend else 0)

    def reduce(self, x: np.ndarray) -> np.ndarray:
        """Minimal coordinates of a full state whose attitude is the base attitude."""
        parts = [x[..., P_COM], x[..., V_COM], np.zeros(x.shape[:-1] + (3,)), x[..., OMEGA]]
        if not self.lagless:
            parts.append(x[..., N_BODY : N_BODY + self.n])
        if self.pend:
            parts += [x[..., PEND_R][..., :2], x[..., PEND_V][..., :2]]
        return np.concatenate(parts, -1)

    def full(self, xm: np.ndarray, f_cmd: np.ndarray | None = None) -> np.ndarray:
        x = np.broadcast_to(self.x_base, xm.shape[:-1] + self.x_base.shape).copy()
        x[..., P_COM], x[..., V_COM], x[..., OMEGA] = xm[..., 0:3], xm[..., 3:6], xm[..., 9:12]
        q0 = np.broadcast_to(self.x_base[QUAT], xm.shape[:-1] + (4,))
        q = q0 + quat_derivative(q0, xm[..., 6:9])  # q0 (x) [1, dtheta/2]: first order exact
        x[..., QUAT] = q / np.linalg.norm(q, axis=-1, keepdims=True)
        i = 12
        if self.lagless:
            x[..., N_BODY : N_BODY + self.n] = np.clip(f_cmd, self.PA.f_min, self.PA.f_max)
        else:
            x[..., N_BODY : N_BODY + self.n] = xm[..., 12 : 12 + self.n]
            i += self.n
        if self.pend:
            a, b, ad, bd = (xm[..., i + j] for j in range(4))
            L = float(self.PA.pend_L)
            c = np.sqrt(np.maximum(L * L - a * a - b * b, 1e-12))
            x[..., PEND_R] = np.stack([a, b, c], -1)
            x[..., PEND_V] = np.stack([ad, bd, -(a * ad + b * bd) / c], -1)
        return x


# --------------------------------------------------------------------------- operating point


@dataclass(frozen=True)
class OperatingPoint:
    """A hover at rest of the closed loop: plant state (full, see :mod:`vtol_impedance.sim.plant`),
    controller state, what the sensors read, the reference, and the commands (thrust N, body torque N m
    FRD, rotor forces N) that hold it."""

    x: np.ndarray
    controller_state: ControllerState
    measurement: Measurement
    reference: Reference
    thrust: float
    tau_B: np.ndarray
    f_rotor: np.ndarray
    rp_d: np.ndarray  # desired roll and pitch of eq. (16), rad

    @property
    def eta(self) -> np.ndarray:
        """Attitude at the operating point (ZYX Euler, rad)."""
        return euler_from_rotation(quat_to_rotation(self.x[QUAT]))


class _Setup(NamedTuple):
    CA: Any
    PA: PlantArrays
    coords: _Coordinates
    ref: Reference
    template: ControllerState
    live: np.ndarray


def _reference(p_W: Any, psi: float, comply: Any) -> Reference:
    p = as_finite("operating point p_W", p_W, (3,))
    if p.shape != (3,):
        raise InputError(f"the operating point is one position of shape (3,), got shape {p.shape}")
    c = np.broadcast_to(as_finite("comply", comply), (6,)) if np.ndim(comply) == 0 else as_finite("comply", comply)
    if c.shape == (3,):
        c = np.concatenate([c, np.zeros(3)])
    if c.shape != (6,) or np.any((c < 0) | (c > 1)):
        raise InputError(f"comply must be 1, 3 or 6 fractions in [0, 1], got {np.asarray(comply).tolist()}")
    psi = scalar("psi", psi)
    return Reference(p, np.zeros(3), np.zeros(3), np.asarray(psi), np.asarray(0.0), np.asarray(0.0), c)


def _steady(force_W: Any, torque_B: Any):
    f = as_finite("force_W", force_W, (3,))
    tau = as_finite("torque_B", torque_B, (3,))
    if not (np.any(f) or np.any(tau)):
        return None

    def steady(t, p_W, v_W, R_WB):  # noqa: ANN001, ANN202
        return np.broadcast_to(f, p_W.shape), np.broadcast_to(tau, p_W.shape)

    return steady


def _lin_plant(plant: PlantParams) -> PlantParams:
    tau = equivalent_rotor_tau(plant.rotor_tau_up, plant.rotor_tau_down)
    # no ground: the model is of free flight (the simulator's ground is not touched at hover)
    return replace(plant, rotor_tau_up=tau, rotor_tau_down=tau, ground=False)


def operating_point(
    controller: ControllerParams,
    plant: PlantParams,
    p_W: Any = (0.0, 0.0, -1.0),
    psi: float = 0.0,
    comply: Any = 0.0,
    force_W: Any = (0.0, 0.0, 0.0),
    torque_B: Any = (0.0, 0.0, 0.0),
) -> OperatingPoint:
    """The closed loop's hover at rest at the reference ``p_W`` (world NED, m) and yaw ``psi`` (rad),
    with a steady external force ``force_W`` (N, world) and moment ``torque_B`` (N m, body) on the vehicle.

    Solved by Newton's method on the fixed point of one control period (plant at rest, controller state
    unchanged). Raises :class:`TrimError` where no such hover exists within the rotors' limits and the
    controller's tilt limit.
    """
    return _trim(_setup(controller, plant, p_W, psi, comply), force_W, torque_B)[0]


def _setup(controller: ControllerParams, plant: PlantParams, p_W: Any, psi: float, comply: Any) -> _Setup:
    if not isinstance(controller, ControllerParams):
        raise InputError(f"controller must be a ControllerParams, got {type(controller).__name__}")
    if not isinstance(plant, PlantParams):
        raise InputError(f"plant must be a PlantParams, got {type(plant).__name__}")
    if controller.vehicle.n_rotors != plant.vehicle.n_rotors:
        raise InputError(
            f"the controller's vehicle has {controller.vehicle.n_rotors} rotors and the plant's "
            f"{plant.vehicle.n_rotors}"
        )
    ref = _reference(p_W, psi, comply)
    CA = compile_controllers(controller)
    lin = _lin_plant(plant)
    PA = compile_plants(lin)
    x0 = initial_state(PA, ref.p_W, np.array([0.0, 0.0, float(ref.psi)]))
    coords = _Coordinates(PA, x0, lagless=lin.rotor_tau_up <= 0.0)
    meas0 = measurement(PA, x0, x0)
    S = initial_controller_state(CA)
    for _ in range(2):  # started: the estimator and the filter hold their first samples
        S, _out = controller_step(CA, S, meas0, ref)
    return _Setup(CA, PA, coords, ref, S, np.ones(flatten_state(S).size, dtype=bool))


def _controller_fn(su: _Setup):
    """``(s, y, d) -> (s', [thrust, tau_B], rp_d)`` batched: one period of the controller with the
    attitude stage fed the desired roll and pitch ``d``."""

    def fn(s: np.ndarray, y: np.ndarray, d: np.ndarray | None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        S = unflatten_state(su.template, s)
        meas = Measurement(y[..., 0:3], y[..., 3:6], y[..., 6:9], y[..., 9:12])
        pos = position_step(su.CA, S, meas, su.ref)
        rp_d = pos.rp_d
        S2, out = attitude_step(su.CA, S, meas, su.ref, pos if d is None else pos._replace(rp_d=d))
        v = np.concatenate([np.asarray(out.thrust_request)[..., None], out.tau_B_request], -1)
        return flatten_state(S2, su.template), v, rp_d

    return fn


def _measure(su: _Setup, x: np.ndarray) -> np.ndarray:
    m = measurement(su.PA, x, x)
    return np.concatenate([m.p_W, m.v_W, m.eta, m.eta_dot], -1)


def _live(su: _Setup, s: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Controller states that influence its outputs, directly or through other states."""
    fn = _controller_fn(su)
    h = 1e-6 * np.maximum(1.0, np.abs(s))
    AK = jacobian(lambda X: fn(X, np.broadcast_to(y, (len(X), y.size)), None)[0], s, h)
    out = jacobian(
        lambda X: np.concatenate(fn(X, np.broadcast_to(y, (len(X), y.size)), None)[1:], -1), s, h
    )  # fmt: skip
    tol = 1e-9
    live = np.any(np.abs(out) > tol, axis=0)
    while True:
        grown = live | np.any(np.abs(AK[live]) > tol, axis=0)
        if np.array_equal(grown, live):
            return live
        live = grown


def _trim(su: _Setup, force_W: Any, torque_B: Any) -> tuple[OperatingPoint, _Setup, Any]:
    steady = _steady(force_W, torque_B)
    need = float(np.linalg.norm((su.PA.mass + su.PA.pend_m) * GRAVITY_W + np.asarray(force_W, dtype=float)))
    have = float(np.sum(su.PA.f_max))
    if need > have:
        raise TrimError(
            f"the vehicle cannot hover here: it needs {need:.3g} N of thrust (its true mass with the payload and the "
            f"steady force), and its rotors give at most {have:.3g} N"
        )
    fn = _controller_fn(su)
    c = su.coords
    s0 = flatten_state(su.template)
    y0 = _measure(su, c.x_base)
    live = _live(su, s0, y0)
    su = su._replace(live=live)
    nx = c.size

    def residual(Z: np.ndarray) -> np.ndarray:
        xm = Z[..., :nx]
        s = np.broadcast_to(s0, Z.shape[:-1] + s0.shape).copy()
        s[..., live] = Z[..., nx:]
        x = c.full(xm, np.zeros(Z.shape[:-1] + (c.n,)))
        y = _measure(su, x)
        s2, v, _rp = fn(s, y, None)
        f = allocate(v[..., 0], v[..., 1:], su.CA.E, su.CA.E_pinv, su.CA.f_min, su.CA.f_max,
                     su.CA.thrust_shift_max).f  # fmt: skip
        return np.concatenate([_plant_rate(c, xm, f, steady), (s2 - s)[..., live]], -1)

    z = np.concatenate([c.reduce(c.x_base), s0[live]])
    scale = np.maximum(1.0, np.abs(z))
    for _ in range(60):
        r = residual(z[None])[0]
        if np.max(np.abs(r)) < 1e-10:
            break
        J = jacobian(residual, z, 1e-7 * scale)
        dz = np.linalg.lstsq(J, -r, rcond=None)[0]
        step = 1.0
        while step > 1e-3 and np.max(np.abs(residual((z + step * dz)[None])[0])) > np.max(np.abs(r)):
            step *= 0.5
        z = z + step * dz
    else:
        raise TrimError("no hover found at this operating point (Newton's method did not converge)")
    if np.max(np.abs(residual(z[None])[0])) > 1e-8:
        raise TrimError("no hover found at this operating point (Newton's method stalled)")
    s = s0.copy()
    s[live] = z[nx:]
    xm = z[:nx]
    y = _measure(su, c.full(xm, np.zeros(c.n)))
    S = unflatten_state(su.template, s)
    meas = Measurement(y[0:3], y[3:6], y[6:9], y[9:12])
    pos = position_step(su.CA, S, meas, su.ref)
    S2, out = attitude_step(su.CA, S, meas, su.ref, pos)
    x = c.full(xm, out.f_rotor)
    op = OperatingPoint(
        x, S, meas, su.ref, float(out.thrust), np.asarray(out.tau_B), np.asarray(out.f_rotor), np.asarray(pos.rp_d)
    )
    _check_trim(su, op, out, pos)
    coords = _Coordinates(su.PA, x, c.lagless)
    return op, su._replace(coords=coords, template=S), steady


def _check_trim(su: _Setup, op: OperatingPoint, out: Any, pos: Any) -> None:
    f, lo, hi = op.f_rotor, su.PA.f_min, su.PA.f_max
    if bool(out.saturated) or np.any(f > hi + 1e-9) or np.any(f < lo - 1e-9):
        i = int(np.argmax(np.maximum(f - hi, lo - f)))
        raise TrimError(
            f"the vehicle cannot hover here: rotor {i + 1} would need {f[i]:.3g} N, outside its limits "
            f"[{lo[i]:.3g}, {hi[i]:.3g}] N (total thrust {op.thrust:.3g} N for the true mass and the steady wrench)"
        )
    if bool(pos.tilt_limited):
        raise TrimError(
            f"the vehicle cannot hover here: the steady force needs more tilt than tilt_max "
            f"({np.degrees(su.CA.tilt_max):.0f} deg) or more lift than the rotors can give"
        )


# --------------------------------------------------------------------------- the linear loop


def _zoh(A: np.ndarray, B: np.ndarray, t: float) -> tuple[np.ndarray, np.ndarray]:
    """``exp(A t)`` and ``int_0^t exp(A s) ds B``."""
    n, m = B.shape
    aug = np.zeros((n + m, n + m))
    aug[:n, :n], aug[:n, n:] = A * t, B * t
    E = scipy.linalg.expm(aug)
    return E[:n, :n], E[:n, n:]


def _delay_split(delay: float, Ts: float) -> tuple[int, float]:
    """A latency as ``k`` whole periods and the rest ``0 <= frac < Ts`` (0 when within rounding)."""
    k = int(np.floor(delay / Ts + 1e-9))
    frac = delay - k * Ts
    return k, (0.0 if frac <= 1e-12 * Ts else frac)


def _modelled_delays(sensors: SensorParams, plant_rate: float) -> dict[str, float]:
    """The latencies the simulator flies (:class:`~vtol_impedance.sim.sensors.SensorSuite`): rounded to
    plant steps, s."""
    dt = 1.0 / plant_rate
    k_mocap, k_imu = latency_steps(sensors, dt)
    return {"position": k_mocap * dt, "attitude": k_imu * dt}


def sampled_plant(
    A: np.ndarray, B: np.ndarray, C_groups: list[tuple[np.ndarray, float]], Ts: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Discrete ``(A_d, B_d, C_d)`` at the period ``Ts`` of ``x' = A x + B u`` with ``u`` held over each
    period, read by output groups ``(C_i, delay_i)``: group ``i`` reports ``C_i x(t_k - delay_i)``.

    A delay ``n Ts + delta`` (``0 <= delta < Ts``) is the output ``w_j = C exp(A (Ts - delta)) x_j +
    C int_0^{Ts - delta} exp(A s) ds B u_j`` (the state ``Ts - delta`` into period ``j``, exact for held
    inputs; ``C x_j`` when ``delta = 0``) passed through a line of ``n + 1`` (``n`` when ``delta = 0``) unit
    delays. State: ``[x_k, the delay lines]``. No feedthrough: ``D_d = 0``.
    """
    nx, nu = B.shape
    Phi, Gam = _zoh(A, B, Ts)
    reads = []
    for C, delay in C_groups:
        k, frac = _delay_split(delay, Ts)
        if frac == 0.0:
            reads.append((C, np.zeros((C.shape[0], nu)), k))
        else:
            P2, G2 = _zoh(A, B, Ts - frac)
            reads.append((C @ P2, C @ G2, k + 1))
    n_line = sum(Cx.shape[0] * k for Cx, _, k in reads)
    nz = nx + n_line
    ny = sum(Cx.shape[0] for Cx, _, _ in reads)
    Ad = np.zeros((nz, nz))
    Bd = np.zeros((nz, nu))
    Cd = np.zeros((ny, nz))
    Ad[:nx, :nx], Bd[:nx] = Phi, Gam
    row, pos = 0, nx
    for Cx, Du, k in reads:
        m = Cx.shape[0]
        if k == 0:
            Cd[row : row + m, :nx] = Cx
        else:  # w_k enters the line; each step moves it on; the last slot is read
            Ad[pos : pos + m, :nx], Bd[pos : pos + m] = Cx, Du
            for j in range(1, k):
                Ad[pos + m * j : pos + m * (j + 1), pos + m * (j - 1) : pos + m * j] = np.eye(m)
            Cd[row : row + m, pos + m * (k - 1) : pos + m * k] = np.eye(m)
            pos += m * k
        row += m
    return Ad, Bd, Cd


@dataclass(frozen=True)
class LinearLoop:
    """The closed loop linearised at ``op``, sampled at ``Ts``, as three python-control blocks:

    * ``plant``: rotor commands ``f[i]`` (N) to the measurement ``y`` (:data:`MEASUREMENTS`), with the
      rotors, the rigid body and the sensors' latencies;
    * ``allocation``: ``v = [thrust, tau_x, tau_y, tau_z]`` (N, N m FRD) to ``f[i]`` (static);
    * ``controller``: ``y`` and the desired roll and pitch ``d[0..1]`` fed to the attitude stage, to ``v``
      and ``r[0..1]``, the desired roll and pitch eq. (16) computes (closed: ``d = r``).

    ``delays`` are the latencies modelled (s, rounded to plant steps), ``rotor_tau`` the equivalent lag.
    """

    Ts: float
    plant: ct.StateSpace
    allocation: ct.StateSpace
    controller: ct.StateSpace
    op: OperatingPoint
    delays: dict[str, float]
    rotor_tau: float

    def closed(self) -> ct.StateSpace:
        """The closed loop (no inputs; outputs the commands ``v``)."""
        return self._interconnect(None, [], [f"ctrl.{v}" for v in COMMANDS])

    def poles(self) -> np.ndarray:
        """Closed-loop poles as continuous-time equivalents ``s = ln(z) / Ts`` (rad/s); pure delays
        (``z = 0``) are left out."""
        z = np.linalg.eigvals(self.closed().A)
        z = z[np.abs(z) > 1e-9]
        return np.log(z.astype(complex)) / self.Ts

    def loop(self, name: str) -> ct.StateSpace:
        """The loop transfer ``L(z)`` broken at ``name`` (:data:`LOOPS`) with every other loop closed, in
        the negative-feedback convention (the loop is closed by ``1 + L``)."""
        if name not in LOOPS:
            raise InputError(f"unknown loop {name!r}; the loops are {', '.join(LOOPS)}")
        i = LOOPS.index(name)
        if i < 4:
            inp, out = f"alloc.{COMMANDS[i]}", f"ctrl.{COMMANDS[i]}"
        else:
            inp, out = f"ctrl.{ATTITUDE_IN[i - 4]}", f"ctrl.{ATTITUDE_OUT[i - 4]}"
        sys = self._interconnect(i, [inp], [out])
        return ct.ss(sys.A, sys.B, -sys.C, -sys.D, self.Ts, inputs=[name], outputs=[name], name=f"L {name}")

    def _interconnect(self, skip: int | None, inputs: list[str], outputs: list[str]) -> ct.StateSpace:
        """The blocks joined by their connections (all but loop ``skip``), with external ``inputs`` added
        at block inputs and ``outputs`` read at block outputs (``"block.signal"``), solved exactly:
        ``u = M y + E w`` with ``y = C x + D u`` gives ``u = (I - M D)^{-1} (M C x + E w)``."""
        blocks = {"plant": self.plant, "alloc": self.allocation, "ctrl": self.controller}
        u_index, y_index = {}, {}
        nu = ny = nx = 0
        A_list, B_list, C_list, D_list = [], [], [], []
        for name, sysb in blocks.items():
            for lab in sysb.input_labels:
                u_index[f"{name}.{lab}"] = nu
                nu += 1
            for lab in sysb.output_labels:
                y_index[f"{name}.{lab}"] = ny
                ny += 1
            nx += sysb.nstates
            A_list.append(sysb.A)
            B_list.append(sysb.B)
            C_list.append(sysb.C)
            D_list.append(sysb.D)
        A, B, C, D = (scipy.linalg.block_diag(*parts) for parts in (A_list, B_list, C_list, D_list))
        M = np.zeros((nu, ny))
        for dst, src in self._connections(skip):
            M[u_index[dst], y_index[src]] = 1.0
        E = np.zeros((nu, len(inputs)))
        for j, name in enumerate(inputs):
            E[u_index[name], j] = 1.0
        P = np.zeros((len(outputs), ny))
        for j, name in enumerate(outputs):
            P[j, y_index[name]] = 1.0
        W = np.linalg.solve(np.eye(nu) - M @ D, np.hstack([M @ C, E]))  # u = W [x; w]
        Wx, Ww = W[:, :nx], W[:, nx:]
        return ct.ss(A + B @ Wx, B @ Ww, P @ (C + D @ Wx), P @ D @ Ww, self.Ts)

    def _connections(self, skip: int | None) -> list[tuple[str, str]]:
        """``(destination input, source output)`` pairs of the closed loop, without loop ``skip``."""
        conns = [(f"plant.{f}", f"alloc.{f}") for f in self.allocation.output_labels]
        conns += [(f"ctrl.{y}", f"plant.{y}") for y in MEASUREMENTS]
        conns += [(f"alloc.{v}", f"ctrl.{v}") for j, v in enumerate(COMMANDS) if j != skip]
        pairs = enumerate(zip(ATTITUDE_IN, ATTITUDE_OUT, strict=True))
        conns += [(f"ctrl.{a}", f"ctrl.{b}") for j, (a, b) in pairs if skip != 4 + j]
        return conns


def _check_size(controller: ControllerParams, plant: PlantParams, delays: dict[str, float]) -> None:
    """Refuse, before any work, a loop of more than :data:`MAX_LOOP_STATES` states: the plant's minimal
    coordinates and the latencies' delay lines (six states per control period, as :func:`sampled_plant`)."""
    if not isinstance(controller, ControllerParams) or not isinstance(plant, PlantParams):
        return  # named by _setup
    Ts = float(controller.Ts)
    periods = [k + (frac > 0) for k, frac in (_delay_split(d, Ts) for d in delays.values())]
    lines = 6 * sum(periods)
    n = 12 + plant.vehicle.n_rotors + (4 if plant.pendulum_mass > 0 else 0) + lines
    if n > MAX_LOOP_STATES:
        raise LoopSizeError(
            f"the linearised loop would have {n} states, more than MAX_LOOP_STATES = {MAX_LOOP_STATES}: a "
            f"{1e3 * delays['position']:g} ms position and {1e3 * delays['attitude']:g} ms attitude latency are "
            f"{sum(periods)} control periods at {1.0 / Ts:g} Hz, each a line of six states; lower the latency or "
            "the control rate to have margins computed"
        )


def linearize(
    controller: ControllerParams,
    plant: PlantParams,
    sensors: SensorParams | None = None,
    p_W: Any = (0.0, 0.0, -1.0),
    psi: float = 0.0,
    comply: Any = 0.0,
    force_W: Any = (0.0, 0.0, 0.0),
    torque_B: Any = (0.0, 0.0, 0.0),
    plant_rate: float = 1000.0,
) -> LinearLoop:
    """Linearise the sampled closed loop at the hover of :func:`operating_point` (see the module docstring).

    ``sensors`` gives the latencies (noise is irrelevant here); ``plant_rate`` (Hz) the plant step the
    simulator rounds them to.
    """
    sensors = SensorParams() if sensors is None else sensors
    if not isinstance(sensors, SensorParams):
        raise InputError(f"sensors must be a SensorParams, got {type(sensors).__name__}")
    plant_rate = scalar("plant_rate", plant_rate, lo=0.0, lo_open=True)
    delays = _modelled_delays(sensors, plant_rate)
    _check_size(controller, plant, delays)
    su = _setup(controller, plant, p_W, psi, comply)
    op, su, steady = _trim(su, force_W, torque_B)
    Ts = float(su.CA.Ts)
    c = su.coords
    fn = _controller_fn(su)
    live = su.live
    s = flatten_state(op.controller_state)
    y = np.concatenate([op.measurement.p_W, op.measurement.v_W, op.measurement.eta, op.measurement.eta_dot])
    d = op.rp_d
    xm = c.reduce(op.x)
    n = c.n

    # Plant: A, B in minimal coordinates (held commands), the sensors' output maps.
    hx = 1e-6
    A = jacobian(lambda X: _plant_rate(c, X, op.f_rotor, steady), xm, hx)
    B = jacobian(lambda F: _plant_rate(c, np.broadcast_to(xm, (len(F), xm.size)), F, steady), op.f_rotor, hx)
    Cs = jacobian(lambda X: _measure(su, c.full(X, np.broadcast_to(op.f_rotor, (len(X), n)))), xm, hx)
    Ad, Bd, Cd = sampled_plant(A, B, [(Cs[:6], delays["position"]), (Cs[6:], delays["attitude"])], Ts)
    rotors = [f"f{i + 1}" for i in range(n)]
    plant_ss = ct.ss(Ad, Bd, Cd, 0.0, Ts, inputs=rotors, outputs=list(MEASUREMENTS), name="plant")

    # Allocation: the controller's own allocator, differentiated.
    v0 = np.concatenate([[op.thrust], op.tau_B])
    CA = su.CA
    F = jacobian(
        lambda V: allocate(V[..., 0], V[..., 1:], CA.E, CA.E_pinv, CA.f_min, CA.f_max, CA.thrust_shift_max).f, v0, 1e-6
    )
    alloc_ss = ct.ss(
        np.zeros((0, 0)), np.zeros((0, 4)), np.zeros((n, 0)), F, Ts, inputs=list(COMMANDS), outputs=rotors,
        name="alloc",
    )  # fmt: skip

    # Controller: states that matter, inputs y and d, outputs v and r.
    def state_next(X: np.ndarray) -> np.ndarray:
        S = np.broadcast_to(s, (len(X), s.size)).copy()
        S[:, live] = X
        return S

    hs = 1e-6 * np.maximum(1.0, np.abs(s[live]))
    by = np.broadcast_to

    def f_s(X: np.ndarray) -> np.ndarray:
        s2, v, r = fn(state_next(X), by(y, (len(X), y.size)), by(d, (len(X), 2)))
        return np.concatenate([s2[:, live], v, r], -1)

    def f_y(Y: np.ndarray) -> np.ndarray:
        s2, v, r = fn(by(s, (len(Y), s.size)), Y, by(d, (len(Y), 2)))
        return np.concatenate([s2[:, live], v, r], -1)

    def f_d(D: np.ndarray) -> np.ndarray:
        s2, v, r = fn(by(s, (len(D), s.size)), by(y, (len(D), y.size)), D)
        return np.concatenate([s2[:, live], v, r], -1)

    Js, Jy, Jd = jacobian(f_s, s[live], hs), jacobian(f_y, y, 1e-6), jacobian(f_d, d, 1e-6)
    ns = int(live.sum())
    AK, CK = Js[:ns], Js[ns:]
    BK = np.hstack([Jy[:ns], Jd[:ns]])
    DK = np.hstack([Jy[ns:], Jd[ns:]])
    ctrl_ss = ct.ss(
        AK, BK, CK, DK, Ts, inputs=list(MEASUREMENTS + ATTITUDE_IN), outputs=list(COMMANDS + ATTITUDE_OUT),
        name="ctrl",
    )  # fmt: skip
    tau_eq = equivalent_rotor_tau(plant.rotor_tau_up, plant.rotor_tau_down)
    return LinearLoop(Ts, plant_ss, alloc_ss, ctrl_ss, op, delays, tau_eq)


def _plant_rate(c: _Coordinates, X: np.ndarray, f_cmd: np.ndarray, steady: Any) -> np.ndarray:
    """Time derivative of the minimal coordinates for held commands ``f_cmd`` (the rotation vector's is
    the body rate: exact to first order about a state at rest)."""
    x = c.full(X, f_cmd)
    xd = plant_derivative(c.PA, x, f_cmd, 0.0, steady)
    parts = [xd[..., P_COM], xd[..., V_COM], x[..., OMEGA], xd[..., OMEGA]]
    if not c.lagless:
        parts.append(xd[..., N_BODY : N_BODY + c.n])
    if c.pend:
        parts += [x[..., PEND_V][..., :2], xd[..., PEND_V][..., :2]]
    return np.concatenate(parts, -1)
