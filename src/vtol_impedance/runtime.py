"""The controller for a flight loop (a ROS node, a companion computer, another simulator): eqs. (6)-(20)
behind one object that keeps its state, checks its inputs, and runs either backend.

It sits above both executions of the same equations, the NumPy reference (:mod:`vtol_impedance.control`)
and the compiled kernels (:mod:`vtol_impedance.compiled`), so that neither imports the other.
"""

from __future__ import annotations

import math
import sys
import warnings
from collections.abc import Callable, Sequence
from typing import NamedTuple, TypeVar

import numpy as np

from .control.impedance import (
    ControllerArrays,
    ControllerParams,
    compile_controllers,
    controller_step,
    initial_controller_state,
)
from .control.signals import ControlOutput, Measurement, Reference, comply6
from .conventions import MAX_PITCH_RAD, G
from .errors import InputError, SingularityError, as_finite, scalar
from .estimator.momentum import EstimatorDesign, EstimatorParams, estimator_step
from .estimator.momentum import design as design_estimator
from .estimator.momentum import initial_state as estimator_initial_state
from .model.dynamics import body_moment_from_euler
from .model.kinematics import check_euler_regular, euler_rate_matrix_Q
from .model.mixer import moment_reach
from .model.vehicle import HoverWarning, warn_if_cannot_hover

_T = TypeVar("_T")
_F8 = np.dtype(np.float64)
_ND = np.ndarray
_ONE_F8 = (8,)  # the strides of a contiguous vector of float64


#: :meth:`Controller.step` warns once when the estimated external force exceeds this many times the
#: nominal weight: a payload, wind or a push on a multirotor stays well below it (the paper's case
#: studies: 0.09), the ground under a vehicle at rest gives 1, while inputs in a wrong frame (ENU read
#: as NED) gave 2.6 in a test flight.
IMPLAUSIBLE_ESTIMATE = 1.5
#: ... and when the estimated external moment (body FRD) exceeds this many times what the rotors can give about
#: that axis: a vehicle that flies holds its moments within its rotors' reach, while rotors with the wrong spins
#: or positions in FLU read as FRD (a foreign simulator, twelfth stop) gave a yaw estimate of 1.7 times it.
IMPLAUSIBLE_MOMENT = 1.5
#: ... held that long (s): a hard landing or a knock gives a moment estimate beyond the rotors' reach for a
#: moment (the estimator's filter spreads an impulse over a few 1/wn, 0.1-0.25 s at the paper's and the designed
#: bandwidths); a wrong spin or position holds it as long as the vehicle flies.
MOMENT_PERSIST_S = 0.5
#: :meth:`Controller.step` warns once when the yaw reference is further than this (rad) from the measured yaw.
#: Eq. (20) turns the desired roll and pitch with the *desired* yaw, so while the heading catches up, the tilt
#: that holds a steady horizontal force (wind, a push, a payload's offset) points the wrong way: with 2 N held
#: sideways, a heading step of 0.5 rad moved a 1 kg quadrotor 2.5 cm, of pi/2 32 cm, of pi 3.1 m (a foreign
#: simulator), and the Pelican 0.4-0.6 m for pi in this project's own (twelfth stop); ramped at 1 rad/s, pi
#: moved it 0.8 cm. Below 0.5 rad the excursion is a few centimetres.
YAW_GAP_RAD = 0.5


#: With the clock ``t`` given to a step, a period that differs from ``Ts`` by more than this share of it is
#: warned about: a real-time loop's jitter stays well inside it, a loop run at another rate than the
#: controller's ``Ts`` (a simulator stepping it at 200 Hz with the default 100 Hz) or a gap is far outside.
PERIOD_TOLERANCE = 0.5
#: ... and a mean period over at least :data:`MEAN_MIN_STEPS` timed steps that differs from ``Ts`` by more
#: than this share: a loop at 70 or 130 Hz with a 100 Hz controller (each period inside the tolerance above)
#: left the estimate of a 1 N step 0.15-0.25 N off G(s) F in a foreign simulator, against 0.035 N on time.
MEAN_TOLERANCE = 0.05
#: The fewest timed steps whose mean period is judged (:data:`MEAN_TOLERANCE`).
MEAN_MIN_STEPS = 20


class _Clock:
    """The optional clock of :meth:`Controller.step` and :meth:`Estimator.step`: time must advance, and a
    period far from ``Ts`` (:data:`PERIOD_TOLERANCE`), or a mean period off it (:data:`MEAN_TOLERANCE`), is
    warned about once until ``reset()``: the estimator differentiates the momentum over ``Ts`` and the
    filters advance by ``Ts`` per step, so a step every ``2 Ts`` doubles the rate of change of momentum it
    sees: in motion the estimate is off by ``m a``, in silence. An untimed step forgets the clock."""

    def __init__(self, Ts: float) -> None:
        self.Ts = float(Ts)
        self.t_prev: float | None = None
        self.t_first: float | None = None
        self.n = 0

    def check(self, t: object, warned: set[str], who: str, stacklevel: int = 4) -> float | None:
        """``t`` as a float (s) that comes after the last step's, or :class:`InputError`; None stays None.
        Warns, before the step is taken (an error filter then leaves the state unchanged)."""
        if t is None:
            return None
        narrow = isinstance(t, np.floating) and np.finfo(type(t)).bits < 64
        t = scalar("t (the step's time, s)", t)
        if self.t_prev is None:
            return t
        if not t > self.t_prev:
            hint = " (a float32 time rounds steps of a large clock together: pass seconds as float64)" if narrow else ""
            raise InputError(
                f"t = {t!r} s does not come after the previous step's t = {self.t_prev!r} s{hint}: the clock must "
                "advance by Ts every step (reset() starts a new flight; the state is unchanged)"
            )
        dt = t - self.t_prev
        mean = (t - self.t_first) / (self.n + 1)  # t_first is set with t_prev
        if "period" not in warned and abs(dt / self.Ts - 1.0) > PERIOD_TOLERANCE:
            said = f"stepped {dt:.6g} s after its previous step"
        elif "period" not in warned and self.n + 1 >= MEAN_MIN_STEPS and abs(mean / self.Ts - 1.0) > MEAN_TOLERANCE:
            said = f"stepped every {mean:.6g} s on average over its last {self.n + 1} steps"
        else:
            return t
        warned.add("period")
        warnings.warn(
            f"{who} was {said}, but it was built for a step every Ts = {self.Ts:g} s ({1.0 / self.Ts:g} Hz): its "
            "estimate and filters assume Ts, so a loop at another rate gives a wrong estimate in silence. Build it "
            "with Ts = your period (or step it every Ts); after a gap in the data call reset(); warned once until "
            "reset()",
            ControllerWarning,
            stacklevel=stacklevel,
        )
        return t

    def commit(self, t: float | None) -> None:
        """Record a step taken at ``t`` (None: an untimed step, which forgets the clock)."""
        if t is None:
            self.t_prev = self.t_first = None
            self.n = 0
            return
        if self.t_first is None:
            self.t_first, self.n = t, 0
        else:
            self.n += 1
        self.t_prev = t


_PITCH_RANGE = (
    "pitch theta = {theta:.4g} rad is beyond +-pi/2, where ZYX Euler angles keep it: are the angles in degrees, "
    "or of another Euler sequence? (eta = [roll, pitch, yaw] of R = Rz(yaw) Ry(pitch) Rx(roll), in rad; "
    "Measurement.from_frames converts a quaternion)"
)


def _check_attitude(eta: np.ndarray) -> None:
    """A ZYX pitch within +-pi/2 and away from its singularity (:class:`SingularityError`)."""
    pitch = np.abs(eta[..., 1])
    if np.any(pitch > MAX_PITCH_RAD):
        raise InputError(_PITCH_RANGE.format(theta=float(np.max(pitch))))
    check_euler_regular(eta)


def _euler_rates(eta: np.ndarray, omega_B: np.ndarray) -> np.ndarray | None:
    """``eta_dot = Q(eta)^-1 omega_B`` of eq. (1c) in closed form for one vehicle (a 3x3 solve costs more
    than the step); None where it does not exist (a non-finite value, the singularity, a wrong shape)."""
    if omega_B.shape != (3,) or not (np.isfinite(eta).all() and np.isfinite(omega_B).all()):
        return None
    cf, sf, ct, st = math.cos(eta[0]), math.sin(eta[0]), math.cos(eta[1]), math.sin(eta[1])
    if abs(ct) < 1e-9:
        return None
    p, q, r = float(omega_B[0]), float(omega_B[1]), float(omega_B[2])
    psi_dot = (sf * q + cf * r) / ct
    return np.array((p + st * psi_dot, cf * q - sf * r, psi_dot))


class ControllerWarning(UserWarning):
    """Something the controller did that a user should know of (once per cause and :class:`Controller`)."""


def _caller() -> int:
    """The ``stacklevel`` of the first frame outside this module: a warning raised here points at the user's
    line whichever path (timed, untimed, single, batch) led to it."""
    frame, level = sys._getframe(1), 1
    while frame is not None and frame.f_code.co_filename == __file__:
        frame, level = frame.f_back, level + 1
    return level


def _rebuilt(cls: type, args: tuple, kwargs: dict, learnt: dict) -> object:
    """A :class:`Controller` or :class:`Estimator` built afresh, then given what another learnt (a copy, an
    unpickling): arrays are filled in place, since the compiled step holds them. The original warned of its
    vehicle already."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", HoverWarning)
        obj = cls(*args, **kwargs)
    for name, value in learnt.items():
        old = getattr(obj, name, None)
        if isinstance(old, np.ndarray) and isinstance(value, np.ndarray) and old.shape == value.shape:
            old[...] = value
        else:
            setattr(obj, name, value)
    return obj


class _Learns:
    """Copies and pickles of an object that learns in flight: independent of the original (a copy stepped
    does not move the original's estimate), with what it learnt so far, on either backend. The compiled
    kernels are not data: a copy builds its own."""

    _LEARNT: tuple[str, ...] = ()

    def _init_args(self) -> tuple[tuple, dict]:
        raise NotImplementedError

    def __reduce__(self) -> tuple:
        args, kwargs = self._init_args()
        return (_rebuilt, (type(self), args, kwargs, {n: getattr(self, n) for n in self._LEARNT if hasattr(self, n)}))

    def __copy__(self) -> object:
        import copy

        return copy.deepcopy(self)  # a shallow copy would share the estimate and the filters


def _vec_input(name: str, value: object, bs: tuple[int, ...], who: str = "this controller") -> np.ndarray:
    arr = as_finite(name, value, (3,))
    if arr.shape[:-1] != bs:
        raise InputError(f"{name} has shape {arr.shape}; {who} expects {bs + (3,)}")
    return arr


def _scalar_input(name: str, value: object, bs: tuple[int, ...]) -> np.ndarray:
    arr = as_finite(name, value)
    if arr.shape not in ((), bs):
        expected = "a scalar" if not bs else f"a scalar or shape {bs}"
        raise InputError(f"{name} has shape {arr.shape}; this controller expects {expected}")
    return arr


def _vector3(name: str, value: object, limit: float) -> np.ndarray:
    """One finite, plausible 3-vector (a batch of them, ``(1, 3)``, is refused: one sample is one vehicle's)."""
    return _plausible(name, _vec_input(name, value, (), "one sample of the estimator"), limit)


_ANGLES = ("eta", "psi_d")


def _plausible(name: str, value: np.ndarray, limit: float) -> np.ndarray:
    """Refuse a finite value beyond any vehicle's (it would overflow the arithmetic and poison the state)."""
    if np.any(np.abs(value) > limit):
        hint = " (an angle: wrap it into [-pi, pi); the controller wraps the yaw error itself)"
        hint = hint if name in _ANGLES else ""
        raise InputError(
            f"{name} = {np.asarray(value).tolist()} is beyond any vehicle's (|{name}| <= {limit:g}){hint}; the "
            "controller's state is unchanged"
        )
    return value


def _comply_input(value: object, bs: tuple[int, ...]) -> np.ndarray:
    arr = as_finite("comply (Reference.comply)", value)
    if arr.shape not in ((), (3,), (6,), bs + (3,), bs + (6,)):
        raise InputError(
            f"Reference.comply has shape {arr.shape}; give a fraction, 3 fractions (x, y, z), 6 (x, y, z, roll, "
            f"pitch, yaw) or {bs + (6,)}"
        )
    if np.any((arr < 0) | (arr > 1)):
        raise InputError(f"Reference.comply must be within [0, 1] (0 rejects, 1 complies), got {arr.tolist()}")
    return np.broadcast_to(comply6(arr), bs + (6,))


def _describe(a: object) -> str:
    if type(a) is not np.ndarray:
        return type(a).__name__
    layout = "" if a.flags.c_contiguous else "non-contiguous "
    return f"{layout}{a.dtype} array of shape {a.shape}"


def _plain(out: ControlOutput) -> ControlOutput:
    """One vehicle's output with plain numbers where the batch has arrays of shape ``()``."""
    return out._replace(
        thrust=float(out.thrust),
        thrust_request=float(out.thrust_request),
        saturated=bool(out.saturated),
        tilt_limited=bool(out.tilt_limited),
        rp_scale=float(out.rp_scale),
        yaw_scale=float(out.yaw_scale),
    )


class Controller(_Learns):
    """Stateful controller + estimator for use outside the simulator (a flight loop, a ROS node).

    >>> import numpy as np
    >>> from vtol_impedance import Controller
    >>> from vtol_impedance.control import ControllerParams, Measurement, Reference
    >>> ctrl = Controller(ControllerParams.paper("pdc"))
    >>> p_W, v_W, eta, gyro = np.array([0, 0, -1.0]), np.zeros(3), np.zeros(3), np.zeros(3)
    >>> out = ctrl.step(Measurement(p_W, v_W, eta, omega_B=gyro), Reference(np.array([0, 0, -1.0])))
    >>> round(out.thrust, 2)  # hovering at the reference: the nominal weight, 1.2 kg x 9.81 m/s^2
    11.77

    :meth:`step` validates its inputs (numeric, finite, shape ``(3,)`` or the batch's ``(B, 3)``, away from
    the Euler singularity) and returns a :class:`ControlOutput` (plain floats and ``(3,)`` arrays for one
    vehicle). :meth:`step_arrays` is the low-overhead path for real-time loops: flat ``y = [p_W, v_W, eta,
    eta_dot]`` and ``r = [p_d, v_d, a_d, psi_d, psi_dot_d, psi_ddot_d]`` (float64, shape ``(12,)``, or
    ``(15,)`` or ``(18,)`` with the comply fractions of the world axes, or of the world axes and the Euler
    angles, appended) in, a flat
    output record out (:data:`vtol_impedance.compiled.layouts.OUTPUT`, fields named as :class:`ControlOutput`),
    one compiled call.

    The controller keeps what it learnt in flight (the wrench estimate, the attitude filter, the PID
    integral, the last command); :meth:`reset` forgets it. Call it before every new flight.

    ``backend="compiled"`` (default) runs the numba kernels, ``"numpy"`` the reference functions of this
    module; both compute the same numbers. A :class:`ControllerWarning` is issued once per cause
    (rotor saturation, tilt limit, an implausible estimate, a yaw reference far from the measured yaw:
    :data:`YAW_GAP_RAD`) per controller and :meth:`reset`. ``params``, ``backend`` and ``arrays`` are read-only:
    build a new controller for other parameters. A copy (``copy.copy``, ``copy.deepcopy``, ``pickle``) is an
    independent controller with what this one learnt so far.
    """

    _LEARNT = ("state", "_warned", "_moment_high", "_clock", "_s", "_h")

    def __init__(self, params: ControllerParams | Sequence[ControllerParams], backend: str = "compiled") -> None:
        if backend not in ("compiled", "numpy"):
            raise InputError(f"backend must be 'compiled' or 'numpy', got {backend!r}")
        single = isinstance(params, ControllerParams)
        if not single and (
            isinstance(params, str)
            or not hasattr(params, "__iter__")
            or not all(isinstance(p, ControllerParams) for p in params)  # type: ignore[union-attr]
        ):
            raise InputError(f"params must be a ControllerParams or a sequence of them, got {params!r:.80}")
        # a snapshot: a list changed later changes neither this controller nor its copies
        self._params = params if single else tuple(params)  # type: ignore[arg-type]
        self._backend = backend
        self._arrays = compile_controllers(self._params)
        each = (self._params,) if single else self._params
        for vehicle in {id(p.vehicle): p.vehicle for p in each}.values():  # type: ignore[union-attr]
            warn_if_cannot_hover(vehicle, stacklevel=2)
        if backend == "compiled":
            from .compiled import controller as kernels

            batch = self.arrays if self.arrays.batch_shape else compile_controllers([params])  # type: ignore[list-item]
            self._k = kernels
            self._p, self._d = kernels.pack_controller(batch)
            self._nr = batch.E.shape[-1]
            self._out = kernels.new_output(self._p.shape[0])
            self._out_views = [self._out[b] for b in range(self._p.shape[0])]  # each vehicle's record, a view
            self._step_entry = kernels.checked_step_entry()
        #: What :meth:`step_arrays` calls, in one tuple (one attribute read per call); None with NumPy.
        self._fast: tuple | None = None
        self._weight = np.asarray(self.arrays.mass) * G
        self._reach_B = moment_reach(self.arrays.E, self.arrays.f_min, self.arrays.f_max)
        self.reset()

    @property
    def params(self) -> ControllerParams | Sequence[ControllerParams]:
        """What the controller was built from (read-only: build a new one for other parameters)."""
        return self._params

    @property
    def backend(self) -> str:
        return self._backend

    @property
    def arrays(self) -> ControllerArrays:
        """The parameters as arrays (:func:`vtol_impedance.control.compile_controllers`), read-only."""
        return self._arrays

    def _init_args(self) -> tuple[tuple, dict]:
        return (self._params,), {"backend": self._backend}

    @property
    def n_rotors(self) -> int:
        return int(self.arrays.E.shape[-1])

    def reset(self) -> None:
        """Forget the wrench estimate, the attitude filter, the PID integral and the held command.

        Without it a controller reused for a second flight starts with the first flight's estimate.
        """
        self.state = initial_controller_state(self.arrays)
        self._warned: set[str] = set()
        self._moment_high = 0  # steps in a row with an implausible moment estimate
        self._clock = _Clock(self.arrays.Ts)
        if self.backend == "compiled":
            self._s, self._h = self._k.initial_state(self._p, self._d)
            self._fast = (self._step_entry, self._p, self._d, self._s, self._h, self._out, self._out_views)

    def step_arrays(self, y: np.ndarray, r: np.ndarray, vehicle: int = 0, t: float | None = None) -> np.void:
        """One compiled step for ``vehicle`` with flat inputs ``y (12,)`` and ``r (12,)``, ``(15,)`` or
        ``(18,)`` (with ``comply`` for x, y, z or for x, y, z, roll, pitch, yaw), C-contiguous float64.

        Returns the output record (:data:`vtol_impedance.compiled.layouts.OUTPUT`: ``out["f_rotor"][:n]``,
        ``out["f_hat_W"]``, ``out["thrust"]``, ...; a view, overwritten by the next call). Raises
        :class:`InputError` on a wrong type, dtype, shape, a non-finite value or a pitch beyond +-pi/2, and
        :class:`SingularityError` at theta = +-90 deg. ``y`` holds Euler rates, not the gyro's body rates
        (``eta_dot = Q(eta)^-1 omega_B``). ``t``: the step's time (s, any clock; for a batch, vehicle 0's
        steps are timed), checked as :meth:`step` checks it.
        """
        timed = None  # vehicle 0's time, checked: only its steps advance the clock
        if t is not None:
            if vehicle == 0:
                timed = self._clock.check(t, self._warned, "the controller", stacklevel=3)
            else:
                scalar("t (the step's time, s)", t)
        elif vehicle == 0 and self._clock.t_prev is not None:
            self._clock.commit(None)  # an untimed step: the next timed one starts the clock again
        fast = self._fast
        if fast is None:
            raise InputError("step_arrays needs backend='compiled'")
        entry, p, d, s, h, o, views = fast
        if type(vehicle) is not int and isinstance(vehicle, np.integer):
            vehicle = int(vehicle)  # an index from NumPy (np.arange, np.flatnonzero) is an index
        if type(vehicle) is not int or not 0 <= vehicle < len(views):
            raise InputError(f"step_arrays: vehicle must be an int in [0, {len(views)}), got {vehicle!r}")
        # the compiled entry point skips numba's dispatch (a microsecond); its argument types are checked here
        if type(y) is _ND is type(r) and y.dtype is _F8 is r.dtype and y.strides == _ONE_F8 == r.strides:
            status = entry(p, d, s, h, vehicle, y, r, o)
        else:
            status = 3
        out = views[vehicle]
        if status:
            if status == 3:
                raise InputError(
                    "step_arrays: y and r must be C-contiguous float64 arrays of shape (12,) (r: or (15,) or (18,)), "
                    f"got {_describe(y)} and {_describe(r)}"
                )
            if status == 2:
                raise SingularityError(f"pitch theta = {np.degrees(y[7]):.3f} deg is at the Euler singularity")
            if status == 6:
                raise InputError(_PITCH_RANGE.format(theta=y[7]))
            if status == 4:
                raise InputError(f"comply fractions must be within [0, 1] (0 rejects, 1 complies), got {r[12:]}")
            if status == 5:
                raise InputError(
                    f"a measurement or reference beyond any vehicle's (|p| <= 1e6 m, |v| <= 1e4 m/s, |eta| <= 1e3 rad, "
                    f"rates <= 1e4 rad/s): y = {y}, r = {r}; the controller's state is unchanged"
                )
            raise InputError(f"non-finite measurement or reference: y = {y}, r = {r}")
        if timed is not None:
            self._clock.commit(timed)
        return out

    def _measurement(self, meas: Measurement, bs: tuple[int, ...]) -> Measurement:
        if not isinstance(meas, Measurement):
            raise InputError(f"step expects a Measurement, got {type(meas).__name__}")
        p_W, v_W, eta = (_vec_input(n, v, bs) for n, v in (("p_W", meas.p_W), ("v_W", meas.v_W), ("eta", meas.eta)))
        for name, v, lim in (("p_W", p_W, 1e6), ("v_W", v_W, 1e4), ("eta", eta, 1e3)):
            _plausible(name, v, lim)
        if (meas.eta_dot is None) == (meas.omega_B is None):
            raise InputError("Measurement needs exactly one of eta_dot (Euler rates) or omega_B (gyro body rates)")
        _check_attitude(eta)
        if meas.eta_dot is not None:
            eta_dot = _plausible("eta_dot", _vec_input("eta_dot", meas.eta_dot, bs), 1e4)
        else:
            omega_B = _plausible("omega_B", _vec_input("omega_B", meas.omega_B, bs), 1e4)
            eta_dot = np.linalg.solve(euler_rate_matrix_Q(eta), omega_B[..., None])[..., 0]
        return Measurement(p_W, v_W, eta, eta_dot)

    def _timed(self, t: object, step: Callable[[], _T]) -> _T:
        """``step()`` at the time ``t`` (:class:`_Clock`)."""
        tt = self._clock.check(t, self._warned, "the controller", stacklevel=5)
        out = step()
        self._clock.commit(tt)
        return out

    def step(self, meas: Measurement, ref: Reference, t: float | None = None) -> ControlOutput:
        """One control period (call it every ``Ts``): returns rotor forces, thrust, torque and the estimate.

        ``t`` (optional, s, any clock: the simulator's time, the flight stack's): the time of this step.
        Given, it must advance, or the step is refused (:class:`InputError`, the state unchanged), and a
        period far from ``Ts`` (more than :data:`PERIOD_TOLERANCE` of it off: a loop at another rate, a
        gap) is a :class:`ControllerWarning`, once until :meth:`reset`."""
        if t is not None:
            return self._timed(t, lambda: self._step(meas, ref))
        out = self._step(meas, ref)
        self._clock.commit(None)  # an untimed step: the next timed one starts the clock again
        return out

    def _step(self, meas: Measurement, ref: Reference) -> ControlOutput:
        bs = self.arrays.batch_shape
        if not bs and self._fast is not None:
            out = self._step_single(meas, ref)
            if out is not None:
                self._warn_once(out)
                self._warn_yaw(meas.eta, ref.psi)
                return out
            # refused or unusual: the named checks below say why (the kernel left the state unchanged)
        meas = self._measurement(meas, bs)  # sense: checked, the gyro's rates as Euler rates (1c)
        ref = self._reference(ref, bs)
        if self.backend == "numpy":  # estimate (6)-(13), control (14)-(20), allocate (4)
            self.state, out = controller_step(self.arrays, self.state, meas, ref)
        else:
            out = self._step_compiled(meas, ref, bs)
        self._warn_once(out)
        self._warn_yaw(meas.eta, ref.psi)
        return out if bs else _plain(out)

    def _reference(self, ref: Reference, bs: tuple[int, ...]) -> Reference:
        """``ref`` checked (finite, shaped for this batch, within any vehicle's reach) and as arrays."""
        if not isinstance(ref, Reference):
            raise InputError(f"step expects a Reference, got {type(ref).__name__}")
        ref = Reference(
            as_finite("p_d (Reference.p_W)", ref.p_W, (3,)),
            as_finite("v_d (Reference.v_W)", ref.v_W, (3,)),
            as_finite("a_d (Reference.a_W)", ref.a_W, (3,)),
            _scalar_input("psi_d", ref.psi, bs),
            _scalar_input("psi_dot_d", ref.psi_dot, bs),
            _scalar_input("psi_ddot_d", ref.psi_ddot, bs),
            _comply_input(ref.comply, bs),
        )
        for name, v, lim in zip(("p_d", "v_d", "a_d"), ref[:3], (1e6, 1e4, 1e5), strict=True):
            if v.shape[:-1] not in ((), bs):
                raise InputError(f"reference {name} has shape {v.shape}; this controller expects (3,) or {bs + (3,)}")
            _plausible(name, v, lim)
        for name, v, lim in zip(("psi_d", "psi_dot_d", "psi_ddot_d"), ref[3:6], (1e3, 1e4, 1e5), strict=True):
            _plausible(name, v, lim)
        return ref

    def _warn_once(self, out: ControlOutput) -> None:
        causes = (
            (
                "saturated",
                "the rotors could not give the requested thrust and torque (see ControlOutput.saturated, "
                "rp_scale, yaw_scale)",
            ),
            (
                "tilt_limited",
                "the tilt or lift limit of eq. (16) clamped the desired attitude (tilt_max, "
                "min_lift_accel; see ControlOutput.tilt_limited)",
            ),
        )
        for field_name, text in causes:
            if field_name not in self._warned and np.any(getattr(out, field_name)):
                self._warned.add(field_name)
                warnings.warn(f"{text}; warned once per cause until reset()", ControllerWarning, stacklevel=_caller())
        # an estimate beyond the vehicle's weight is rare in flight and common with a frame mistake
        ratio = np.linalg.norm(out.f_hat_W, axis=-1) / self._weight
        if "f_hat_W" not in self._warned and np.any(ratio > IMPLAUSIBLE_ESTIMATE):
            self._warned.add("f_hat_W")
            warnings.warn(
                f"the estimated external force is {np.max(ratio):.2g} times the vehicle's weight: unless something "
                "that strong pushes it, check the inputs' frames (p_W, v_W in world NED, z down; eta ZYX Euler "
                "angles in rad of the NED/FRD attitude; omega_B in body FRD; Measurement.from_frames converts "
                "ENU/FLU and quaternions) and the mass; warned once until reset()",
                ControllerWarning,
                stacklevel=_caller(),
            )
        reach = self._reach_B  # an axis the rotors cannot turn (no reach) is not judged
        ratio_m = np.divide(np.abs(out.tau_hat_B), reach, out=np.zeros(np.shape(reach)), where=reach > 0)
        self._moment_high = self._moment_high + 1 if np.any(ratio_m > IMPLAUSIBLE_MOMENT) else 0
        if "tau_hat_B" not in self._warned and self._moment_high * self.arrays.Ts >= MOMENT_PERSIST_S:
            self._warned.add("tau_hat_B")
            axis = "xyz"[int(np.argmax(np.max(ratio_m.reshape(-1, 3), axis=0)))]
            warnings.warn(
                f"the estimated external moment about body {axis} has been {np.max(ratio_m):.2g} times what the rotors "
                f"can give about it for {MOMENT_PERSIST_S:g} s: unless something that strong turns the vehicle, check "
                "the rotors' spin directions and positions (body FRD: x forward, y right, z down) and omega_B's frame; "
                "warned once until reset()",
                ControllerWarning,
                stacklevel=_caller(),
            )

    def _warn_yaw(self, eta: object, psi_d: object) -> None:
        """Warn once when the yaw reference is :data:`YAW_GAP_RAD` or more from the measured yaw."""
        if "yaw" in self._warned:
            return
        gap = np.abs((np.asarray(psi_d, float) - np.asarray(eta, float)[..., 2] + math.pi) % (2 * math.pi) - math.pi)
        if np.any(gap > YAW_GAP_RAD):
            self._warned.add("yaw")
            warnings.warn(
                f"the yaw reference is {np.max(gap):.2f} rad from the measured yaw: eq. (20) tilts for the desired "
                "heading, so while the heading turns a horizontal force the vehicle holds (wind, a push) is held in "
                "the wrong direction and the vehicle is pushed off (with 2 N sideways, pi/2 moved a 1 kg quadrotor "
                "30 cm); ramp heading changes (Reference.psi_dot) by about 1 rad/s; warned once until reset()",
                ControllerWarning,
                stacklevel=_caller(),
            )

    def _step_single(self, meas: Measurement, ref: Reference) -> ControlOutput | None:
        """One vehicle through the checked kernel, which tests finiteness, range and the attitude itself
        (those Python checks cost five times the step). None for anything it did not take."""
        if type(meas) is not Measurement or type(ref) is not Reference:
            return None
        if (meas.eta_dot is None) == (meas.omega_B is None):
            return None
        try:
            vec = [np.asarray(v, dtype=float) for v in (*meas[:3], *ref[:3])]
            yaw = [np.asarray(v, dtype=float) for v in ref[3:6]]
            comply = comply6(ref.comply)
        except (TypeError, ValueError):
            return None
        if any(v.shape != (3,) for v in vec) or any(v.shape != () for v in yaw) or comply.shape != (6,):
            return None
        if meas.eta_dot is not None:
            rates = np.asarray(meas.eta_dot, dtype=float)
        else:
            rates = _euler_rates(vec[2], np.asarray(meas.omega_B, dtype=float))
            if rates is None:
                return None
        if rates.shape != (3,):
            return None
        y = np.concatenate((vec[0], vec[1], vec[2], rates))
        r = np.concatenate((vec[3], vec[4], vec[5], yaw, comply))
        entry, p, d, s, h, o, views = self._fast  # type: ignore[misc]
        if entry(p, d, s, h, 0, y, r, o):
            return None
        rec = views[0]
        out = ControlOutput._make([rec[name].copy() for name in ControlOutput._fields])
        return _plain(out._replace(f_rotor=out.f_rotor[: self._nr]))

    def _step_compiled(self, meas: Measurement, ref: Reference, bs: tuple[int, ...]) -> ControlOutput:
        k = self._k
        B = self._p.shape[0]
        y = np.concatenate([np.broadcast_to(v, bs + (3,)).reshape(B, 3) for v in meas[:4]], -1)
        r = np.concatenate(
            [
                np.broadcast_to(ref.p_W, bs + (3,)).reshape(B, 3),
                np.broadcast_to(ref.v_W, (B, 3)),
                np.broadcast_to(ref.a_W, (B, 3)),
                np.stack([np.broadcast_to(v, bs).reshape(B) for v in (ref.psi, ref.psi_dot, ref.psi_ddot)], -1),
                np.broadcast_to(ref.comply, bs + (6,)).reshape(B, 6),
            ],
            -1,
        )
        for b in range(B):
            k.step_one(self._p, self._d, self._s, self._h, b, y[b], np.ascontiguousarray(r[b]), self._out)
        o = self._out.reshape(bs)
        fields = {name: o[name].copy() for name in ControlOutput._fields}
        fields["f_rotor"] = fields["f_rotor"][..., : self._nr]
        return ControlOutput(**fields)


class EstimatorOutput(NamedTuple):
    """The estimate after one sample: ``f_hat_W`` (N, world NED, at the body origin), ``tau_hat_eta`` (the
    moment in Euler coordinates, as eq. (5b)) and ``tau_hat_B`` (N m, body FRD, ``Q^{-T} tau_hat_eta``)."""

    f_hat_W: np.ndarray
    tau_hat_eta: np.ndarray
    tau_hat_B: np.ndarray


class Estimator(_Learns):
    """The momentum-based estimator of eqs. (6)-(13) alone, one sample at a time (an online loop fed by
    telemetry, another simulator): the same kernels as the simulator's controller and ``estimate``.

    >>> import numpy as np
    >>> from vtol_impedance import Estimator
    >>> est = Estimator(mass=1.0, inertia_B=[0.01, 0.01, 0.02], Ts=0.01)
    >>> z = np.zeros(3)
    >>> out = [est.step(z, z, thrust_prev=9.81 + 1.0, tau_B_prev=z, omega_B=z) for _ in range(300)][-1]
    >>> np.round(out.f_hat_W, 3)  # held still with 1 N more thrust than weight: the world pushes 1 N down
    array([0., 0., 1.])

    ``thrust_prev`` (N) and ``tau_B_prev`` (N m, body FRD) are the command held over the period that just
    ended; without a torque command (``tau_B_prev=None``) the moment estimate is meaningless and reported
    as NaN. Call :meth:`step` every ``Ts`` seconds; after a gap in the data call :meth:`reset` (the filter
    assumes uniform sampling). ``backend="numpy"`` runs :func:`vtol_impedance.estimator.estimator_step`.
    ``mass``, ``I_B``, ``params`` and ``backend`` are read-only; a copy or a pickle is an independent estimator
    with what this one learnt.
    """

    _LEARNT = ("_fresh", "_clock", "_warned", "_s", "_h", "_state")

    def __init__(
        self,
        mass: float,
        inertia_B: object,
        Ts: float,
        params: EstimatorParams | None = None,
        backend: str = "compiled",
    ) -> None:
        if backend not in ("compiled", "numpy"):
            raise InputError(f"backend must be 'compiled' or 'numpy', got {backend!r}")
        self._mass = scalar("mass", mass, lo=0.0, lo_open=True)
        from .model.vehicle import check_inertia

        try:
            I_B = check_inertia(inertia_B)  # symmetric, positive definite, a rigid body's
        except InputError as exc:
            raise InputError(f"inertia_B: {exc}") from None
        self._I_B = np.ascontiguousarray(I_B, dtype=float)
        self._I_B.flags.writeable = False
        self._params = params or EstimatorParams()
        if not isinstance(self._params, EstimatorParams):
            raise InputError(f"params must be an EstimatorParams, got {type(params).__name__}")
        self._design = design_estimator(self._params, Ts)
        self._backend = backend
        if backend == "compiled":
            from .compiled import estimator as kernels

            self._k = kernels
            self._d = kernels.pack_design(self.design)
            self._I = tuple(float(v) for v in self.I_B.ravel())
            self._out = np.zeros(9)
        self.reset()

    @property
    def Ts(self) -> float:  # noqa: N802
        return float(self.design.Ts)

    @property
    def design(self) -> EstimatorDesign:
        """The discretised estimator (eqs. (10)-(12)), read-only."""
        return self._design

    @property
    def mass(self) -> float:
        return self._mass

    @property
    def I_B(self) -> np.ndarray:  # noqa: N802
        return self._I_B

    @property
    def params(self) -> EstimatorParams:
        return self._params

    @property
    def backend(self) -> str:
        return self._backend

    def _init_args(self) -> tuple[tuple, dict]:
        return (self._mass, self._I_B, self.Ts), {"params": self._params, "backend": self._backend}

    def reset(self) -> None:
        """Start afresh: the next sample fills the history with its command and returns a zero estimate."""
        self._fresh = True
        self._clock = _Clock(self.Ts)
        self._warned: set[str] = set()
        if self.backend == "compiled":
            self._s, self._h = self._k.initial_state(self._d, 1)
        else:
            self._state = estimator_initial_state(self.design)

    def step(
        self,
        v_W: object,
        eta: object,
        thrust_prev: float,
        tau_B_prev: object | None = None,
        *,
        eta_dot: object | None = None,
        omega_B: object | None = None,
        t: float | None = None,
    ) -> EstimatorOutput:
        """One sample: measured world velocity (m/s, NED), ZYX Euler angles (rad) and exactly one of their
        rates ``eta_dot`` or the gyro's ``omega_B`` (rad/s, body FRD). ``t`` (optional, s, any clock): the
        sample's time, checked as :meth:`Controller.step` checks it (it must advance; a period far from
        ``Ts``, a gap or another rate, is a :class:`ControllerWarning`: call :meth:`reset` after a gap)."""
        tt = self._clock.check(t, self._warned, "the estimator", stacklevel=3)
        v_W = _vector3("v_W", v_W, 1e4)
        eta = _vector3("eta", eta, 1e3)
        _check_attitude(eta)
        if (eta_dot is None) == (omega_B is None):
            raise InputError("Estimator.step needs exactly one of eta_dot (Euler rates) or omega_B (gyro body rates)")
        if eta_dot is not None:
            eta_dot = _vector3("eta_dot", eta_dot, 1e4)
        else:
            omega_B = _vector3("omega_B", omega_B, 1e4)
            eta_dot = np.linalg.solve(euler_rate_matrix_Q(eta), omega_B)
        u = scalar("thrust_prev (N)", thrust_prev, lo=0.0, hi=1e6)  # rotors push, never pull
        no_moment = tau_B_prev is None
        tau = np.zeros(3) if no_moment else _vector3("tau_B_prev", tau_B_prev, 1e6)
        if self.backend == "compiled":
            o = self._out
            self._k.sample_one(
                self._d, self._s, self._h, self.mass, self._I, np.ascontiguousarray(v_W, dtype=float),
                np.ascontiguousarray(eta, dtype=float), np.ascontiguousarray(eta_dot, dtype=float), u,
                np.ascontiguousarray(tau, dtype=float), self._fresh, o,
            )  # fmt: skip
            f, t_eta, t_B = o[:3].copy(), o[3:6].copy(), o[6:9].copy()
        else:
            self._state, w = estimator_step(self.design, self._state, eta, eta_dot, v_W, u, tau, self.mass, self.I_B)
            f, t_eta = w[:3], w[3:]
            t_B = body_moment_from_euler(t_eta, eta)
        self._fresh = False
        self._clock.commit(tt)
        if no_moment:
            t_eta = np.full(3, np.nan)
            t_B = np.full(3, np.nan)
        return EstimatorOutput(f, t_eta, t_B)
