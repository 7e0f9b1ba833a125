"""Where a sweep's chunks are computed: in this process, on a loopback Dask ``LocalCluster``, or on an
existing Dask cluster; every wait on the scheduler bounded, every fault an event with a message.

- **The task carries its content.** A chunk's task is the resolved :class:`~.spec.Sweep` (the base
  scenario's values, not its file name) and the chunk index: a worker opens no user file.
- **Bounded waits.** The scheduler must answer within ``connect_timeout`` (:data:`CONNECT_TIMEOUT_S`): an
  address that accepts connections but says nothing (a wrong service, a proxy, a wedged scheduler) fails
  naming the address. While no worker is connected, ``waiting for workers (0 connected)`` is shown, up to
  ``wait_workers`` (:data:`WAIT_WORKERS_S`). While chunks run, the scheduler is asked for a sign of life
  every :data:`PING_S` and must answer within ``connect_timeout``.
- **Losses are events.** A lost scheduler raises :class:`ClusterError` (the caller says what was kept and
  how to resume); a lost worker is counted (:attr:`Executor.worker_losses`) and its chunks run elsewhere;
  a chunk is tried ``1 + retries`` times (:data:`RETRIES`) and one failing every try is named with its
  parameters (:class:`ChunkError`) while the others go on.
- **Streamed.** At most about two chunks per worker thread are submitted at a time; each result is handed
  over as it completes and its future released, so memory is bounded by the chunks in flight and a lost
  worker never recomputes a chunk already written.
"""

from __future__ import annotations

import asyncio
import concurrent.futures
import json
import logging
import os
import sys
import time
import warnings
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

from ..errors import InputError, VtolImpedanceError

#: What a Dask future raises when it was cancelled under us (its scheduler lost): concurrent's (an
#: Exception) and asyncio's (a BaseException), both caught so the loss is said, not reported as a crash.
CANCELLED = (concurrent.futures.CancelledError, asyncio.CancelledError)
#: What talking to a scheduler that went away raises besides: Dask's ``CommClosedError`` ("ConnectionPool
#: closing") is an ``OSError``, as are refused and reset connections. No file is touched while talking to
#: it (results are written by the caller), so here an ``OSError`` is always the connection's.
LOST = (*CANCELLED, OSError)

#: Deadline for reaching and hearing from the scheduler (connect and first answer; each later ping), s.
CONNECT_TIMEOUT_S = 10.0
#: How long to wait for a first worker before giving up, s (``--wait-workers`` changes it).
WAIT_WORKERS_S = 60.0
#: How often a running sweep asks the scheduler for a sign of life (and its workers), s.
PING_S = 2.0
#: Extra tries of a chunk whose task raised (Dask's ``retries``); a killed worker's chunks are moved
#: by the scheduler itself (up to ``distributed.scheduler.allowed-failures`` times).
RETRIES = 2


class ClusterError(VtolImpedanceError):
    """The Dask cluster cannot be reached, does not answer, has no worker, or was lost while running."""


class UnreachableError(ClusterError, InputError):
    """The scheduler named (``--scheduler``, ``--scheduler-file``) refuses, or does not answer in time."""


class ChunkError(VtolImpedanceError):
    """Chunks that failed on every try; ``failures`` lists ``(chunk, parameters, error)``."""

    def __init__(self, message: str, failures: list[tuple[int, str, str]]) -> None:
        super().__init__(message)
        self.failures = failures


def _numba_one_thread() -> None:
    try:
        import numba

        numba.set_num_threads(1)
    except (ImportError, ValueError):
        pass


def chunk_task(sweep: Any, k: int, backend: str = "compiled") -> tuple[int, dict, dict | None]:
    """What a Dask worker runs: fly chunk ``k`` of ``sweep`` (``Sweep.task(k)``: the resolved sweep with that
    chunk's points; nothing is read from disk)."""
    from .run import run_units

    _numba_one_thread()
    return (k, *run_units(_carried(sweep), sweep.chunk_units(k), backend))


def _carried(sweep: Any) -> Any:
    """``sweep`` flying the vehicle file it carries: its text written to this worker's temporary folder
    (named by its hash), never the user's file read here."""
    if not sweep.vehicle_file:
        return sweep
    import dataclasses
    import hashlib
    import tempfile

    from ..io import write_text

    text = sweep.vehicle_file["text"]
    path = Path(tempfile.gettempdir()) / "vtol-impedance-vehicles" / f"{hashlib.sha256(text.encode()).hexdigest()}.toml"
    if not path.exists():
        write_text(path, text)  # atomic: workers sharing the folder never read half a file
    return dataclasses.replace(sweep, base=dataclasses.replace(sweep.base, vehicle=str(path)))


def warm_task(sweep: Any, backend: str = "compiled") -> int:
    """What a Dask worker runs before its first chunk: compile (or load from its cache) the kernels."""
    from .run import warm_up

    _numba_one_thread()
    warm_up(_carried(sweep), backend)
    return os.getpid()


def address_ok(address: str) -> bool:
    """``[protocol://]host:port`` with a port in 1..65535 (what a Dask scheduler listens on)."""
    import re

    pattern = r"(?:(tcp|tls|inproc|ucx|ws|wss)://)?(\[[0-9a-fA-F:]+\]|[A-Za-z0-9._-]+):(\d{1,5})"
    m = re.fullmatch(pattern, address.strip())
    return bool(m) and 0 < int(m.group(3)) < 65536


def scheduler_address(scheduler_file: str | Path) -> str:
    """The address in a Dask scheduler file (``dask scheduler --scheduler-file F`` writes it)."""
    from ..errors import path_like

    path = path_like("--scheduler-file", scheduler_file)
    try:
        address = json.loads(Path(path).read_text(encoding="utf-8")).get("address")
    except (OSError, ValueError, AttributeError) as exc:
        raise InputError(f"--scheduler-file {path} is not a readable Dask scheduler file ({exc})") from None
    if not isinstance(address, str) or not address_ok(address):
        raise InputError(f"--scheduler-file {path} names no scheduler address (got {address!r})")
    return address


def probe(address: str, timeout: float, security: Any = None) -> dict[str, Any]:
    """Ask the scheduler at ``address`` who it is, within ``timeout`` seconds in all (connection and answer):
    Dask's own connect waits without end for a peer that accepts and never answers."""
    import asyncio
    import socket
    from urllib.parse import urlsplit

    from distributed.comm import connect

    args = security.get_connection_args("client") if security is not None else {}
    parts = urlsplit(address if "://" in address else f"tcp://{address}")
    if parts.scheme in ("tcp", "tls") and parts.hostname and parts.port:  # a refusal is said at once
        try:
            socket.create_connection((parts.hostname, parts.port), timeout=timeout).close()
        except OSError as exc:
            raise UnreachableError(f"cannot reach the Dask scheduler at {address}: {exc.strerror or exc}") from None

    async def ask() -> dict[str, Any]:
        comm = await connect(address, timeout=timeout, **args)
        try:
            await comm.write({"op": "identity"})
            return await comm.read()
        finally:
            comm.abort()

    async def bounded() -> dict[str, Any]:
        return await asyncio.wait_for(ask(), timeout)

    try:
        answer = asyncio.run(bounded())
    except TimeoutError:
        raise UnreachableError(
            f"no answer from the Dask scheduler at {address} within {timeout:g} s (it accepts connections but says "
            "nothing: is it a Dask scheduler, and is it running?); --connect-timeout S waits longer"
        ) from None
    except (OSError, ValueError, TypeError) as exc:
        raise UnreachableError(f"cannot reach the Dask scheduler at {address}: {exc}") from None
    if not isinstance(answer, dict) or answer.get("type") != "Scheduler":
        raise UnreachableError(f"{address} answered, but not as a Dask scheduler ({str(answer)[:80]})")
    return answer


def _ignore_interrupt() -> None:
    """In a local cluster's worker process: ignore SIGINT (the command stops the cluster itself)."""
    import signal

    signal.signal(signal.SIGINT, signal.SIG_IGN)


def _bokeh() -> bool:
    try:
        import bokeh  # noqa: F401
    except ImportError:
        return False
    return True


class _QuietDask(logging.Filter):
    """While a sweep runs on Dask, the errors Dask logs (with tracebacks) about a lost connection are
    dropped: the sweep reports the loss itself, with what was kept. Its warnings still show."""

    closing = False  # while the cluster is closed, its warnings (workers killed on the way out) are ours too

    def filter(self, record: logging.LogRecord) -> bool:
        floor = logging.WARNING if self.closing else logging.ERROR
        return not (record.name.startswith(("distributed", "tornado")) and record.levelno >= floor)

    def __enter__(self) -> _QuietDask:
        names = ["", *(n for n in logging.root.manager.loggerDict if n.startswith(("distributed", "tornado")))]
        self.handlers = {h for name in names for h in logging.getLogger(name).handlers}
        for h in self.handlers:
            h.addFilter(self)
        return self

    def __exit__(self, *exc: object) -> None:
        for h in self.handlers:
            h.removeFilter(self)


class Executor:
    """Where chunks are computed: in this process (default), on a loopback ``LocalCluster`` of ``workers``
    processes, or on the Dask cluster at ``scheduler`` (or named by ``scheduler_file``). A context manager;
    the cluster lives as long as it. ``log`` receives its messages (stderr by default)."""

    def __init__(
        self, workers: int | None = None, scheduler: str | None = None, scheduler_file: str | Path | None = None,
        connect_timeout: float = CONNECT_TIMEOUT_S, wait_workers: float = WAIT_WORKERS_S,
        log: Callable[[str], None] | None = None,
    ) -> None:  # fmt: skip
        from ..errors import scalar

        if sum(x is not None and x != "" for x in (workers, scheduler, scheduler_file)) > 1:
            raise InputError(
                "give one of --workers (a local cluster), --scheduler or --scheduler-file (an existing one)"
            )
        if workers is not None and (isinstance(workers, bool) or not isinstance(workers, int) or workers < 1):
            raise InputError(f"--workers must be a whole number of at least 1, got {workers!r}")
        self.connect_timeout = float(scalar("--connect-timeout", connect_timeout, lo=0.0, lo_open=True, hi=3600.0))
        self.wait_workers = float(scalar("--wait-workers", wait_workers, lo=0.0, hi=7 * 86400.0))
        cores = os.cpu_count() or 1
        self.note = ""
        if workers is not None and workers > cores:  # more processes than cores only adds memory
            self.note = f"--workers {workers} capped at {cores}, this machine's cores"
            workers = cores
        if scheduler_file is not None:
            scheduler = scheduler_address(scheduler_file)
        if scheduler is not None and not address_ok(scheduler):
            raise InputError(
                f"--scheduler {scheduler!r} is not a Dask scheduler address; give one like tcp://HOST:8786"
            )
        self.workers, self.scheduler = workers, scheduler
        self.log = log if log is not None else (lambda m: print(m, file=sys.stderr, flush=True))
        self.client = self.cluster = None
        self.worker_losses = 0
        self._seen: set[str] = set()
        self._warmed: set[str] = set()
        self._last_ping = 0.0

    @property
    def distributed(self) -> bool:
        return self.workers is not None or bool(self.scheduler)

    @property
    def where(self) -> str:
        """The cluster in words: ``this process``, ``a local cluster of 2 workers``, ``tcp://...``."""
        if self.scheduler:
            return f"the Dask scheduler at {self.scheduler}"
        return f"a local cluster of {self.workers} workers" if self.workers else "this process"

    def connect(self) -> None:
        """Only check that the scheduler answers (within the deadline): before any folder is created."""
        if self.scheduler:
            self._security_and_probe()

    def _security_and_probe(self) -> Any:
        try:
            from distributed import Security
        except ImportError:
            raise InputError("--workers and --scheduler need Dask: pip install 'vtol-impedance[dask]'") from None
        security = Security()  # from Dask's config: distributed.comm.tls.* (see the sweeps guide, TLS)
        if self.scheduler.startswith("tls://") and not security.require_encryption and not security.tls_ca_file:
            raise InputError(
                f"--scheduler {self.scheduler} is a TLS address but Dask's config has no TLS settings; set "
                "distributed.comm.tls.ca-file, .client.cert and .client.key (docs: sweeps, 'TLS')"
            )
        probe(self.scheduler, self.connect_timeout, security)
        return security

    def __enter__(self) -> Executor:
        if not self.distributed:
            return self
        self._quiet = _QuietDask()  # a loss is said once, by us: not as Dask's logged tracebacks
        self._quiet.__enter__()
        try:
            from dask.distributed import Client, LocalCluster
        except ImportError:
            raise InputError("--workers and --scheduler need Dask: pip install 'vtol-impedance[dask]'") from None
        if self.scheduler:
            security = self._security_and_probe()
            try:
                self.client = Client(self.scheduler, timeout=f"{self.connect_timeout}s", security=security)
            except (OSError, TimeoutError, ValueError, TypeError) as exc:
                raise ClusterError(f"cannot reach the Dask scheduler at {self.scheduler}: {exc}") from None
        else:
            one = {k: "1" for k in ("NUMBA_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS")}
            self.cluster = LocalCluster(
                n_workers=self.workers, threads_per_worker=1, processes=True, host="127.0.0.1",
                dashboard_address="127.0.0.1:0" if _bokeh() else None, env=one,
            )  # fmt: skip
            self.client = Client(self.cluster)
            self.client.run(_ignore_interrupt)  # Ctrl-C reaches the whole group: the command alone answers it
        info = self.client.scheduler_info()
        board = self.client.dashboard_link if "dashboard" in info.get("services", {}) else None
        self.log(
            f"Dask: {self.where}, {len(info.get('workers', {}))} worker(s) connected; dashboard: "
            + (board or "none (the scheduler runs no dashboard: pip install bokeh where it runs)")
        )
        return self

    def __exit__(self, *exc: object) -> None:
        if getattr(self, "_quiet", None) is not None:
            self._quiet.closing = True
        with warnings.catch_warnings():  # a lost scheduler makes closing noisy; the loss is reported already
            warnings.simplefilter("ignore")
            if self.client is not None:
                try:
                    self.client.close(timeout=self.connect_timeout)
                except Exception:  # noqa: BLE001 (closing a client whose scheduler is gone)
                    pass
            if self.cluster is not None:
                self.cluster.close()
        if getattr(self, "_quiet", None) is not None:
            self._quiet.__exit__()
            self._quiet = None

    # ------------------------------------------------------------------ waits and watching

    def _workers(self) -> dict[str, Any]:
        try:
            return dict(self.client.scheduler_info().get("workers", {}))
        except LOST as exc:
            raise self._lost(f"it stopped answering ({type(exc).__name__})") from None

    def _lost(self, what: str) -> ClusterError:
        return ClusterError(f"lost {self.where}: {what}")

    def _watch(self, force: bool = False) -> dict[str, Any]:
        """Check the scheduler is alive (asked every :data:`PING_S`, or now with ``force``), count lost
        workers and wait (bounded) while none is connected; returns the workers."""
        if self.client.status not in ("running", "connecting", "newly-created"):
            raise self._lost(f"the client's connection is {self.client.status}")
        now = time.monotonic()
        if force or now - self._last_ping >= PING_S:
            try:
                ident = self.client.sync(self.client.scheduler.identity, callback_timeout=self.connect_timeout)
            except (Exception, *CANCELLED) as exc:  # noqa: BLE001 (no answer: the scheduler is lost)
                why = "no answer" if isinstance(exc, TimeoutError) else f"it stopped answering ({type(exc).__name__})"
                raise self._lost(f"{why} within {self.connect_timeout:g} s") from None
            self._last_ping = now
            workers = dict(ident.get("workers", {}))
            gone = self._seen - set(workers)  # counted on the scheduler's own answer only (the cache lags)
            if gone:
                self.worker_losses += len(gone)
                self.log(f"note: lost {len(gone)} worker(s) ({', '.join(sorted(gone))}); their chunks run elsewhere")
            self._seen = set(workers)
        else:
            workers = self._workers()
        if not workers:
            self._wait_for_workers()
            self._last_ping = 0.0  # the next call asks the scheduler who joined
            workers = self._workers()
        return workers

    def _wait_for_workers(self) -> None:
        deadline = time.monotonic() + self.wait_workers
        self.log(
            f"waiting for workers (0 connected) at {self.scheduler or 'the local cluster'}, up to "
            f"{self.wait_workers:g} s (--wait-workers S waits longer)"
        )
        while True:
            left = deadline - time.monotonic()
            if left <= 0:
                raise ClusterError(
                    f"no worker joined {self.where} within {self.wait_workers:g} s; start some (dask worker "
                    f"{self.scheduler or 'ADDRESS'}) or wait longer with --wait-workers SECONDS"
                )
            try:
                self.client.wait_for_workers(1, timeout=min(left, 10.0))
                return
            except TimeoutError:  # (an OSError: caught before the connection's others)
                n = len(self._workers())
                if n:
                    return
                self.log(f"waiting for workers ({n} connected), {left:.0f} s left")
            except LOST as exc:  # the scheduler went away while we waited
                raise self._lost(f"it stopped answering ({type(exc).__name__})") from None
            if self.client.status not in ("running", "connecting", "newly-created"):
                raise self._lost(f"the client's connection is {self.client.status}")

    def warm_workers(self, sweep: Any, backend: str = "compiled") -> None:
        """Compile (or load from their cache) the kernels on each connected worker not warmed yet, with
        progress: workers on other machines do not share this machine's compile cache."""
        from dask.distributed import as_completed

        workers = [w for w in self._watch() if w not in self._warmed]
        if not workers:
            return
        futures = {
            self.client.submit(warm_task, sweep.task(0), backend, workers=[w], allow_other_workers=False, pure=False): w
            for w in workers
        }
        done = 0
        ac = as_completed(futures)
        while not ac.is_empty():
            if not ac.has_ready():
                self._watch()
                time.sleep(0.1)
                continue
            for fut in ac.next_batch(block=False):
                w = futures.pop(fut)
                if fut.status == "finished":
                    self._warmed.add(w)
                    done += 1
                    self.log(f"  kernels ready on {done}/{len(workers)} worker(s)")
                fut.release()
            if any(w not in self._workers() for w in futures.values()):  # a worker left while warming
                for f in [f for f, w in futures.items() if w not in self._workers()]:
                    f.cancel()
                    futures.pop(f)
                ac = as_completed(futures)

    # ------------------------------------------------------------------ the work

    def map_chunks(
        self, sweep: Any, chunks: list[int], backend: str = "compiled",
        on_unit: Callable[[int], None] | None = None, retries: int = RETRIES,
    ) -> Iterator[tuple[int, dict, dict | None]]:  # fmt: skip
        """``(k, rows, traces)`` for every chunk, as each completes (``on_unit``: see
        :func:`~.run.run_units`, in this process only; on Dask a chunk is the unit of progress). On Dask, a
        bounded number of chunks is in flight, each future released once its result is handed over; a
        chunk that fails on every one of its ``1 + retries`` tries is named in a :class:`ChunkError` raised
        after the others are done (a ``DesignError`` is raised as is: it is a property of the gains)."""
        from .run import run_units

        if not self.distributed:
            for k in chunks:
                yield (k, *run_units(sweep, sweep.chunk_units(k), backend, on_unit))
            return
        from dask.distributed import as_completed

        from ..robust.design import DesignError

        key = f"vtol-chunk-{sweep.digest()[:12]}"
        todo = list(chunks)[::-1]
        live: dict[Any, int] = {}
        failures: list[tuple[int, str, str]] = []
        ac = as_completed()

        def refill(workers: dict[str, Any]) -> None:
            slots = max(2, 2 * sum(int(w.get("nthreads", 1)) for w in workers.values()))
            while todo and len(live) < slots:
                k = todo.pop()
                fut = self.client.submit(
                    chunk_task, sweep.task(k), k, backend, key=f"{key}-{k}", pure=False, retries=retries
                )
                live[fut] = k
                ac.add(fut)

        try:
            refill(self._watch())
            while live:
                if not ac.has_ready():
                    time.sleep(0.05)
                    refill(self._watch())
                    continue
                for fut in ac.next_batch(block=False):
                    k = live.pop(fut)
                    if fut.status == "finished":
                        result = fut.result()
                        fut.release()  # the worker may drop it: it is written once handed over
                        yield result
                        continue
                    exc = fut.exception() if fut.status == "error" else None
                    fut.release()
                    if exc is None:  # cancelled: the connection to the scheduler was lost (or it forgot the task)
                        self._watch(force=True)  # names the loss when the scheduler is gone
                        raise self._lost(f"chunk {k} was cancelled by the scheduler")
                    if isinstance(exc, DesignError):
                        raise exc
                    failures.append((k, _chunk_params(sweep, k), f"{type(exc).__name__}: {exc}"))
                refill(self._watch())
        except LOST as exc:  # a future cancelled under us (FutureCancelledError), a closed comm: it is gone
            raise self._lost(f"the connection to it was lost ({type(exc).__name__})") from None
        self._watch(force=True)  # a worker lost near the end is counted too
        if failures:
            lines = "; ".join(f"chunk {k} ({p}): {e}" for k, p, e in failures[:5])
            raise ChunkError(f"{len(failures)} chunk(s) failed on every one of {1 + retries} tries: {lines}", failures)


def _chunk_params(sweep: Any, k: int) -> str:
    """The parameters a chunk flies, in words (for a failure that names them)."""
    from .spec import _fmt_point

    units = sweep.chunk_units(k)
    points = list(dict.fromkeys(u.point for u in units))
    text = " | ".join(_fmt_point(sweep.points[p]) for p in points[:3]) + (" | ..." if len(points) > 3 else "")
    return f"units {units[0].index}-{units[-1].index}, seeds {units[0].seed}...: {text}"
