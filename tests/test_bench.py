"""The benchmark command runs and reports; it asserts no timing (speed is measured, not tested)."""

import json
from pathlib import Path

import pytest

from vtol_impedance.bench import table
from vtol_impedance.cli import main


def test_quick_bench_writes_a_complete_report(tmp_path, capsys, monkeypatch):
    """``bench --quick --quiet``: no cold compile, the table (and only the table) printed, the JSON written.
    The sweep on a 2-worker LocalCluster is the in-process sweep's code with ``workers=2``: asked for, it is
    left to tests/test_sweeps.py, which runs that cluster (two worker processes cost ~10 s on two cores);
    the in-process sweep runs and must have flown (a failed sweep is reported as text, not raised)."""
    import vtol_impedance.bench as bench

    real_sweep, asked = bench._sweep, []

    def sweep(workers, quick):
        asked.append(workers)
        return real_sweep(workers, quick) if workers is None else "left out by tests/test_bench.py"

    monkeypatch.setattr(bench, "_sweep", sweep)
    out = tmp_path / "bench.json"
    assert main(["bench", "--quick", "--quiet", "--out", str(out)]) == 0
    printed = capsys.readouterr()
    assert printed.err == "" and "single vehicle, case C realistic, compiled" in printed.out
    assert "not measured (--quick)" in printed.out
    saved = json.loads(out.read_text())
    assert saved["compile_first_s"] is None
    assert [b["n"] for b in saved["batched"]] == [1, 10]
    assert all(b["failed"] == 0 and b["veh_s_per_s"] > 0 and b["peak_rss_mb"] > 0 for b in saved["batched"])
    for key in ("single_compiled", "single_numpy", "single_mujoco", "batch_mujoco", "free_flight_mujoco"):
        assert saved[key]["real_time_factor"] > 0
    assert saved["batch_mujoco"]["vehicles"] == 2
    assert asked == [None, 2]
    assert saved["sweep_in_process"]["flights"] == 2 * 2 * 2  # rates x estimator bandwidths x controllers
    lat = saved["latency"]
    assert 0 < lat["step_arrays_median_us"] <= lat["step_arrays_p99_us"]
    assert 0 < lat["step_arrays_call_median_us"]  # the call into a kernel that does nothing
    text = table(saved)
    assert "NumPy ref." in text and "batched N = 10" in text and "RotorPy" in text and "MuJoCo plant" in text
    assert "2 vehicles on MuJoCo (threads), per vehicle" in text and "MuJoCo, free flight" in text
    assert "sweep flights/s, in this process" in text


def test_a_bad_report_path_or_yardstick_is_refused_before_measuring(tmp_path, capsys, monkeypatch):
    """Both were once found only after minutes of measuring: the measurements must not start."""
    import vtol_impedance.bench as bench

    def measured(*a, **k):
        raise AssertionError("measuring started")

    monkeypatch.setattr(bench, "_child", measured)
    (tmp_path / "file").write_text("x")
    for args, message in (
        (["--out", str(tmp_path)], "not a file"),
        (["--out", str(tmp_path / "file" / "b.json")], "is not a folder"),
        (["--out", str(tmp_path / "b.json"), "--yardstick", str(tmp_path / "nope.py")], "no file"),
        (["--out", str(tmp_path / "b.json"), "--yardstick", str(tmp_path / "file")], "not the yardstick"),
    ):
        assert main(["bench", "--quick", "--quiet", *args]) == 2
        assert message in capsys.readouterr().err


def test_live_accuracy_statistics_are_the_mean_and_the_p95_of_the_error(tmp_path, capsys):
    """``bench --live``'s numbers on a hand-made series: an estimate of a 1 N downward force that reads
    1.02 N with one sample in twenty at 1.30 N, and x alternating +-0.01 N; what came before ``t_from`` is
    left out. Its bad options are refused before anything flies."""
    import numpy as np

    from vtol_impedance.bench import _wrench_stats

    t = np.arange(200) * 0.02
    f = np.zeros((200, 3))
    f[:, 0] = np.where(np.arange(200) % 2 == 0, 0.01, -0.01)
    f[:, 2] = np.where(np.arange(200) % 20 == 0, 1.30, 1.02)
    f[:100] = 50.0  # the settling: left out
    s = _wrench_stats(t, f, np.array([0.0, 0.0, 1.0]), t_from=2.0)
    assert s["samples"] == 100
    np.testing.assert_allclose(s["mean_error_N"], [0.0, 0.0, 0.95 * 0.02 + 0.05 * 0.30], atol=1e-12)
    # 95 of the 100 z errors are 0.02, five are 0.30: the 95th percentile lies between them
    assert 0.02 <= s["p95_abs_error_N"][2] <= 0.30 and s["p95_abs_error_N"][0] == 0.01
    for args, message in ((["--live", "--quick"], "not with --live"), (["--live-seconds", "30"], "with --live only"),
                          (["--live", "--live-seconds", "1"], "--live-seconds")):  # fmt: skip
        assert main(["bench", "--quiet", "--out", str(tmp_path / "b.json"), *args]) == 2
        assert message in capsys.readouterr().err


def test_the_realistic_limit_says_why_it_was_skipped(tmp_path, monkeypatch):
    """Without the C plant, without a compiler, or with a file that does not build: a reason in the report,
    never a traceback after minutes of measuring. With both there (the project's machine), a small batch is
    measured against it and the ratio is the quotient of the two speeds."""
    import shutil

    import vtol_impedance.bench as bench

    assert bench._realistic_limit(tmp_path, 40, 0.1, 1, log=lambda m: None).startswith("skipped: no ")
    (tmp_path / "plant_soa.c").write_text("this is not C\n")
    if shutil.which("gcc") or shutil.which("cc"):
        why = bench._realistic_limit(tmp_path, 40, 0.1, 1, log=lambda m: None)
        assert why.startswith("skipped: ") and "did not build" in why
    monkeypatch.setattr(shutil, "which", lambda name: None)
    assert "no C compiler" in bench._realistic_limit(tmp_path, 40, 0.1, 1, log=lambda m: None)
    monkeypatch.undo()
    text = bench.table(_minimal_report())
    assert "realistic-plant limit" in text and "skipped: --quick" in text
    c_plant = Path(__file__).resolve().parents[1] / bench.REALISTIC_DIR
    if (c_plant / "plant_soa.c").is_file() and (shutil.which("gcc") or shutil.which("cc")):
        r = bench._realistic_limit(c_plant, 64, 0.2, 1, log=lambda m: None)
        assert isinstance(r, dict), r
        assert r["limit_veh_s_per_s"] > 0 and r["project_veh_s_per_s"] > 0
        assert r["ratio"] == r["project_veh_s_per_s"] / r["limit_veh_s_per_s"]
        (one,) = r["rounds"]  # one round: its pair is the bests, and the median its ratio
        assert one == {"limit_veh_s_per_s": r["limit_veh_s_per_s"], "project_veh_s_per_s": r["project_veh_s_per_s"]}
        assert r["ratio_median"] == pytest.approx(r["ratio"], rel=1e-12)
        slow = {**one, "limit_veh_s_per_s": 2 * one["limit_veh_s_per_s"]}  # a second round: half the ratio
        text = bench.table({**_minimal_report(), "realistic_limit": {**r, "rounds": [one, slow]}})
        assert f"median {r['ratio_median']:.2f}): {r['ratio']:.2f}, {r['ratio'] / 2:.2f}" in text
        assert "batch 64 x 0.2 s, 2 threads / C plant alone" in bench.table({**_minimal_report(), "realistic_limit": r})


def _minimal_report():
    return {"single_compiled": {"real_time_factor": 1.0}, "single_numpy": {"real_time_factor": 1.0},
            "latency": {"step_arrays_median_us": 1.0, "step_arrays_p99_us": 2.0, "step_median_us": 3.0},
            "compile_first_s": None, "batched": [], "rotorpy": "not installed",
            "realistic_limit": "skipped: --quick (give --realistic DIR to measure it)"}  # fmt: skip
