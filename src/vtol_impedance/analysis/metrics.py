"""Scalar metrics of a run, computed only from a :class:`~vtol_impedance.sim.result.Result`: the column titles
here; :func:`compute_metrics` and :func:`window_mask` live with the result (:mod:`vtol_impedance.sim.result`),
which the simulator also uses, and are exported here."""

from __future__ import annotations

from ..sim.result import compute_metrics, window_mask  # defined with the result the simulator returns

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


__all__ = ["METRIC_COLUMNS", "compute_metrics", "window_mask"]
