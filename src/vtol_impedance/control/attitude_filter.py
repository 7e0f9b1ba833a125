"""Second-order low-pass filter on the desired attitude (Sec. IV of the paper, after eq. (20)).

``x_ddot = wn^2 (eta_d_raw - x) - 2 zeta wn x_dot`` per axis, discretised exactly (zero-order hold on
the raw input) at the control period. It returns the smoothed ``eta_d`` and its first and second
derivatives for eq. (18b).
"""

from __future__ import annotations

import functools
from typing import NamedTuple

import numpy as np
import scipy.linalg

from ..errors import scalar


class FilterDesign(NamedTuple):
    Ad: np.ndarray  # (2, 2)
    Bd: np.ndarray  # (2,)
    wn: float
    zeta: float


class FilterState(NamedTuple):
    x: np.ndarray  # (..., k) value
    x_dot: np.ndarray  # (..., k) rate
    started: bool


def design_filter(wn: float, zeta: float, Ts: float) -> FilterDesign:
    wn = scalar("attitude filter wn", wn, lo=0.0, lo_open=True)
    zeta = scalar("attitude filter zeta", zeta, lo=0.0, lo_open=True)
    return _design(wn, zeta, float(Ts))


@functools.lru_cache(maxsize=256)
def _design(wn: float, zeta: float, Ts: float) -> FilterDesign:
    """The exact zero-order-hold discretisation (kept for reuse: a batch designs the same filter for every
    vehicle; the arrays are read-only)."""
    A = np.array([[0.0, 1.0], [-wn * wn, -2.0 * zeta * wn]])
    aug = np.zeros((3, 3))
    aug[:2, :2] = A * Ts
    aug[1, 2] = wn * wn * Ts
    E = scipy.linalg.expm(aug)
    Ad, Bd = E[:2, :2], E[:2, 2]
    Ad.flags.writeable = Bd.flags.writeable = False
    return FilterDesign(Ad, Bd, wn, zeta)


def filter_step(
    des: FilterDesign, state: FilterState, u: np.ndarray
) -> tuple[FilterState, np.ndarray, np.ndarray, np.ndarray]:
    """Output value, rate and acceleration at this sample for the new input ``u``, and the next state."""
    if not state.started:
        state = FilterState(np.array(u, dtype=float), np.zeros_like(u, dtype=float), True)
    x, xd = state.x, state.x_dot
    xdd = des.wn * des.wn * (u - x) - 2.0 * des.zeta * des.wn * xd
    x_next = des.Ad[0, 0] * x + des.Ad[0, 1] * xd + des.Bd[0] * u
    xd_next = des.Ad[1, 0] * x + des.Ad[1, 1] * xd + des.Bd[1] * u
    return FilterState(x_next, xd_next, True), x, xd, xdd
