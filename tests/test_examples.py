"""Examples run as tests; the CI script runs the README's test command."""

import runpy
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]


def test_controller_in_your_loop_example():
    mod = runpy.run_path(str(ROOT / "examples" / "controller_in_your_loop.py"))
    f_hat = mod["main"](6.0)
    assert f_hat[2] == pytest.approx(0.110 * 9.81, rel=0.01)
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
