"""Examples run as tests; the CI script runs the README's test command."""

import runpy
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]


def test_controller_in_your_loop_example():
    mod = runpy.run_path(str(ROOT / "examples" / "controller_in_your_loop.py"))
    f_hat = mod["main"](3.0)  # the estimate settles in ~0.5 s (10 rad/s): 3 s of this Python loop suffice
    assert f_hat[2] == pytest.approx(0.110 * 9.81, rel=1e-3)  # 1e-4 at 3 s; the estimator's bias would show
    np.testing.assert_allclose(f_hat[:2], 0.0, atol=1e-3)


def test_ci_runs_the_readme_test_command():
    readme = (ROOT / "README.md").read_text()
    ci = (ROOT / ".ci" / "run").read_text()
    cmd = 'python3 -m venv .venv && .venv/bin/pip install ".[test]" && .venv/bin/python -m pytest'
    assert cmd in readme and cmd in ci


def test_attitude_filter_measurement_example_runs():
    mod = runpy.run_path(str(ROOT / "examples" / "attitude_filter_bandwidth.py"))
    rows = mod["measure"](bandwidths=(20.0,), cases=("case-c-circle",), seeds=(0,))
    assert rows[0]["rms_ep_cm"] < 2.0 and rows[0]["limited_pct"] == 0.0


def test_estimate_from_a_log_example(tmp_path):
    """A simulated flight logged the ROS way (ENU, FLU, xyzw, degrees, normalised thrust) and read back:
    the estimate is the in-flight one and follows the simulator's true wrench through G(s)."""
    mod = runpy.run_path(str(ROOT / "examples" / "estimate_from_a_log.py"))
    out = mod["run"](tmp_path, duration=12.0)
    late = out["t"] > 1.0
    np.testing.assert_allclose(out["f_est"][late], out["f_flight"][late], atol=0.02)
    steady = out["t"] > 5.0  # the payload's weight and the fan's mean push, after G has settled
    np.testing.assert_allclose(out["f_est"][steady].mean(0), out["f_true"][steady].mean(0), atol=0.02)
