"""Sweeps: specs refused before work, results independent of how the work is split (chunks, Dask
workers, interruptions, a killed worker), the summary, the physics seen through a sweep, and tuning."""

from __future__ import annotations

import json
import math
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from vtol_impedance.cli import main
from vtol_impedance.errors import InputError
from vtol_impedance.sweeps import from_dict, read_dataset, run_sweep, summarise, write_report
from vtol_impedance.sweeps.run import Executor, SweepFolder
from vtol_impedance.sweeps.spec import Axis
from vtol_impedance.sweeps.tune import best_scenario_toml, optimize, tuning_from_dict

SMALL = {
    "name": "small",
    "base": "case-a-payload",
    "controllers": ["pd", "pdc"],
    "seeds": 2,
    "seed": 11,
    "chunk": 2,
    "set": {"trajectory": {"hover_duration": 2.0}},
    "axes": {"payload.mass": [0.05, 0.15], "control.estimator_wn": [5.0, 15.0]},
}


def _same(a, b) -> None:
    """Two datasets hold the same flights with the same numbers (NaN equal to NaN)."""
    assert a.column_names == b.column_names and a.num_rows == b.num_rows
    for n in a.column_names:
        x, y = a[n].to_pylist(), b[n].to_pylist()
        assert all(
            p == q or (isinstance(p, float) and math.isnan(p) and math.isnan(q)) for p, q in zip(x, y, strict=True)
        ), n


@pytest.fixture(scope="module")
def reference(tmp_path_factory):
    out = tmp_path_factory.mktemp("ref") / "sweep"
    run_sweep(from_dict(SMALL), out, show_progress=False)
    return read_dataset(out)


# ----------------------------------------------------------------------------- refused before any work


@pytest.mark.parametrize(
    "change, message",
    [
        ({"axes": {"payload.mas": [0.1]}}, "unknown key 'payload.mas'"),
        ({"axes": {"payload.mass": []}}, "axis 'payload.mass' is empty"),
        ({"axes": {}}, "needs \\[axes\\]"),
        ({"axes": {"control.rate": [30.0]}}, "point 0 .*whole multiple"),
        ({"axes": {"payload.mass": [-1.0]}}, "payload.mass"),
        ({"axes": {"payload.mass": {"min": 0.0, "max": 0.2}}}, "needs n"),
        ({"axes": {"payload.mass": {"min": 0.3, "max": 0.2, "n": 3}}}, "min 0.3 is above max"),
        ({"mode": "zip", "axes": {"payload.mass": [0.1, 0.2], "control.Kp": [10.0]}}, "equal length"),
        ({"controllers": ["pd", "lqr"]}, "controllers must be"),
        ({"mode": "spiral"}, "mode must be one of"),
        ({"seeds": 0}, "seeds"),
        ({"colour": "red"}, "colour"),
        ({"axes": {"payload.offset_B[5]": [0.1]}}, "component 5"),
        ({"axes": {"seed": [1, 2]}}, "seed cannot be an axis"),
        ({"max_flights": 3}, "above max_flights = 3"),
        (
            {"axes": {"payload.mass": [0.1, 0.2], "payload.mass,plant.rotor_drag": [[0.5, 0.1]]}},
            r"axis 'payload.mass,plant.rotor_drag' sets 'payload.mass', which axis 'payload.mass' sets too",
        ),
        ({"set": {"payload": {"mass": 0.3}}}, r"axis 'payload.mass' sets 'payload.mass', which \[set\] sets too"),
        ({"set": {"seed": 3}}, r"\[set\] seed: the sweep sets each flight's seed"),
        # a vector and one of its entries are one value: the rows would name values never flown
        (
            {"axes": {"payload.offset_B": [[0.0, 0, 0], [0.05, 0, 0]], "payload.offset_B[0]": [0.02]}},
            r"'payload.offset_B\[0\]', which axis 'payload.offset_B' sets too",
        ),
        (
            {"set": {"payload.offset_B[2]": 0.09}, "axes": {"payload.offset_B": [[0.0, 0, 0]]}},
            r"which \[set\] sets too \(as 'payload.offset_B\[2\]'\)",
        ),
        ({"controllers": [["pd"]]}, "controllers must be"),
        (
            {"max_flights": 10**9, "axes": {"payload.mass": {"min": 0.0, "max": 0.3, "n": 2000},
                                            "control.Kp": {"min": 8.0, "max": 30.0, "n": 1000}}},
            "2000000 points, above the 1000000 one sweep file can list",
        ),  # fmt: skip
        ({"description": {"a": 1}}, "description must be a str"),
        (
            {
                "axes": {
                    "payload.mass": {"min": 0.0, "max": 0.3, "n": 10000},
                    "control.Kp": {"min": 8.0, "max": 30.0, "n": 10000},
                }
            },
            "100000000 points",
        ),
    ],
)
def test_bad_specs_fail_before_any_work(change, message, tmp_path):
    spec = {**SMALL, **change}
    with pytest.raises(InputError, match=message):
        from_dict(spec)


def test_cli_refuses_a_bad_sweep_file_without_creating_anything(tmp_path, capsys):
    f = tmp_path / "bad.toml"
    f.write_text('name = "bad"\nbase = "case-a-payload"\n[axes]\n"payload.mas" = [0.1]\n')
    rc = main(["sweep", str(f), "--out", str(tmp_path / "o")])
    err = capsys.readouterr().err
    assert rc == 2 and "payload.mas" in err and "Traceback" not in err
    assert not (tmp_path / "o").exists()
    assert main(["sweep", "no-such-study", "--out", str(tmp_path / "o")]) == 2
    assert "rate-vs-bandwidth" in capsys.readouterr().err
    assert main(["sweep", str(f), "--workers", "0"]) == 2
    assert main(["sweep-report", str(tmp_path)]) == 2
    assert "not a sweep folder" in capsys.readouterr().err


# ----------------------------------------------------------------------------- the same results however split


def test_chunking_does_not_change_the_results(reference, tmp_path):
    run_sweep(from_dict({**SMALL, "chunk": 3}), tmp_path / "c3", show_progress=False)
    _same(read_dataset(tmp_path / "c3"), reference)
    assert len(list((tmp_path / "c3" / "chunks").glob("*.parquet"))) == 3


def test_interrupted_sweep_resumes_to_the_identical_dataset(reference, tmp_path, monkeypatch, capsys):
    out = tmp_path / "sweep"
    sweep = from_dict(SMALL)
    real = SweepFolder.write_chunk
    calls = {"n": 0}

    def flaky(self, k, rows, traces):
        calls["n"] += 1
        if calls["n"] == 3:
            raise KeyboardInterrupt  # Ctrl-C after two chunks
        real(self, k, rows, traces)

    monkeypatch.setattr(SweepFolder, "write_chunk", flaky)
    with pytest.raises(KeyboardInterrupt):
        run_sweep(sweep, out, show_progress=False)
    monkeypatch.setattr(SweepFolder, "write_chunk", real)
    assert len(list((out / "chunks").glob("*.parquet"))) == 2
    assert not list(out.rglob("*.tmp*"))
    assert f"interrupted: 2 of {sweep.n_chunks} chunks are kept in {out}; resume with:" in capsys.readouterr().err
    assert json.loads((out / "sweep.json").read_text())["runs"][-1]["ended"] == "interrupted"
    with pytest.raises(InputError, match="backend 'compiled'"):  # one dataset, one engine: not half NumPy
        run_sweep(sweep, out, show_progress=False, backend="numpy")
    assert len(list((out / "chunks").glob("*.parquet"))) == 2
    _, computed = run_sweep(sweep, out, show_progress=False)
    assert computed == sweep.n_chunks - 2
    _same(read_dataset(out), reference)
    _, computed = run_sweep(sweep, out, show_progress=False)
    assert computed == 0  # nothing left to do


def test_killed_process_resumes(reference, tmp_path):
    spec = tmp_path / "small.toml"
    spec.write_text(_toml(SMALL))
    out = tmp_path / "sweep"
    cmd = [sys.executable, "-m", "vtol_impedance.cli", "sweep", str(spec), "--out", str(out), "--quiet", "--no-report"]
    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    deadline = time.time() + 120
    while time.time() < deadline and not list((out / "chunks").glob("chunk-*.parquet")):
        time.sleep(0.05)
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    assert main(["sweep", str(spec), "--out", str(out), "--quiet"]) == 0
    _same(read_dataset(out), reference)
    assert (out / "report.html").exists() and (out / "manifest.json").exists()


def test_a_different_sweep_in_the_same_folder_is_refused(tmp_path):
    out = tmp_path / "sweep"
    small = {**SMALL, "axes": {"payload.mass": [0.1]}, "seeds": 1}
    run_sweep(from_dict(small), out, show_progress=False)
    other = from_dict({**small, "seed": 12})
    with pytest.raises(InputError, match="holds another sweep"):
        run_sweep(other, out, show_progress=False)
    run_sweep(other, out, restart=True, show_progress=False)
    assert json.loads((out / "sweep.json").read_text())["sweep"]["seed"] == 12
    (tmp_path / "foreign").mkdir()
    (tmp_path / "foreign" / "notes.txt").write_text("mine")
    with pytest.raises(InputError, match="no sweep wrote"):
        run_sweep(other, tmp_path / "foreign", show_progress=False)


def test_local_cluster_matches_in_process_and_survives_a_killed_worker(reference, tmp_path):
    pytest.importorskip("dask.distributed")
    out = tmp_path / "dask"
    run_sweep(from_dict(SMALL), out, workers=2, show_progress=False)
    _same(read_dataset(out), reference)

    # kill one worker process as soon as the first chunk is back: the scheduler reruns its work elsewhere
    sweep = from_dict({**SMALL, "chunk": 1})
    folder = SweepFolder(sweep, tmp_path / "killed")
    got = {}
    try:
        with Executor(workers=2) as ex:
            pids = list(ex.client.run(os.getpid).values())
            for i, (k, rows, traces) in enumerate(ex.map_chunks(sweep, list(range(sweep.n_chunks)))):
                folder.write_chunk(k, rows, traces)
                got[k] = rows
                if i == 0:
                    os.kill(pids[0], signal.SIGKILL)
    finally:
        folder.close()
    assert sorted(got) == list(range(sweep.n_chunks))
    _same(read_dataset(tmp_path / "killed"), reference)


# ----------------------------------------------------------------------------- summary and physics


def test_summary_statistics_and_figures(reference, tmp_path):
    out = tmp_path / "sweep"
    run_sweep(from_dict(SMALL), out, show_progress=False)
    files = write_report(out)
    names = {p.name for p in files}
    assert {
        "summary.csv",
        "heatmap.png",
        "compensation.png",
        "against-axis0.png",
        "report.html",
        "manifest.json",
    } <= names
    s = summarise(out)
    cols = {n: np.asarray(reference[n].to_pylist()) for n in reference.column_names}
    for r in s["rows"]:
        sel = (cols["point"] == r["point"]) & (cols["controller"] == r["controller"])
        assert r["n"] == 2
        assert r["mean"] == pytest.approx(np.mean(cols["rms_ep_cm"][sel]))
    from vtol_impedance.io import verify_run_folder

    verify_run_folder(out)


def test_a_text_axis_gets_its_report(tmp_path):
    """An axis of words (the estimator's prototype) is summarised and drawn per word, as a number axis is."""
    spec = dict(SMALL, seeds=1, axes={"control.estimator_prototype": ["zeta", "binomial"]})
    out = tmp_path / "words"
    run_sweep(from_dict(spec), out, show_progress=False)
    assert "report.html" in {p.name for p in write_report(out)}
    s = summarise(out)
    assert {(r["control.estimator_prototype"], r["controller"]) for r in s["rows"]} == {
        (w, c) for w in ("zeta", "binomial") for c in ("pd", "pdc")
    }
    assert all(np.isfinite(r["mean"]) for r in s["rows"])


def test_unfinished_sweep_has_no_report(tmp_path):
    out = tmp_path / "sweep"
    run_sweep(from_dict(SMALL), out, show_progress=False)
    next((out / "chunks").glob("*.parquet")).unlink()
    with pytest.raises(InputError, match="not finished"):
        write_report(out)


def test_pd_sag_along_a_payload_axis_is_the_analytic_one(tmp_path):
    """Through the whole sweep machinery: with ideal effects PD holds a payload m_p with a steady error
    m_p g / Kp (Kp = 16), PD+C with none."""
    masses = [0.0, 0.1, 0.2, 0.3]
    spec = {"name": "sag", "base": "case-a-payload", "controllers": ["pd", "pdc"], "seed": 1,
            "set": {"ideal": True, "trajectory": {"hover_duration": 12.0}, "payload": {"offset_B": [0.0, 0.0, 0.0]}},
            "axes": {"payload.mass": masses}}  # fmt: skip
    run_sweep(from_dict(spec), tmp_path / "sag", show_progress=False)
    t = read_dataset(tmp_path / "sag")
    cols = {n: np.asarray(t[n].to_pylist()) for n in t.column_names}
    for m in masses:
        pd_ = cols["ss_ep_cm"][(cols["payload.mass"] == m) & (cols["controller"] == "pd")][0]
        pdc = cols["ss_ep_cm"][(cols["payload.mass"] == m) & (cols["controller"] == "pdc")][0]
        assert pd_ == pytest.approx(100 * m * 9.81 / 16.0, abs=0.05)
        assert pdc < 0.1


# ----------------------------------------------------------------------------- tuning


def test_optimizer_finds_the_known_optimum_of_a_toy_cost():
    search = [Axis("control.Kp", lo=1.0, hi=100.0, log=True), Axis("control.estimator_wn", lo=1.0, hi=40.0)]

    def cost(p):
        return (math.log(p["control.Kp"] / 16.0)) ** 2 + ((p["control.estimator_wn"] - 10.0) / 10.0) ** 2

    best, value, history = optimize(search, cost, trials=80, seed=3)
    assert len(history) == 80
    assert best["control.Kp"] == pytest.approx(16.0, rel=0.25)
    assert best["control.estimator_wn"] == pytest.approx(10.0, abs=2.5)
    assert value < 0.1
    again, _, _ = optimize(search, cost, trials=80, seed=3)
    assert again == best  # seeded: the same search


def _tuned(tmp_path, head: str, rest: str):
    """The tuning folder of ``tune`` on a case-A tuning of PD+C (``head``: its trials, seed and population;
    ``rest``: its tables), after checking that the command succeeded."""
    spec = tmp_path / "tune.toml"
    spec.write_text(f'name = "t"\nbase = "case-a-payload"\ncontroller = "pdc"\n{head}\n{rest}')
    out = tmp_path / "tune"
    assert main(["tune", str(spec), "--out", str(out), "--quiet"]) == 0
    return out


def test_tune_cli_writes_a_scenario_that_runs(tmp_path, capsys):
    out = _tuned(
        tmp_path, "trials = 3\nseed = 1\npopulation = 2",
        '[set]\ntrajectory.hover_duration = 2.0\n[search]\n"control.Kp" = {min = 8.0, max = 30.0, log = true}\n'
        '[spread]\n"payload.mass" = {min = 0.05, max = 0.2}\n',
    )  # fmt: skip
    best = (out / "best.toml").read_text()
    assert "control.Kp" in best and (out / "trials.csv").read_text().count("\n") == 4
    assert main(["run", str(out / "best.toml"), "--out", str(tmp_path / "run"), "--quiet", "--no-plots"]) == 0
    bad = tmp_path / "bad.toml"
    bad.write_text('name = "t"\nbase = "case-a-payload"\n[search]\n"control.Kp" = {min = -1.0, max = 30.0}\n')
    assert main(["tune", str(bad), "--out", str(tmp_path / "x")]) == 2
    assert "control.Kp" in capsys.readouterr().err


def test_a_combination_no_scenario_takes_is_a_failed_trial_not_a_stop(tmp_path, capsys):
    """Every corner of the box is valid, but a 20 Hz loop with an attitude filter faster than about 63 rad/s
    is not (wn Ts >= pi): such trials fail with the reason recorded, and the search goes on to a best that
    flies (it stopped with exit 2 after flying the first trials, writing nothing)."""
    out = _tuned(
        tmp_path, "trials = 8\nseed = 3\npopulation = 1",
        '[set]\nduration = 1.0\n[search]\n"control.rate" = [20, 500]\n'
        '"control.attitude_filter_wn" = {min = 10.0, max = 100.0}\n',
    )  # fmt: skip
    trials = (out / "trials.csv").read_text()
    assert "invalid: " in trials and "attitude_filter_wn" in trials
    assert (out / "best.toml").exists()
    # on Dask the same error comes back named in a ChunkError: the input's own errors fail the trial, the
    # machine's (a worker out of memory) still stop the tuning
    from vtol_impedance.sweeps.tune import _input_error

    assert _input_error("InputError: attitude_filter_wn * Ts") and _input_error("DesignError: no bandwidth")
    assert not _input_error("MemoryError: ") and not _input_error("KilledWorker: chunk 3")


def test_tuning_population_is_the_same_for_every_trial():
    t = tuning_from_dict({"name": "t", "base": "case-a-payload", "population": 3, "seed": 5,
                          "search": {"control.Kp": {"min": 8.0, "max": 30.0}},
                          "spread": {"payload.mass": {"min": 0.0, "max": 0.3}}})  # fmt: skip
    a = t.trial_sweep({"control.Kp": 10.0})
    b = t.trial_sweep({"control.Kp": 20.0})
    assert a["axes"] == b["axes"] and len(a["axes"]["payload.mass"]) == 3
    assert "control.Kp = 20.0" in best_scenario_toml(t, {"control.Kp": 20.0})
    search = {"control.Kp": {"min": 8.0, "max": 30.0}}
    with pytest.raises(InputError, match=r"\[spread\] 'control.Kp' sets 'control.Kp', which \[search\]"):
        tuning_from_dict({"name": "t", "base": "case-a-payload", "search": search, "spread": search})
    with pytest.raises(InputError, match=r"estimator_order.*a \[search\] range draws real numbers"):
        binomial = {"control": {"estimator_prototype": "binomial"}}
        tuning_from_dict({"name": "t", "base": "case-a-payload", "set": binomial,
                          "search": {"control.estimator_order": {"min": 2, "max": 4}}})  # fmt: skip
    with pytest.raises(InputError, match="one per tuning"):  # once "got [\"['pd', 'pdc']\"]"
        tuning_from_dict({"name": "t", "base": "case-a-payload", "controller": ["pd", "pdc"],
                          "search": {"control.Kp": {"min": 8.0, "max": 30.0}}})  # fmt: skip


def _toml(d: dict, prefix: str = "") -> str:
    lines, tables = [], []
    for k, v in d.items():
        if isinstance(v, dict):
            tables.append((k, v))
        else:
            lines.append(f"{json.dumps(k) if '[' in k or '.' in k else k} = {json.dumps(v)}")
    out = "\n".join(lines) + "\n"
    for k, v in tables:
        out += f"[{prefix}{k}]\n" + _toml(v, f"{prefix}{k}.").replace("\n[", "\n[")
    return out


def test_unreachable_scheduler_fails_before_the_folder_exists(tmp_path, capsys):
    pytest.importorskip("dask.distributed")
    spec = tmp_path / "small.toml"
    spec.write_text(_toml(SMALL))
    out = tmp_path / "s"
    assert main(["sweep", str(spec), "--scheduler", "tcp://127.0.0.1:1", "--out", str(out), "--quiet"]) == 2
    assert "cannot reach the Dask scheduler" in capsys.readouterr().err and not out.exists()


def test_a_chunk_of_another_sweep_or_a_corrupt_one_is_recomputed(reference, tmp_path, capsys):
    """Resuming checks each chunk by its content (the sweep's digest and the chunk index written into the
    file), not by its name: a chunk copied from another sweep, a truncated file and one with the wrong
    rows are moved to rejected/ and computed again, and the dataset is the reference's."""
    out, other = tmp_path / "s", tmp_path / "o"
    run_sweep(from_dict(SMALL), out, show_progress=False)
    run_sweep(from_dict({**SMALL, "seed": 99}), other, show_progress=False)
    chunks = sorted((out / "chunks").glob("*.parquet"))
    (other / "chunks" / chunks[0].name).replace(chunks[0])  # same name, another sweep's rows
    chunks[1].write_bytes(chunks[1].read_bytes()[:100])  # truncated
    _, computed = run_sweep(from_dict(SMALL), out, show_progress=False)
    assert computed == 2
    assert sorted(p.name for p in (out / "rejected").iterdir()) == [chunks[0].name, chunks[1].name]
    _same(read_dataset(out), reference)
    # the report refuses a foreign chunk by content too
    (other / "chunks" / chunks[2].name).replace(chunks[2])
    with pytest.raises(InputError, match="belongs to another sweep"):
        summarise(out)


def test_workers_are_capped_by_the_machine_and_addresses_checked(capsys):
    ex = Executor(100_000)
    assert ex.workers == (os.cpu_count() or 1) and "capped" in ex.note
    for bad in ("not-an-address", "tcp://host:99999", "", "tcp://"):
        with pytest.raises(InputError, match="not a Dask scheduler address"):
            Executor(None, bad)
    with pytest.raises(InputError, match="whole number"):
        Executor(2.5)  # type: ignore[arg-type]


def _tuning(tmp_path, search: str, extra: str = "") -> Path:
    spec = tmp_path / "tune.toml"
    spec.write_text(
        'name = "tune-t"\nbase = "case-a-payload"\ncontroller = "pdc"\ntrials = 3\nseed = 1\npopulation = 1\n'
        f"{extra}[set]\ntrajectory.hover_duration = 1.0\n[search]\n{search}\n"
    )
    return spec


def test_tune_never_writes_a_best_that_failed(tmp_path, capsys, monkeypatch):
    """Every trial's flights fail (the failure detector forced on): no best.toml, a clear error."""
    import vtol_impedance.sweeps.tune as tune_mod

    real = tune_mod.trial_cost
    monkeypatch.setattr(tune_mod, "trial_cost",
                        lambda t, rows: real(t, {**rows, "diverged": [True] * len(rows["diverged"])}))  # fmt: skip
    out = tmp_path / "o"
    assert main(["tune", str(_tuning(tmp_path, '"control.Kp" = {min = 8.0, max = 30.0}')), "--out", str(out),
                 "--quiet"]) == 2  # fmt: skip
    assert "no best.toml is written" in capsys.readouterr().err and not out.exists()


def test_tune_names_its_folder_once_and_says_when_the_best_sits_on_a_bound(tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    spec = _tuning(tmp_path, '"control.Kp" = {min = 30.0, max = 31.0}\n"control.estimator_prototype" = ["zeta"]')
    assert main(["tune", str(spec), "--quiet"]) == 0
    assert (tmp_path / "results" / "tune-t" / "best.toml").is_file()  # not results/tune-tune-t
    err = capsys.readouterr().err
    assert "sits on the search range" in err or "control.Kp" not in err
    bad = _tuning(tmp_path, '"control.estimator_prototype" = ["zeta", "bogus"]')
    assert main(["tune", str(bad), "--quiet", "--out", str(tmp_path / "b")]) == 2
    assert "bogus" in capsys.readouterr().err and not (tmp_path / "b").exists()


def test_tune_counts_gains_without_a_robust_design_as_failed_trials(tmp_path):
    """D_p above what any attitude bandwidth keeps stable (20 ms latency, the Pelican: about 29 N s/m) is a
    property of the trial, not bad input: the study runs on, those trials cost the failure penalty and say
    why, and a designable trial wins."""
    from vtol_impedance.sweeps.tune import tune, tuning_from_dict

    t = tuning_from_dict({"name": "t", "base": "case-a-payload", "controller": "pdc", "trials": 4, "seed": 2,
                          "population": 1, "set": {"duration": 2.0, "trajectory.hover_duration": 1.0},
                          "search": {"control.Dp": [60.0, 12.0]},
                          "cost": {"failure_penalty": 777.0}})  # fmt: skip
    res = tune(t)
    by_dp = {r["control.Dp"]: r for r in res["trials"]}
    assert set(by_dp) == {60.0, 12.0}
    assert by_dp[60.0]["cost"] == 777.0 and "Dp must come down" in by_dp[60.0]["no_design"]
    assert by_dp[12.0]["no_design"] == "" and by_dp[12.0]["cost"] < 777.0
    assert res["best"]["control.Dp"] == 12.0


def test_axis_grids_draws_and_unit_seeds_follow_their_definitions():
    """A log grid from 1 to 100 in three is 1, 10, 100 (linear: 0, 0.5, 1); log draws have the geometric
    median sqrt(lo hi), linear ones the mean (lo + hi) / 2; a unit's seed depends on the sweep seed and its
    own indices only, so adding points or repeats never changes another unit's noise."""
    from vtol_impedance.sweeps.spec import _axis, unit_seed

    assert _axis("control.Kp", {"min": 1.0, "max": 100.0, "n": 3, "log": True}, "grid").grid() == pytest.approx(
        [1.0, 10.0, 100.0]
    )
    assert _axis("control.Kp", {"min": 0.0, "max": 1.0, "n": 3}, "grid").grid() == pytest.approx([0.0, 0.5, 1.0])
    rng = np.random.default_rng(0)
    logs = [_axis("control.Kp", {"min": 1.0, "max": 100.0, "log": True}, "random").draw(rng) for _ in range(4000)]
    lins = [_axis("control.Kp", {"min": 1.0, "max": 100.0}, "random").draw(rng) for _ in range(4000)]
    assert np.median(logs) == pytest.approx(10.0, rel=0.1) and min(logs) >= 1.0 and max(logs) <= 100.0
    assert np.mean(lins) == pytest.approx(50.5, rel=0.03)
    seeds = {(p, r): unit_seed(11, p, r) for p in range(4) for r in range(3)}
    assert len(set(seeds.values())) == 12 and all(0 <= s < 2**63 for s in seeds.values())
    assert all(unit_seed(11, p, r) == s for (p, r), s in seeds.items())  # no hidden state
    assert unit_seed(12, 0, 0) != seeds[0, 0]
    small = from_dict({**SMALL, "seeds": 1})
    big = from_dict({**SMALL, "seeds": 2, "axes": {**SMALL["axes"], "payload.mass": [0.05, 0.15, 0.25]}})
    assert [u.seed for u in small.units if u.repeat == 0][:2] == [u.seed for u in big.units if u.repeat == 0][:2]


def test_a_trials_cost_from_hand_rows():
    """Cost = mean over the population of (metric + saturation weight x saturation %) for members that flew,
    the failure penalty for those that did not, plus the margin penalty for members short of the phase
    margin; a best value at either end of its range gets a note, one inside none."""
    from vtol_impedance.sweeps.tune import bound_notes, trial_cost

    base = {"name": "t", "base": "case-a-payload", "search": {"control.Kp": {"min": 8.0, "max": 30.0}}}
    t = tuning_from_dict({**base, "cost": {"saturation_weight": 0.1, "failure_penalty": 1000.0}})
    rows = {"rms_ep_cm": [2.0, 4.0, 1.0], "sat_pct": [10.0, 0.0, 0.0], "diverged": [False, False, True]}
    cost, parts = trial_cost(t, rows)
    assert cost == pytest.approx((3.0 + 4.0 + 1000.0) / 3) and parts == {"metric_mean": 3.0, "failed": 1}
    tm = tuning_from_dict({**base, "cost": {"min_phase_margin_deg": 30.0, "margin_penalty": 100.0}})
    rows.update(margin_stable=[1.0, 1.0, 0.0], pm_min_deg=[40.0, 20.0, 50.0], diverged=[False, False, False])
    cost, parts = trial_cost(tm, rows)
    assert cost == pytest.approx((2.0 + 104.0 + 101.0) / 3) and parts["below_margin"] == 2
    assert bound_notes(t, {"control.Kp": 30.0}) and bound_notes(t, {"control.Kp": 8.0})
    assert not bound_notes(t, {"control.Kp": 19.0})


def test_kept_traces_hold_the_force_the_model_misses_and_rows_count_repeats(tmp_path):
    """A sweep keeping every 10th sample: in case A's hover the "true" force is the one the nominal model
    misses, the payload's weight (0.110 kg x g, +z in NED; the explicit external force is zero there), and
    the estimate follows it; the flight rows number each point's repeats 0..seeds-1."""
    import pyarrow.parquet as pq

    spec = {**SMALL, "controllers": ["pdc"], "seeds": 2, "traces": 10, "set": {"trajectory": {"hover_duration": 4.0}},
            "axes": {"payload.mass": [0.11, 0.2]}}  # fmt: skip
    out = tmp_path / "sweep"
    run_sweep(from_dict(spec), out, show_progress=False)
    rows = read_dataset(out).to_pydict()
    assert rows["repeat"] == [0, 1, 0, 1] and rows["point"] == [0, 0, 1, 1]
    tr = pq.read_table(sorted((out / "traces").glob("*.parquet"))).to_pydict()
    t, unit = np.asarray(tr["t_s"]), np.asarray(tr["unit"])
    assert np.allclose(np.diff(t[unit == 0]), 0.1)  # every 10th 100 Hz tick
    hover = (t > 6.5) & (unit == 0)  # after the take-off (1 + 4 s) has settled
    assert np.mean(np.asarray(tr["fz_true_N"])[hover]) == pytest.approx(0.110 * 9.81, rel=0.05)
    assert np.mean(np.asarray(tr["fz_hat_N"])[hover]) == pytest.approx(0.110 * 9.81, rel=0.1)
    heavy = (t > 6.5) & (unit == 2)
    assert np.mean(np.asarray(tr["fz_true_N"])[heavy]) == pytest.approx(0.2 * 9.81, rel=0.05)


def test_the_resume_command_repeats_what_resuming_needs_and_never_restart():
    from vtol_impedance.cli.main import build_parser
    from vtol_impedance.cli.sweep import resume_command

    args = build_parser().parse_args(
        ["sweep", "my sweep.toml", "--scheduler", "tcp://h:8786", "--restart", "--yes", "--backend", "numpy"]
    )
    cmd = resume_command(args, Path("out dir"))
    assert cmd == "vtol-impedance sweep 'my sweep.toml' --out 'out dir' --scheduler tcp://h:8786 --backend numpy --yes"


def test_the_cluster_flags_help_names_the_true_defaults():
    from vtol_impedance.cli.main import build_parser
    from vtol_impedance.sweeps.cluster import CONNECT_TIMEOUT_S, WAIT_WORKERS_S

    sub = next(a for a in build_parser()._actions if a.dest == "command").choices["sweep"]
    helps = {a.dest: a.help for a in sub._actions}
    assert f"(default {CONNECT_TIMEOUT_S:g})" in helps["connect_timeout"]
    assert f"(default {WAIT_WORKERS_S:g})" in helps["wait_workers"]


def test_two_entries_of_one_vector_are_two_values():
    """Distinct entries of one vector are distinct values (only a vector and its own entries overlap), and an
    axis over one entry of a vector that [set] gives whole varies that entry (built-in payload-vs-offset)."""
    sw = from_dict({**SMALL, "axes": {"payload.offset_B[0]": [0.0, 0.02], "payload.offset_B[1]": [0.01]}},
                   check_points=False)  # fmt: skip
    assert len(sw.points) == 2
    sw = from_dict({**SMALL, "set": {"payload.offset_B": [0.0, 0.0, 0.03]}, "axes": {"payload.offset_B[0]": [0.02]}},
                   check_points=False)  # fmt: skip
    assert sw.point_spec(0).payload.offset_B == (0.02, 0.0, 0.03)
