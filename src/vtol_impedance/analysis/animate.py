"""An animated GIF of a run: every vehicle in 3D (drawn east-north-up so that up is up), its reference,
the estimated external force (solid arrow) and the true one the nominal model misses (thin), a wall and
a hanging pendulum where the scenario has them. Matplotlib with Pillow's GIF writer; written atomically."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from ..io import atomic_path
from ..model.kinematics import rotation_zyx
from ..sim.result import Result
from .plots import COLORS, NAMES, plt

ARROW_MAX_M = 0.6  # the longest force arrow of the run, m


def _enu(v: np.ndarray) -> np.ndarray:
    """NED -> the plotted east, north, up."""
    return np.stack([v[..., 1], v[..., 0], -v[..., 2]], -1)


def _arms(result: Result, b: int) -> np.ndarray:
    rotors = result.config.get("plants", [{}])[min(b, len(result.config.get("plants", [{}])) - 1)]
    pos = [r["position_B"] for r in rotors.get("vehicle", {}).get("rotors", [])]
    return np.asarray(pos, dtype=float) if pos else np.array([[0.2, 0, 0], [0, 0.2, 0], [-0.2, 0, 0], [0, -0.2, 0]])


def write_gif(result: Result, path: Path, fps: int = 8, max_frames: int = 160, title: str = "") -> Path:
    """Animate ``result`` into ``path`` (a ``.gif``) at ``fps`` frames per second of simulated time
    (fewer frames for long runs, at most ``max_frames``)."""
    from matplotlib.animation import FuncAnimation, PillowWriter
    from mpl_toolkits.mplot3d.art3d import Poly3DCollection

    t = result.t
    step = max(1, int(round((t[1] - t[0]) ** -1 / fps)) if len(t) > 1 else 1)
    frames = np.arange(0, len(t), step)
    if len(frames) > max_frames:
        frames = np.linspace(0, len(t) - 1, max_frames).astype(int)
    B = len(result.labels)
    p = _enu(result["p_W"])
    ref = _enu(result["p_ref_W"][0])
    lo = np.minimum(np.nanmin(p.reshape(-1, 3), 0), np.nanmin(ref, 0)) - 0.4
    hi = np.maximum(np.nanmax(p.reshape(-1, 3), 0), np.nanmax(ref, 0)) + 0.4
    fig = plt.figure(figsize=(8.0, 6.4), dpi=90)
    ax = fig.add_axes((0.0, 0.0, 0.74, 0.95), projection="3d")  # the legend gets the right-hand strip
    ax.set_xlim(lo[0], hi[0])
    ax.set_ylim(lo[1], hi[1])
    ax.set_zlim(min(lo[2], 0.0), hi[2])
    ax.set_xlabel("east [m]")
    ax.set_ylabel("north [m]")
    ax.set_zlabel("up [m]")
    for d in result.config.get("disturbances", []):
        if d.get("kind") == "wall":
            c = _enu(np.asarray(d["position_W"], dtype=float))
            n = _enu(np.asarray(d["normal_W"], dtype=float))
            u = np.cross(n, [0, 0, 1.0]) if abs(n[2]) < 0.9 else np.array([1.0, 0, 0])
            u /= np.linalg.norm(u)
            v = np.cross(n, u)
            s = 0.8
            corners = np.array([c + s * (a * u + b_ * v) for a, b_ in ((-1, -1), (1, -1), (1, 1), (-1, 1), (-1, -1))])
            ax.plot(corners[:, 0], corners[:, 1], corners[:, 2], color="saddlebrown", lw=2)
            ax.add_collection3d(Poly3DCollection([corners[:4]], color="burlywood", alpha=0.35))
    ax.plot(ref[:, 0], ref[:, 1], ref[:, 2], "--", color="gray", lw=0.8)
    arms = [_arms(result, b) for b in range(B)]  # body FRD
    art = []
    for b, lab in enumerate(result.labels):
        col = COLORS.get(lab, f"C{b}")
        body = [ax.plot([], [], [], color=col, lw=2.5)[0] for _ in range(len(arms[b]))]
        trail = ax.plot([], [], [], color=col, lw=0.8, alpha=0.6)[0]
        f_hat = ax.plot([], [], [], color=col, lw=2.2, label=f"{NAMES.get(lab, lab)}: estimate")[0]
        f_true = ax.plot([], [], [], color=col, lw=0.9, ls=":", label=f"{NAMES.get(lab, lab)}: true")[0]
        link = ax.plot([], [], [], "-o", color="dimgray", lw=1.0, ms=5, markevery=[1])[0]
        art.append((body, trail, f_hat, f_true, link))
    target = ax.plot([], [], [], "x", color="black", ms=7)[0]
    text = ax.text2D(0.02, 0.95, "", transform=ax.transAxes)
    fig.legend(loc="center right", fontsize=8, frameon=False)
    ax.set_title(title or result.config.get("scenario", {}).get("name", ""), fontsize=10)
    f_hat_all = _enu(result["f_hat_W"])
    f_true_all = _enu(result["f_lumped_W"])
    biggest = max(np.nanmax(np.linalg.norm(f_hat_all, axis=-1)), np.nanmax(np.linalg.norm(f_true_all, axis=-1)), 1e-3)
    scale = ARROW_MAX_M / biggest
    f_hat_all, f_true_all = f_hat_all * scale, f_true_all * scale
    eta = result["eta"]
    plants = result.config.get("plants", [])
    # the pendulum's link points along its pull on the vehicle (the external force, in the air)
    pend_L = [float(pl.get("pendulum_length", 0.0)) if pl.get("pendulum_mass", 0.0) > 0 else 0.0 for pl in plants]
    f_ext = _enu(result["f_ext_W"])

    def draw(k: int):
        for b in range(B):
            body, trail, fh, ft, link = art[b]
            c = p[b, k]
            if not np.all(np.isfinite(c)):
                continue
            L = pend_L[min(b, len(pend_L) - 1)] if pend_L else 0.0
            if L > 0:
                d = f_ext[b, k] / max(np.linalg.norm(f_ext[b, k]), 1e-9)
                link.set_data_3d([c[0], c[0] + L * d[0]], [c[1], c[1] + L * d[1]], [c[2], c[2] + L * d[2]])
            R = rotation_zyx(eta[b, k])
            for line, arm in zip(body, arms[b], strict=True):
                tip = c + _enu(R @ arm)
                line.set_data_3d([c[0], tip[0]], [c[1], tip[1]], [c[2], tip[2]])
            k0 = max(0, k - 300)
            trail.set_data_3d(p[b, k0 : k + 1, 0], p[b, k0 : k + 1, 1], p[b, k0 : k + 1, 2])
            for line, f in ((fh, f_hat_all[b, k]), (ft, f_true_all[b, k])):
                line.set_data_3d([c[0], c[0] + f[0]], [c[1], c[1] + f[1]], [c[2], c[2] + f[2]])
        target.set_data_3d([ref[k, 0]], [ref[k, 1]], [ref[k, 2]])
        text.set_text(f"t = {t[k]:5.1f} s   arrows: {scale:.2g} m per N")
        return []

    anim = FuncAnimation(fig, draw, frames=frames, blit=False)
    try:
        with atomic_path(path) as tmp:
            gif = tmp.with_suffix(".gif")  # Pillow picks the format by the extension
            try:
                anim.save(gif, writer=PillowWriter(fps=fps))
                os.replace(gif, tmp)
            finally:
                gif.unlink(missing_ok=True)
    finally:
        plt.close(fig)
    return path
