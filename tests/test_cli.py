"""The command-line interface end to end on shortened scenarios, including its errors."""

import json
import shutil
import subprocess
import sys

import pytest

from vtol_impedance.cli import main
from vtol_impedance.scenarios.spec import PAPER_CONTROL
from vtol_impedance.sim import Result


def test_help_and_list(capsys):
    with pytest.raises(SystemExit) as e:
        main(["--help"])
    assert e.value.code == 0
    assert "paper" in capsys.readouterr().out
    assert main(["list"]) == 0
    out = capsys.readouterr().out
    assert "case-a-payload-v1" in out and "pdc" in out


# the paper command end to end (its files, terminal output and report): tests/test_first_hour.py


def test_run_and_compare_with_overrides(tmp_path, capsys):
    out = tmp_path / "r"
    assert (
        main(
            [
                "run",
                "case-a-payload",
                "--controller",
                "pd",
                "--duration",
                "0.5",
                "--no-plots",
                "--quiet",
                "--out",
                str(out),
                "--set",
                "payload.mass=0.2",
                "--seed",
                "3",
            ]
        )
        == 0
    )
    r = Result.load(out / "case-a-payload-v1.npz")
    assert r.labels == ["pd"] and r.config["seed"] == 3
    assert r.config["scenario"]["payload"]["mass"] == 0.2
    assert (
        main(
            [
                "compare",
                "yaw-step",
                "--controllers",
                "pd,pdc",
                "--duration",
                "0.3",
                "--no-plots",
                "--quiet",
                "--out",
                str(out),
                "--ideal",
            ]
        )
        == 0
    )
    assert Result.load(out / "yaw-step-v1.npz").labels == ["pd", "pdc"]


def test_scenario_file(tmp_path):
    f = tmp_path / "mine.toml"
    f.write_text('base = "case-a-payload"\nname = "mine-v1"\nduration = 0.3\n[payload]\nmass = 0.3\n')
    assert main(["run", str(f), "--no-plots", "--quiet", "--out", str(tmp_path / "r")]) == 0
    assert Result.load(tmp_path / "r" / "mine-v1.npz").config["scenario"]["payload"]["mass"] == 0.3


@pytest.mark.parametrize(
    "argv,msg",
    [
        (["run", "case-z"], "valid scenarios: case-a-payload"),
        (["run", "case-a-payload", "--set", "payload.weight=1"], "payload.weight"),
        (["run", "case-a-payload", "--set", "control.estimator_wn=400"], "estimator bandwidth"),
        (["run", "case-a-payload", "--set", "payload.mass=nan"], "finite"),
        (["run", "/no/such/file.toml"], "cannot read"),
    ],
)
def test_errors_are_clear(argv, msg, capsys, tmp_path):
    assert main(argv + ["--out", str(tmp_path), "--quiet", "--duration", "0.1"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error:") and msg in err


def test_slow_control_rate_warns_about_the_estimator(tmp_path, capsys):
    argv = [
        "run",
        "case-a-payload",
        "--set",
        "control.rate=10",
        "--set",
        "plant_rate=1000",
        "--duration",
        "0.5",
        *(f"--set={k}={json.dumps(v)}" for k, v in PAPER_CONTROL.items()),
    ]  # bandwidths by hand: no design
    assert main(argv + ["--no-plots", "--quiet", "--out", str(tmp_path)]) == 0
    err = capsys.readouterr().err  # the CLI prints warnings as one line each, once
    assert "warning: estimator |p| * Ts" in err and err.count("warning: estimator") == 1


def test_console_script_is_installed():
    exe = shutil.which("vtol-impedance")
    cmd = [exe] if exe else [sys.executable, "-m", "vtol_impedance"]
    p = subprocess.run(cmd + ["list"], capture_output=True, text=True, timeout=60)
    assert p.returncode == 0 and "case-b-fan-v1" in p.stdout
