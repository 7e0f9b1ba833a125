"""Figures and tables of stability margins (:mod:`vtol_impedance.robust`): Bode and Nyquist plots of every
loop, the closed-loop poles, and a table per controller. They read margin reports; they compute nothing."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from ..robust import MarginReport, Thresholds
from .plots import COLORS, _label, _save, plt

LOOP_COLORS = {
    "thrust": "tab:gray",
    "roll torque": "tab:blue",
    "pitch torque": "tab:orange",
    "yaw torque": "tab:green",
    "roll reference": "tab:purple",
    "pitch reference": "tab:brown",
}
STYLES = {"pdc": "-", "pd": "--", "pid": ":", "comply": "-."}


def _fmt(v: float, unit: str = "", digits: int = 1) -> str:
    if v is None or (isinstance(v, float) and np.isnan(v)):
        return "unstable"
    if np.isinf(v):
        return "none"
    return f"{v:.{digits}f}{unit}"


def margin_rows(reports: dict[str, MarginReport]) -> tuple[list[str], list[list[str]]]:
    """A row per controller and loop: phase margin, gain margins up and down, delay margin, crossover,
    sensitivity peak."""
    head = ["controller", "loop", "phase margin [deg]", "gain margin up [dB]", "gain margin down [dB]",
            "delay margin [ms]", "crossover [rad/s]", "sensitivity peak"]  # fmt: skip
    rows = []
    for variant, r in reports.items():
        for m in r.loops.values():
            rows.append([
                _label(variant), m.name, _fmt(m.phase_deg), _fmt(m.gain_up_db), _fmt(m.gain_down_db),
                _fmt(1e3 * m.delay_s, digits=0), _fmt(m.crossover, digits=2), _fmt(m.sensitivity_peak, digits=2),
            ])  # fmt: skip
    return head, rows


def pole_rows(
    reports: dict[str, MarginReport], thresholds: Thresholds | None = None
) -> tuple[list[str], list[list[str]]]:
    """A row per controller: stability, the rightmost and the least damped closed-loop pole, the verdict."""
    head = ["controller", "closed loop", "rightmost pole [1/s]", "least damped pole", "damping", "verdict"]
    rows = []
    for variant, r in reports.items():
        s, d = r.rightmost, r.least_damped
        v = r.violations(thresholds)
        rows.append([
            _label(variant), "stable" if r.stable else "UNSTABLE", f"{s.real:+.3f} {s.imag:+.2f}j",
            f"{d.real:+.3f} {d.imag:+.2f}j", f"{r.damping:.3f}", "ok" if not v else "; ".join(v),
        ])  # fmt: skip
    return head, rows


def _line(cells: list[str], widths: list[int]) -> str:
    return "  ".join(c.ljust(w) for c, w in zip(cells, widths, strict=True))


def text_margins(reports: dict[str, MarginReport], thresholds: Thresholds | None = None) -> str:
    """The two tables as aligned text for the terminal."""
    out = []
    for head, rows in (pole_rows(reports, thresholds), margin_rows(reports)):
        if head[-1] == "verdict":  # the verdict goes below, it is long
            rows = [r[:-1] for r in rows]
            head = head[:-1]
        widths = [max(len(h), *(len(r[i]) for r in rows)) for i, h in enumerate(head)]
        out += [_line(c, widths) for c in [head, ["-" * w for w in widths], *rows]] + [""]
    return "\n".join(out)


def bode_curves(m: Any) -> tuple[np.ndarray, np.ndarray]:
    """Magnitude (dB) and unwrapped phase (deg) of a loop's ``L`` (a :class:`~vtol_impedance.robust.LoopMargins`)
    on its frequencies, the phase shifted by whole turns so that it lies in [-360, 0) deg at the gain
    crossover (where the phase margin is read against -180 deg)."""
    H = m.response
    ph = np.degrees(np.unwrap(np.angle(H)))
    c = int(np.argmin(np.abs(np.log(np.abs(H)))))  # the gain crossover
    ph -= 360.0 * np.floor(ph[c] / 360.0 + 1.0)
    return 20 * np.log10(np.abs(H)), ph


def plot_bode(reports: dict[str, MarginReport], path: Path, title: str = "") -> Path:
    """Magnitude and phase of every loop transfer ``L`` (closed by ``1 + L``) per controller: the rotor
    commands on the left, the attitude references on the right. Gain crossovers are where the magnitude
    crosses 0 dB; the phase margin is the distance of the phase from -180 deg there."""
    fig, ax = plt.subplots(2, 2, figsize=(11, 6.5), sharex=True)
    for variant, r in reports.items():
        for name, m in r.loops.items():
            col = 1 if "reference" in name else 0
            w = m.omega
            style = dict(color=LOOP_COLORS.get(name), ls=STYLES.get(variant, "-"), lw=1.1)
            mag_db, ph = bode_curves(m)
            ax[0, col].semilogx(w, mag_db, label=f"{_label(variant)}, {name}", **style)
            ax[1, col].semilogx(w, ph, **style)
    for col, name in enumerate(("rotor commands (thrust, torques)", "attitude references (roll, pitch)")):
        ax[0, col].axhline(0.0, color="k", lw=0.6)
        ax[1, col].axhline(-180.0, color="k", lw=0.6)
        ax[0, col].set_title(name, fontsize=10)
        ax[0, col].set_ylim(-40, 60)
        ax[1, col].set_ylim(-540, 180)
        ax[1, col].set_xlim(1e-2, np.pi / float(next(iter(reports.values())).info["control_period_s"]))
        ax[1, col].set_xlabel("frequency [rad/s]")
        for a in ax[:, col]:
            a.grid(alpha=0.3, which="both")
        ax[0, col].legend(fontsize=6.5, ncol=2, loc="lower left")
    ax[0, 0].set_ylabel("|L| [dB]")
    ax[1, 0].set_ylabel("phase of L [deg]")
    fig.suptitle(title or "Loop transfers at the operating point (line style: controller; colour: loop)", fontsize=11)
    fig.tight_layout()
    return _save(fig, path)


def plot_nyquist(reports: dict[str, MarginReport], path: Path, thresholds: Thresholds | None = None) -> Path:
    """Nyquist plots near -1, one panel per controller: a loop is robust when its curve keeps away from
    -1; the grey circle marks the sensitivity peak the phase-margin threshold allows."""
    t = Thresholds() if thresholds is None else thresholds
    n = len(reports)
    fig, axes = plt.subplots(1, n, figsize=(4.2 * n, 4.2), squeeze=False)
    radius = 2.0 * np.sin(np.radians(t.phase_deg) / 2.0)  # |1 + L| at the threshold's phase margin
    for a, (variant, r) in zip(axes[0], reports.items(), strict=True):
        for name, m in r.loops.items():
            H = m.response
            a.plot(H.real, H.imag, color=LOOP_COLORS.get(name), lw=1, label=name)
            a.plot(H.real, -H.imag, color=LOOP_COLORS.get(name), lw=0.5, alpha=0.4)
        th = np.linspace(0, 2 * np.pi, 200)
        a.plot(-1 + radius * np.cos(th), radius * np.sin(th), color="0.6", lw=0.8)
        a.plot([-1], [0], "r+", ms=10)
        a.set_xlim(-3, 1.5)
        a.set_ylim(-2.25, 2.25)
        a.set_aspect("equal")
        a.grid(alpha=0.3)
        state = "stable" if r.stable else f"UNSTABLE ({r.rightmost.real:+.2f} 1/s)"
        a.set_title(f"{_label(variant)}: {state}", fontsize=10, color=COLORS.get(variant, "k"))
        a.set_xlabel("Re L")
    axes[0, 0].set_ylabel("Im L")
    axes[0, 0].legend(fontsize=7, loc="lower left")
    fig.tight_layout()
    return _save(fig, path)


def plot_poles(reports: dict[str, MarginReport], path: Path, thresholds: Thresholds | None = None) -> Path:
    """Closed-loop poles (continuous equivalents) near the origin: right of the axis grows, inside the
    grey wedge is damped less than the threshold."""
    t = Thresholds() if thresholds is None else thresholds
    fig, a = plt.subplots(figsize=(6.5, 5))
    for variant, r in reports.items():
        p = r.poles[np.abs(r.poles) < 80]
        a.plot(p.real, p.imag, "x" if variant != "pd" else "o", mfc="none", color=COLORS.get(variant, "k"),
               label=_label(variant), ms=6)  # fmt: skip
    slope = np.sqrt(1 - t.damping**2) / t.damping
    a.fill_betweenx([-80, 80], [-80 / slope, -80 / slope], [0, 0], color="0.9", zorder=0)
    a.fill_between([-80 / slope, 0], [80, 0], [-80, 0], color="0.9", zorder=0,
                   label=f"damping < {t.damping:g}")  # fmt: skip
    a.axvline(0.0, color="r", lw=0.8)
    a.set_xlim(-40, 5)
    a.set_ylim(-60, 60)
    a.set_xlabel("real part [1/s]")
    a.set_ylabel("imaginary part [rad/s]")
    a.grid(alpha=0.3)
    a.legend(fontsize=8)
    a.set_title("Closed-loop poles at the operating point", fontsize=10)
    return _save(fig, path)


def plot_margins(
    reports: dict[str, MarginReport], folder: Path, stem: str, thresholds: Thresholds | None = None
) -> list[Path]:
    """``<stem>_bode.png``, ``<stem>_nyquist.png``, ``<stem>_poles.png``."""
    return [
        plot_bode(reports, Path(folder) / f"{stem}_bode.png"),
        plot_nyquist(reports, Path(folder) / f"{stem}_nyquist.png", thresholds),
        plot_poles(reports, Path(folder) / f"{stem}_poles.png", thresholds),
    ]


def margins_json(reports: dict[str, MarginReport]) -> dict[str, Any]:
    """Everything numeric of the reports (no frequency responses)."""
    out = {}
    for variant, r in reports.items():
        out[variant] = {
            "summary": r.summary(),
            "violations": r.violations(),
            "rightmost_pole": [r.rightmost.real, r.rightmost.imag],
            "least_damped_pole": [r.least_damped.real, r.least_damped.imag],
            "loops": {
                k: {
                    f: getattr(m, f)
                    for f in ("gain_up_db", "gain_down_db", "phase_deg", "crossover", "delay_s", "sensitivity_peak")
                }
                for k, m in r.loops.items()
            },  # fmt: skip
            "info": r.info,
        }
    return out
