"""Running a sweep: chunks of units on the compiled batch engine, in this process or on Dask.

Layout of a sweep folder (``results/sweep-<name>`` or ``--out``)::

    sweep.json                 the resolved sweep (every point and seed) and its SHA-256: what resuming checks
    chunks/chunk-000000.parquet   one file per chunk, one row per flight, written atomically
    traces/chunk-000000.parquet   decimated traces, when the sweep keeps them
    summary files              written by the report once every chunk is there, with manifest.json

A chunk is written once, complete (temporary name, then rename), and never appended to. Running the same
command again after an interruption (Ctrl-C, a killed worker, a killed process) computes only the
chunks whose files are missing; since every unit's seed depends only on the sweep seed and its indices,
the dataset is the same as an uninterrupted run's. A folder holding another sweep is refused.

On Dask (``workers=N`` starts a loopback ``LocalCluster``, ``scheduler=ADDRESS`` joins an existing one;
see :mod:`.cluster`) each task carries the resolved sweep, so a worker reads no file; the client writes
the chunk files as results arrive, so workers need no shared disk. ``sweep.json`` also keeps the run
record (``runs``: where each run ran, the chunks it computed, the workers it lost, how it ended).
"""

from __future__ import annotations

import json
import os
import sys
import warnings
from collections.abc import Callable, Iterable
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import InputError
from ..estimator.momentum import EstimatorBandwidthWarning
from ..io import FolderLock, write_text, write_with
from .budget import Progress
from .cluster import ChunkError, ClusterError, Executor
from .spec import Sweep, Unit, changes

METRICS = ("rms_ep_cm", "max_ep_cm", "ss_ep_cm", "rms_ev_cms", "rms_f_err_N", "rms_tau_err_mNm", "sat_pct")
#: Stability-margin columns of every flight row (``margins = true``, the default): the point's controller
#: linearised at the scenario's operating point (:mod:`vtol_impedance.scenarios.margins`).
MARGINS = ("margin_stable", "pm_min_deg", "gm_min_db", "dm_min_ms", "ms_max", "growth_rate", "damping_min", "margin_ok")


#: Outcome columns of a sweep with ``measures = true`` (flights logged every :data:`MEASURE_DECIMATE`-th
#: control tick): ``settle_ev_cms`` the RMS over the last :data:`SETTLE_S` of the task window of the
#: velocity error less its centred mean over :data:`WOBBLE_S` (the wobble: a settled loop has none; a
#: steady offset, a trajectory's smooth lag or a slow yield to a push are removed), ``push_peak_cm`` the largest
#: displacement along a push while it acts and 2 s after, ``wall_force_N`` the contact force held over the
#: window's last 4 s and ``wall_force_err_pct`` its error against comply's command (``nan`` where the
#: scenario has no push or wall, or the controller commands no force).
OUTCOMES = ("settle_ev_cms", "push_peak_cm", "wall_force_N", "wall_force_err_pct")
#: With margins and ``measures`` (or ``margins_at`` other than "window"): where the margins were taken
#: (``margin_at_s``) and what the linear model leaves out at this point (``margin_scope``, "" when nothing).
SCOPE = ("margin_at_s", "margin_scope")
MEASURE_DECIMATE = 2
SETTLE_S = 4.0
WOBBLE_S = 1.0


def outcome_columns(result: Any) -> list[dict[str, float]]:
    """The flight outcome columns of :data:`OUTCOMES` per vehicle of a traced ``result``."""
    from ..analysis.measures import push_numbers, wall_numbers
    from ..analysis.metrics import window_mask

    t = result.t
    dt = float(np.median(np.diff(t)))
    k = max(1, int(round(WOBBLE_S / dt)))
    m = window_mask(result)
    # the tail, where a centred mean over WOBBLE_S fits inside the trace
    tail = m & (t >= t[m][-1] - SETTLE_S) & (t <= t[-1] - 0.5 * WOBBLE_S - dt)
    pushes, walls = push_numbers(result, fit=False), wall_numbers(result)
    nan = float("nan")
    out = []
    for b in range(len(result.labels)):
        ev = result.e_v[b]
        slow = np.stack([np.convolve(ev[:, i], np.ones(k) / k, mode="same") for i in range(3)], -1)
        w = np.linalg.norm((ev - slow)[tail], axis=-1)
        out.append({
            "settle_ev_cms": 100.0 * float(np.sqrt(np.mean(w * w))) if w.size and np.all(np.isfinite(w)) else nan,
            "push_peak_cm": pushes[b]["peak_cm"] if pushes else nan,
            "wall_force_N": walls[b]["held_N"] if walls else nan,
            "wall_force_err_pct": walls[b]["error_pct"] if walls else nan,
        })  # fmt: skip
    return out


def margin_scope(spec: Any, controller: str, comply: Any) -> str:
    """What the margin check of ``controller`` at this point does not cover ("" when nothing): a wall's
    contact (the linearisation is of free flight), comply with its fractions all zero at the operating
    point (then it is checked as reject)."""
    out = []
    if any(d.get("kind") == "wall" for d in spec.disturbances):
        out.append("wall contact not in the linear model (free flight checked)")
    if controller == "comply" and not np.any(np.asarray(comply) > 0):
        out.append("comply off at the operating point (checked as reject)")
    return "; ".join(out)


def point_margins(spec: Any, controllers: list[str], at: str | None = None) -> dict[str, dict[str, Any]]:
    """The margin columns of one sweep point, per controller (``nan`` where it cannot hover); with ``at``
    (``"engaged"``, see :func:`~vtol_impedance.scenarios.margins.scenario_margins`) also ``margin_at_s``
    and ``margin_scope``."""
    from ..robust import TrimError
    from ..scenarios.margins import engaged_time, operating_point_of, scenario_margins
    from ..scenarios.spec import checked

    extra: dict[str, dict[str, Any]] = {c: {} for c in controllers}
    t_op = None
    if at is not None:
        built = checked(spec, list(controllers))[0]
        t_op = engaged_time(built) if at == "engaged" else built.window[0]
        comply = operating_point_of(built, t_op)["comply"]
        extra = {c: {"margin_at_s": float(t_op), "margin_scope": margin_scope(spec, c, comply)} for c in controllers}
    try:
        reports = scenario_margins(spec, controllers, at=t_op)
    except TrimError:
        nan = float("nan")
        return {c: {k: nan for k in MARGINS} | {"margin_stable": 0.0, "margin_ok": 0.0} | extra[c] for c in controllers}
    out = {}
    for c, r in reports.items():
        s = r.summary()
        out[c] = {
            "margin_stable": s["stable"], "pm_min_deg": s["pm_min_deg"], "gm_min_db": s["gm_min_db"],
            "dm_min_ms": s["dm_min_ms"], "ms_max": s["ms_max"], "growth_rate": s["growth_rate"],
            "damping_min": s["damping_min"], "margin_ok": float(not r.violations()),
        } | extra[c]  # fmt: skip
    return out


SWEEP_FILE = "sweep.json"


def run_units(
    sweep: Sweep, units: Iterable[Unit], backend: str = "compiled", on_unit: Callable[[int], None] | None = None
) -> tuple[dict, dict | None]:
    """Fly ``units`` and return the flight rows and (when kept) the decimated traces, as column dicts;
    ``on_unit(flights)`` is called after each unit (progress)."""
    from ..errors import choice, instance

    instance("sweep", sweep, Sweep)
    if isinstance(units, str) or not hasattr(units, "__iter__"):
        raise InputError(f"units must be a sequence of Unit, got {units!r:.80}")
    units = list(units)
    if not all(isinstance(u, Unit) for u in units):
        raise InputError(f"units must be a sequence of Unit, got {units!r:.80}")
    choice("backend", backend, ("compiled", "numpy"))
    from ..analysis.metrics import compute_metrics
    from ..scenarios import simulate

    rows: dict[str, list] = {k: [] for k in ("unit", "point", "repeat", "seed", "controller")}
    rows.update({a.key: [] for a in sweep.axes})
    rows.update({m: [] for m in METRICS})
    rows.update(diverged=[], failure_reason=[], failure_time_s=[])
    if sweep.margins:
        rows.update({m: [] for m in MARGINS})
    scoped = sweep.margins and (sweep.measures or sweep.margins_at != "window")
    if scoped:
        rows.update({m: [] for m in SCOPE})
    if sweep.measures:
        rows.update({m: [] for m in OUTCOMES})
    margins_of: dict[int, dict[str, dict[str, float]]] = {}
    traces: dict[str, list] | None = None
    if sweep.traces:
        traces = {k: [] for k in ("unit", "controller", "t_s", "ep_norm_m", "fx_hat_N", "fy_hat_N", "fz_hat_N",
                                  "fx_true_N", "fy_true_N", "fz_true_N")}  # fmt: skip
    for u in units:
        spec = sweep.point_spec(u.point)
        log = f"decimate:{sweep.traces}" if sweep.traces else "metrics"
        if sweep.measures and not sweep.traces:
            log = f"decimate:{MEASURE_DECIMATE}"
        with warnings.catch_warnings():  # a study may mean to go near the sampling rate; the spec counts them
            warnings.simplefilter("ignore", EstimatorBandwidthWarning)
            r = simulate(spec, sweep.controllers, seed=u.seed, backend=backend, log=log)
        if sweep.margins and u.point not in margins_of:  # once per point: the seed does not change them
            margins_of[u.point] = point_margins(spec, sweep.controllers, sweep.margins_at if scoped else None)
        outcomes = outcome_columns(r) if sweep.measures else None
        for b, row in enumerate(compute_metrics(r)):
            if sweep.margins:
                for k, v in margins_of[u.point][sweep.controllers[b]].items():
                    rows[k].append(v)
            if outcomes is not None:
                for k, v in outcomes[b].items():
                    rows[k].append(v)
            rows["unit"].append(u.index)
            rows["point"].append(u.point)
            rows["repeat"].append(u.repeat)
            rows["seed"].append(u.seed)
            rows["controller"].append(sweep.controllers[b])
            for a in sweep.axes:
                rows[a.key].append(sweep.points[u.point][a.key])
            for m in METRICS:
                rows[m].append(float(row[m]))
            fail = r.failures[b] if b < len(r.failures) else None
            rows["diverged"].append(fail is not None)
            rows["failure_reason"].append("" if fail is None else str(fail["reason"]))
            rows["failure_time_s"].append(float("nan") if fail is None else float(fail["time"]))
            if traces is not None:
                n = len(r.t)
                traces["unit"] += [u.index] * n
                traces["controller"] += [sweep.controllers[b]] * n
                traces["t_s"] += r.t.tolist()
                traces["ep_norm_m"] += np.linalg.norm(r.e_p[b], axis=-1).tolist()
                for i, a in enumerate("xyz"):
                    traces[f"f{a}_hat_N"] += r["f_hat_W"][b, :, i].tolist()
                    traces[f"f{a}_true_N"] += r["f_lumped_W"][b, :, i].tolist()
        if on_unit is not None:
            on_unit(len(sweep.controllers))
    return rows, traces


def _table(cols: dict[str, list], meta: dict[str, str] | None = None):
    import pyarrow as pa

    out = {}
    for k, v in cols.items():
        if v and isinstance(v[0], list | tuple):  # vector-valued axes: one string column
            out[k] = pa.array([json.dumps(x) for x in v])
        else:
            out[k] = pa.array(v)
    return pa.table(out, metadata=meta)


#: Key of the schema metadata that binds a chunk file to its sweep and index.
CHUNK_META = b"vtol_impedance_chunk"


def chunk_name(k: int) -> str:
    return f"chunk-{k:06d}.parquet"


class SweepFolder:
    """The folder of one sweep: its description, lock and the chunk files (see the module docstring)."""

    def __init__(self, sweep: Sweep, folder: Path, restart: bool = False, where: Path | None = None) -> None:
        from ..errors import instance, path_like
        from ..io import check_output_folder

        self.sweep = instance("sweep", sweep, Sweep)
        self.folder = path_like("folder", folder).absolute()
        if self.folder.exists() and not self.folder.is_dir():
            raise InputError(f"output {self.folder} is a file, not a folder")
        if self.folder.exists() and any(self.folder.iterdir()) and not (self.folder / SWEEP_FILE).exists():
            raise InputError(f"output folder {self.folder} holds files that no sweep wrote; choose another --out")
        if not (self.folder / SWEEP_FILE).exists():
            check_output_folder(self.folder, swapped=False)  # chunks are written into it, it is never swapped
        self.lock = FolderLock(self.folder)
        self.chunks = self.folder / "chunks"
        self.traces = self.folder / "traces"
        desc = {"digest": sweep.digest(), "sweep": sweep.to_dict(), "source": sweep.source,
                "where": str(where) if where else None, "versions": _versions()}  # fmt: skip
        existing = self.folder / SWEEP_FILE
        if existing.exists():
            try:
                old = json.loads(existing.read_text(encoding="utf-8"))
            except (OSError, ValueError) as exc:
                self.lock.close()
                raise InputError(
                    f"{existing} is not readable ({exc}); remove the folder or choose another --out"
                ) from None
            if old.get("digest") != desc["digest"]:
                if not restart:
                    self.lock.close()
                    diff = changes(old.get("sweep"), desc["sweep"])
                    what = f": {'; '.join(diff)} (in sweep.json -> now)" if diff else " (its description differs)"
                    raise InputError(
                        f"{self.folder} holds another sweep{what}; its chunks were flown with the values in "
                        "sweep.json, so they are not resumed: use --restart to discard them or choose another --out"
                    )
                import shutil

                for sub in (self.chunks, self.traces):
                    shutil.rmtree(sub, ignore_errors=True)
                for f in self.folder.iterdir():
                    if f.is_file():
                        f.unlink()
            elif isinstance(old.get("runs"), list):
                desc["runs"] = old["runs"]  # the run record goes on
        self.folder.mkdir(parents=True, exist_ok=True)
        self.chunks.mkdir(exist_ok=True)
        if sweep.traces:
            self.traces.mkdir(exist_ok=True)
        desc.setdefault("runs", [])
        write_text(existing, json.dumps(desc, indent=1, default=str))
        self.description = desc

    def record_run(self, run: dict[str, Any]) -> None:
        """Append ``run`` (where it ran, chunks computed, workers lost, how it ended) to the run record in
        ``sweep.json`` (rewritten atomically)."""
        self.description["runs"].append(run)
        write_text(self.folder / SWEEP_FILE, json.dumps(self.description, indent=1, default=str))

    def done(self) -> int:
        """How many chunks are on disk, complete (without checking their content)."""
        names = {chunk_name(k) for k in range(self.sweep.n_chunks)}
        return sum(1 for p in self.chunks.glob("chunk-*.parquet") if p.name in names)

    def missing(self) -> list[int]:
        """Chunks still to compute. A chunk file counts as done only if its content says it is this sweep's
        chunk ``k`` with every row (schema metadata written with it); a corrupt or foreign file is moved to
        ``rejected/`` with a note, and its chunk computed again."""
        need = []
        self.repairs: list[str] = []
        for k in range(self.sweep.n_chunks):
            path = self.chunks / chunk_name(k)
            ok = path.exists() and self._chunk_ok(path, k)
            if ok and self.sweep.traces and not (self.traces / chunk_name(k)).exists():
                ok = False
            if not ok:
                need.append(k)
        for p in self.chunks.glob("chunk-*.parquet"):  # a chunk index this sweep does not have
            if p.name not in {chunk_name(k) for k in range(self.sweep.n_chunks)}:
                self._reject(p, "it is not a chunk of this sweep")
        return need

    def _chunk_ok(self, path: Path, k: int) -> bool:
        """Whether ``path`` holds exactly chunk ``k`` of this sweep: its metadata (when written by a version
        that writes it) names this sweep and chunk, and its rows are this chunk's units, seeds, controllers
        and parameter values."""
        import pyarrow.parquet as pq

        try:
            table = pq.read_table(path)
            meta = json.loads((table.schema.metadata or {}).get(CHUNK_META, b"{}"))
            cols = {n: table[n].to_pylist() for n in ("unit", "point", "seed", "controller")}
            axes = {a.key: table[a.key].to_pylist() for a in self.sweep.axes}
        except Exception as exc:  # noqa: BLE001 (any unreadable file or missing column is a corrupt chunk)
            self._reject(path, f"it is not a readable chunk ({type(exc).__name__})")
            return False
        if meta and (meta.get("digest") != self.sweep.digest() or meta.get("chunk") != k):
            self._reject(path, "it was written by another sweep (its metadata says so)")
            return False
        units = self.sweep.chunk_units(k)
        want = [(u.index, u.point, u.seed, c) for u in units for c in self.sweep.controllers]
        got = list(zip(cols["unit"], cols["point"], cols["seed"], cols["controller"], strict=True))
        if sorted(got) != sorted(want):
            self._reject(path, f"its rows are not this chunk's flights ({len(got)} rows, {len(want)} expected)")
            return False
        for key, values in axes.items():
            for point, v in zip(cols["point"], values, strict=True):
                expected = self.sweep.points[point][key]
                if (json.loads(v) if isinstance(v, str) else v) != expected:
                    self._reject(path, f"its {key} values are another sweep's")
                    return False
        return True

    def _reject(self, path: Path, why: str) -> None:
        rejected = self.folder / "rejected"
        rejected.mkdir(exist_ok=True)
        os.replace(path, rejected / path.name)
        self.repairs.append(f"{path.name}: {why}; moved to rejected/ and computed again")

    def write_chunk(self, k: int, rows: dict, traces: dict | None) -> None:
        import pyarrow.parquet as pq

        meta = {CHUNK_META: json.dumps({"digest": self.sweep.digest(), "chunk": k}).encode()}
        if traces is not None:  # traces first: a chunk counts as done when its rows exist
            t = _table(traces, meta)
            write_with(self.traces / chunk_name(k), lambda fh: pq.write_table(t, fh))
        table = _table(rows, meta)
        write_with(self.chunks / chunk_name(k), lambda fh: pq.write_table(table, fh))

    def close(self) -> None:
        self.lock.close()


def _versions() -> dict[str, str]:
    from .. import __version__
    from ..io import _versions as lib_versions

    return {"vtol-impedance": __version__, **lib_versions()}


def warm_up(sweep: Sweep, backend: str = "compiled") -> None:
    """Compile the kernels in this process (or load them from the cache): one short flight of the first
    point. Its shortness makes a timed disturbance fall after its end: that warning is not the user's."""
    from ..scenarios import set_value, simulate
    from ..scenarios.spec import ScenarioWarning

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", EstimatorBandwidthWarning)
        warnings.simplefilter("ignore", ScenarioWarning)
        spec = set_value(sweep.point_spec(0), "duration", 0.05)
        simulate(spec, sweep.controllers[:1], backend=backend, log="metrics")


def execute(
    sweep: Sweep,
    folder: SweepFolder,
    chunks: list[int],
    executor: Executor,
    backend: str = "compiled",
    progress: Callable[[int], None] | None = None,
) -> None:
    """Compute ``chunks`` on ``executor`` (entered) and write each as it completes; ``progress(flights)``
    is told of every unit (in this process) or chunk (on Dask) done."""
    if not chunks:
        return
    if executor.scheduler is None:
        warm_up(sweep, backend)  # in this process, or for a local cluster's workers (they share the cache)
    if executor.distributed:
        executor.warm_workers(sweep, backend)
    if isinstance(progress, Progress):
        progress.start()  # the time left is the flights', not the compile's
    on_unit = None if executor.distributed else progress
    for k, rows, traces in executor.map_chunks(sweep, chunks, backend, on_unit):
        folder.write_chunk(k, rows, traces)
        if progress and executor.distributed:
            progress(len(sweep.chunk_units(k)) * len(sweep.controllers))


def read_dataset(folder: Path, digest: str | None = None):
    """The flights of a sweep folder as one pyarrow table, in unit order; with ``digest``, every chunk must
    say it belongs to that sweep."""
    from ..errors import instance, path_like

    folder = path_like("folder", folder)
    if digest is not None:
        instance("digest", digest, str)
    import pyarrow as pa
    import pyarrow.parquet as pq

    files = sorted((Path(folder) / "chunks").glob("chunk-*.parquet"))
    if not files:
        raise InputError(f"{folder} has no sweep results (no chunks/chunk-*.parquet)")
    tables = []
    for f in files:
        try:
            t = pq.read_table(f)
            owner = json.loads((t.schema.metadata or {}).get(CHUNK_META, b"{}")).get("digest")
            if digest is not None and owner is not None and owner != digest:
                raise InputError(f"{f} belongs to another sweep; run the sweep command again to recompute that chunk")
            tables.append(t.replace_schema_metadata(None))
        except InputError:
            raise
        except Exception as exc:  # noqa: BLE001 (any unreadable file)
            raise InputError(
                f"{f} is not a readable chunk ({type(exc).__name__}); run the same sweep command again: it moves the "
                "file aside and computes that chunk anew"
            ) from None
    try:
        table = pa.concat_tables(tables)
    except pa.ArrowInvalid as exc:
        raise InputError(f"the chunks of {folder} do not hold the same columns ({exc}); run the sweep again") from None
    return table.sort_by([("unit", "ascending"), ("controller", "ascending")])


def run_sweep(
    sweep: Sweep,
    out: Path,
    workers: int | None = None,
    scheduler: str | None = None,
    backend: str = "compiled",
    restart: bool = False,
    where: Path | None = None,
    show_progress: bool = True,
    scheduler_file: str | Path | None = None,
    connect_timeout: float | None = None,
    wait_workers: float | None = None,
    resume: str | None = None,
) -> tuple[Path, int]:
    """Run (or resume) a sweep into ``out``; returns the folder and how many chunks were computed now.

    ``workers``, ``scheduler``, ``scheduler_file``, ``connect_timeout`` and ``wait_workers``: see
    :class:`~vtol_impedance.sweeps.cluster.Executor`. ``resume`` is the command that resumes this run (the
    CLI passes its own): an interruption (a :class:`KeyboardInterrupt`, re-raised), the loss of the cluster
    (:class:`~vtol_impedance.sweeps.cluster.ClusterError`) or chunks failing every try
    (:class:`~vtol_impedance.sweeps.cluster.ChunkError`) each say how many chunks were kept and name it.
    Every run is added to the run record (``runs`` in ``sweep.json``) with the worker losses it saw."""
    from ..errors import choice, instance, path_like, scalar
    from . import cluster

    instance("sweep", sweep, Sweep)
    out = path_like("out", out)
    if workers is not None:
        scalar("workers", workers, lo=1, integer=True)
    if scheduler is not None:
        instance("scheduler", scheduler, str)
    choice("backend", backend, ("compiled", "numpy"))
    executor = Executor(
        workers,
        scheduler,
        scheduler_file,
        cluster.CONNECT_TIMEOUT_S if connect_timeout is None else connect_timeout,
        cluster.WAIT_WORKERS_S if wait_workers is None else wait_workers,
        log=(lambda m: print(m, file=sys.stderr, flush=True)) if show_progress else (lambda m: None),
    )  # fmt: skip  (validates the choice before touching the folder)
    if executor.note:
        print(f"note: {executor.note}", file=sys.stderr)
    executor.connect()  # a silent or unreachable scheduler fails here, before the folder exists
    folder = SweepFolder(sweep, out, restart, where)
    resume = resume or f"the same run_sweep into {folder.folder}"
    todo: list[int] = []
    run: dict[str, Any] = {"started": _now(), "on": executor.where, "backend": backend, "chunks_computed": 0,
                           "worker_losses": 0, "ended": "error"}  # fmt: skip
    try:
        todo = folder.missing()
        flown = {r["backend"] for r in folder.description["runs"] if r.get("chunks_computed") and "backend" in r}
        if len(todo) < sweep.n_chunks and flown - {backend}:  # one dataset, one engine
            raise InputError(
                f"{folder.folder} holds chunks flown with backend {sorted(flown)[0]!r}; resuming with {backend!r} "
                f"would mix the two in one dataset: resume with --backend {sorted(flown)[0]}, or --restart"
            )
        for note in folder.repairs:
            print(f"note: {note}", file=sys.stderr)
        if show_progress:
            done = sweep.n_chunks - len(todo)
            msg = f"sweep {sweep.name}: {sweep.n_flights} flights in {sweep.n_chunks} chunks"
            msg += f" ({done} already done, resuming)" if done else ""
            print(msg, file=sys.stderr)
        flights = sum(len(sweep.chunk_units(k)) for k in todo) * len(sweep.controllers)
        try:
            with executor:
                execute(sweep, folder, todo, executor, backend, Progress(flights, "flights", show_progress))
        except KeyboardInterrupt:
            run["ended"] = "interrupted"
            print(f"interrupted: {_kept(folder)}; resume with: {resume}", file=sys.stderr)
            raise
        except ClusterError as exc:
            run["ended"] = f"cluster: {exc}"
            raise ClusterError(f"{exc}. {_kept(folder)}; resume with: {resume}") from None
        except ChunkError as exc:
            run["ended"] = f"chunks failed: {exc}"
            raise ChunkError(f"{exc}. {_kept(folder)}; resume with: {resume}", exc.failures) from None
        run["ended"] = "complete"
    finally:
        run["chunks_computed"] = max(0, folder.done() - (sweep.n_chunks - len(todo))) if todo else 0
        run["worker_losses"] = executor.worker_losses
        try:
            folder.record_run(run)
        finally:
            folder.close()
    return folder.folder, len(todo)


def _kept(folder: SweepFolder) -> str:
    return f"{folder.done()} of {folder.sweep.n_chunks} chunks are kept in {folder.folder}"


def _now() -> str:
    import datetime

    return datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds")
