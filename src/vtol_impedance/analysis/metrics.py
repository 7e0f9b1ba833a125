"""Scalar metrics of a run, computed only from a :class:`~vtol_impedance.sim.result.Result`."""

from __future__ import annotations

from typing import Any

import numpy as np

from ..errors import InputError, as_finite, instance
from ..sim.result import STEADY_TAIL_S, Result, metrics_row, window_mask_of

#: Metric keys of a result's table (``rms_ep_cm``, ...) and the column titles they are printed with.
METRIC_COLUMNS: dict[str, str] = {
    "rms_ep_cm": "RMS ‖e_p‖ [cm]",
    "max_ep_cm": "max ‖e_p‖ [cm]",
    "ss_ep_cm": "steady ‖e_p‖ [cm]",
    "rms_ev_cms": "RMS ‖ė_p‖ [cm/s]",
    "rms_f_err_N": "RMS ‖f_hat − f‖ [N]",
    "rms_tau_err_mNm": "RMS ‖tau_hat − tau‖ [mN m]",
    "sat_pct": "limited [%]",
}


def _check(result: Result, window: Any) -> None:
    instance("result", result, Result)
    if window is not None and (isinstance(window, str) or as_finite("window", window).shape[-1:] not in ((2,), (3,))):
        raise InputError(f"window must be (t0, t1) in seconds, got {window!r}")


def window_mask(result: Result, window: tuple[float, float] | None = None) -> np.ndarray:
    """Samples inside the task window (default: the one stored in the result's config).

    A run cut shorter than the window's start (``--duration``) falls back to the whole run.
    """
    _check(result, window)
    return window_mask_of(result.t, window if window is not None else result.config.get("window"))


def _rms(a: np.ndarray) -> float:
    a = a[np.isfinite(a)]
    return float(np.sqrt(np.mean(a * a))) if a.size else float("nan")


def compute_metrics(result: Result, window: tuple[float, float] | None = None) -> list[dict[str, Any]]:
    """One row per vehicle: position/velocity error statistics, estimation error, saturation.

    ``ss_ep_cm`` is the mean ``|e_p|`` over the last :data:`STEADY_TAIL_S` seconds of the window;
    the estimation error compares the estimate with the lumped wrench the nominal model misses
    (``f_lumped_W``, ``tau_lumped_eta``). A run logged with ``log="metrics"`` already carries them.
    """
    _check(result, window)
    if not result.data:
        if result.metrics is None:
            raise ValueError("the result has neither traces nor metrics")
        return [dict(m) for m in result.metrics]
    m = window_mask(result, window)
    t = result.t[m]
    tail = t >= (t[-1] - STEADY_TAIL_S)
    ep = np.linalg.norm(result.e_p[:, m], axis=-1)
    ev = np.linalg.norm(result.e_v[:, m], axis=-1)
    f_err = np.linalg.norm(result["f_hat_W"][:, m] - result["f_lumped_W"][:, m], axis=-1)
    tau_err = np.linalg.norm(result["tau_hat_eta"][:, m] - result["tau_lumped_eta"][:, m], axis=-1)
    # any limit: the rotor allocation or the tilt/lift bound of eq. (16)
    limited = (
        result["saturated"]
        if "tilt_limited" not in result.data
        else np.fmax(result["saturated"], result["tilt_limited"])
    )
    sat = limited[:, m]
    rows = []
    for b, label in enumerate(result.labels):
        alive = np.isfinite(ep[b])
        has = bool(np.any(alive))
        rows.append(
            metrics_row(
                label,
                rms_ep=_rms(ep[b]),
                max_ep=float(np.max(ep[b][alive])) if has else float("nan"),
                ss_ep=float(np.mean(ep[b][tail & alive])) if np.any(tail & alive) else float("nan"),
                rms_ev=_rms(ev[b]),
                rms_f=_rms(f_err[b]),
                rms_tau=_rms(tau_err[b]),
                sat=float(np.mean(sat[b][alive])) if has else float("nan"),
                failure=result.failures[b] if b < len(result.failures) else None,
            )
        )
    return rows
