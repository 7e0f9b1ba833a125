"""Vehicle parameters (nominal or true), rotor geometry and presets.

A multirotor is its rigid body (mass, inertia) plus a list of rotors, each a position ``r_i`` in the body
frame (FRD, m), a spin sign ``s_i`` and force limits ``[f_min_i, f_max_i]`` (N), plus the yaw drag factor
``c`` (N m per N). Every rotor pushes along ``-z_B``; rotor ``i`` with force ``f_i`` gives the moment
``r_i x (-f_i e3) + s_i c f_i e3`` about the body origin, so the effectiveness matrix ``E`` (4 x n) maps
rotor forces to ``[u, tau_x, tau_y, tau_z]`` (DESIGN.md section 1). The paper's '+' quadrotor of
eq. (4) is the layout ``"plus"``: rotor 1 aft (x = -l), 2 left (y = -l), 3 forward, 4 right, spins
(+1, -1, +1, -1), which reproduces ``u = sum f``, ``tau_phi = l (f2 - f4)``, ``tau_theta = l (f3 - f1)``,
``tau_psi = c (f1 - f2 + f3 - f4)``.

Spin sign: ``s_i = +1`` is a propeller turning counter-clockwise seen from above, whose drag pushes the
body nose-right (positive yaw about the FRD ``z`` axis, which points down).
"""

from __future__ import annotations

import functools
import tomllib
import warnings
from dataclasses import dataclass, field, replace
from importlib import resources
from pathlib import Path
from typing import Any

import numpy as np

from ..conventions import G
from ..errors import InputError, as_finite, check_keys, choice, positive, scalar
from ..io import read_toml
from .aero import check_coefficients

#: Rotor layouts built from an arm length, see :func:`layout_positions`.
LAYOUTS = ("plus", "x", "hex")
#: The most rotors a vehicle may have (the compiled kernels size their buffers by it).
MAX_ROTORS = 12
#: What a vehicle file that leaves a key out flies with (the Pelican of the paper, Sec. VI.A, and its rotors,
#: DESIGN.md section 4); :func:`vehicle_from_dict` announces each one it fills in, except ``f_min`` = 0 (a
#: rotor that can stop: the neutral assumption, not the Pelican's).
FILE_DEFAULTS = {"layout": "plus", "arm_length": 0.21, "f_max": 7.0, "f_min": 0.0, "drag_factor": 0.016}


class VehicleDefaultWarning(UserWarning):
    """A vehicle file left out a key and the Pelican's value was filled in (see :data:`FILE_DEFAULTS`)."""


class HoverWarning(UserWarning):
    """A vehicle's rotors cannot lift its weight (:func:`warn_if_cannot_hover`)."""


def warn_if_cannot_hover(vehicle: VehicleParams, stacklevel: int = 2, mass: float | None = None,
                         carrying: str = "") -> None:  # fmt: skip
    """Warn (:class:`HoverWarning`) when the vehicle's rotors at full thrust cannot lift its own weight, or
    ``mass`` (kg) when given (``carrying``: what it adds, for the message): a controller built for it can only let
    it fall (a heavy vehicle left with the default ``f_max`` of 7 N per rotor is the usual cause)."""
    weight = (vehicle.mass if mass is None else mass) * G
    lift = float(vehicle.geometry.f_max.sum())
    if lift < weight:
        warnings.warn(
            f"vehicle {vehicle.name or '(unnamed)'}{carrying}: its rotors give at most {lift:.4g} N together, less "
            f"than its weight {weight:.4g} N (thrust-to-weight {lift / weight:.2f}): it cannot hover; set f_max "
            "(f_max_from_motor) or check the mass",
            HoverWarning,
            stacklevel=stacklevel + 1,
        )


def check_inertia(inertia: Any) -> np.ndarray:
    """A nominal inertia ``(3, 3)`` from 3 values or a matrix: finite, symmetric, positive definite and
    physical (principal moments obey the triangle inequality)."""
    I_B = as_finite("inertia", inertia)
    if I_B.shape == (3,):
        I_B = np.diag(I_B)
    if I_B.shape != (3, 3):
        raise InputError(f"inertia must be 3 values or a 3x3 matrix, got shape {I_B.shape}")
    asym = np.abs(I_B - I_B.T)
    if np.max(asym) > 1e-9 * max(np.max(np.abs(I_B)), 1e-300):
        i, j = np.unravel_index(np.argmax(asym), asym.shape)
        raise InputError(
            f"inertia must be symmetric: I[{i},{j}] = {I_B[i, j]:.6g} but I[{j},{i}] = {I_B[j, i]:.6g} (a product of "
            "inertia appears twice; was the matrix transcribed row by row?)"
        )
    ev = np.linalg.eigvalsh(I_B)
    if np.any(ev <= 0):
        raise InputError(f"inertia must be positive definite, its principal moments are {np.round(ev, 8).tolist()}")
    if ev[0] + ev[1] < ev[2] * (1 - 1e-9):
        short = 100.0 * (ev[2] - ev[0] - ev[1]) / ev[2]
        hint = (
            "measured values this close to the bound (a flat frame's) are within their error of it: give I3 = I1 + I2"
            if short < 5.0
            else "a typo or mixed units?"
        )
        raise InputError(
            f"inertia is not a rigid body's: principal moments {np.round(ev, 8).tolist()} break the triangle "
            f"inequality (I1 + I2 >= I3) by {short:.2g} % of I3; {hint}"
        )
    return I_B


def _inertia(value: Any) -> np.ndarray:
    arr = check_inertia(value).copy()
    arr.setflags(write=False)
    return arr


def distinct_vehicles(vehicles: list[VehicleParams]) -> tuple[list[VehicleParams], np.ndarray]:
    """The distinct objects of ``vehicles`` (by identity, in order of first use) and each entry's row among
    them: a batch's arrays read a vehicle shared by thousands of entries once."""
    first: dict[int, int] = {}
    rows = np.array([first.setdefault(id(v), len(first)) for v in vehicles], dtype=np.int64)
    return list({id(v): v for v in vehicles}.values()), rows


def f_max_from_motor(thrust_constant: float, max_speed: float) -> float:
    """Largest rotor force ``k_f * omega_max^2`` (N) from the thrust constant ``k_f`` (N s^2/rad^2) and the
    maximum rotor speed ``omega_max`` (rad/s), the way flight stacks and RotorPy describe a motor."""
    return (
        scalar("thrust_constant", thrust_constant, lo=0.0, lo_open=True)
        * scalar("max_speed", max_speed, lo=0.0, lo_open=True) ** 2
    )


def drag_factor_from_constants(torque_constant: float, thrust_constant: float) -> float:
    """Yaw drag factor ``c = k_m / k_f`` (N m per N) of eq. (4d) from the rotor torque constant ``k_m``
    (N m s^2/rad^2) and thrust constant ``k_f`` (N s^2/rad^2): both scale with the speed squared."""
    return scalar("torque_constant", torque_constant, lo=0.0, lo_open=True) / scalar(
        "thrust_constant", thrust_constant, lo=0.0, lo_open=True
    )


@dataclass(frozen=True)
class Rotor:
    """One rotor: ``position_B`` (m, FRD, from the body origin), ``spin`` (+1 or -1, see the module
    docstring: +1 yaws the body nose-right; a z-up simulator's sign whose +1 yaws it counter-clockwise seen
    from above, as RotorPy's ``rotor_directions``, is the opposite), force
    limits ``f_min``, ``f_max`` (N; unset, the Pelican's 0 and 7 N: give your rotors')."""

    position_B: tuple[float, float, float]
    spin: int
    f_max: float = 7.0
    f_min: float = 0.0

    def __post_init__(self) -> None:
        pos = as_finite("rotor position_B", self.position_B, (3,))
        if pos.shape != (3,):
            raise InputError(f"rotor position_B must be 3 values, got shape {pos.shape}")
        object.__setattr__(self, "position_B", tuple(float(v) for v in pos))
        if self.spin not in (1, -1) or isinstance(self.spin, bool):
            raise InputError(f"rotor spin must be +1 or -1, got {self.spin!r}")
        object.__setattr__(self, "spin", int(self.spin))
        object.__setattr__(self, "f_max", scalar("rotor f_max", self.f_max, lo=0.0, lo_open=True))
        object.__setattr__(self, "f_min", scalar("rotor f_min", self.f_min, lo=0.0))
        if self.f_min >= self.f_max:
            raise InputError(f"rotor f_min = {self.f_min} must be below f_max = {self.f_max}")


def layout_positions(layout: str, arm_length: float) -> tuple[np.ndarray, np.ndarray]:
    """Rotor positions ``(n, 3)`` and spins ``(n,)`` of a named layout with the given arm length.

    * ``"plus"``: eq. (4) of the paper; rotors aft, left, forward, right; spins (+, -, +, -).
    * ``"x"``: rotors at 45 deg: 1 front-right, 2 rear-left, 3 front-left, 4 rear-right; spins
      (+, +, -, -) (the common quad-X numbering of flight stacks).
    * ``"hex"``: six rotors every 60 deg from forward, turning towards the right; spins alternate from +.
    """
    choice("layout", layout, LAYOUTS)
    arm_length = scalar("arm_length", arm_length, lo=0.0, lo_open=True)
    if layout == "plus":
        ang = np.radians([180.0, -90.0, 0.0, 90.0])
        spins = np.array([1, -1, 1, -1])
    elif layout == "x":
        ang = np.radians([45.0, -135.0, -45.0, 135.0])
        spins = np.array([1, 1, -1, -1])
    elif layout == "hex":
        ang = np.radians(np.arange(6) * 60.0)
        spins = np.array([1, -1, 1, -1, 1, -1])
    else:
        raise InputError(f"unknown rotor layout {layout!r}; choose one of {', '.join(LAYOUTS)} or give rotors")
    pos = arm_length * np.stack([np.cos(ang), np.sin(ang), np.zeros_like(ang)], -1)
    pos[np.abs(pos) < 1e-15] = 0.0
    return pos, spins


def effectiveness(positions_B: np.ndarray, spins: np.ndarray, drag_factor: float | np.ndarray) -> np.ndarray:
    """Effectiveness matrix ``E (..., 4, n)``: ``[u, tau_B] = E f`` for rotor forces ``f (n,)`` along ``-z_B``.

    Column ``i`` is ``[1, r_i x (-e3) + s_i c e3]`` = ``[1, -r_iy, r_ix, s_i c]``. Batched over leading
    axes of ``positions_B (..., n, 3)``, ``spins (..., n)`` and ``drag_factor (...)``.
    """
    r = as_finite("positions_B", positions_B)
    if r.ndim < 2 or r.shape[-1] != 3:
        raise InputError(f"positions_B must have shape (..., n, 3), got {r.shape}")
    spins = as_finite("spins", spins, r.shape[-2:-1])
    c = positive("drag_factor", drag_factor)
    if c.shape not in ((), r.shape[:-2]):
        raise InputError(f"drag_factor of shape {c.shape} does not match the batch of positions_B {r.shape}")
    s = spins * c[..., None]
    return np.stack([np.ones(r.shape[:-1]), -r[..., 1], r[..., 0], s], axis=-2)  # eq. (4) for any layout


@dataclass(frozen=True, eq=False)
class RotorGeometry:
    """Arrays of a vehicle's rotors: ``E (4, n)``, its pseudo-inverse ``E_pinv (n, 4)``, limits ``(n,)``."""

    positions_B: np.ndarray
    spins: np.ndarray
    f_min: np.ndarray
    f_max: np.ndarray
    drag_factor: float
    E: np.ndarray
    E_pinv: np.ndarray

    @property
    def n(self) -> int:
        return int(self.spins.shape[0])


@dataclass(frozen=True, eq=False)
class VehicleParams:
    """Rigid body and rotors of a multirotor, nominal (the controller's) or true (the plant's).

    Attributes
    ----------
    mass : float
        Mass, kg.
    inertia : ndarray, shape (3, 3)
        ``I_B`` about the centre of mass in the body frame, kg m^2 (a 3-vector is a diagonal).
    drag_factor : float
        ``c`` of eq. (4d), N m per N; the default 0.016 is the paper's Pelican's: give your rotors'
        (:func:`drag_factor_from_constants`).
    rotors : tuple of Rotor or None
        Explicit rotors (:class:`Rotor`); or leave ``None`` and give a ``layout`` with the shorthand
        ``arm_length`` (m), ``f_max``, ``f_min`` (N, the same for every rotor). Unset, the limits are the
        Pelican's (7 N and 0 per rotor, arm 0.21 m): for another vehicle give its own
        (:func:`f_max_from_motor`) and check :attr:`thrust_to_weight` (multirotors fly at 1.5-5).
    layout : {"plus", "x", "hex"}
        ``"plus"`` (eq. (4), the default), ``"x"`` or ``"hex"`` (:func:`layout_positions`).
    name : str
        Label.
    rotor_drag : float or (float, float)
        Rotor (blade-flapping, H-force) drag ``(d_x, d_y)`` in the rotor plane, N per m/s of body-frame
        airspeed (one number: both); 0 (the default): none. See :mod:`vtol_impedance.model.aero`.
    inflow_damping : float
        Thrust lost per m/s of climb speed along the thrust axis, N per m/s (``d_z``); 0: none.
    body_drag : float or (float, float, float)
        Quadratic body drag ``(c_x, c_y, c_z)`` per body axis, N per (m/s)^2 (``1/2 rho C_d A``); 0: none.
        The three aerodynamic terms act on the true plant only: the controller never reads them (what it
        does not know stays in the plant); the margin check's linearisation does.
    """

    mass: float
    inertia: np.ndarray
    arm_length: float | None = None
    drag_factor: float = 0.016
    f_max: float | None = None
    f_min: float | None = None
    name: str = "custom"
    layout: str = "plus"
    rotors: tuple[Rotor, ...] | None = None
    rotor_drag: float | tuple[float, float] = 0.0
    inflow_damping: float = 0.0
    body_drag: float | tuple[float, float, float] = 0.0
    _geometry: RotorGeometry | None = field(default=None, init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        object.__setattr__(self, "mass", scalar("mass", self.mass, lo=0.0, lo_open=True))
        object.__setattr__(self, "inertia", _inertia(self.inertia))
        object.__setattr__(self, "drag_factor", scalar("drag_factor", self.drag_factor, lo=0.0, lo_open=True))
        if not isinstance(self.name, str):
            raise InputError(f"vehicle name must be a string, got {self.name!r}")
        object.__setattr__(self, "rotor_drag", check_coefficients("rotor_drag", self.rotor_drag, 2))
        object.__setattr__(self, "inflow_damping", check_coefficients("inflow_damping", self.inflow_damping, 1)[0])
        object.__setattr__(self, "body_drag", check_coefficients("body_drag", self.body_drag, 3))
        if self.rotors is not None:
            given = [k for k in ("arm_length", "f_max", "f_min") if getattr(self, k) is not None]
            if given:
                raise InputError(
                    f"give either explicit rotors or the shorthand {given} with a layout, not both "
                    "(per-rotor limits live in each Rotor)"
                )
            rotors = tuple(self.rotors)
            if not all(isinstance(r, Rotor) for r in rotors):
                raise InputError("rotors must be a sequence of vtol_impedance.model.Rotor")
            pos = np.array([r.position_B for r in rotors], dtype=float).reshape(-1, 3)
            spins = np.array([r.spin for r in rotors])
            f_min = np.array([r.f_min for r in rotors])
            f_max = np.array([r.f_max for r in rotors])
            object.__setattr__(self, "rotors", rotors)
        else:
            for k, default in (("arm_length", 0.21), ("f_max", 7.0), ("f_min", 0.0)):
                if getattr(self, k) is None:
                    object.__setattr__(self, k, default)
            object.__setattr__(self, "arm_length", scalar("arm_length", self.arm_length, lo=0.0, lo_open=True))
            object.__setattr__(self, "f_max", scalar("f_max", self.f_max, lo=0.0, lo_open=True))
            object.__setattr__(self, "f_min", scalar("f_min", self.f_min, lo=0.0))
            if self.f_min >= self.f_max:
                raise InputError(f"f_min = {self.f_min} must be below f_max = {self.f_max}")
            pos, spins = layout_positions(self.layout, self.arm_length)
            f_min = np.full(len(spins), self.f_min)
            f_max = np.full(len(spins), self.f_max)
        object.__setattr__(self, "_geometry", _geometry(pos, spins, f_min, f_max, self.drag_factor))

    @property
    def geometry(self) -> RotorGeometry:
        assert self._geometry is not None
        return self._geometry

    @property
    def n_rotors(self) -> int:
        return self.geometry.n

    @property
    def linear_drag_B(self) -> tuple[float, float, float]:
        """``(d_x, d_y, d_z)``: rotor drag and inflow damping, N per m/s, body axes."""
        return (*self.rotor_drag, self.inflow_damping)  # type: ignore[return-value]

    @property
    def has_aero(self) -> bool:
        """Whether the description carries any aerodynamic term."""
        return any(self.linear_drag_B) or any(self.body_drag)  # type: ignore[arg-type]

    def without_aero(self) -> VehicleParams:
        """A copy without rotor drag, inflow damping or body drag."""
        return replace(self, rotor_drag=0.0, inflow_damping=0.0, body_drag=0.0)

    @property
    def thrust_to_weight(self) -> float:
        """Maximum total thrust over nominal weight."""
        return float(self.geometry.f_max.sum() / (self.mass * G))

    def with_rotor_limits(self, f_max: float | None = None, f_min: float | None = None) -> VehicleParams:
        """A copy with every rotor's limits replaced (``None`` keeps them)."""
        rotors = [
            Rotor(
                tuple(p),
                int(s),
                float(f_max) if f_max is not None else float(hi),
                float(f_min) if f_min is not None else float(lo),
            )
            for p, s, lo, hi in zip(
                self.geometry.positions_B, self.geometry.spins, self.geometry.f_min, self.geometry.f_max, strict=True
            )
        ]
        return VehicleParams(
            self.mass, self.inertia, drag_factor=self.drag_factor, name=self.name, rotors=tuple(rotors),
            rotor_drag=self.rotor_drag, inflow_damping=self.inflow_damping, body_drag=self.body_drag,
        )  # fmt: skip

    def to_dict(self, memo: dict[int, dict[str, Any]] | None = None) -> dict[str, Any]:
        """The vehicle as plain data. ``memo``: dictionaries already made, by ``id`` of their vehicle (a batch
        flies one vehicle thousands of times: its entries then share one dictionary)."""
        if memo is not None:
            made = memo.get(id(self))
            if made is None:
                made = memo[id(self)] = self.to_dict()
            return made
        g = self.geometry
        return {
            "name": self.name,
            "mass": self.mass,
            "inertia": self.inertia.tolist(),
            "drag_factor": self.drag_factor,
            "rotors": [  # one tolist() per array: a batch's config lists thousands of vehicles
                {"position_B": p, "spin": int(s), "f_min": float(lo), "f_max": float(hi)}
                for p, s, lo, hi in zip(
                    g.positions_B.tolist(), g.spins.tolist(), g.f_min.tolist(), g.f_max.tolist(), strict=True
                )
            ],
        } | self._aero_dict()

    def _aero_dict(self) -> dict[str, Any]:
        """The aerodynamic terms that are not 0 (a record without them reads as before they existed)."""
        terms = {"rotor_drag": list(self.rotor_drag), "inflow_damping": self.inflow_damping,  # type: ignore[arg-type]
                 "body_drag": list(self.body_drag)}  # type: ignore[arg-type]  # fmt: skip
        return {k: v for k, v in terms.items() if any(np.ravel(v).tolist())}  # one conversion: thousands in a batch


def _geometry(pos: np.ndarray, spins: np.ndarray, f_min: np.ndarray, f_max: np.ndarray, c: float) -> RotorGeometry:
    n = len(spins)
    if not 4 <= n <= MAX_ROTORS:
        raise InputError(f"a multirotor needs 4 to {MAX_ROTORS} rotors, got {n}")
    E = effectiveness(pos, spins, c)
    if np.linalg.matrix_rank(E, tol=1e-9 * max(1.0, np.abs(E).max())) < 4:
        raise InputError(
            "the rotor layout cannot produce thrust, roll, pitch and yaw independently (effectiveness matrix "
            f"rank < 4); positions {pos.tolist()}, spins {spins.tolist()}"
        )
    E_pinv = np.linalg.pinv(E)
    pu = E_pinv[:, 0]
    if np.all(pu > 0) and np.max(f_min / pu) >= np.min(f_max / pu):
        raise InputError(
            f"rotor limits leave no collective thrust that every rotor can share (f_min {list(f_min)}, "
            f"f_max {list(f_max)})"
        )
    if np.any(pu <= 0):
        raise InputError(
            "with this rotor layout pure thrust would need a negative force on some rotor "
            f"(thrust shares {E_pinv[:, 0].round(4).tolist()}); place the rotors around the body origin"
        )
    arrays = [np.array(a, dtype=float) for a in (pos, spins, f_min, f_max)]
    E.setflags(write=False)
    E_pinv.setflags(write=False)
    for a in arrays:
        a.setflags(write=False)
    return RotorGeometry(*arrays, float(c), E, E_pinv)


PRESET_KEYS = (
    "name",
    "mass",
    "inertia_diag",
    "inertia",
    "layout",
    "arm_length",
    "drag_factor",
    "f_max",
    "f_min",
    "thrust_constant",
    "torque_constant",
    "max_speed",
    "rotors",
    "rotor_drag",
    "inflow_damping",
    "body_drag",
)
ROTOR_KEYS = ("position_B", "spin", "f_max", "f_min", "max_speed")


def _one_of_each(data: dict[str, Any], source: str) -> None:
    """Refuse a table that says one thing twice (one of the two would be dropped in silence) or gives a
    constant that nothing uses."""
    pairs = [("inertia", "inertia_diag"), ("drag_factor", "torque_constant"), ("f_max", "max_speed")]
    for a, b in pairs:
        if a in data and b in data:
            raise InputError(f"{source}: give {a} or {b}, not both (one would be ignored)")
    rows = [r for r in data.get("rotors", []) if isinstance(r, dict)] if isinstance(data.get("rotors"), list) else []
    if "rotors" in data:
        given = [k for k in ("layout", "arm_length", "f_max", "f_min", "max_speed") if k in data]
        if given:
            raise InputError(
                f"{source}: give either explicit [[rotors]] or the shorthand {given} with a layout, not both "
                "(each rotor takes its own position_B, spin, f_max, f_min)"
            )
        for i, r in enumerate(data["rotors"] if isinstance(data["rotors"], list) else []):
            if isinstance(r, dict) and "f_max" in r and "max_speed" in r:
                raise InputError(f"{source}: rotors[{i}]: give f_max or max_speed, not both (one would be ignored)")
    if "torque_constant" in data and "thrust_constant" not in data:
        raise InputError(f"{source}: torque_constant needs thrust_constant (drag factor = torque / thrust constant)")
    rotor_speeds = "max_speed" in data or any("max_speed" in r for r in rows)
    if "thrust_constant" in data and "torque_constant" not in data and not rotor_speeds:
        raise InputError(
            f"{source}: thrust_constant is used with max_speed (rotor limits) or torque_constant (drag factor); "
            "alone it sets nothing"
        )


def vehicle_from_dict(data: dict[str, Any], source: str = "vehicle") -> VehicleParams:
    """Build a vehicle from a parsed TOML table (see ``presets/*.toml`` and the README).

    Rotor limits may be given as ``f_max`` or as ``thrust_constant`` and ``max_speed`` (rad/s); the drag
    factor as ``drag_factor`` or as ``torque_constant`` with ``thrust_constant``. A key left out flies with
    the Pelican's value (:data:`FILE_DEFAULTS`), announced once per key with a
    :class:`VehicleDefaultWarning`; the resolved vehicle (``VehicleParams.to_dict``) is what a run records.

    Warns
    -----
    VehicleDefaultWarning
        For each of ``layout``, ``arm_length``, ``f_max`` (also per rotor) and ``drag_factor`` the table leaves
        out.
    """
    from ..errors import instance

    instance("data", data, dict)
    if not isinstance(data, dict):
        raise InputError(f"{source}: expected a table, got {data!r}")
    check_keys(source, data, PRESET_KEYS)
    _one_of_each(data, source)
    try:
        inertia = data["inertia"] if "inertia" in data else data["inertia_diag"]
        mass = data["mass"]
    except KeyError as exc:
        raise InputError(f"{source}: missing key {exc.args[0]!r} (need mass and inertia or inertia_diag)") from None
    kf = data.get("thrust_constant")
    if "drag_factor" in data:
        c = data["drag_factor"]
    elif "torque_constant" in data and kf is not None:
        c = drag_factor_from_constants(data["torque_constant"], kf)
    else:
        c = FILE_DEFAULTS["drag_factor"]
    from_constants = "torque_constant" in data and kf is not None
    defaulted = [] if "drag_factor" in data or from_constants else ["drag_factor"]

    def limit(table: dict[str, Any], where: str) -> float | None:
        if "f_max" in table:
            return table["f_max"]
        if "max_speed" in table:
            if kf is None:
                raise InputError(f"{where}: max_speed needs the vehicle's thrust_constant")
            return f_max_from_motor(kf, table["max_speed"])
        return None

    name = data.get("name", source)
    aero = {k: data[k] for k in ("rotor_drag", "inflow_damping", "body_drag") if k in data}  # default 0: none
    for key, want in (("name", str), ("layout", str)):
        if key in data and not isinstance(data[key], want):
            raise InputError(f"{source}: {key} must be a string, got {data[key]!r}")
    try:
        if "rotors" in data:
            rows = data["rotors"]
            if not isinstance(rows, list) or not all(isinstance(r, dict) for r in rows):
                raise InputError(f"{source}: rotors must be a list of tables ([[rotors]])")
            rotors = []
            for i, r in enumerate(rows):
                where = f"{source}: rotors[{i}]"
                check_keys(where, r, ROTOR_KEYS)
                if "position_B" not in r or "spin" not in r:
                    raise InputError(f"{where}: needs position_B and spin")
                fmax = limit(r, where)
                if fmax is None and "rotors[].f_max" not in defaulted:
                    defaulted.append("rotors[].f_max")
                fmin = r.get("f_min", FILE_DEFAULTS["f_min"])
                rotors.append(Rotor(r["position_B"], r["spin"], FILE_DEFAULTS["f_max"] if fmax is None else fmax, fmin))
            vehicle = VehicleParams(mass, inertia, drag_factor=c, name=name, rotors=tuple(rotors), **aero)
        else:
            f_max = limit(data, source)
            defaulted += [k for k in ("layout", "arm_length") if k not in data]
            defaulted += ["f_max"] if f_max is None else []
            vehicle = VehicleParams(
                mass,
                inertia,
                arm_length=data.get("arm_length"),
                drag_factor=c,
                f_max=f_max,
                f_min=data.get("f_min"),
                name=name,
                layout=data.get("layout", FILE_DEFAULTS["layout"]),
                **aero,
            )
    except (TypeError, ValueError) as exc:
        if isinstance(exc, InputError):
            raise InputError(f"{source}: {exc}") from None
        raise InputError(f"{source}: malformed value ({exc})") from None
    for key in defaulted:
        value = FILE_DEFAULTS[key.removeprefix("rotors[].")]
        warnings.warn(
            f"{source}: no {key} given, flying the Pelican's {key.removeprefix('rotors[].')} = {value!r} "
            "(give your vehicle's)",
            VehicleDefaultWarning,
            stacklevel=2,
        )
    return vehicle


def preset_names() -> list[str]:
    """Names of the vehicle presets shipped with the package (``pelican``, ``pelican-x``, ``hexarotor``),
    for :func:`load_preset`."""
    files = resources.files("vtol_impedance") / "presets"
    return sorted(p.name[:-5] for p in files.iterdir() if p.name.endswith(".toml"))


def load_preset(name: str = "pelican") -> VehicleParams:
    """A vehicle preset shipped in ``vtol_impedance/presets/NAME.toml``, or a vehicle TOML file by path."""
    if not isinstance(name, str):
        raise InputError(f"vehicle preset must be a preset name or a .toml path, got {name!r}")
    if name.endswith(".toml"):
        path = Path(name)
        data = read_toml(path, "vehicle file")
        return vehicle_from_dict(data, str(path))
    return _shipped_preset(name)


@functools.lru_cache(maxsize=32)
def _shipped_preset(name: str) -> VehicleParams:
    """Shipped presets are read once per process (a VehicleParams is immutable)."""
    available = preset_names()
    if name not in available:
        raise InputError(f"unknown vehicle preset {name!r}; available: {', '.join(available)} (or a .toml path)")
    data = tomllib.loads((resources.files("vtol_impedance") / "presets" / f"{name}.toml").read_text())
    return vehicle_from_dict(data, name)


__all__ = [
    "FILE_DEFAULTS",
    "LAYOUTS",
    "MAX_ROTORS",
    "Rotor",
    "RotorGeometry",
    "VehicleDefaultWarning",
    "VehicleParams",
    "drag_factor_from_constants",
    "effectiveness",
    "f_max_from_motor",
    "layout_positions",
    "load_preset",
    "preset_names",
    "vehicle_from_dict",
]
