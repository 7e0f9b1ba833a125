"""Simulation results: named arrays, labels, failures and the exact configuration that produced them."""

from __future__ import annotations

import json
import zipfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import InputError, as_finite, instance, path_like
from ..io import write_with
from ..records import SIGNALS, rows_to_data, signal_shape

__all__ = [
    "SIGNALS",
    "STEADY_TAIL_S",
    "Result",
    "compute_metrics",
    "metrics_row",
    "rows_to_data",
    "signal_shape",
    "window_mask",
    "window_mask_of",
]

SCHEMA_VERSION = 1

#: Length of the tail of the task window over which the steady-state error is averaged, s.
STEADY_TAIL_S = 5.0


def window_mask_of(t: np.ndarray, window: tuple[float, float] | None) -> np.ndarray:
    """Samples of ``t`` inside ``window`` (default: all); a window holding fewer than two samples, as in a
    run cut shorter than the window's start, falls back to the whole run."""
    if window is None:
        return np.ones_like(t, dtype=bool)
    m = (t >= window[0]) & (t <= window[1])
    return m if np.count_nonzero(m) > 1 else np.ones_like(t, dtype=bool)


def metrics_row(
    controller: str,
    rms_ep: float,
    max_ep: float,
    ss_ep: float,
    rms_ev: float,
    rms_f: float,
    rms_tau: float,
    sat: float,
    failure: dict[str, Any] | None,
) -> dict[str, Any]:
    """One table row from SI values (m, m/s, N, N m, fraction); the row holds the displayed units."""
    return {
        "controller": controller,
        "rms_ep_cm": 100 * float(rms_ep),
        "max_ep_cm": 100 * float(max_ep),
        "ss_ep_cm": 100 * float(ss_ep),
        "rms_ev_cms": 100 * float(rms_ev),
        "rms_f_err_N": float(rms_f),
        "rms_tau_err_mNm": 1000 * float(rms_tau),
        "sat_pct": 100 * float(sat),
        "failure": None if failure is None else f"{failure['reason']} at {failure['time']:.2f} s",
    }


@dataclass
class Result:
    """Time series of ``B`` simulated vehicles: ``data[name]`` is ``(B, N, *shape)``, ``t`` is ``(N,)``.

    ``labels`` name each vehicle (for example the controller variant); ``failures[b]`` is ``None`` or a
    dict with the ``time`` and ``reason`` at which vehicle ``b`` was stopped; ``config`` is the exact
    configuration (scenario, controllers, plant, sensors, seed) that produced the run. A run logged with
    ``log="metrics"`` has no traces (``data`` is empty) and carries ``metrics`` instead; one logged with
    ``log="decimate:K"`` carries both (the metrics taken at every control tick).
    """

    t: np.ndarray
    labels: list[str]
    data: dict[str, np.ndarray]
    config: dict[str, Any] = field(default_factory=dict)
    failures: list[dict[str, Any] | None] = field(default_factory=list)
    metrics: list[dict[str, Any]] | None = None

    def __post_init__(self) -> None:
        self.t = as_finite("t", self.t)
        if self.t.ndim != 1:
            raise InputError(f"t must be one time per sample, shape (N,), got {self.t.shape}")
        if not isinstance(self.labels, list | tuple) or not all(isinstance(x, str) for x in self.labels):
            raise InputError(f"labels must be a list of names, got {self.labels!r:.80}")
        instance("data", self.data, dict)
        instance("config", self.config, dict)

    def __getitem__(self, name: str) -> np.ndarray:
        return self.data[name]

    def index(self, label: str) -> int:
        if label not in self.labels:
            raise InputError(f"no vehicle labelled {label!r}; labels: {self.labels}")
        return self.labels.index(label)

    @property
    def e_p(self) -> np.ndarray:
        """Position error ``p - p_d`` of the true body origin, ``(B, N, 3)``."""
        return self.data["p_W"] - self.data["p_ref_W"]

    @property
    def e_v(self) -> np.ndarray:
        return self.data["v_W"] - self.data["v_ref_W"]

    def save(self, path: str | Path) -> Path:
        """Write an ``.npz`` (arrays plus a JSON header), atomically."""
        header = {
            "schema": SCHEMA_VERSION,
            "labels": self.labels,
            "config": self.config,
            "failures": self.failures,
            "metrics": self.metrics,
            "signals": {k: {"unit": SIGNALS[k][1], "meaning": SIGNALS[k][2]} for k in self.data if k in SIGNALS},
        }
        arrays = {f"data__{k}": v for k, v in self.data.items()}
        text = json.dumps(header, default=_plain)  # before the file is opened: a value JSON cannot hold writes nothing
        target = path_like("path", path)
        if target.is_dir():
            raise InputError(f"{target} is a folder; give the result file's path (for example {target / 'result.npz'})")

        def writer(fh) -> None:
            np.savez_compressed(fh, t=self.t, header=np.array(text), **arrays)

        return write_with(target, writer)

    @classmethod
    def load(cls, path: str | Path) -> Result:
        """Read a file written by :meth:`save`; a corrupt or foreign file raises :class:`InputError`."""
        path = path_like("path", path)
        try:
            z = np.load(path, allow_pickle=False)
            if not isinstance(z, np.lib.npyio.NpzFile):  # a .npy array: not a result
                raise ValueError("a single array, not a result archive")
            with z:
                header = json.loads(str(z["header"]))
                t = z["t"]
                data = {k[6:]: z[k] for k in z.files if k.startswith("data__")}
        except (OSError, ValueError, KeyError, zipfile.BadZipFile, json.JSONDecodeError, EOFError) as exc:
            raise InputError(f"{path} is not a readable vtol-impedance result file: {exc}") from exc
        if not isinstance(header, dict):
            raise InputError(f"{path} is not a vtol-impedance result file: its header is not a table")
        if header.get("schema") != SCHEMA_VERSION:
            raise InputError(f"{path} has result schema {header.get('schema')}, expected {SCHEMA_VERSION}")
        labels, config, failures, metrics = (header.get(k) for k in ("labels", "config", "failures", "metrics"))
        if not (isinstance(labels, list) and isinstance(config, dict) and isinstance(failures, list)):
            raise InputError(f"{path}: the header's labels, config or failures are missing or of the wrong kind")
        for f in failures:
            if f is not None and not (isinstance(f, dict) and {"time", "reason"} <= set(f)):
                raise InputError(f"{path}: a failure must be null or have a time and a reason, got {f!r:.80}")
        if metrics is not None and not (isinstance(metrics, list) and all(isinstance(m, dict) for m in metrics)):
            raise InputError(f"{path}: the metrics must be a list of tables, got {metrics!r:.80}")
        if (failures and len(failures) != len(labels)) or (metrics is not None and len(metrics) != len(labels)):
            raise InputError(f"{path}: the header's failures or metrics do not have one entry per vehicle label")
        B = len(labels)
        for k, v in data.items():
            if v.shape[:2] != (B, len(t)):
                raise InputError(f"{path}: signal {k} has shape {v.shape}, expected ({B}, {len(t)}, ...)")
        return cls(t, labels, data, config, failures, metrics)


def _plain(value: Any) -> Any:
    """A NumPy scalar or array in a result's header as plain JSON; anything else is refused by name."""
    if isinstance(value, np.generic | np.ndarray):
        return value.tolist()
    raise InputError(f"the result's header holds a {type(value).__name__} ({value!r:.60}), which a file cannot keep")


def _check(result: Result, window: Any) -> None:
    """A window given by the caller must be ``(t0, t1)`` with ``t0 <= t1`` and hold two samples of the run
    (the fallback to the whole run is for the stored window of a run cut short, not for a caller's)."""
    instance("result", result, Result)
    if window is None:
        return
    if not result.data:
        raise InputError(
            f"window {window!r}: this result has no traces (log=\"metrics\"), only the metrics of its own window "
            f"{result.config.get('window')}; fly it with log=\"full\" or \"decimate:K\" to measure another"
        )
    w = None if isinstance(window, str) else as_finite("window", window)
    if w is None or w.shape != (2,):
        raise InputError(f"window must be (t0, t1) in seconds, got {window!r}")
    if w[1] < w[0]:
        raise InputError(f"window must be (t0, t1) with t0 <= t1, got {window!r}")
    if np.count_nonzero((result.t >= w[0]) & (result.t <= w[1])) < 2 and len(result.t) > 1:
        raise InputError(
            f"window {window!r} holds fewer than two samples of the run ({result.t[0]:g} to {result.t[-1]:g} s)"
        )


def window_mask(result: Result, window: tuple[float, float] | None = None) -> np.ndarray:
    """Samples inside the task window (default: the one stored in the result's config).

    A run cut shorter than the window's start (``--duration``) falls back to the whole run.
    """
    _check(result, window)
    return window_mask_of(result.t, window if window is not None else result.config.get("window"))


def _rms(a: np.ndarray) -> float:
    a = a[np.isfinite(a)]
    return float(np.sqrt(np.mean(a * a))) if a.size else float("nan")


_METRIC_SIGNALS = ("p_W", "p_ref_W", "v_W", "v_ref_W", "f_hat_W", "f_lumped_W", "tau_hat_eta", "tau_lumped_eta",
                   "saturated")  # fmt: skip


def compute_metrics(result: Result, window: tuple[float, float] | None = None) -> list[dict[str, Any]]:
    """One row per vehicle: position/velocity error statistics, estimation error, saturation.

    ``ss_ep_cm`` is the mean ``|e_p|`` over the last :data:`STEADY_TAIL_S` seconds of the window;
    the estimation error compares the estimate with the lumped wrench the nominal model misses
    (``f_lumped_W``, ``tau_lumped_eta``). A run logged with ``log="metrics"`` or ``"decimate:K"`` already
    carries them, taken at every control tick over its own window: those are returned (without ``window``),
    not a recount on every K-th sample, which gives other numbers. Another ``window`` on a decimated run is
    measured on the samples it kept.
    """
    _check(result, window)
    if result.metrics is not None and window is None:
        return [dict(m) for m in result.metrics]
    if not result.data:
        if result.metrics is None:
            raise InputError("the result has neither traces nor metrics")
        return [dict(m) for m in result.metrics]
    missing = [k for k in _METRIC_SIGNALS if k not in result.data]
    if missing:
        raise InputError(f"the result's traces lack {', '.join(missing)}: the metrics need them")
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
