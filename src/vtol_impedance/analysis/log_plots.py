"""Figures of a wrench estimate on a flight log (Agg backend, written atomically)."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from .plots import AXES, AXIS_COLORS, _save, plt

if TYPE_CHECKING:
    from ..logs.estimate import LogEstimate


def _time(est: LogEstimate) -> tuple[np.ndarray, float, str]:
    """The time axis, with NaN between segments so that no line is drawn across a restart; a log on a unix
    clock (or any large offset) is shown from its first sample."""
    t0 = float(est.t[0]) if abs(float(est.t[0])) > 1e5 else 0.0
    label = "time [s]" if t0 == 0.0 else f"time [s] from t = {t0:.3f} s"
    return _broken(est, est.t - t0), t0, label


def _broken(est: LogEstimate, y: np.ndarray) -> np.ndarray:
    """``y`` (samples along axis 0) with a NaN row inserted before every restart after the first."""
    cut = np.flatnonzero(est.flight.restart)[1:]
    y = np.asarray(y, dtype=float)
    return np.insert(y, cut, np.nan, axis=0) if len(cut) else y


def _gaps(ax, est: LogEstimate) -> None:
    """Restarts (the data stop) as red dashed lines, bridged dropouts as grey bands."""
    _, off, _ = _time(est)
    for t0 in est.t[est.flight.restart][1:]:
        ax.axvline(t0 - off, color="tab:red", lw=0.9, ls="--")
    for g in est.flight.gaps:
        if g["action"] == "bridged":
            ax.axvspan(g["t0_s"] - off, g["t1_s"] - off, color="gray", alpha=0.18, lw=0)


def plot_log_wrench(est: LogEstimate, path: Path, title: str = "") -> Path:
    """Estimated force (world NED) and moment (body FRD); zero-phase dashed where computed."""
    rows = 2 if est.tau_B is not None else 1
    fig, ax = plt.subplots(rows, 1, figsize=(9, 3.2 * rows + 0.6), sharex=True, squeeze=False)
    ax = ax[:, 0]
    t, off, tlabel = _time(est)
    for i in range(3):
        ax[0].plot(t, _broken(est, est.f_W[:, i]), color=AXIS_COLORS[i], lw=1.0, label=f"f_{AXES[i]} causal")
        if est.f_W_zp is not None:
            ax[0].plot(
                t,
                _broken(est, est.f_W_zp[:, i]),
                color=AXIS_COLORS[i],
                lw=0.9,
                ls="--",
                label=f"f_{AXES[i]} zero-phase",
            )
        if rows == 2:
            ax[1].plot(
                t, _broken(est, 1000 * est.tau_B[:, i]), color=AXIS_COLORS[i], lw=1.0, label=f"tau_{AXES[i]} causal"
            )
            if est.tau_B_zp is not None:
                ax[1].plot(t, _broken(est, 1000 * est.tau_B_zp[:, i]), color=AXIS_COLORS[i], lw=0.9, ls="--")
    ax[0].set_ylabel("external force, world NED [N]")
    if rows == 2:
        ax[1].set_ylabel("external moment, body FRD [mN m]")
    ax[-1].set_xlabel(tlabel)
    if est.bias is not None:
        a, b = est.bias["segment_s"]
        for x in ax:
            x.axvspan(a - off, b - off, color="tab:green", alpha=0.08, label=None)
    for x in ax:
        _gaps(x, est)
        x.grid(alpha=0.3)
        x.legend(loc="best", fontsize=7, ncol=3)
    ax[0].set_title(title or "Estimated external wrench")
    _legend_note(fig, est)
    return _save(fig, path)


def plot_log_inputs(est: LogEstimate, path: Path, title: str = "") -> Path:
    """What the estimator was given: velocity, attitude and collective thrust on the common grid."""
    fl = est.flight
    fig, ax = plt.subplots(3, 1, figsize=(9, 7.5), sharex=True)
    t, _, tlabel = _time(est)
    for i in range(3):
        ax[0].plot(t, _broken(est, fl.v_W[:, i]), color=AXIS_COLORS[i], lw=0.9, label=f"v_{AXES[i]}")
        ax[1].plot(
            t, _broken(est, np.degrees(fl.eta[:, i])), color=AXIS_COLORS[i], lw=0.9, label=("roll", "pitch", "yaw")[i]
        )
    ax[2].plot(t, _broken(est, est.thrust_N), color="black", lw=0.9, label="thrust")
    if est.hover is not None and np.ptp(est.hover) > 0:
        ax2 = ax[2].twinx()
        ax2.plot(t, _broken(est, est.hover), color="tab:purple", lw=0.8, ls="--", label="hover thrust (normalised)")
        ax2.set_ylabel("hover thrust [0..1]", color="tab:purple")
    ax[0].set_ylabel("velocity, NED [m/s]")
    ax[1].set_ylabel("attitude (ZYX) [deg]")
    ax[2].set_ylabel("collective thrust [N]")
    ax[2].set_xlabel(tlabel)
    for x in ax:
        _gaps(x, est)
        x.grid(alpha=0.3)
        x.legend(loc="best", fontsize=7, ncol=3)
    ax[0].set_title(title or f"Inputs resampled at {fl.rate_hz:g} Hz")
    _legend_note(fig, est)
    return _save(fig, path)


def _legend_note(fig, est: LogEstimate) -> None:
    restarts = int(est.flight.restart.sum()) - 1
    bridged = sum(1 for g in est.flight.gaps if g["action"] == "bridged")
    parts = []
    if est.bias is not None:
        parts.append("green band: quiet segment")
    if bridged:
        parts.append(f"grey bands: {bridged} bridged dropout(s), estimator state carried")
    if restarts:
        parts.append(f"red dashed: {restarts} restart(s) where the data stop")
    if parts:
        # under the figure (the saved area grows to hold it), clear of the x-axis label
        fig.text(0.01, 0.0, "; ".join(parts), fontsize=7, color="dimgray", ha="left", va="top")
