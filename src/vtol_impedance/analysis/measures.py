"""The measures a scenario is *for*, computed from a result: what its table leads with.

The paper's cases are about position error (:mod:`.metrics`); the interaction scenarios are about other
things, found from the scenario's own content so that a user's scenario file gets them too:

* a **wall**: the contact force held (mean over the last 4 s of the task window, N), what the comply
  impedance commands there ``K_d (x_d - x_contact)``, the error, the estimate of it, whether contact was
  lost after it was made;
* a **push** (a force): the largest displacement along it while it acts and 2 s after (cm), the
  position 2 s after it ends (the return, cm) and, for ``comply``, the impedance ``M, D, K`` identified
  from the response by least squares on the true force the nominal model misses;
* a **twist** (a push with a moment only): the same about yaw (rad) and the identified ``M_o, D_o, K_o``;
* a **pendulum**: PD's sag against ``(payload + bob) g / Kp``, and the estimate against the link's pull
  (max and RMS along x, N).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from ..conventions import G
from ..sim.result import Result
from .metrics import window_mask


def _dist(result: Result, kind: str) -> list[dict[str, Any]]:
    """The flown disturbances of ``kind``, every field present (the defaults a scenario file may leave out
    filled in: ``config["disturbances"]``); an older result without them: the scenario's own tables."""
    flown = result.config.get("disturbances")
    if flown is None:
        flown = result.config.get("scenario", {}).get("disturbances", [])
    return [d for d in flown if d.get("kind") == kind]


def _fit(t: np.ndarray, e: np.ndarray, ed: np.ndarray, f: np.ndarray, sel: np.ndarray) -> np.ndarray:
    """Least squares ``f = M e'' + D e' + K e`` over ``sel``."""
    A = np.stack([np.gradient(ed, t), ed, e], -1)[sel]
    return np.linalg.lstsq(A, f[sel], rcond=None)[0]


def wall_numbers(result: Result) -> list[dict[str, Any]] | None:
    """Per vehicle, the wall contact numbers of :func:`wall_measures`: ``held_N``, ``commanded_N`` and
    ``error_pct`` (``nan`` but for comply), ``estimate_N``, ``lost`` (bool); ``None`` without a wall."""
    walls = _dist(result, "wall")
    if not walls:
        return None
    w = walls[0]
    spec = result.config["scenario"]
    n = -np.asarray(w["normal_W"], dtype=float)  # into the wall
    n /= np.linalg.norm(n)
    contact = float(np.dot(w["position_W"], n)) - float(w["radius"])
    target = float(np.dot(spec["trajectory"]["move_offset"], n))
    K = np.broadcast_to(np.asarray(spec["interaction"]["K"], dtype=float), (3,))
    K_n = float(np.abs(n) @ K)
    m = window_mask(result)
    t = result.t
    last = m & (t > t[m][-1] - 4.0)
    out = []
    for b, lab in enumerate(result.labels):
        held = float(-(result["f_ext_W"][b, last] @ n).mean())
        est = float(-(result["f_hat_W"][b, last] @ n).mean())
        x = result["p_W"][b] @ n
        touching = x >= contact
        lost = bool(touching.any() and not np.all(touching[t > t[np.argmax(touching)] + 3.0]))
        commanded = K_n * (target - contact) if lab == "comply" else float("nan")
        err = 100.0 * (held - commanded) / commanded if lab == "comply" else float("nan")
        out.append({"held_N": held, "commanded_N": commanded, "error_pct": err, "estimate_N": est, "lost": lost})
    return out


def wall_measures(result: Result) -> tuple[list[str], list[list[str]]] | None:
    got = wall_numbers(result)
    if got is None:
        return None
    head = ["controller", "contact force held [N]", "commanded [N]", "error [%]", "estimate [N]", "contact lost"]
    rows = [
        [lab, f"{r['held_N']:.3f}", _f(r["commanded_N"], 3), _f(r["error_pct"], 1), f"{r['estimate_N']:.3f}",
         "yes" if r["lost"] else "no"]
        for lab, r in zip(result.labels, got, strict=True)
    ]  # fmt: skip
    return head, rows


def push_numbers(result: Result, fit: bool = True) -> list[dict[str, Any]] | None:
    """Per vehicle, the push numbers of :func:`push_measures`: ``peak_cm`` (the largest displacement along
    the push while it acts and 2 s after), ``left_cm`` (2 s after it), ``fit`` (comply's identified
    ``M, D, K`` when ``fit``, else ``nan``); ``None`` without a push (or without traces before and during
    it)."""
    pushes = [d for d in _dist(result, "push") if np.any(np.asarray(d.get("force_W", (0, 0, 0))) != 0)]
    if not pushes:
        return None
    p = pushes[0]
    d = np.asarray(p["force_W"], dtype=float)
    d /= np.linalg.norm(d)
    t0, t1 = float(p["t_on"]), float(p["t_on"]) + float(p["duration"])
    t = result.t
    during = (t >= t0) & (t <= t1 + 2.0)
    after = (t >= t1 + 2.0) & (t <= t1 + 2.5)
    before = (t > t0 - 2.0) & (t < t0)
    if not during.any() or not before.any():
        return None
    out = []
    for b, lab in enumerate(result.labels):
        x = result["p_W"][b] @ d
        base = x[before].mean()
        peak = 100.0 * float(np.abs(x[during] - base).max())
        left = 100.0 * float(np.abs(x[after] - base).mean()) if after.any() else float("nan")
        mdk = [float("nan")] * 3
        if lab == "comply" and fit and np.all(np.isfinite(x)):  # a failed flight's traces end in nan
            e = x - result["p_ref_W"][b] @ d
            ed = result["v_W"][b] @ d - result["v_ref_W"][b] @ d
            sel = (t > t0 - 0.5) & (t < t[-1] - 0.5)
            mdk = _fit(t, e, ed, result["f_lumped_W"][b] @ d, sel).tolist()
        out.append({"peak_cm": peak, "left_cm": left, "fit": mdk})
    return out


def push_measures(result: Result) -> tuple[list[str], list[list[str]]] | None:
    got = push_numbers(result)
    if got is None:
        return None
    head = ["controller", "yield along the push [cm]", "left 2 s after it [cm]", "M [kg]", "D [N s/m]", "K [N/m]"]
    rows = [
        [lab, f"{r['peak_cm']:.2f}", _f(r["left_cm"], 2), _f(r["fit"][0], 3), _f(r["fit"][1], 2), _f(r["fit"][2], 2)]
        for lab, r in zip(result.labels, got, strict=True)
    ]
    return head, rows


def twist_measures(result: Result) -> tuple[list[str], list[list[str]]] | None:
    twists = [d for d in _dist(result, "push") if not np.any(np.asarray(d.get("force_W", (0, 0, 0))) != 0)
              and np.any(np.asarray(d.get("torque_B", (0, 0, 0))) != 0)]  # fmt: skip
    if not twists:
        return None
    t0 = float(twists[0]["t_on"])
    t = result.t
    if not np.any(t >= t0):  # the twist falls after the flight (a shortened run): nothing to measure
        return None
    head = ["controller", "yaw yield [rad]", "yaw left at the end [rad]", "M_o [kg m^2]", "D_o [N m s/rad]",
            "K_o [N m/rad]"]  # fmt: skip
    rows = []
    for b, lab in enumerate(result.labels):
        e = result["eta"][b, :, 2] - result["psi_ref"][b]
        peak = float(np.abs(e[(t >= t0)]).max())
        left = float(np.abs(e[t > t[-1] - 1.0]).max())
        fit = [float("nan")] * 3
        if lab == "comply":
            sel = (t > t0 - 0.5) & (t < t[-1] - 0.5)
            fit = _fit(t, e, result["omega_B"][b, :, 2], result["tau_lumped_eta"][b, :, 2], sel).tolist()
        rows.append([lab, f"{peak:.3f}", f"{left:.3f}", _f(fit[0], 4), _f(fit[1], 3), _f(fit[2], 3)])
    return head, rows


def pendulum_measures(result: Result) -> tuple[list[str], list[list[str]]] | None:
    spec = result.config.get("scenario", {})
    bob = float(spec.get("plant", {}).get("pendulum_mass", 0.0))
    if bob <= 0:
        return None
    m = window_mask(result)
    payload = float(spec.get("payload", {}).get("mass", 0.0))
    Kp = float(np.mean(np.broadcast_to(np.asarray(spec.get("control", {}).get("Kp", 16.0), dtype=float), (3,))[2]))
    head = ["controller", "vertical error [cm]", "(payload + bob) g / Kp [cm]", "RMS |e_p| [cm]",
            "estimate - link force, max / RMS (x) [N]"]  # fmt: skip
    rows = []
    for b, lab in enumerate(result.labels):
        sag = 100.0 * float((result["p_W"][b, m, 2] - result["p_ref_W"][b, m, 2]).mean())
        rms = 100.0 * float(np.sqrt(np.mean(np.sum(result.e_p[b, m] ** 2, -1))))
        d = np.abs(result["f_hat_W"][b, m, 0] - result["f_ext_W"][b, m, 0])
        rows.append([lab, f"{sag:.2f}", f"{100 * (payload + bob) * G / Kp:.2f}", f"{rms:.2f}",
                     f"{d.max():.3f} / {np.sqrt(np.mean(d * d)):.3f}"])  # fmt: skip
    return head, rows


MEASURES = (
    ("Wall contact", wall_measures),
    ("Push", push_measures),
    ("Twist about yaw", twist_measures),
    ("Pendulum", pendulum_measures),
)


def purpose_tables(result: Result, name: str = "") -> list[tuple[str, list[str], list[list[str]]]]:
    """``(title, head, rows)`` of each measure that applies to the scenario (none for the paper's cases)."""
    from ..control.impedance import DISPLAY_NAMES

    out = []
    for title, fn in MEASURES:
        got = fn(result)
        if got is not None:
            head, rows = got
            rows = [[DISPLAY_NAMES.get(r[0], r[0]), *r[1:]] for r in rows]
            out.append((f"{name}: {title.lower()}" if name else title, head, rows))
    return out


def _f(v: float, digits: int) -> str:
    return "—" if v is None or not np.isfinite(v) else f"{v:.{digits}f}"
