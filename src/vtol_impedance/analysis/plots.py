"""Figures mirroring the paper's Figs. 4-9, drawn only from results. Uses the non-interactive Agg backend."""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from ..control.impedance import DISPLAY_NAMES  # noqa: E402
from ..io import atomic_path  # noqa: E402
from ..sim.result import Result  # noqa: E402
from .metrics import window_mask  # noqa: E402

COLORS = {"pdc": "tab:blue", "pid": "tab:red", "pd": "black", "comply": "tab:green"}
NAMES = DISPLAY_NAMES
AXES = ("x", "y", "z")
AXIS_COLORS = ("tab:blue", "tab:red", "black")


def _save(fig: plt.Figure, path: Path) -> Path:
    with atomic_path(path) as tmp:
        fig.savefig(tmp, format=path.suffix[1:], dpi=110, bbox_inches="tight")
    plt.close(fig)
    return path


def _label(label: str) -> str:
    return NAMES.get(label, label)


def plot_errors(result: Result, path: Path, title: str = "") -> Path:
    """(a) position error norm, (b) velocity error norm for every controller (Figs. 4, 6, 8b)."""
    m = window_mask(result)
    t = result.t[m]
    fig, ax = plt.subplots(2, 1, figsize=(8, 5.5), sharex=True)
    for b, lab in enumerate(result.labels):
        c = COLORS.get(lab)
        ax[0].plot(t, 100 * np.linalg.norm(result.e_p[b, m], axis=-1), color=c, lw=1, label=_label(lab))
        ax[1].plot(t, 100 * np.linalg.norm(result.e_v[b, m], axis=-1), color=c, lw=0.8, label=_label(lab))
    ax[0].set_ylabel("|e_p| [cm]")
    ax[1].set_ylabel("|e_p_dot| [cm/s]")
    ax[1].set_xlabel("time [s]")
    ax[0].set_title(title or "Position and velocity error norms (task window)")
    for a in ax:
        a.grid(alpha=0.3)
        a.legend(loc="upper right", fontsize=8)
    return _save(fig, path)


def plot_inputs(result: Result, path: Path, title: str = "") -> Path:
    """Thrust and body torques actually commanded (after allocation), one column per controller so that
    none hides another (Fig. 4d); the rows share their scales."""
    n = len(result.labels)
    fig, ax = plt.subplots(4, n, figsize=(4.2 * n + 1.0, 8), sharex=True, sharey="row", squeeze=False)
    for b, lab in enumerate(result.labels):
        c = COLORS.get(lab)
        ax[0, b].plot(result.t, result["thrust"][b], color=c, lw=0.8)
        for i in range(3):
            ax[i + 1, b].plot(result.t, 1000 * result["tau_B"][b, :, i], color=c, lw=0.6)
        ax[0, b].set_title(_label(lab), fontsize=10, color=c)
        ax[-1, b].set_xlabel("time [s]")
        for a in ax[:, b]:
            a.grid(alpha=0.3)
    ax[0, 0].set_ylabel("u [N]")
    for i, name in enumerate(("roll", "pitch", "yaw")):
        ax[i + 1, 0].set_ylabel(f"tau_{name} [mN m]")
    fig.suptitle(title or "Control inputs (allocated)")
    fig.tight_layout()
    return _save(fig, path)


def _robust_limits(*series: np.ndarray) -> tuple[float, float]:
    """Limits that show the bulk of the signals: the 0.5-99.5 % range with a margin, so that a landing's
    contact spike does not set the scale (the spike is drawn, clipped at the edge)."""
    v = np.concatenate([np.ravel(s) for s in series])
    v = v[np.isfinite(v)]
    if not v.size:
        return -1.0, 1.0
    lo, hi = np.percentile(v, [0.5, 99.5])
    pad = 0.15 * max(hi - lo, 1e-3)
    return float(lo - pad), float(hi + pad)


def plot_wrench(result: Result, path: Path, label: str = "pdc", title: str = "") -> Path:
    """Estimated forces and moments (thick) against what the nominal model misses (thin), Figs. 5, 7, 9.
    The vertical scale is set by the task window (a landing's spike is clipped at the edge)."""
    b = result.index(label) if label in result.labels else 0
    fig, ax = plt.subplots(2, 1, figsize=(8, 6.5), sharex=True)
    t = result.t
    m = window_mask(result)
    for i in range(3):
        ax[0].plot(t, result["f_lumped_W"][b, :, i], color=AXIS_COLORS[i], lw=0.5, alpha=0.5)
        ax[0].plot(t, result["f_hat_W"][b, :, i], color=AXIS_COLORS[i], lw=1.4, label=f"{AXES[i]}")
        ax[1].plot(t, 1000 * result["tau_lumped_eta"][b, :, i], color=AXIS_COLORS[i], lw=0.5, alpha=0.5)
        ax[1].plot(t, 1000 * result["tau_hat_eta"][b, :, i], color=AXIS_COLORS[i], lw=1.4, label=f"{AXES[i]}")
    ax[0].set_ylim(*_robust_limits(result["f_lumped_W"][b, m], result["f_hat_W"][b, m]))
    ax[1].set_ylim(*_robust_limits(1000 * result["tau_lumped_eta"][b, m], 1000 * result["tau_hat_eta"][b, m]))
    ax[0].set_ylabel("force, world NED [N]")
    ax[1].set_ylabel("moment, Euler coords [mN m]")
    ax[1].set_xlabel("time [s]")
    ax[0].set_title(title or f"Estimated external wrench ({_label(result.labels[b])})")
    thick = plt.Line2D([], [], color="gray", lw=1.4, label="estimate (thick)")
    thin = plt.Line2D([], [], color="gray", lw=0.5, alpha=0.6, label="true, what the model misses (thin)")
    for a in ax:
        a.grid(alpha=0.3)
        h, _ = a.get_legend_handles_labels()
        a.legend(handles=[*h, thick, thin], loc="upper right", fontsize=7, ncol=5)
    return _save(fig, path)


def plot_xy(result: Result, path: Path, title: str = "") -> Path:
    """Horizontal path over the task window, one panel per controller with the reference dashed in each,
    so that no path hides another (Fig. 8a shows PD+C's), titled with its RMS horizontal distance from the
    reference (cm); the panels share their scales. y east, x north (m)."""
    m = window_mask(result)
    n = len(result.labels)
    fig, ax = plt.subplots(1, n, figsize=(3.8 * n + 0.6, 4.4), sharex=True, sharey=True, squeeze=False)
    for b, lab in enumerate(result.labels):
        a = ax[0, b]
        a.plot(result["p_ref_W"][b, m, 1], result["p_ref_W"][b, m, 0], "--", color="gray", lw=1.5, label="reference")
        a.plot(result["p_W"][b, m, 1], result["p_W"][b, m, 0], color=COLORS.get(lab), lw=1, label=_label(lab))
        e_xy = result["p_W"][b, m, :2] - result["p_ref_W"][b, m, :2]
        rms = 100 * np.sqrt(np.nanmean(np.sum(e_xy * e_xy, axis=-1)))  # the paths differ by cm on a 1 m circle
        a.set_title(f"{_label(lab)}: RMS {rms:.1f} cm off the reference", fontsize=9, color=COLORS.get(lab))
        a.set_xlabel("y (east) [m]")
        a.set_aspect("equal")
        a.grid(alpha=0.3)
        a.legend(fontsize=7, loc="upper right")
    ax[0, 0].set_ylabel("x (north) [m]")
    fig.suptitle(title or "Horizontal path")
    fig.tight_layout()
    return _save(fig, path)


def plot_case(result: Result, folder: Path, stem: str) -> list[Path]:
    """All figures of one case into ``folder`` as ``{stem}_*.png``."""
    folder.mkdir(parents=True, exist_ok=True)
    name = result.config.get("scenario", {}).get("name", stem)
    paths = [
        plot_errors(result, folder / f"{stem}_errors.png", f"{name}: error norms"),
        plot_inputs(result, folder / f"{stem}_inputs.png", f"{name}: inputs"),
        plot_wrench(result, folder / f"{stem}_wrench.png", title=f"{name}: estimated wrench (PD+C)"),
    ]
    if result.config.get("scenario", {}).get("trajectory", {}).get("kind") in ("circle", "figure-eight"):
        paths.append(plot_xy(result, folder / f"{stem}_xy.png", f"{name}: x-y path"))
    return paths
