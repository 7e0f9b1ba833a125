"""Stability margins of the sampled closed loop: per loop, the gain, phase and delay margins and the
sensitivity peak; for the whole loop, the closed-loop poles.

Each loop of :data:`~vtol_impedance.robust.linear.LOOPS` is broken with the others closed, and its
transfer ``L`` (closed by ``1 + L``) is evaluated on the unit circle, ``z = exp(j w Ts)``, from
``1e-3`` rad/s to the Nyquist frequency; python-control's :func:`control.stability_margins` finds every
crossing on that grid:

* **gain margins**, upward and downward: a loop around a double integrator is conditionally stable, so
  lowering its gain (a weaker rotor, a heavier vehicle) destabilises it too. ``gain_up_db`` is how much
  the gain may rise, ``gain_down_db`` how much it may fall, both in dB (``inf``: no such limit);
* **phase margin** (deg) at the gain crossover, and the **delay margin** ``PM / w_c`` (s): how much
  more latency the loop tolerates;
* **sensitivity peak** ``max |1 / (1 + L)|`` (the inverse of the distance to -1).

These distances mean something only for a stable closed loop. When the closed loop has a pole outside
the unit circle the report says *unstable*, with the rightmost pole, and every margin is ``nan``: an
unstable loop never shows a positive margin.

Thresholds (:class:`Thresholds`, defaults 20 deg, 3 dB, least damping 0.1): see the README, section
"Stability margins", for the measurements behind them.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import control as ct
import numpy as np
import scipy.linalg

from ..errors import InputError, as_finite, instance, scalar
from .linear import LOOPS, LinearLoop

#: Frequencies at which loops are evaluated: from this, rad/s, to the Nyquist frequency.
OMEGA_MIN = 1e-3
N_OMEGA = 300


@dataclass(frozen=True)
class Thresholds:
    """What a closed loop must keep to pass :meth:`MarginReport.violations`.

    ``phase_deg``: least phase margin of any loop; ``gain_db``: least gain margin, up or down;
    ``damping``: least damping ratio of any closed-loop pole. The defaults are justified in the README
    ("Stability margins").
    """

    phase_deg: float = 20.0
    gain_db: float = 3.0
    damping: float = 0.1

    def __post_init__(self) -> None:
        object.__setattr__(self, "phase_deg", scalar("phase_deg", self.phase_deg, lo=0.0, hi=90.0))
        object.__setattr__(self, "gain_db", scalar("gain_db", self.gain_db, lo=0.0, hi=60.0))
        object.__setattr__(self, "damping", scalar("damping", self.damping, lo=0.0, hi=1.0))


@dataclass(frozen=True)
class LoopMargins:
    """Margins of one loop (see the module docstring); ``omega`` (rad/s) and ``response`` (complex) are
    ``L`` on the unit circle, for plots."""

    name: str
    gain_up_db: float
    gain_down_db: float
    phase_deg: float
    crossover: float
    delay_s: float
    sensitivity_peak: float
    omega: np.ndarray = field(repr=False)
    response: np.ndarray = field(repr=False)

    @property
    def gain_db(self) -> float:
        """The smaller of the upward and downward gain margins, dB."""
        return min(self.gain_up_db, self.gain_down_db)


@dataclass(frozen=True)
class MarginReport:
    """Margins of every loop, the closed-loop poles (continuous equivalents, rad/s) and a verdict."""

    loops: dict[str, LoopMargins]
    poles: np.ndarray
    label: str = ""
    info: dict[str, Any] = field(default_factory=dict)

    @property
    def stable(self) -> bool:
        return bool(np.all(self.poles.real < 0.0))

    @property
    def rightmost(self) -> complex:
        """The closed-loop pole with the largest real part (its real part is the growth rate, 1/s)."""
        return complex(self.poles[np.argmax(self.poles.real)])

    @property
    def least_damped(self) -> complex:
        """The closed-loop pole with the smallest damping ratio ``-Re(s) / |s|``."""
        return complex(self.poles[np.argmin(_damping(self.poles))])

    @property
    def damping(self) -> float:
        return float(np.min(_damping(self.poles)))

    def summary(self) -> dict[str, float]:
        """Scalars for tables and sweeps: the worst loop's margins, the poles' growth and damping."""
        loops = list(self.loops.values())
        out = {
            "stable": float(self.stable),
            "pm_min_deg": min(m.phase_deg for m in loops),
            "gm_min_db": min(m.gain_db for m in loops),
            "dm_min_ms": 1e3 * min(m.delay_s for m in loops),
            "ms_max": max(m.sensitivity_peak for m in loops),
            "growth_rate": self.rightmost.real,
            "damping_min": self.damping,
        }
        return {k: float(v) for k, v in out.items()}

    def violations(self, thresholds: Thresholds | None = None) -> list[str]:
        """What falls short of ``thresholds``, one sentence each (empty: the loop passes)."""
        t = Thresholds() if thresholds is None else thresholds
        if not self.stable:
            s = self.rightmost
            return [
                f"unstable: a closed-loop pole at {s.real:+.3g} {s.imag:+.3g}j rad/s grows at {s.real:.3g} 1/s "
                f"({abs(s.imag) / (2 * np.pi):.2g} Hz)"
            ]
        out = []
        worst = min(self.loops.values(), key=lambda m: m.phase_deg)
        if worst.phase_deg < t.phase_deg:
            out.append(
                f"phase margin {worst.phase_deg:.1f} deg at the {worst.name} loop ({worst.crossover:.3g} rad/s) is "
                f"below {t.phase_deg:g} deg (delay margin {1e3 * worst.delay_s:.0f} ms)"
            )
        g = min(self.loops.values(), key=lambda m: m.gain_db)
        if g.gain_db < t.gain_db:
            way = "lowered" if g.gain_down_db <= g.gain_up_db else "raised"
            out.append(f"gain margin {g.gain_db:.1f} dB at the {g.name} loop (gain {way}) is below {t.gain_db:g} dB")
        if self.damping < t.damping:
            s = self.least_damped
            out.append(
                f"least damped closed-loop pole {s.real:.3g} {s.imag:+.3g}j rad/s has damping {self.damping:.2f} "
                f"< {t.damping:g}"
            )
        return out


def _damping(poles: np.ndarray) -> np.ndarray:
    return -poles.real / np.maximum(np.abs(poles), 1e-300)


class FrequencyResponse:
    """``L(exp(j w Ts))`` of a discrete state-space loop, evaluated fast: the complex Schur form
    ``A = U T U*`` is computed once, so each frequency costs one triangular solve."""

    def __init__(self, L: ct.StateSpace) -> None:
        self.Ts = float(L.dt)
        A, B, C, D = (np.asarray(m, dtype=float) for m in (L.A, L.B, L.C, L.D))
        if A.shape[0]:
            T, U = scipy.linalg.schur(A, output="complex")
            self.T = np.ascontiguousarray(T)
            self.b, self.c = np.ascontiguousarray(U.conj().T @ B[:, 0]), np.ascontiguousarray(C[0] @ U)
        else:
            self.T = np.zeros((0, 0))
        self.d = complex(D[0, 0])

    def __call__(self, omega: np.ndarray) -> np.ndarray:
        omega = np.atleast_1d(np.asarray(omega, dtype=float))
        out = np.full(omega.shape, self.d, dtype=complex)
        if not self.T.shape[0]:
            return out
        from ..compiled.algebra import triangular_response

        # (z I - T) x = b by back substitution at each frequency (compiled: a page of sliders waits for it)
        z = np.ascontiguousarray(np.exp(1j * omega.ravel() * self.Ts))
        flat = out.ravel().copy()
        triangular_response(self.T, self.b, self.c, z, flat)
        return flat.reshape(out.shape)


def _refine(fn: Any, brackets: list[tuple[float, float]]) -> list[float]:
    """Where the vectorised ``fn`` changes sign in each ``[a, b]`` of ``brackets``: two rounds of a
    17-point log subgrid, then linear interpolation (about 1e-7 relative for a crossing bracketed by a 2 %
    grid step). Every bracket is refined in the same call of ``fn`` (one triangular solve per round for
    all of them: the margins of a loop cost three solves, not three per crossing)."""
    if not brackets:
        return []
    ab = np.array(brackets, dtype=float)
    done = np.full(len(ab), np.nan)
    for last in (False, True):
        w = np.geomspace(ab[:, 0], ab[:, 1], 17, axis=1)  # (K, 17)
        f = fn(w.ravel()).reshape(w.shape)
        for k in range(len(ab)):
            if not np.isnan(done[k]):
                continue
            change = np.flatnonzero(np.sign(f[k, :-1]) != np.sign(f[k, 1:]))
            if not change.size:  # touches zero without crossing: the closest point
                done[k] = w[k, np.argmin(np.abs(f[k]))]
                continue
            i = int(change[0])
            ab[k] = w[k, i], w[k, i + 1]
            fa, fb = f[k, i], f[k, i + 1]
            if last:
                a, b = ab[k]
                done[k] = a + (b - a) * fa / (fa - fb) if fa != fb else a
    return [float(x) for x in done]


def loop_margins(name: str, L: ct.StateSpace, omega: np.ndarray | None = None) -> LoopMargins:
    """Margins of the loop ``L`` (discrete, closed by ``1 + L``) from its frequency response: every
    crossing on the grid ``omega`` is refined by bisection on the exact response."""
    instance("name", name, str)
    instance("L", L, ct.StateSpace)
    if not L.isdtime(strict=True) or L.ninputs != 1 or L.noutputs != 1:
        raise InputError(
            f"L must be a discrete single-input single-output loop, got {L.ninputs}x{L.noutputs}, dt={L.dt}"
        )
    if omega is not None:
        omega = as_finite("omega", omega)
        if omega.ndim != 1 or omega.size < 2 or not np.all(omega > 0):
            raise InputError(f"omega must be 2 or more frequencies > 0 (rad/s), got {omega.tolist()}")
    resp = FrequencyResponse(L)
    if omega is None:
        omega = np.logspace(np.log10(OMEGA_MIN), np.log10(np.pi / resp.Ts), N_OMEGA)
    H = resp(omega)

    def mag(w: np.ndarray) -> np.ndarray:
        return np.log(np.abs(resp(w)))

    def imag(w: np.ndarray) -> np.ndarray:
        return resp(w).imag

    # Gain crossovers |L| = 1: phase margins and delay margins.
    logmag = np.log(np.abs(H))
    at = np.flatnonzero(np.sign(logmag[:-1]) != np.sign(logmag[1:]))
    wcs = _refine(mag, [(omega[i], omega[i + 1]) for i in at])
    # Phase crossovers: L crosses the negative real axis (and the Nyquist end, where L is real).
    at = np.flatnonzero(np.sign(H.imag[:-1]) != np.sign(H.imag[1:]))
    wps = _refine(imag, [(omega[i], omega[i + 1]) for i in at])
    L_at = resp(np.array(wcs + wps))
    pms = [float(np.degrees(np.angle(-v))) for v in L_at[: len(wcs)]]  # 180 deg + angle(L), wrapped
    gains = [1.0 / abs(v) for v in L_at[len(wcs) :] if v.real < 0]
    if H[-1].real < 0 and abs(H[-1].imag) < 1e-9 * max(1.0, abs(H[-1])):
        gains.append(1.0 / abs(H[-1]))
    g = np.asarray(gains)
    gain_up = float(20.0 * np.log10(g[g > 1.0].min())) if np.any(g > 1.0) else np.inf
    gain_down = float(-20.0 * np.log10(g[g < 1.0].max())) if np.any(g < 1.0) else np.inf
    if pms:
        i = int(np.argmin(np.abs(pms)))
        phase, wc = abs(pms[i]), wcs[i]
        delay = min(np.radians(abs(p)) / w for p, w in zip(pms, wcs, strict=True))
    else:
        phase, wc, delay = np.inf, np.nan, np.inf
    peak = float(np.max(1.0 / np.abs(1.0 + H)))
    return LoopMargins(name, gain_up, gain_down, phase, float(wc), float(delay), peak, omega, H)


def margins(loop: LinearLoop, label: str = "", loops: tuple[str, ...] | None = None) -> MarginReport:
    """The margins of every loop (or of ``loops``, a subset of :data:`LOOPS`) and the closed-loop poles
    of a linearised closed loop. Computed with one BLAS thread, so that the numbers do not depend on the
    thread count (a sweep's rows are the same in this process and on Dask workers)."""
    from threadpoolctl import threadpool_limits

    instance("loop", loop, LinearLoop)
    instance("label", label, str)
    if loops is not None and (not isinstance(loops, tuple | list) or not set(loops) <= set(LOOPS)):
        raise InputError(f"loops must be a tuple of names from {LOOPS}, got {loops!r}")
    with threadpool_limits(limits=1, user_api="blas"):
        poles = loop.poles()
        loops = {name: loop_margins(name, loop.loop(name)) for name in (LOOPS if loops is None else loops)}
    op = loop.op
    info = {
        "delays_s": dict(loop.delays),
        "rotor_tau_s": loop.rotor_tau,
        "control_period_s": loop.Ts,
        "hover_thrust_N": op.thrust,
        "attitude_rad": op.eta.tolist(),
    }
    report = MarginReport(loops, poles, label, info)
    if not report.stable:  # distances to -1 mean nothing for an unstable loop: never show them
        nan = float("nan")
        report = MarginReport(
            {k: LoopMargins(k, nan, nan, nan, nan, nan, nan, m.omega, m.response) for k, m in loops.items()},
            poles,
            label,
            info,
        )
    return report
