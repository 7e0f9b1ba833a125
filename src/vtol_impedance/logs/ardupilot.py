"""ArduCopter's motor thrust curve: PWM to rotor thrust and back, from the vehicle's own parameters.

ArduCopter (``AP_MotorsMulticopter`` with its thrust linearisation) sends rotor ``i`` the PWM width

.. math::

    \\mathrm{pwm} = p_{min} + (p_{max} - p_{min})\\,(s_{min} + (s_{max} - s_{min})\\, y), \\qquad
    a\\,(y v)^2 + (1 - a)\\,(y v) = T

for a thrust ``T`` in units of the rotor's maximum thrust (0..1, the space of ``MOT_THST_HOVER`` and
``CTUN.ThO``), with ``a = MOT_THST_EXPO``, ``s_min, s_max = MOT_SPIN_MIN, MOT_SPIN_MAX``, ``p_min, p_max =
MOT_PWM_MIN, MOT_PWM_MAX`` (when either is 0 or they are not ordered, ArduCopter uses the throttle channel's
``RC3_MIN, RC3_MAX``; so does this module) and ``v`` the battery scale: ``v = V / MOT_BAT_VOLT_MAX`` with the
voltage ``V`` clamped to ``[max(MOT_BAT_VOLT_MIN, 0.6 MOT_BAT_VOLT_MAX), MOT_BAT_VOLT_MAX]`` when the
compensation is on (``MOT_BAT_VOLT_MAX > 0``, ``MOT_BAT_VOLT_MIN < MOT_BAT_VOLT_MAX``, ``V >= 0.25
MOT_BAT_VOLT_MIN``), else ``v = 1``. Reading a PWM back inverts it: ``y`` from the PWM, ``T = a (y v)^2 +
(1 - a)(y v)``, clamped to 0..1.

Not modelled (recorded in the documentation): ArduCopter filters the voltage at 0.5 Hz and uses its resting
estimate (sag removed) where this module takes the voltage given per sample; its air-density compensation
(thrust divided by the density ratio) makes ``T`` read high by ``1 / ratio`` away from sea level.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import asdict, dataclass

import numpy as np

from ..errors import InputError, scalar

#: The parameters the curve needs (``MOT_BAT_VOLT_MIN`` only when ``MOT_BAT_VOLT_MAX > 0``; ``RC3_MIN/MAX``
#: only when ``MOT_PWM_MIN/MAX`` are unset).
CURVE_PARAMS = ("MOT_THST_EXPO", "MOT_SPIN_MIN", "MOT_SPIN_MAX", "MOT_PWM_MIN", "MOT_PWM_MAX", "MOT_BAT_VOLT_MAX")
#: ArduCopter 4.x defaults (the parameter documentation), for the simulated autopilot and the tests.
DEFAULTS = {"MOT_THST_EXPO": 0.65, "MOT_SPIN_MIN": 0.15, "MOT_SPIN_MAX": 0.95, "MOT_PWM_MIN": 1000.0,
            "MOT_PWM_MAX": 2000.0, "MOT_BAT_VOLT_MAX": 0.0, "MOT_BAT_VOLT_MIN": 0.0}  # fmt: skip


@dataclass(frozen=True)
class MotorCurve:
    """ArduCopter's PWM-to-thrust curve (module docstring) with its parameters.

    Parameters
    ----------
    expo : float
        ``MOT_THST_EXPO``, -1..1 (0: linear).
    spin_min, spin_max : float
        ``MOT_SPIN_MIN`` < ``MOT_SPIN_MAX``, 0..1 of the PWM range.
    pwm_min, pwm_max : float
        The PWM range (us): ``MOT_PWM_MIN/MAX``, or ``RC3_MIN/MAX`` when those are unset.
    bat_volt_max, bat_volt_min : float
        ``MOT_BAT_VOLT_MAX/MIN`` (V); compensation off when ``bat_volt_max <= 0``.
    pwm_from : str
        Which parameters gave the PWM range.
    """

    expo: float = 0.65
    spin_min: float = 0.15
    spin_max: float = 0.95
    pwm_min: float = 1000.0
    pwm_max: float = 2000.0
    bat_volt_max: float = 0.0
    bat_volt_min: float = 0.0
    pwm_from: str = "MOT_PWM_MIN/MAX"

    def __post_init__(self) -> None:
        scalar("MOT_THST_EXPO (expo)", self.expo, lo=-1.0, hi=1.0)
        scalar("MOT_SPIN_MIN (spin_min)", self.spin_min, lo=0.0, hi=1.0)
        scalar("MOT_SPIN_MAX (spin_max)", self.spin_max, lo=0.0, hi=1.0)
        if not self.spin_min < self.spin_max:
            raise InputError(f"MOT_SPIN_MIN ({self.spin_min:g}) must be below MOT_SPIN_MAX ({self.spin_max:g})")
        scalar(f"{self.pwm_from} minimum (pwm_min)", self.pwm_min, lo=0.0, hi=3000.0)
        scalar(f"{self.pwm_from} maximum (pwm_max)", self.pwm_max, lo=0.0, hi=3000.0)
        if not self.pwm_min < self.pwm_max:
            raise InputError(f"the PWM range {self.pwm_from} is {self.pwm_min:g}..{self.pwm_max:g} us: not ordered")
        scalar("MOT_BAT_VOLT_MAX (bat_volt_max)", self.bat_volt_max, lo=0.0, hi=100.0)
        scalar("MOT_BAT_VOLT_MIN (bat_volt_min)", self.bat_volt_min, lo=0.0, hi=100.0)

    @classmethod
    def from_params(cls, params: Mapping[str, float]) -> MotorCurve:
        """The curve from a vehicle's parameters; raises :class:`InputError` naming every one missing."""
        need = list(CURVE_PARAMS)
        if float(params.get("MOT_BAT_VOLT_MAX", 0.0) or 0.0) > 0.0:
            need.append("MOT_BAT_VOLT_MIN")
        pmin, pmax = params.get("MOT_PWM_MIN"), params.get("MOT_PWM_MAX")
        unset = pmin is not None and pmax is not None and not (0 < pmin < pmax)
        if unset:  # ArduCopter then takes the throttle channel's range
            need += ["RC3_MIN", "RC3_MAX"]
        missing = [p for p in need if p not in params]
        if missing:
            raise InputError(
                f"ArduCopter motor outputs need the parameter(s) {', '.join(missing)} to be read as thrust "
                "(the PWM is not linear in thrust)"
            )
        g = {k: float(v) for k, v in params.items() if k in (*need, "MOT_BAT_VOLT_MIN")}
        return cls(
            expo=g["MOT_THST_EXPO"],
            spin_min=g["MOT_SPIN_MIN"],
            spin_max=g["MOT_SPIN_MAX"],
            pwm_min=g["RC3_MIN"] if unset else g["MOT_PWM_MIN"],
            pwm_max=g["RC3_MAX"] if unset else g["MOT_PWM_MAX"],
            bat_volt_max=g["MOT_BAT_VOLT_MAX"],
            bat_volt_min=g.get("MOT_BAT_VOLT_MIN", 0.0),
            pwm_from="RC3_MIN/MAX (MOT_PWM_MIN/MAX unset)" if unset else "MOT_PWM_MIN/MAX",
        )

    @property
    def compensates(self) -> bool:
        """Whether ArduCopter scales the outputs by the battery voltage (``MOT_BAT_VOLT_MAX/MIN`` set)."""
        return self.bat_volt_max > 0.0 and self.bat_volt_min < self.bat_volt_max

    def voltage_scale(self, volt: float | np.ndarray | None) -> np.ndarray:
        """``v`` of the module docstring for battery voltage(s) ``volt`` (V); 1 without compensation or voltage."""
        if not self.compensates or volt is None:
            return np.asarray(1.0)
        V = np.asarray(volt, dtype=float)
        lo = max(self.bat_volt_min, 0.6 * self.bat_volt_max)
        v = np.clip(V, lo, self.bat_volt_max) / self.bat_volt_max
        return np.where(np.isfinite(V) & (V >= 0.25 * self.bat_volt_min), v, 1.0)

    def thrust(self, pwm: np.ndarray, volt: float | np.ndarray | None = None) -> np.ndarray:
        """Rotor thrust (0..1 of its maximum) from PWM widths (us), with the battery voltage(s) (V) if compensated."""
        act = (np.asarray(pwm, dtype=float) - self.pwm_min) / (self.pwm_max - self.pwm_min)
        y = np.clip((act - self.spin_min) / (self.spin_max - self.spin_min), 0.0, 1.0)
        x = y * self.voltage_scale(volt)
        return np.clip(self.expo * x * x + (1.0 - self.expo) * x, 0.0, 1.0)

    def pwm(self, thrust: np.ndarray, volt: float | np.ndarray | None = None) -> np.ndarray:
        """PWM widths (us) ArduCopter sends for rotor thrusts (0..1 of the maximum): the inverse of :meth:`thrust`."""
        T = np.clip(np.asarray(thrust, dtype=float), 0.0, 1.0)
        a = self.expo
        if a == 0.0:
            x = T
        else:  # the root in 0..1 of a x^2 + (1 - a) x = T
            x = ((a - 1.0) + np.sqrt((1.0 - a) ** 2 + 4.0 * a * T)) / (2.0 * a)
        y = np.clip(x / self.voltage_scale(volt), 0.0, 1.0)
        return self.pwm_min + (self.pwm_max - self.pwm_min) * (self.spin_min + (self.spin_max - self.spin_min) * y)

    def to_dict(self) -> dict[str, float | str]:
        """The parameters by field name (``MotorCurve(**d)`` rebuilds it), with :meth:`describe`'s line."""
        return {**asdict(self), "text": self.describe()}

    @classmethod
    def from_dict(cls, d: Mapping[str, float | str]) -> MotorCurve:
        """The inverse of :meth:`to_dict`."""
        return cls(**{k: v for k, v in d.items() if k != "text"})  # type: ignore[arg-type]

    def describe(self) -> str:
        """The parameters in one line, for the choices a run records."""
        bat = (
            f"battery compensation {self.bat_volt_min:g}..{self.bat_volt_max:g} V"
            if self.compensates
            else "no battery compensation (MOT_BAT_VOLT_MAX 0)"
        )
        return (
            f"MOT_THST_EXPO {self.expo:g}, MOT_SPIN_MIN/MAX {self.spin_min:g}/{self.spin_max:g}, "
            f"PWM {self.pwm_min:g}..{self.pwm_max:g} us ({self.pwm_from}), {bat}"
        )


def motor_channels(params: Mapping[str, float], n_max: int = 16) -> list[int] | None:
    """Output channels (1-based) that drive motors, in motor order, from ``SERVOn_FUNCTION`` (33..40: Motor1..8);
    ``None`` when the parameters name none."""
    by_motor = {}
    for ch in range(1, n_max + 1):
        f = params.get(f"SERVO{ch}_FUNCTION")
        if f is not None and np.isfinite(f) and 33 <= f <= 40 and float(f).is_integer():  # a damaged one: none
            by_motor.setdefault(int(f) - 32, ch)
    return [by_motor[k] for k in sorted(by_motor)] or None
