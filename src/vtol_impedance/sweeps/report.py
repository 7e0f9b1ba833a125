"""Summary of a sweep: statistics per point and controller, heat maps over two axes, error against each
axis with its spread, failure regions marked, and the self-contained HTML report."""

from __future__ import annotations

import csv
import io
import json
from pathlib import Path
from typing import Any

import numpy as np

from ..control.impedance import DISPLAY_NAMES
from ..errors import InputError
from ..io import MANIFEST, sha256_of, write_text
from .run import METRICS, SWEEP_FILE, read_dataset

LABELS = DISPLAY_NAMES
METRIC_LABELS = {
    "rms_ep_cm": "RMS |e_p| [cm]",
    "max_ep_cm": "max |e_p| [cm]",
    "ss_ep_cm": "steady |e_p| [cm]",
    "rms_ev_cms": "RMS |de_p| [cm/s]",
    "rms_f_err_N": "RMS |f_hat - f| [N]",
    "rms_tau_err_mNm": "RMS |tau_hat - tau| [mN m]",
    "sat_pct": "limited [%]",
}


#: How a sweep axis is named on a figure: the quantity and its unit.
AXIS_LABELS = {
    "payload.mass": "payload mass [kg]",
    "payload.offset_B": "payload offset, body FRD [m]",
    "plant.inertia_scale": "true inertia / nominal",
    "plant.rotor_tau_up": "rotor spin-up time constant [s]",
    "plant.rotor_tau_down": "rotor spin-down time constant [s]",
    "plant.rotor_drag": "rotor drag [N s/m]",
    "plant.arm_length_scale": "true arm length / nominal",
    "plant.drag_factor_scale": "true drag factor / nominal",
    "plant.pendulum_mass": "pendulum bob [kg]",
    "sensors.mocap_delay": "position latency [s]",
    "sensors.imu_delay": "attitude latency [s]",
    "sensors.pos_noise": "position noise [m]",
    "sensors.vel_noise": "velocity noise [m/s]",
    "control.rate": "control rate [Hz]",
    "control.estimator_wn": "estimator bandwidth [rad/s]",
    "control.wn_o": "roll/pitch bandwidth [rad/s]",
    "control.attitude_filter_wn": "attitude filter [rad/s]",
    "control.Kp": "Kp [N/m]",
    "control.Dp": "Dp [N s/m]",
    "control.Ki": "Ki [N/(m s)]",
    "trajectory.circle_speed": "circle speed [m/s]",
    "trajectory.circle_radius": "circle radius [m]",
    "interaction.M": "apparent mass [kg]",
    "interaction.K": "stiffness [N/m]",
    "interaction.D": "damping [N s/m]",
}


def axis_label(key: str) -> str:
    """``"payload mass [kg]"`` for ``payload.mass``; joint axes ``a,b`` as ``a / b``; unknown keys as they are."""
    import re

    parts = []
    for k in key.split(","):
        m = re.match(r"^(.*)\[(\d)\]$", k.strip())
        base, idx = (m.group(1), m.group(2)) if m else (k.strip(), None)
        name = AXIS_LABELS.get(base, base)
        parts.append(name.replace(" [", f" {'xyz'[int(idx)]} [", 1) if idx is not None else name)
    return " / ".join(parts)


def tick(v: Any) -> str:
    """A short tick label: numbers to 3 digits, a vector of equal components as one number."""
    if isinstance(v, str):
        try:
            v = json.loads(v)
        except ValueError:
            return v
    if isinstance(v, list | tuple):
        if len(v) > 1 and all(x == v[0] for x in v):
            return tick(v[0])
        return "(" + ", ".join(tick(x) for x in v) + ")"
    return f"{v:.3g}" if isinstance(v, float | int) else str(v)


def _columns(table) -> dict[str, np.ndarray]:
    return {name: np.asarray(table[name].to_pylist(), dtype=object) for name in table.column_names}


def summarise(folder: Path, metric: str = "rms_ep_cm") -> dict[str, Any]:
    """Per point and controller: the axis values, mean, std, min and max of ``metric`` over the seeds, and
    the share of failed flights (failed flights are left out of the statistics)."""
    from ..errors import path_like

    folder = path_like("folder", folder)
    if metric not in METRICS:
        raise InputError(f"metric must be one of {', '.join(METRICS)}, got {metric!r}")
    if not (Path(folder) / SWEEP_FILE).is_file():
        raise InputError(f"{folder} is not a sweep folder (it has no {SWEEP_FILE}); give the --out of a sweep")
    try:
        desc = json.loads((Path(folder) / SWEEP_FILE).read_text(encoding="utf-8"))
    except ValueError as exc:
        raise InputError(f"{Path(folder) / SWEEP_FILE} is not readable: {exc}") from None
    sw = desc["sweep"]
    cols = _columns(read_dataset(folder, desc.get("digest")))
    n_expected = len(sw["points"]) * sw["seeds"] * len(sw["controllers"])
    rows = []
    for i, point in enumerate(sw["points"]):
        for c in sw["controllers"]:
            sel = (cols["point"] == i) & (cols["controller"] == c)
            vals = cols[metric][sel].astype(float)
            failed = cols["diverged"][sel].astype(bool)
            ok = vals[~failed & np.isfinite(vals)]
            rows.append({
                "point": i, "controller": c, **point, "n": int(sel.sum()),
                "mean": float(ok.mean()) if ok.size else float("nan"),
                "std": float(ok.std()) if ok.size else float("nan"),
                "min": float(ok.min()) if ok.size else float("nan"),
                "max": float(ok.max()) if ok.size else float("nan"),
                "failed_share": float(failed.mean()) if sel.any() else float("nan"),
            })  # fmt: skip
    return {"metric": metric, "axes": sw["axes"], "controllers": sw["controllers"], "rows": rows,
            "flights": int(len(cols["unit"])), "expected": n_expected, "sweep": sw, "cols": cols}  # fmt: skip


def _axis_values(rows: list[dict], key: str) -> list:
    vals = sorted({json.dumps(r[key]) for r in rows}, key=lambda s: json.loads(s) if not s.startswith("[") else s)
    return [json.loads(v) for v in vals]


def plot_heatmaps(s: dict[str, Any], path: Path, x: str, y: str) -> Path:
    """Mean metric over ``x`` and ``y`` (averaged over any other axis), one panel per controller; cells
    with failed flights crossed out."""
    from matplotlib.colors import LogNorm

    from ..analysis.plots import _save, plt

    xs, ys = _axis_values(s["rows"], x), _axis_values(s["rows"], y)
    ctrls = s["controllers"]
    grids = {}
    for c in ctrls:
        cells: dict[tuple[int, int], list[float]] = {}
        f = np.zeros((len(ys), len(xs)))
        for r in s["rows"]:
            if r["controller"] != c:
                continue
            i, j = ys.index(r[y]), xs.index(r[x])
            cells.setdefault((i, j), []).append(r["mean"])
            f[i, j] = max(f[i, j], r["failed_share"])
        m = np.full((len(ys), len(xs)), np.nan)
        for (i, j), vals in cells.items():  # the median over the other axes: one bad corner does not set it
            v = np.asarray(vals, dtype=float)
            m[i, j] = float(np.median(v[np.isfinite(v)])) if np.isfinite(v).any() else np.nan
        grids[c] = (m, f)
    finite = np.concatenate([g[0][np.isfinite(g[0])] for g in grids.values()] + [np.array([1.0])])
    pos = finite[finite > 0]
    norm = LogNorm(vmin=max(pos.min(), 1e-3), vmax=max(pos.max(), pos.min() * 1.01))
    fig, axs = plt.subplots(1, len(ctrls), figsize=(4.6 * len(ctrls) + 1.2, 4.2), squeeze=False)
    for ax, c in zip(axs[0], ctrls, strict=True):
        m, f = grids[c]
        im = ax.imshow(m, origin="lower", aspect="auto", norm=norm, cmap="viridis")
        for i in range(len(ys)):
            for j in range(len(xs)):
                if f[i, j] > 0:
                    ax.text(j, i, "x", ha="center", va="center", color="red", fontsize=12, fontweight="bold")
                elif np.isfinite(m[i, j]) and len(xs) * len(ys) <= 120:
                    ax.text(j, i, f"{m[i, j]:.2g}", ha="center", va="center", color="white", fontsize=6)
        ax.set_xticks(range(len(xs)), [tick(v) for v in xs], rotation=45, ha="right", fontsize=8)
        ax.set_yticks(range(len(ys)), [tick(v) for v in ys], fontsize=8)
        ax.set_xlabel(axis_label(x))
        ax.set_ylabel(axis_label(y))
        ax.set_title(LABELS.get(c, c))
    label = METRIC_LABELS[s["metric"]] + " (mean over seeds, median over other axes)"
    fig.colorbar(im, ax=axs[0].tolist(), label=label)
    fig.suptitle(f"{s['sweep']['name']}: red x = at least one flight failed there")
    return _save(fig, path)


def plot_compensation(s: dict[str, Any], path: Path, x: str, y: str) -> Path | None:
    """PD+C over PD at every point (below 1: compensation helps); the contour 1 is where it stops helping."""
    if not {"pd", "pdc"} <= set(s["controllers"]):
        return None
    from matplotlib.colors import LogNorm

    from ..analysis.plots import _save, plt

    xs, ys = _axis_values(s["rows"], x), _axis_values(s["rows"], y)
    val = {(r["controller"], json.dumps(r[x]), json.dumps(r[y])): r for r in s["rows"]}
    ratio = np.full((len(ys), len(xs)), np.nan)
    failed = np.zeros_like(ratio, dtype=bool)
    for i, vy in enumerate(ys):
        for j, vx in enumerate(xs):
            a, b = val.get(("pdc", json.dumps(vx), json.dumps(vy))), val.get(("pd", json.dumps(vx), json.dumps(vy)))
            if a and b:
                ratio[i, j] = a["mean"] / b["mean"] if b["mean"] > 0 else np.nan
                failed[i, j] = a["failed_share"] > 0 or b["failed_share"] > 0
    fig, ax = plt.subplots(figsize=(6.5, 4.8))
    r = ratio[np.isfinite(ratio) & (ratio > 0)]
    lim = max(float(np.max(np.abs(np.log10(r)))) if r.size else 1.0, 0.1)
    im = ax.imshow(ratio, origin="lower", aspect="auto", cmap="RdBu_r", norm=LogNorm(10**-lim, 10**lim))
    if np.isfinite(ratio).sum() > 3 and len(xs) > 1 and len(ys) > 1:
        ax.contour(np.log10(np.where(np.isfinite(ratio) & (ratio > 0), ratio, 1e3)), levels=[0.0], colors="black")
    for i in range(len(ys)):
        for j in range(len(xs)):
            if failed[i, j]:
                ax.text(j, i, "x", ha="center", va="center", color="red", fontsize=12, fontweight="bold")
    ax.set_xticks(range(len(xs)), [tick(v) for v in xs], rotation=45, ha="right", fontsize=8)
    ax.set_yticks(range(len(ys)), [tick(v) for v in ys], fontsize=8)
    ax.set_xlabel(axis_label(x))
    ax.set_ylabel(axis_label(y))
    fig.colorbar(im, ax=ax, label=f"{METRIC_LABELS[s['metric']]}: PD+C / PD")
    ax.set_title("Where compensation helps (blue) and where it stops (red); black: ratio 1")
    return _save(fig, path)


def plot_against(s: dict[str, Any], path: Path, axis: str) -> Path:
    """The metric against one axis for each controller: median over seeds and the other axes, with the
    10-90 % band, failures as red crosses at the top."""
    from ..analysis.plots import COLORS, _save, plt

    cols = s["cols"]
    xs = _axis_values(s["rows"], axis)
    fig, ax = plt.subplots(figsize=(7, 4.2))
    stored = lambda v: v if isinstance(v, str) else json.dumps(v)  # noqa: E731 (vectors: stored as JSON)
    key = np.array([stored(v) for v in cols[axis]])
    vals = cols[s["metric"]].astype(float)
    failed = cols["diverged"].astype(bool)
    top = np.nanmax(np.where(failed, np.nan, vals)) if np.any(~failed) else 1.0
    numeric = all(isinstance(v, int | float) for v in xs)
    xpos = np.array(xs, dtype=float) if numeric else np.arange(len(xs), dtype=float)
    for c in s["controllers"]:
        med, lo, hi, nfail = [], [], [], []
        for v in xs:
            sel = (key == stored(v)) & (cols["controller"] == c)
            ok = vals[sel & ~failed]
            ok = ok[np.isfinite(ok)]
            med.append(np.median(ok) if ok.size else np.nan)
            lo.append(np.percentile(ok, 10) if ok.size else np.nan)
            hi.append(np.percentile(ok, 90) if ok.size else np.nan)
            nfail.append(int((sel & failed).sum()))
        color = COLORS.get(c)
        ax.plot(xpos, med, "o-", color=color, label=LABELS.get(c, c), ms=3)
        ax.fill_between(xpos, lo, hi, color=color or "gray", alpha=0.15)
        bad = np.array(nfail) > 0
        if bad.any():
            ax.plot(xpos[bad], np.full(bad.sum(), top * 1.15), "x", color="red", ms=8)
    if numeric and np.all(xpos > 0) and xpos.max() / max(xpos.min(), 1e-300) > 20:
        ax.set_xscale("log")
    if not numeric:
        ax.set_xticks(xpos, [tick(v) for v in xs], rotation=30, ha="right", fontsize=8)
    if np.any(np.isfinite(vals) & (vals > 0) & ~failed):  # a log axis needs one positive value
        ax.set_yscale("log")
    ax.set_xlabel(axis_label(axis))
    ax.set_ylabel(METRIC_LABELS[s["metric"]])
    ax.grid(alpha=0.3, which="both")
    ax.legend(fontsize=8)
    ax.set_title(f"{s['sweep']['name']}: median and 10-90 % band; red x: failed flights")
    return _save(fig, path)


#: A flight "oscillates" when its RMS position error exceeds this (cm) or it failed: what the margin
#: check is judged against (README, "Stability margins").
OSCILLATING_CM = 0.5


def margin_agreement(s: dict[str, Any]) -> dict[str, dict[str, float]]:
    """Per controller: how often the linear model's verdict (closed loop unstable) agrees with the flights
    (RMS |e_p| above :data:`OSCILLATING_CM` or failed), and the counts behind it."""
    cols = s["cols"]
    out = {}
    for c in s["controllers"]:
        sel = cols["controller"] == c
        rms = cols["rms_ep_cm"][sel].astype(float)
        osc = cols["diverged"][sel].astype(bool) | ~(rms <= OSCILLATING_CM)
        unstable = cols["margin_stable"][sel].astype(float) < 0.5
        out[c] = {"cells": int(sel.sum()), "oscillating": int(osc.sum()), "unstable": int(unstable.sum()),
                  "agreement": float(np.mean(osc == unstable)) if sel.any() else float("nan")}  # fmt: skip
    return out


def plot_margin_check(s: dict[str, Any], path: Path) -> Path | None:
    """PD+C over PD at every point against the worst phase margin the check computed for PD+C there:
    right of the threshold the check passes, and compensation should not be worse than PD (ratio <= 1);
    unstable points (no margin) are drawn at the left edge."""
    cols = s["cols"]
    if "pm_min_deg" not in cols or not {"pd", "pdc"} <= set(s["controllers"]):
        return None
    from ..analysis.plots import _save, plt
    from ..robust import Thresholds

    m = s["metric"]
    pdc, pd = cols["controller"] == "pdc", cols["controller"] == "pd"
    key = lambda sel: list(zip(cols["unit"][sel].tolist(), strict=True))  # noqa: E731
    if key(pdc) != key(pd):
        return None
    ratio = cols[m][pdc].astype(float) / np.maximum(cols[m][pd].astype(float), 1e-12)
    pm = cols["pm_min_deg"][pdc].astype(float)
    stable = cols["margin_stable"][pdc].astype(float) > 0.5
    ok = cols["margin_ok"][pdc].astype(float) > 0.5
    failed = cols["diverged"][pdc].astype(bool)
    ratio = np.where(failed | ~np.isfinite(ratio), 1e3, ratio)
    x = np.where(stable, pm, -5.0)
    fig, ax = plt.subplots(figsize=(7.5, 4.5))
    for sel, colour, label in ((ok, "tab:blue", "the check passes"), (~ok & stable, "tab:orange", "thin margins"),
                               (~stable, "tab:red", "unstable (drawn at -5 deg)")):  # fmt: skip
        ax.plot(x[sel], ratio[sel], "o", ms=4, color=colour, alpha=0.7, label=f"{label} ({int(sel.sum())})")
    t = Thresholds()
    ax.axvline(t.phase_deg, color="k", lw=0.8)
    ax.axhline(1.0, color="k", lw=0.6, ls="--")
    ax.set_yscale("log")
    ax.set_xlabel("PD+C's worst phase margin at the point [deg] (from the linear model)")
    ax.set_ylabel(f"{METRIC_LABELS[m]}: PD+C / PD (failed: top)")
    ax.grid(alpha=0.3, which="both")
    ax.legend(fontsize=8)
    ax.set_title(f"{s['sweep']['name']}: is compensation worse than PD where the check passes?", fontsize=10)
    return _save(fig, path)


def write_report(folder: Path, metric: str = "rms_ep_cm", x: str | None = None, y: str | None = None) -> list[Path]:
    """Summary CSV, figures, ``report.html`` and ``manifest.json`` into the sweep folder."""
    from ..errors import instance, path_like

    folder = path_like("folder", folder)
    for name, v in (("metric", metric), ("x", x), ("y", y)):
        if v is not None:
            instance(name, v, str)
    from ..analysis.report import write_html

    folder = Path(folder)
    s = summarise(folder, metric)
    axes = s["axes"]
    for a in (x, y):
        if a is not None and a not in axes:
            raise InputError(f"{a!r} is not an axis of this sweep; its axes are {', '.join(axes)}")
    if s["flights"] < s["expected"]:
        raise InputError(
            f"{folder} holds {s['flights']} of {s['expected']} flights: the sweep is not finished; run the same "
            "sweep command again to compute the missing chunks"
        )
    buf = io.StringIO()
    head = ["point", "controller", *axes, "n", "mean", "std", "min", "max", "failed_share"]
    w = csv.writer(buf)
    w.writerow(head)
    for r in s["rows"]:
        w.writerow([json.dumps(r[h]) if isinstance(r[h], list) else r[h] for h in head])
    files = [write_text(folder / "summary.csv", buf.getvalue())]
    figs = []
    if len(axes) >= 2:
        xa, ya = x or axes[0], y or next(a for a in axes if a != (x or axes[0]))
        figs.append(plot_heatmaps(s, folder / "heatmap.png", xa, ya))
        comp = plot_compensation(s, folder / "compensation.png", xa, ya)
        if comp is not None:
            figs.append(comp)
    for i, a in enumerate(axes):
        figs.append(plot_against(s, folder / f"against-axis{i}.png", a))
    check = plot_margin_check(s, folder / "margin-check.png")
    if check is not None:
        figs.append(check)
    judged = "settle_ev_cms" in s["cols"] and "margin_stable" in s["cols"]
    if judged:
        figs.append(plot_verdict_outcome({s["sweep"]["name"]: s["cols"]}, folder / "verdict-outcome.png"))
    files += figs
    table_rows = [
        [str(r["point"]), LABELS.get(r["controller"], r["controller"])]
        + [f"{r[a]:.4g}" if isinstance(r[a], float) else str(r[a]) for a in axes]
        + [f"{r['mean']:.3g}", f"{r['std']:.2g}", f"{100 * r['failed_share']:.0f}"]
        for r in s["rows"][:2000]
    ]
    fails = sum(r["failed_share"] > 0 for r in s["rows"])
    notes = [
        f"{s['flights']} flights: {len(s['sweep']['points'])} points x {s['sweep']['seeds']} seeds x "
        f"{len(s['controllers'])} controllers; metric {METRIC_LABELS[metric]} over each scenario's task window.",
        f"{fails} point/controller pairs had failed flights (red x in the figures); they are left out of the means.",
    ]
    if "margin_stable" in s["cols"] and "settle_ev_cms" not in s["cols"]:  # else: the verdict notes below
        for c, a in margin_agreement(s).items():
            if c in ("pd", "pid"):  # their RMS holds the payload's sag: "above 0.5 cm" is no oscillation test
                continue
            notes.append(
                f"{LABELS.get(c, c)}: the linear model calls {a['unstable']} of {a['cells']} flights unstable; "
                f"{a['oscillating']} oscillated (RMS |e_p| above {OSCILLATING_CM} cm or failed): agreement "
                f"{100 * a['agreement']:.1f} %."
            )
    if judged:
        vo = verdict_outcome(s["cols"])
        for c, a in vo["counts"].items():
            notes.append(
                f"{LABELS.get(c, c)}: of {a['cells']} flights the check's verdict (stable or not) agrees with the "
                f"flight in {a['agree']}, {a['false_alarm']} false alarms (unstable, settled), {a['miss']} misses "
                f"(stable, wobbled: failed, wobble above {WOBBLE_CMS} cm/s or a transient above "
                f"{TRANSIENT_FACTOR:g} x the median peak); against the thresholds {a['agree_t']} / "
                f"{a['false_alarm_t']} / {a['miss_t']}"
                + (f"; {a['scoped']} rows' check leaves a loop out (margin_scope)" if a["scoped"] else "")
            )
        buf = io.StringIO()
        w = csv.writer(buf)
        w.writerow(["unit", "controller", "verdict", "margin_scope", "wobbled", "settle_ev_cms", "rms_ep_cm"])
        cols = s["cols"]
        for i in range(len(cols["unit"])):
            w.writerow([cols["unit"][i], cols["controller"][i], vo["verdict"][i], vo["scope"][i],
                        int(vo["wobbled"][i]), cols["settle_ev_cms"][i], cols["rms_ep_cm"][i]])  # fmt: skip
        files.append(write_text(folder / "verdict.csv", buf.getvalue()))
    files.append(
        write_html(
            folder, f"Sweep {s['sweep']['name']}",
            tables=[("Per point and controller", [*head[:2], *axes, "mean", "std", "failed %"], table_rows)],
            figures={"Figures": figs}, notes=notes, config=s["sweep"], seed=s["sweep"]["seed"],
        )
    )  # fmt: skip
    manifest = {
        "tool": "vtol-impedance sweep",
        "sweep_digest": json.loads((folder / SWEEP_FILE).read_text())["digest"],
        "files": {
            str(p.relative_to(folder)): {"sha256": sha256_of(p), "bytes": p.stat().st_size}
            for p in sorted(folder.rglob("*"))
            if p.is_file() and p.name != MANIFEST
        },
    }
    files.append(write_text(folder / MANIFEST, json.dumps(manifest, indent=1)))
    return files


# ----------------------------------------------------------------------------- verdict against outcome

#: A flight "wobbled" (``measures = true`` sweeps) when it failed, when ``settle_ev_cms`` (the velocity
#: error's wobble over the task window's last 4 s) is above this, or, in a scenario with a push, when
#: its largest error is above :data:`TRANSIENT_FACTOR` times the median of the cells sharing its
#: controller and the :data:`GROUP_BY` values present (a transient that grew before it decayed; a
#: trajectory's largest error grows with latency without any oscillation, so it has no such clause).
#: Measured on the three widened robustness studies (docs/guide/margins.md): the settled flights'
#: wobble is at most 0.74 cm/s, the oscillating ones' at least 1.11 cm/s; 0.9 is between (geometric mean).
WOBBLE_CMS = 0.9
TRANSIENT_FACTOR = 2.0
#: Axes whose values set a push's excursion without any oscillation (PD's payload sag).
GROUP_BY = ("payload.mass", "trajectory.kind", "trajectory.kind,trajectory.circle_speed")


def verdict_outcome(cols: dict[str, np.ndarray]) -> dict[str, Any]:
    """Per flight row of a ``measures = true`` sweep (the columns of :func:`summarise`): the check's verdict
    (``"unstable"``, ``"thin"``: stable with margins below the thresholds, ``"passes"``), whether the flight
    wobbled (see :data:`WOBBLE_CMS`), and the counts per controller: ``cells``; against the strict verdict
    (unstable or not) ``agree``, ``false_alarm`` (unstable, settled), ``miss`` (stable, wobbled); against
    the thresholds ``agree_t``, ``false_alarm_t`` (below, settled), ``miss_t`` (passes, wobbled); and the
    six cells of verdict x outcome (``passes/settled`` ...), plus ``scoped``: rows whose check leaves out a
    loop (``margin_scope``)."""
    if "settle_ev_cms" not in cols or "margin_stable" not in cols:
        raise InputError("the sweep has no outcome or margin columns: it needs measures = true and margins = true")
    ctrl = cols["controller"].astype(str)
    failed = cols["diverged"].astype(bool)
    settle = cols["settle_ev_cms"].astype(float)
    pushed = np.isfinite(cols["push_peak_cm"].astype(float))
    peak = np.where(pushed, cols["max_ep_cm"].astype(float), np.nan)
    big = np.zeros(len(ctrl), dtype=bool)
    keys = [ctrl] + [cols[k].astype(str) for k in GROUP_BY if k in cols]
    group = np.array(["|".join(parts) for parts in zip(*keys, strict=True)])
    for g in np.unique(group):
        sel = group == g
        alive = peak[sel][~failed[sel] & np.isfinite(peak[sel])]
        if alive.size:  # no push (nan): no transient clause
            big[sel] = peak[sel] > TRANSIENT_FACTOR * np.median(alive)
    wobbled = failed | ~(settle <= WOBBLE_CMS) | big
    stable = cols["margin_stable"].astype(float) > 0.5
    ok = cols["margin_ok"].astype(float) > 0.5
    verdict = np.where(~stable, "unstable", np.where(ok, "passes", "thin"))
    scope = cols["margin_scope"].astype(str) if "margin_scope" in cols else np.full(len(ctrl), "")
    counts: dict[str, dict[str, int]] = {}
    for c in dict.fromkeys(ctrl.tolist()):
        sel = ctrl == c
        w, st, k = wobbled[sel], stable[sel], ok[sel]
        row = {
            "cells": int(sel.sum()),
            "agree": int(np.sum(st & ~w) + np.sum(~st & w)), "false_alarm": int(np.sum(~st & ~w)),
            "miss": int(np.sum(st & w)),
            "agree_t": int(np.sum(k & ~w) + np.sum(~k & w)), "false_alarm_t": int(np.sum(~k & ~w)),
            "miss_t": int(np.sum(k & w)), "scoped": int(np.sum(scope[sel] != "")),
        }  # fmt: skip
        for v in ("passes", "thin", "unstable"):
            for o, mask in (("settled", ~w), ("wobbled", w)):
                row[f"{v}/{o}"] = int(np.sum((verdict[sel] == v) & mask))
        counts[c] = row
    return {"verdict": verdict, "wobbled": wobbled, "scope": scope, "counts": counts}


def plot_verdict_outcome(studies: dict[str, dict[str, np.ndarray]], path: Path) -> Path:
    """One panel: every flight of ``studies`` (name -> columns) at its worst phase margin (unstable: at the
    left edge) against its wobble (failed: at the top), coloured by study and controller; the threshold
    lines of the check and of the outcome."""
    from ..analysis.plots import _save, plt
    from ..robust import Thresholds

    fig, ax = plt.subplots(figsize=(8.0, 4.8))
    markers = {"pd": "s", "pdc": "o", "comply": "^"}
    colours = iter(plt.rcParams["axes.prop_cycle"].by_key()["color"])
    for name, cols in studies.items():
        colour = next(colours)
        ctrl = cols["controller"].astype(str)
        for c in dict.fromkeys(ctrl.tolist()):
            sel = ctrl == c
            stable = cols["margin_stable"][sel].astype(float) > 0.5
            x = np.where(stable, cols["pm_min_deg"][sel].astype(float), -4.0)
            y = cols["settle_ev_cms"][sel].astype(float)
            y = np.where(cols["diverged"][sel].astype(bool) | ~np.isfinite(y), 300.0, np.maximum(y, 0.02))
            ax.plot(x, y, markers.get(c, "o"), ms=5, color=colour, alpha=0.75, mfc="none" if c == "pd" else colour,
                    label=f"{name}: {LABELS.get(c, c)} ({int(sel.sum())})")  # fmt: skip
    ax.axvline(Thresholds().phase_deg, color="k", lw=0.8)
    ax.axvline(0.0, color="k", lw=0.5, ls=":")
    ax.axhline(WOBBLE_CMS, color="tab:red", lw=0.8, ls="--")
    ax.set_yscale("log")
    ax.set_xlabel("worst phase margin the check computed [deg] (unstable: drawn at -4)")
    ax.set_ylabel("wobble: RMS of e_v less its 1 s mean, last 4 s [cm/s] (failed: top)")
    ax.grid(alpha=0.3, which="both")
    ax.legend(fontsize=7, ncol=2)
    ax.set_title("Widened robustness study: the check's margin against the flight's wobble", fontsize=10)
    return _save(fig, path)
