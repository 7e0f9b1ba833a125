"""Sweeps on a real Dask cluster: a ``dask scheduler`` and ``dask worker`` processes on 127.0.0.1, started in
a folder where the sweep's scenario file does not exist. The task carries its content (the workers fly a
file they cannot see, bit for bit as in this process); an edited base is refused on resume, naming the
change; every fault (a silent port, no workers, a killed worker, a killed scheduler) ends in bounded time
with a message, never a hang or a traceback."""

from __future__ import annotations

import json
import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest

pytest.importorskip("dask.distributed")

from test_sweeps import _same  # noqa: E402

from vtol_impedance.cli import main  # noqa: E402
from vtol_impedance.errors import InputError  # noqa: E402
from vtol_impedance.sweeps import from_dict, load, read_dataset, run_sweep  # noqa: E402
from vtol_impedance.sweeps.cluster import ClusterError, UnreachableError  # noqa: E402
from vtol_impedance.sweeps.run import SweepFolder  # noqa: E402

SRC = Path(__file__).resolve().parents[1] / "src"
DASK = [sys.executable, "-c", "import sys; from dask.cli import run_cli; sys.argv[0] = 'dask'; run_cli()"]

SCENARIO = 'base = "case-a-payload"\nname = "mine-v1"\nduration = 1.0\n[payload]\nmass = 0.12\n'
#: A vehicle file (the Pelican's values under another name), named by the scenario file.
QUAD = (
    (Path(__file__).resolve().parents[1] / "src/vtol_impedance/presets/pelican.toml")
    .read_text()
    .replace('name = "pelican"', 'name = "my-quad"')
)


def _scenario(d: Path, text: str = SCENARIO) -> str:
    return f'vehicle = "{d / "quad.toml"}"\n' + text


SWEEP = (
    'name = "cl"\nbase = "scenario.toml"\ncontrollers = ["pd", "pdc"]\nseeds = 2\nseed = 3\nchunk = 1\n'
    'margins = false\n[axes]\n"control.estimator_wn" = [5.0, 12.0]\n'
)


def _env() -> dict[str, str]:
    return {**os.environ, "PYTHONPATH": str(SRC), "NUMBA_NUM_THREADS": "1", "OMP_NUM_THREADS": "1"}


class Cluster:
    """Processes started here, each in its own session so that teardown ends it and its children."""

    def __init__(self, cwd: Path) -> None:
        self.cwd, self.procs = cwd, []

    def start(self, *args: str) -> subprocess.Popen:
        log = open(self.cwd / f"proc-{len(self.procs)}.log", "wb")  # noqa: SIM115 (closed by the process's end)
        p = subprocess.Popen([*DASK, *args], cwd=self.cwd, env=_env(), stdout=log, stderr=log, start_new_session=True)
        self.procs.append(p)
        return p

    def scheduler(self, name: str) -> tuple[subprocess.Popen, str]:
        f = self.cwd / f"{name}.json"
        p = self.start("scheduler", "--host", "127.0.0.1", "--port", "0", "--no-dashboard", "--scheduler-file", str(f))
        deadline = time.time() + 60
        while time.time() < deadline and not (f.exists() and f.stat().st_size):
            assert p.poll() is None, "the scheduler did not start"
            time.sleep(0.1)
        time.sleep(0.2)  # the file is written whole before the address is served
        return p, json.loads(f.read_text())["address"]

    def worker(self, address: str) -> subprocess.Popen:
        return self.start("worker", address, "--nthreads", "1", "--no-nanny", "--no-dashboard", "--memory-limit", "0")

    def stop(self) -> None:
        for p in self.procs:
            if p.poll() is None:
                os.killpg(p.pid, signal.SIGKILL)
            p.wait()


def _wait_workers(address: str, n: int) -> None:
    from dask.distributed import Client

    with Client(address, timeout="30s") as c:
        c.wait_for_workers(n, timeout=60)


@pytest.fixture(scope="module")
def cluster(tmp_path_factory):
    cwd = tmp_path_factory.mktemp("elsewhere")  # the workers' folder: no scenario file in it
    c = Cluster(cwd)
    try:
        _, c.address = c.scheduler("main")
        c.worker(c.address)
        c.worker(c.address)
        _wait_workers(c.address, 2)
        yield c
    finally:
        c.stop()


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    """A sweep whose base is a scenario file given by a relative path, and its in-process dataset."""
    d = tmp_path_factory.mktemp("user")
    (d / "quad.toml").write_text(QUAD)
    (d / "scenario.toml").write_text(_scenario(d))
    (d / "sweep.toml").write_text(SWEEP)
    run_sweep(load(d / "sweep.toml"), d / "ref", where=d / "sweep.toml", show_progress=False)
    return d, read_dataset(d / "ref")


def test_workers_that_cannot_see_the_file_fly_it_bit_for_bit_and_an_edit_is_refused(cluster, files, capsys):
    d, reference = files
    assert not (cluster.cwd / "scenario.toml").exists()
    sweep = load(d / "sweep.toml")  # the client reads the files, once
    moved, quad = d / "scenario.toml", d / "quad.toml"
    moved.rename(d / "away.toml")  # nobody can read them now: the workers fly what the task carries
    quad.rename(d / "quad-away.toml")
    try:
        run_sweep(sweep, d / "cl", scheduler=cluster.address, where=d / "sweep.toml")
    finally:
        (d / "away.toml").rename(moved)
        (d / "quad-away.toml").rename(quad)
    _same(read_dataset(d / "cl"), reference)
    err = capsys.readouterr().err
    assert "worker(s) connected; dashboard:" in err and "kernels ready on 2/2 worker(s)" in err
    record = json.loads((d / "cl" / "sweep.json").read_text())
    assert record["runs"][-1]["ended"] == "complete" and record["runs"][-1]["chunks_computed"] == 4

    # the file edited between runs: the resume is refused, naming the value that changed
    moved.write_text(_scenario(d, SCENARIO.replace("mass = 0.12", "mass = 0.2")))
    try:
        edited = load(d / "sweep.toml", check_points=False)
        with pytest.raises(InputError, match=r"holds another sweep: base.payload.mass: 0.12 -> 0.2 .*--restart"):
            run_sweep(edited, d / "cl", scheduler=cluster.address, where=d / "sweep.toml")
    finally:
        moved.write_text(_scenario(d))
    # and the vehicle file it names
    quad.write_text(QUAD.replace("mass = 1.2", "mass = 1.3"))
    try:
        edited = load(d / "sweep.toml", check_points=False)
        with pytest.raises(InputError, match=r"holds another sweep: vehicle_file.values.mass: 1.2 -> 1.3"):
            run_sweep(edited, d / "cl", scheduler=cluster.address, where=d / "sweep.toml")
    finally:
        quad.write_text(QUAD)


def test_a_silent_port_fails_within_the_deadline_naming_the_address(tmp_path, files):
    d, _ = files
    silent = socket.socket()
    silent.bind(("127.0.0.1", 0))
    silent.listen(8)  # accepts connections (the kernel does), answers nothing
    address = f"tcp://127.0.0.1:{silent.getsockname()[1]}"
    t0 = time.monotonic()
    try:
        with pytest.raises(UnreachableError, match=f"no answer from the Dask scheduler at {address} within 1.5 s"):
            run_sweep(load(d / "sweep.toml"), tmp_path / "s", scheduler=address, connect_timeout=1.5)
    finally:
        silent.close()
    assert time.monotonic() - t0 < 6.0 and not (tmp_path / "s").exists()


def test_no_workers_then_a_lost_scheduler_then_a_resume_on_a_new_one(cluster, files, tmp_path, monkeypatch, capsys):
    d, reference = files
    spec = str(d / "sweep.toml")
    out = tmp_path / "lost"
    sched, address = cluster.scheduler("second")
    # no worker: said, bounded, then refused with how to go on
    t0 = time.monotonic()
    with pytest.raises(ClusterError, match=r"no worker joined .* within 1.5 s; .*--wait-workers"):
        run_sweep(load(spec, check_points=False), out, scheduler=address, where=Path(spec), wait_workers=1.5)
    assert time.monotonic() - t0 < 20 and "waiting for workers (0 connected)" in capsys.readouterr().err

    cluster.worker(address)
    _wait_workers(address, 1)
    real = SweepFolder.write_chunk

    def kill_scheduler_after_one(self, k, rows, traces):
        real(self, k, rows, traces)
        if sched.poll() is None:
            sched.send_signal(signal.SIGKILL)
            sched.wait()

    monkeypatch.setattr(SweepFolder, "write_chunk", kill_scheduler_after_one)
    t0 = time.monotonic()
    rc = main(["sweep", spec, "--out", str(out), "--scheduler", address, "--connect-timeout", "2", "--no-report"])
    err = capsys.readouterr().err
    assert rc == 1 and time.monotonic() - t0 < 40
    assert f"lost the Dask scheduler at {address}" in err and "Traceback" not in err
    kept = len(list((out / "chunks").glob("chunk-*.parquet")))
    assert f"{kept} of 4 chunks are kept in {out}" in err and kept >= 1
    assert f"resume with: vtol-impedance sweep {spec} --out {out} --scheduler {address}" in err

    monkeypatch.setattr(SweepFolder, "write_chunk", real)
    folder, computed = run_sweep(load(spec), out, scheduler=cluster.address, where=Path(spec), show_progress=False)
    assert computed == 4 - kept  # the kept chunks are not flown again
    _same(read_dataset(out), reference)
    runs = json.loads((out / "sweep.json").read_text())["runs"]
    assert [r["ended"].split(":")[0] for r in runs] == ["cluster", "cluster", "complete"]  # no workers, lost, done
    assert "no worker joined" in runs[0]["ended"] and "lost the Dask scheduler" in runs[1]["ended"]


def test_losing_the_scheduler_is_a_cluster_error_in_the_library_too(monkeypatch):
    """The message and the kind of error, without processes: a scheduler whose client reports it gone."""
    from vtol_impedance.sweeps.cluster import Executor

    ex = Executor(scheduler="tcp://127.0.0.1:9", log=lambda m: None)

    class Gone:
        status = "closed"

    ex.client = Gone()
    with pytest.raises(ClusterError, match=r"lost the Dask scheduler at tcp://127.0.0.1:9: .*closed"):
        ex._watch()


@pytest.mark.parametrize("where", ["scheduler_info", "wait_for_workers", "identity"])
def test_a_connection_closed_mid_call_is_the_schedulers_loss_not_a_file_error(where):
    """Dask's CommClosedError ("ConnectionPool closing") is an OSError: raised from any call to a scheduler
    that went away (seen in CI while waiting for workers), it is said as the loss, never as a file error."""
    from distributed.comm.core import CommClosedError

    from vtol_impedance.sweeps.cluster import Executor

    ex = Executor(scheduler="tcp://127.0.0.1:9", log=lambda m: None, wait_workers=5.0)

    def closing(*a, **k):
        raise CommClosedError("ConnectionPool closing.")

    class Client:
        status = "running"
        scheduler = type("S", (), {"identity": None})()

        def scheduler_info(self):
            return closing() if where == "scheduler_info" else {"workers": {}}

        def wait_for_workers(self, n, timeout):
            if where == "wait_for_workers":
                closing()
            raise TimeoutError  # none joined: the count is asked next

        def sync(self, f, callback_timeout):
            return closing() if where == "identity" else {"workers": {}}

    ex.client = Client()
    with pytest.raises(ClusterError, match=r"lost the Dask scheduler at tcp://127.0.0.1:9: .*CommClosedError"):
        ex._watch(force=True)


def test_the_warm_up_flight_warns_of_nothing(recwarn):
    """A base with a timed disturbance: the short warm-up flight ends before it, which is not the user's."""
    import warnings

    from vtol_impedance.sweeps.run import warm_up

    sweep = from_dict({"name": "w", "base": "operator-push", "controllers": ["pd"], "margins": False,
                       "axes": {"control.estimator_wn": [5.0]}}, check_points=False)  # fmt: skip
    assert sweep.base.disturbances[0]["t_on"] == 10.0  # after the warm-up flight's end
    warnings.simplefilter("always")
    warm_up(sweep)
    assert not [w for w in recwarn if "after the flight ends" in str(w.message)]


def test_the_chunks_in_flight_are_bounded(cluster, files, monkeypatch):
    """Streaming: never more futures alive than about two per worker thread, whatever the sweep's size."""
    from dask.distributed import Client

    from vtol_impedance.sweeps.cluster import Executor

    d, _ = files
    first = load(d / "sweep.toml", check_points=False)
    sweep = from_dict({**first.source, "seeds": 10}, check_points=False, base=first.base)  # 20 chunks
    most = []
    real_submit = Client.submit

    def counting(self, *a, **kw):
        fut = real_submit(self, *a, **kw)
        most.append(len(self.futures))
        return fut

    monkeypatch.setattr(Client, "submit", counting)
    with Executor(scheduler=cluster.address, log=lambda m: None) as ex:
        got = [k for k, _, _ in ex.map_chunks(sweep, list(range(sweep.n_chunks)))]
    assert sorted(got) == list(range(20)) and max(most) <= 4  # 2 worker threads


def test_a_chunk_failing_every_try_is_named_with_its_parameters_and_the_others_are_kept(cluster, tmp_path):
    """A point the workers cannot fly (a control rate that does not divide the plant rate, not checked here
    on purpose): its chunk fails on each of its three tries and is named; the other chunks are written."""
    from vtol_impedance.sweeps import ChunkError

    bad = {"name": "bad", "base": "case-a-payload", "controllers": ["pd"], "margins": False, "chunk": 1,
           "set": {"duration": 0.5}, "axes": {"control.rate": [100.0, 333.0]}}  # fmt: skip
    sweep = from_dict(bad, check_points=False)
    with pytest.raises(
        ChunkError, match=r"1 chunk\(s\) failed on every one of 3 tries: chunk 1 \(.*control.rate = 333"
    ):
        run_sweep(sweep, tmp_path / "bad", scheduler=cluster.address, show_progress=False)
    assert [p.name for p in (tmp_path / "bad" / "chunks").glob("*.parquet")] == ["chunk-000000.parquet"]


def test_a_scheduler_file_names_the_cluster(cluster, tmp_path):
    from vtol_impedance.sweeps.cluster import Executor

    assert Executor(scheduler_file=cluster.cwd / "main.json").scheduler == cluster.address
    with pytest.raises(InputError, match="--scheduler-file .*missing.json is not a readable Dask scheduler file"):
        Executor(scheduler_file=tmp_path / "missing.json")
    (tmp_path / "other.json").write_text('{"type": "Scheduler"}')
    with pytest.raises(InputError, match="names no scheduler address"):
        Executor(scheduler_file=tmp_path / "other.json")
    with pytest.raises(InputError, match="give one of --workers"):
        Executor(workers=2, scheduler_file=cluster.cwd / "main.json")


def test_a_killed_worker_is_counted_and_its_chunks_run_elsewhere(cluster, files, monkeypatch, capsys):
    """Last of the tests on the module's cluster: it kills one of its two workers."""
    d, reference = files
    extra = cluster.procs[2]  # the second worker
    real, calls = SweepFolder.write_chunk, []

    def kill_on_first(self, k, rows, traces):
        real(self, k, rows, traces)
        calls.append(k)
        if len(calls) == 1:
            extra.send_signal(signal.SIGKILL)  # kill -9, mid-sweep
            extra.wait()
            time.sleep(1.0)  # the scheduler sees the connection drop

    monkeypatch.setattr(SweepFolder, "write_chunk", kill_on_first)
    run_sweep(load(d / "sweep.toml"), d / "killed", scheduler=cluster.address, where=d / "sweep.toml")
    _same(read_dataset(d / "killed"), reference)
    assert sorted(calls) == [0, 1, 2, 3]  # each chunk written once: none recomputed after being written
    run = json.loads((d / "killed" / "sweep.json").read_text())["runs"][-1]
    assert run["worker_losses"] == 1 and run["ended"] == "complete"
    assert "lost 1 worker(s)" in capsys.readouterr().err
