"""Impedance gains of eqs. (18a)-(18b) and the paper's values."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import InputError, as_finite, positive, scalar

#: Largest gain accepted (SI units: N/m, N s/m, N m/rad, kg, ...), as the scenarios' ranges: orders of
#: magnitude above any multirotor's, far below where eq. (16)'s arithmetic loses the error's direction.
MAX_GAIN = 1e6
#: Smallest impedance value accepted (a divisor of the impedance law, eq. (20)).
MIN_IMPEDANCE = 1e-6


def _vec3(name: str, value: float | np.ndarray, allow_zero: bool = False) -> np.ndarray:
    arr = as_finite(name, value)
    if arr.shape == (3, 3):  # a diagonal gain matrix, as eq. (18) writes it
        if np.any(arr - np.diag(np.diag(arr))):
            raise InputError(f"{name} must be diagonal (one gain per axis), got off-diagonal entries in {arr.tolist()}")
        arr = np.diag(arr)
    if arr.shape not in ((), (1,), (3,)):
        raise InputError(f"{name} must be a scalar, 3 values or a diagonal 3x3 matrix, got shape {arr.shape}")
    arr = positive(name, arr, allow_zero=allow_zero)
    if np.any(arr > MAX_GAIN):  # the arithmetic of eqs. (16)-(20) would overflow to a wrong command
        raise InputError(f"{name} = {arr.tolist()} is beyond any vehicle's gain (<= {MAX_GAIN:g} in SI units)")
    arr = np.broadcast_to(arr, (3,)).astype(float)
    arr.setflags(write=False)
    return arr


#: Nominal mass of the paper's Pelican, kg (Sec. VI.A), the mass its printed gains were tuned for.
PAPER_MASS = 1.2


@dataclass(frozen=True, eq=False)
class ImpedanceGains:
    """Diagonal gains (per world axis for position, per Euler angle for attitude).

    ``Kp`` [N/m], ``Dp`` [N s/m], ``Ki`` [N/(m s)] act in eq. (18a) (``Ki`` only for the PID baseline);
    ``Ko`` [N m/rad], ``Do`` [N m s/rad] act in eq. (18b).
    """

    Kp: np.ndarray | float
    Dp: np.ndarray | float
    Ko: np.ndarray | float
    Do: np.ndarray | float
    Ki: np.ndarray | float = 0.0

    def __post_init__(self) -> None:
        for name in ("Kp", "Dp", "Ko", "Do"):
            object.__setattr__(self, name, _vec3(name, getattr(self, name)))
        object.__setattr__(self, "Ki", _vec3("Ki", self.Ki, allow_zero=True))

    @classmethod
    def from_natural(
        cls,
        mass: float,
        inertia: np.ndarray,
        wn_p: float,
        zeta_p: float,
        wn_o: float,
        zeta_o: float,
        Ki: float | np.ndarray = 0.0,
    ) -> ImpedanceGains:
        """Gains giving second-order closed loops of eq. (19) with the given (wn, zeta).

        Position: ``Kp = m wn^2``, ``Dp = 2 zeta wn m``; attitude about hover, where ``M(0) = I_B``:
        ``Ko = wn^2 diag(I_B)``, ``Do = 2 zeta wn diag(I_B)``.
        """
        mass = scalar("mass", mass, lo=0.0, lo_open=True)
        I = as_finite("inertia", inertia)
        Idiag = np.diag(I) if I.ndim == 2 else np.broadcast_to(I, (3,))
        for name, v in (("wn_p", wn_p), ("zeta_p", zeta_p), ("wn_o", wn_o), ("zeta_o", zeta_o)):
            positive(name, v)
        return cls(
            Kp=mass * wn_p**2,
            Dp=2.0 * zeta_p * wn_p * mass,
            Ko=wn_o**2 * Idiag,
            Do=2.0 * zeta_o * wn_o * Idiag,
            Ki=Ki,
        )

    @classmethod
    def from_position(
        cls,
        Kp: float | np.ndarray,
        Dp: float | np.ndarray,
        inertia: np.ndarray,
        wn_o: float = 8.0,
        zeta_o: float = 1.0,
        Ki: float | np.ndarray = 0.0,
    ) -> ImpedanceGains:
        """Position gains as given (N/m, N s/m) and attitude gains from the attitude loop's natural
        frequency ``wn_o`` (rad/s) and damping ``zeta_o`` on the nominal ``inertia`` (paper: 8, 1)."""
        att = cls.from_natural(1.0, inertia, 1.0, 1.0, wn_o, zeta_o)
        return cls(Kp=Kp, Dp=Dp, Ko=att.Ko, Do=att.Do, Ki=Ki)

    @classmethod
    def paper(cls, inertia: np.ndarray, Ki: float | np.ndarray = 0.0, mass: float | None = None) -> ImpedanceGains:
        """The printed gains of Sec. VI.A: ``Kp = 16 I``, ``Dp = 12 I``; attitude wn = 8 rad/s, zeta = 1.

        With ``mass`` (kg) the position gains are scaled by ``mass / 1.2`` so that ``Kp/m``, ``Dp/m`` and
        ``Ki/m`` (the closed-loop poles of (19a)) stay the paper's on another vehicle; ``Ki`` is given
        for the paper's 1.2 kg.

        Note: ``Kp = 16``, ``Dp = 12`` do not follow from the stated wn = 4 rad/s, zeta = 1 with
        m = 1.2 kg (that would be Kp = 19.2, Dp = 9.6); they are what the paper printed and what the
        case studies use. The attitude gains follow :meth:`from_natural` with wn = 8, zeta = 1.
        """
        k = 1.0 if mass is None else scalar("mass", mass, lo=0.0, lo_open=True) / PAPER_MASS
        return cls.from_position(16.0 * k, 12.0 * k, inertia, 8.0, 1.0, Ki=np.asarray(Ki, dtype=float) * k)

    def natural(self, mass: float) -> dict[str, np.ndarray]:
        """Natural frequency and damping of the position loop ``m e'' + Dp e' + Kp e = 0``."""
        if mass <= 0:
            raise InputError(f"mass must be > 0, got {mass}")
        wn = np.sqrt(self.Kp / mass)
        return {"wn_p": wn, "zeta_p": self.Dp / (2.0 * np.sqrt(self.Kp * mass))}

    def to_dict(self) -> dict[str, list[float]]:
        return {k: getattr(self, k).tolist() for k in ("Kp", "Dp", "Ki", "Ko", "Do")}


@dataclass(frozen=True, eq=False)
class Impedance:
    """The impedance a ``comply`` controller shows, per world axis (NED):
    ``M_d e'' + D_d e' + K_d e = f_ext`` with ``e = p - p_d``, and per Euler angle:
    ``M_o e_eta'' + D_o e_eta' + K_o e_eta = tau_ext_eta`` with ``e_eta = eta - eta_d`` (the moment in
    Euler coordinates, as in eq. (5b)).

    ``M`` apparent mass [kg], ``D`` damping [N s/m], ``K`` stiffness [N/m]; ``M_o`` apparent inertia
    [kg m^2], ``D_o`` [N m s/rad], ``K_o`` [N m/rad]; scalars or three values, all positive. The attitude
    ones default (``None``) to the vehicle's own inertia and attitude gains. With ``M`` equal to the
    vehicle's mass the law is a plain PD's in the steady state (in transients the lead for the attitude
    filter's delay still uses the estimate); any other apparent mass needs the estimated
    force, fed forward with weight ``m / M - 1``: the vehicle's own inertia must be cancelled in part
    (``M > m``: it feels heavier) or amplified (``M < m``), and only the estimate says how hard it is
    being pushed. The same holds for ``M_o`` and the estimated moment.
    """

    M: np.ndarray | float
    D: np.ndarray | float
    K: np.ndarray | float
    M_o: np.ndarray | float | None = None
    D_o: np.ndarray | float | None = None
    K_o: np.ndarray | float | None = None

    def __post_init__(self) -> None:
        for name in ("M", "D", "K", "M_o", "D_o", "K_o"):
            if getattr(self, name) is None:
                continue
            arr = _vec3(f"impedance {name}", getattr(self, name))
            if np.any(arr < MIN_IMPEDANCE):
                raise InputError(
                    f"impedance {name} must be at least {MIN_IMPEDANCE:g} on every axis, got {arr.tolist()}"
                )
            object.__setattr__(self, name, arr)

    def natural(self) -> dict[str, np.ndarray]:
        """Natural frequency (rad/s) and damping ratio of each axis."""
        wn = np.sqrt(self.K / self.M)
        return {"wn": wn, "zeta": self.D / (2.0 * np.sqrt(self.K * self.M))}

    def to_dict(self) -> dict[str, list[float]]:
        names = ("M", "D", "K", "M_o", "D_o", "K_o")
        return {k: getattr(self, k).tolist() for k in names if getattr(self, k) is not None}
