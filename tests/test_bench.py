"""The benchmark command runs and reports; it asserts no timing (speed is measured, not tested)."""

import json

from vtol_impedance.bench import run, table


def test_quick_bench_writes_a_complete_report(tmp_path):
    out = tmp_path / "bench.json"
    res = run(out, quick=True, log=lambda m: None, compile_times=False)
    saved = json.loads(out.read_text())
    assert saved["batched"] == res["batched"]
    assert [b["n"] for b in saved["batched"]] == [1, 10]
    assert all(b["failed"] == 0 and b["veh_s_per_s"] > 0 and b["peak_rss_mb"] > 0 for b in saved["batched"])
    for key in ("single_compiled", "single_numpy", "single_mujoco"):
        assert saved[key]["real_time_factor"] > 0
    lat = saved["latency"]
    assert 0 < lat["step_arrays_median_us"] <= lat["step_arrays_p99_us"]
    text = table(saved)
    assert "NumPy ref." in text and "batched N = 10" in text and "RotorPy" in text and "MuJoCo plant" in text
