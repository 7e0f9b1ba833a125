"""A user's own inputs: every bad value refused before work with its name, results that never mix, the
controller API for a user's own loop, and the silent wrong answers of the past (each a regression test)."""

import json
import os
import re
import signal
import subprocess
import sys
import time
import tracemalloc
import warnings

import numpy as np
import procs
import pytest

from vtol_impedance import Controller, ControllerWarning
from vtol_impedance.cli import main
from vtol_impedance.control import ControllerParams, Impedance, ImpedanceGains, Measurement, Reference
from vtol_impedance.control.reference import Hold, Trajectory
from vtol_impedance.errors import InputError, SingularityError
from vtol_impedance.io import RunFolder, verify_run_folder
from vtol_impedance.model import load_preset
from vtol_impedance.scenarios import get, load_toml, set_value, simulate
from vtol_impedance.sim import PlantParams, SensorParams, run_closed_loop
from vtol_impedance.sim.loop import Limits

ENV = {**os.environ, "PYTHONUNBUFFERED": "1"}

# --------------------------------------------------------------------------- the command line


@pytest.mark.parametrize(
    "argv,msg",
    [
        (["--duration", "0"], "--duration must be a positive"),
        (["--duration", "-5"], "--duration must be a positive"),
        (["--duration", "nan"], "--duration must be a positive"),
        (["--duration", "0.004"], "shorter than one control period"),
        (["--set", "duration=-1"], "duration must be in"),
        (["--set", "trajectory.altitude=-1"], "trajectory.altitude must be in"),
        (["--set", "control.rate=0"], "control.rate must be in"),
        (["--set", "control.rate=300"], "whole multiple of control.rate"),
        (["--set", "plant_rate=150"], "whole multiple"),
        (["--seed", "-1"], "--seed must be"),
        (["--set", "seed=-3"], "seed must be in"),
        (["--set", "name=../../escape-v1"], "scenario name"),
        (["--set", "name=a/b"], "scenario name"),
        (["--set", 'payload.offset_B="abc"'], "payload.offset_B expects 3 values"),
        (["--set", "payload.offset_B=[1,2]"], "payload.offset_B expects 3 values"),
        (["--set", "payload.mass=true"], "payload.mass expects a number"),
        (["--set", "control.Kp=[[16,1,0],[0,16,0],[0,0,16]]"], "diagonal"),
        (["--set", "control.Kp=[[16,0,0],[0,16,0],[0,0,true]]"], "control.Kp must be finite numbers"),  # not 1
        (["--set", "payload.mass=100000000000000000000000"], "payload.mass must be in"),  # 2**64 and over
        (["--set", "payload.mass=" + "9" * 400], "payload.mass must be a finite number"),  # beyond any float
        (["--set", "payload.offset_B.0=0.1"], "payload.offset_B is a value, not a section; set one entry"),
        (["--set", "interaction.switches.0.t=1"], "give the whole list"),
        (["--set", "payload.mass=0.1", "--set", "payload.mass=0.2"], "--set payload.mass given more than once"),
        (["--set", "payload.offset_B[0]=0.1", "--set", "payload.offset_B=[0,0,0]"],
         "--set payload.offset_B[0] and payload.offset_B given more than once"),
        (["--set", "foo", "--set", "foo"], "--set expects key=value"),
        (["--set", "control.Kp=-1"], "control.Kp must be in"),
        (["--set", "control.estimator_order=2.5"], "integer"),
        (["--set", 'control.estimator_prototype="bessel"'], "prototype"),
        (["--set", "control.tilt_max_deg=95"], "tilt_max_deg"),
        (["--set", "sensors.mocap_delay=100"], "sensors.mocap_delay must be in"),
        (["--set", 'vehicle="mavic"'], "unknown vehicle preset"),
        (["--set", "vehicle=3"], "vehicle expects"),
        (["--set", "duration=1e6"], "GB of memory"),
        (["--set", 'disturbances.0.kind="fan"'], "no disturbances"),
        (["--set", 'trajectory.kind="spiral"'], "trajectory.kind"),
        (["--controller", "lqr"], "invalid choice"),
    ],
)
def test_cli_refuses_bad_values_with_their_name(argv, msg, capsys, tmp_path):
    args = ["run", "case-a-payload", "--quiet", "--no-plots", "--out", str(tmp_path / "o")]
    if "--duration" not in argv and "duration=" not in " ".join(argv):
        args += ["--duration", "0.3"]
    try:
        rc = main(args + argv)
    except SystemExit as e:  # argparse's own usage errors
        rc = e.code
    assert rc == 2
    err = capsys.readouterr().err
    assert msg in err, err
    assert "Traceback" not in err
    assert not (tmp_path / "o").exists()  # refused before anything was written


@pytest.mark.parametrize(
    "toml,msg",
    [
        ('base = "case-a-payload"\nname = 3\n', "scenario name"),
        ('base = "case-a-payload"\nname = "x-v1"\n[control]\nKp = "abc"\n', "control.Kp expects a number"),
        ('base = "case-a-payload"\nname = "x-v1"\n[payload]\noffset_B = "left"\n', "payload.offset_B"),
        ('base = "case-a-payload"\nname = "x-v1"\n[[disturbances]]\nkind = "push"\nt_on = "now"\n', "t_on"),
        ('base = "case-a-payload"\nname = "x-v1"\n[[disturbances]]\nkind = "laser"\n', "unknown disturbance kind"),
        ('base = "case-a-payload"\nname = "x-v1"\ntrajectory = 5\n', "trajectory is a section"),
        ('base = "case-a-payload"\nname = "x-v1"\n[trajectory]\nwobble = 1\n', "unknown key"),
        ('base = "case-a-payload"\nname = "x-v1"\ndisturbances = [1, 2]\n', "disturbances must be"),
        ("base = 7\n", "unknown scenario"),
        ("name = [\n", "cannot read scenario file"),
        ('base = "case-a-payload"\nname = "x-v1"\n[interaction]\nswitches = [[1' + "0" * 400 + ', "x", "comply"]]\n',
         "switch time must be a finite number"),  # fmt: skip
        ('base = "case-a-payload"\nname = "x-v1"\n[payload]\nmass = 1' + "0" * 400 + "\n", "finite number"),
        ('base = "case-a-payload"\nname = "x-v1"\n[payload]\nmass = {}\n', "payload.mass is given an empty table"),
    ],
)
def test_scenario_files_of_the_wrong_type_are_refused(toml, msg, tmp_path, capsys):
    f = tmp_path / "s.toml"
    f.write_text(toml)
    assert main(["run", str(f), "--quiet", "--no-plots", "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err
    assert msg in err and "Traceback" not in err


def test_a_scenario_file_with_a_byte_order_mark_is_read(tmp_path, capsys):
    """Windows editors start a UTF-8 file with a byte-order mark; it is not TOML text, and was refused as
    "Invalid statement (at line 1, column 1)"."""
    f = tmp_path / "bom.toml"
    f.write_bytes(b"\xef\xbb\xbf" + b'base = "case-a-payload"\nname = "bom-v1"\nduration = 0.1\n')
    assert main(["run", str(f), "--quiet", "--no-plots", "--out", str(tmp_path / "o")]) == 0


def test_output_location_is_checked_before_the_work(tmp_path, capsys):
    (tmp_path / "file").write_text("x")
    not_a_folder = "is a file (or a device), not a folder"
    for out, msg in ((tmp_path / "file", not_a_folder), (tmp_path / "file" / "sub", "in its path")):
        t0 = time.perf_counter()
        assert main(["run", "case-a-payload", "--quiet", "--out", str(out)]) == 2
        assert msg in capsys.readouterr().err
        assert time.perf_counter() - t0 < 5.0  # refused up front, not after the 30 s flight
    (tmp_path / "mine").mkdir()
    (tmp_path / "mine" / "thesis.tex").write_text("precious")
    assert main(["run", "case-a-payload", "--quiet", "--duration", "0.2", "--out", str(tmp_path / "mine")]) == 2
    assert "no vtol-impedance run wrote" in capsys.readouterr().err
    assert (tmp_path / "mine" / "thesis.tex").read_text() == "precious"
    # a manifest.json this tool did not write does not make a folder a run of it
    for text in ("garbage", "{}", "[1, 2]", '{"tool": "other", "files": {}}'):
        (tmp_path / "mine" / "manifest.json").write_text(text)
        assert main(["run", "case-a-payload", "--quiet", "--duration", "0.2", "--out", str(tmp_path / "mine")]) == 2
        assert "is not a vtol-impedance run folder" in capsys.readouterr().err
        assert (tmp_path / "mine" / "thesis.tex").read_text() == "precious"
    # a run's folder is replaced by the next run, unless a file was added to it since
    run = ["run", "case-a-payload", "--quiet", "--no-plots", "--duration", "0.2", "--out", str(tmp_path / "run")]
    assert main(run) == 0 and main(run) == 0
    assert not (tmp_path / ".run.lock").exists()  # the lock goes with the run
    (tmp_path / "run" / "notes.txt").write_text("mine")
    assert main(run) == 2
    assert "files its run did not write: ['notes.txt']" in capsys.readouterr().err
    assert (tmp_path / "run" / "notes.txt").read_text() == "mine"
    # a mount point cannot be swapped as a whole: refused before the flight, not after it
    t0 = time.perf_counter()
    assert main(["run", "case-a-payload", "--quiet", "--out", "/proc"]) == 2
    assert "is a mount point" in capsys.readouterr().err and time.perf_counter() - t0 < 5.0


def test_full_disk_is_an_error_not_a_traceback(tmp_path, capsys, monkeypatch):
    import vtol_impedance.analysis.report  # noqa: F401  (imported before io is patched, so it keeps the real one)
    import vtol_impedance.io as vio

    def boom(*a, **k):
        raise OSError(28, "No space left on device", str(tmp_path / "o"))

    monkeypatch.setattr(vio, "write_text", boom)
    monkeypatch.setattr("vtol_impedance.analysis.report.write_text", boom)
    rc = main(["run", "case-a-payload", "--quiet", "--no-plots", "--duration", "0.2", "--out", str(tmp_path / "o")])
    err = capsys.readouterr().err
    assert rc == 1 and "No space left on device" in err and "Traceback" not in err
    assert not (tmp_path / "o").exists()
    assert not list(tmp_path.glob(".o.staging-*"))


# --------------------------------------------------------------------------- run folders


def _cli(*args: str) -> list[str]:
    return [sys.executable, "-m", "vtol_impedance", *args]


def test_a_rerun_killed_at_any_instant_leaves_one_complete_run(tmp_path):
    out = tmp_path / "res"
    first = subprocess.run(
        _cli("run", "case-a-payload", "--duration", "1", "--quiet", "--out", str(out)), env=ENV, timeout=300
    )
    assert first.returncode == 0
    before = verify_run_folder(out)
    seen_new = False
    for delay in (0.3, 0.8, 1.3, 1.8, 2.4, 3.0, 4.0):
        p = subprocess.Popen(
            _cli("run", "case-a-payload", "--duration", "1", "--seed", "7", "--quiet", "--out", str(out)), env=ENV
        )
        time.sleep(delay)
        p.send_signal(signal.SIGKILL)
        p.wait()
        m = verify_run_folder(out)  # whatever the instant: exactly the files of one complete run
        assert m["seed"] in (before["seed"], [7])
        seen_new |= m["seed"] == [7]
    # a later run cleans what the killed ones left
    assert (
        subprocess.run(
            _cli("run", "case-a-payload", "--duration", "0.5", "--quiet", "--no-plots", "--out", str(out)),
            env=ENV,
            timeout=300,
        ).returncode
        == 0
    )
    verify_run_folder(out)
    assert not [p for p in tmp_path.iterdir() if ".staging-" in p.name or ".old-" in p.name]


def test_a_run_killed_between_the_fallbacks_renames_gets_its_previous_run_back(tmp_path):
    """Where the atomic exchange is missing, the previous run is renamed aside before the new one is
    renamed in; killed in between, the next run puts back the complete one renamed aside (not a
    half-removed leftover of an earlier fallback) and clears the rest."""
    out = tmp_path / "res"
    assert main(["run", "case-a-payload", "--quiet", "--no-plots", "--duration", "0.2", "--out", str(out)]) == 0
    good = verify_run_folder(out)
    leftover = tmp_path / ".res.old-zzzz"  # sorts last, holds no manifest: a partly removed old run
    leftover.mkdir()
    (leftover / "metrics.csv").write_text("half gone")
    os.rename(out, tmp_path / ".res.old-aaaa")  # the kill: the previous run aside, no new one yet
    with RunFolder(out):
        assert verify_run_folder(out) == good
    assert not [p for p in tmp_path.iterdir() if ".old-" in p.name or ".staging-" in p.name]


def test_concurrent_runs_into_one_folder_never_interleave(tmp_path):
    out = tmp_path / "res"
    with RunFolder(out):  # a run in progress holds the folder
        p = subprocess.run(
            _cli("run", "case-a-payload", "--duration", "0.2", "--quiet", "--out", str(out)),
            env=ENV,
            capture_output=True,
            text=True,
            timeout=300,
        )
    assert p.returncode == 2 and "another run is writing" in p.stderr
    assert not out.exists()


def test_a_file_output_never_replaces_a_device_a_fifo_or_a_folder(tmp_path, capsys):
    """``--out`` of a command that writes one file (identify, design, bench) is renamed onto at the end: on
    a FIFO or a device (``/dev/null`` as root) that replaced the node with a regular file, and the command
    said "written". Refused up front, the node left as it was; ``write_text`` refuses it too."""
    from vtol_impedance.io import write_text

    fifo = tmp_path / "pipe"
    os.mkfifo(fifo)
    (tmp_path / "dir").mkdir()
    for out in (fifo, tmp_path / "dir"):
        for argv in (["identify", "--example", "px4"], ["design", "pelican", "--cases", "case-a-payload", "--quiet"],
                     ["bench", "--quick", "--quiet"]):  # fmt: skip
            t0 = time.perf_counter()
            assert main([*argv, "--out", str(out)]) == 2, argv
            err = capsys.readouterr().err
            assert ("FIFO" in err if out == fifo else "a folder" in err) and "Traceback" not in err, err
            assert time.perf_counter() - t0 < 10.0  # before the work
        with pytest.raises(InputError, match="not a file"):
            write_text(out, "x")
    assert fifo.is_fifo() and (tmp_path / "dir").is_dir()


def test_a_live_recording_is_never_replaced(tmp_path, capsys):
    """A folder that ``live`` wrote holds a flight that cannot be flown again: no command replaces it, and
    the manifest names the command that wrote a folder (a run's is replaced by the next run, as above)."""
    rec = tmp_path / "live-1"
    with RunFolder(rec, command="live") as f:
        f.path("flight.tlog").write_bytes(b"\xfd" * 64)
        f.path("estimate.csv").write_text("t\n0\n")
        f.commit({"live": True})
    assert json.loads((rec / "manifest.json").read_text())["command"] == "live"
    old = tmp_path / "live-0"  # written before manifests named their command: known by its recording
    old.mkdir()
    (old / "flight.tlog").write_bytes(b"\xfd")
    (old / "manifest.json").write_text(json.dumps({"tool": "vtol-impedance", "files": {"flight.tlog": {}}}))
    for folder in (rec, old):
        for argv in (["run", "case-a-payload", "--quiet", "--no-plots", "--duration", "0.2"],
                     ["margins", "case-a-payload"], ["sweep", "robustness"]):  # fmt: skip
            assert main([*argv, "--out", str(folder)]) == 2, argv
            err = capsys.readouterr().err
            assert "live flight's recording" in err and "Traceback" not in err
            assert (folder / "flight.tlog").is_file()
    with pytest.raises(InputError, match="recording"):
        RunFolder(rec)
    assert main(["identify", "--example", "px4", "--out", str(rec / "flight.tlog")]) == 2  # nor a file inside
    assert "live flight's recording" in capsys.readouterr().err and (rec / "flight.tlog").read_bytes()[:1] == b"\xfd"
    out = tmp_path / "run"
    assert main(["run", "case-a-payload", "--quiet", "--no-plots", "--duration", "0.2", "--out", str(out)]) == 0
    assert json.loads((out / "manifest.json").read_text())["command"] == "run"


def test_manifest_binds_the_files(tmp_path):
    out = tmp_path / "res"
    assert main(["run", "case-a-payload", "--quiet", "--no-plots", "--duration", "0.3", "--out", str(out)]) == 0
    m = verify_run_folder(out)
    assert m["seed"] == [0] and len(m["config_sha256"]) == 64 and "numba" in m["versions"]
    assert set(m["files"]) == {
        "case-a-payload-v1.npz",
        "case-a-payload-v1.config.json",
        "case-a-payload-v1.margins.json",
        "metrics.csv",
        "metrics.md",
        "report.html",
    }
    (out / "metrics.csv").write_text("tampered")
    with pytest.raises(InputError, match="metrics.csv"):
        verify_run_folder(out)


def test_paper_workers_die_with_their_parent(tmp_path):
    # the NumPy backend: its flights take seconds, so the pool is alive when looked for (with a warm numba
    # cache the compiled flights took milliseconds, and the pool could come and go between two looks)
    p = subprocess.Popen(
        _cli("paper", "--jobs", "2", "--backend", "numpy", "--out", str(tmp_path / "p"), "--quiet"), env=ENV,
        start_new_session=True,
    )  # fmt: skip
    children: set[int] = set()
    deadline = time.time() + 120
    while time.time() < deadline and not children and p.poll() is None:
        time.sleep(0.1)
        children = procs.children(p.pid)
    assert children, "the pool never started"
    p.send_signal(signal.SIGKILL)
    p.wait()
    time.sleep(2.0)
    alive = [c for c in children if procs.running(c)]
    assert not alive, f"workers {alive} outlived their parent"


# --------------------------------------------------------------------------- the API


def test_step_arrays_after_reset_is_a_new_flight():
    """reset() forgets the estimate for step_arrays too: after a flight with a push, the first step equals a
    fresh controller's, and the flight that follows is the same to the bit."""
    y = np.zeros(12)
    y[2] = -1.0
    r = y.copy()
    used, fresh = Controller(ControllerParams.paper("pdc")), Controller(ControllerParams.paper("pdc"))
    for k in range(60):  # a vehicle drifting away at 0.5 m/s: the estimator learns a force
        y[0], y[3] = 0.005 * k, 0.5
        used.step_arrays(y, r)
    assert np.abs(used.step_arrays(y, r)["f_hat_W"]).max() > 0.1
    used.reset()
    y[0] = y[3] = 0.0
    for _ in range(5):
        a, b = used.step_arrays(y, r), fresh.step_arrays(y, r)
        assert all(np.array_equal(a[name], b[name]) for name in a.dtype.names)


def test_a_loop_at_another_rate_than_ts_is_warned_about_when_timed():
    """Stepped every 2 Ts, the estimator sees twice the momentum's rate of change: a vehicle pushed by 1 N
    into a constant acceleration is estimated at 2 N, in silence. With the clock ``t`` given, that period is
    a ControllerWarning (once), time going backwards an InputError with the state unchanged, and a real-time
    loop's jitter nothing."""
    from vtol_impedance import Estimator

    m, Ts, a = 1.0, 0.01, 1.0  # 1 N along x on 1 kg, level, the thrust carrying the weight

    def pushed(period, k):
        return np.array([a * k * period, 0.0, 0.0])

    for period, f_true in ((Ts, 1.0), (2 * Ts, 1.0)):
        est = Estimator(m, [0.01, 0.01, 0.02], Ts)
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            outs = [est.step(pushed(period, k), np.zeros(3), m * 9.81, np.zeros(3), omega_B=np.zeros(3),
                             t=k * period) for k in range(400)]  # fmt: skip
        said = [w for w in caught if issubclass(w.category, ControllerWarning)]
        if period == Ts:
            assert outs[-1].f_hat_W[0] == pytest.approx(f_true, abs=1e-3) and not said
        else:  # the wrong number the warning is about, and the warning, once
            assert outs[-1].f_hat_W[0] == pytest.approx(2 * f_true, abs=1e-3)
            assert len(said) == 1 and "built for a step every Ts = 0.01 s" in str(said[0].message)
    ctrl, twin = Controller(ControllerParams.paper("pdc")), Controller(ControllerParams.paper("pdc"))
    meas = Measurement(np.array([0.1, 0.0, -1.0]), np.zeros(3), np.zeros(3), omega_B=np.zeros(3))
    ref = Reference(np.array([0.0, 0.0, -1.0]))
    jitter = np.cumsum(0.01 * (1 + 0.2 * np.sin(np.arange(50))))  # +-20 %: a real-time loop
    with warnings.catch_warnings():
        warnings.simplefilter("error", ControllerWarning)
        for k, t in enumerate(jitter):
            out = ctrl.step(meas, ref, t=t)
            assert out.thrust == twin.step(meas, ref).thrust
            if k == 10:
                with pytest.raises(InputError, match="does not come after the previous step's"):
                    ctrl.step(meas, ref, t=t - 0.005)
                with pytest.raises(InputError, match="t \\(the step's time, s\\)"):
                    ctrl.step(meas, ref, t=float("nan"))
    y = np.array([0.1, 0, -1.0, 0, 0, 0, 0, 0, 0, 0, 0, 0])
    r = np.array([0, 0, -1.0, 0, 0, 0, 0, 0, 0, 0, 0, 0])
    ctrl.reset()  # a new flight: its clock starts again
    ctrl.step_arrays(y, r, t=0.0)
    with pytest.warns(ControllerWarning, match="stepped 0.5 s after"):
        ctrl.step_arrays(y, r, t=0.5)  # a gap
    # each period inside the tolerance, but on average 30 % slow: warned once enough steps tell (both calls)
    for period, warned, arrays in ((0.013, True, False), (0.0101, False, False), (0.013, True, True)):
        ctrl.reset()
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            for k in range(40):
                if arrays:
                    ctrl.step_arrays(y, r, t=k * period)
                else:
                    ctrl.step(meas, ref, t=k * period)
        said = [str(w.message) for w in caught if issubclass(w.category, ControllerWarning)]
        assert (len(said) == 1 and "on average" in said[0]) if warned else not said, said
    # an untimed step in between forgets the clock: its period is not the sum of two (step and step_arrays)
    for step in (lambda t=None: ctrl.step(meas, ref, t=t), lambda t=None: ctrl.step_arrays(y, r, t=t)):
        ctrl.reset()
        with warnings.catch_warnings():
            warnings.simplefilter("error", ControllerWarning)
            for t in (0.0, None, 0.02, 0.03):
                step(t)
    with pytest.raises(InputError, match="t \\(the step's time"):
        Controller([ControllerParams.paper("pdc")] * 2).step_arrays(y, r, 1, t="soon")


def test_step_arrays_checks_type_shape_and_dtype():
    ctrl = Controller(ControllerParams.paper("pdc"))
    y = np.zeros(12)
    y[2] = -1.0
    r = np.zeros(12)
    r[2] = -1.0
    ctrl.step_arrays(y, r)
    for bad, msg in (
        (np.zeros(6), r"float64 array of shape \(6,\)"),
        (np.zeros(13), r"float64 array of shape \(13,\)"),
        (np.zeros((12, 1)), r"float64 array of shape \(12, 1\)"),
        (np.zeros(12, dtype=np.float32), "float32 array"),
        (np.zeros(12, dtype=np.int64), "int64 array"),
        (list(np.zeros(12)), "list"),
        (np.zeros((12, 2))[:, 0], "non-contiguous float64"),
        (np.zeros(12, dtype=">f8"), r">f8 array"),  # the same values in another byte order
        (np.zeros(12).view(np.matrix), "matrix"),
    ):
        with pytest.raises(InputError, match=msg):
            ctrl.step_arrays(y, bad)
        with pytest.raises(InputError, match=msg):
            ctrl.step_arrays(bad, r)
    for vehicle in (3, -1, True, 0.0, np.int64(1), np.bool_(False), "0"):
        with pytest.raises(InputError, match="vehicle"):
            ctrl.step_arrays(y, r, vehicle=vehicle)
    assert ctrl.step_arrays(y, r, vehicle=np.int64(0)).dtype == ctrl.step_arrays(y, r).dtype
    with pytest.raises(InputError, match="backend='compiled'"):
        Controller(ControllerParams.paper("pdc"), backend="numpy").step_arrays(y, r)
    comply = Controller(ControllerParams.paper("comply"))
    with pytest.raises(InputError, match=r"comply fractions must be within \[0, 1\]"):
        comply.step_arrays(y, np.concatenate([r, [1.5, 0.0, 0.0]]))
    # finite but beyond any vehicle: refused, and the state is not poisoned
    huge = y.copy()
    huge[3] = 1e308
    with pytest.raises(InputError, match="beyond any vehicle"):
        ctrl.step_arrays(huge, r)
    out = ctrl.step_arrays(y, r)
    assert all(np.all(np.isfinite(out[name])) for name in out.dtype.names)
    # a pitch of 30 (degrees meant) is no ZYX pitch: refused by both entry points, by both backends
    degrees = y.copy()
    degrees[7] = 30.0
    with pytest.raises(InputError, match=r"pitch theta = 30 rad is beyond \+-pi/2.*degrees"):
        ctrl.step_arrays(degrees, r)
    for backend in ("compiled", "numpy"):
        with pytest.raises(InputError, match="beyond \\+-pi/2"):
            Controller(ControllerParams.paper("pdc"), backend=backend).step(
                Measurement(np.zeros(3), np.zeros(3), np.array([0.0, -1.6, 0.0]), np.zeros(3)),
                Reference(np.zeros(3)))  # fmt: skip
    edge = y.copy()
    edge[7] = -np.pi / 2  # the singularity itself is the singularity's error
    with pytest.raises(SingularityError):
        ctrl.step_arrays(edge, r)
    numpy_ctrl = Controller(ControllerParams.paper("pdc"), backend="numpy")
    with pytest.raises(InputError, match="beyond any vehicle"):
        numpy_ctrl.step(Measurement(np.array([0.0, 0.0, 1e308]), np.zeros(3), np.zeros(3), np.zeros(3)),
                        Reference(np.array([0.0, 0.0, -1.0])))  # fmt: skip
    out = numpy_ctrl.step(Measurement(np.array([0.0, 0.0, -1.0]), np.zeros(3), np.zeros(3), np.zeros(3)),
                          Reference(np.array([0.0, 0.0, -1.0])))  # fmt: skip
    assert np.all(np.isfinite(out.f_rotor))


def test_events_after_the_end_warn_and_winds_beyond_any_vehicle_are_refused(tmp_path, capsys):
    args = ["run", "operator-push", "--duration", "2", "--quiet", "--no-plots", "--out", str(tmp_path / "o")]
    assert main(args) == 0
    err = capsys.readouterr().err
    assert "the push disturbance at 10 s" in err and "after the flight ends (2 s)" in err
    assert err.count("after the flight ends") == 1  # once, however often the scenario is checked
    assert main(["run", "gust", "--set", "disturbances.0.amplitude=200", "--out", str(tmp_path / "g")]) == 2
    assert "beyond any multirotor's flight envelope" in capsys.readouterr().err


def test_reference_and_start_shapes_are_checked():
    ctrl = Controller(ControllerParams.paper("pdc"))
    meas = Measurement(np.zeros(3), np.zeros(3), np.zeros(3), np.zeros(3))
    for make, msg in (  # a field of the wrong shape or type is refused where the Reference is made
        (lambda: Reference(np.zeros(2)), "p_W"),
        (lambda: Reference(np.zeros(3), v_W=np.zeros(4)), "v_W"),
        (lambda: ctrl.step(meas, Reference(np.zeros(3), psi=np.zeros(3))), "psi_d"),
        (lambda: Reference(np.zeros(3), psi="north"), "psi"),
        (lambda: ctrl.step(meas, "hover"), "Reference"),
    ):
        with pytest.raises(InputError, match=msg):
            make()
    veh = load_preset()
    traj = Trajectory((Hold((0, 0, -1.0), 1.0),))
    for start in (np.zeros(2), np.zeros((2, 3)), [0, 0, np.nan], "up"):
        with pytest.raises(InputError, match="start_W"):
            run_closed_loop(PlantParams(veh), [ControllerParams.paper()], traj, 1.0, start_W=start)
    with pytest.raises(InputError, match="seed"):
        run_closed_loop(PlantParams(veh), [ControllerParams.paper()], traj, 1.0, seed=-4)
    with pytest.raises(InputError, match="seed"):
        run_closed_loop(PlantParams(veh), [ControllerParams.paper()], traj, 1.0, seed="seven")


def test_diagonal_matrix_gains_are_accepted_and_others_named():
    I = load_preset().inertia
    g = ImpedanceGains(Kp=np.diag([16.0, 16.0, 20.0]), Dp=12.0, Ko=np.diag([1.0, 1, 1]), Do=0.1)
    np.testing.assert_array_equal(g.Kp, [16, 16, 20])
    with pytest.raises(InputError, match="Kp must be diagonal"):
        ImpedanceGains(Kp=np.ones((3, 3)), Dp=12.0, Ko=1.0, Do=0.1)
    with pytest.raises(InputError, match="Dp must be numeric"):
        ImpedanceGains(Kp=16.0, Dp="12", Ko=1.0, Do=0.1)
    assert ImpedanceGains.from_position(16.0, 12.0, I).Ko[0] == pytest.approx(64 * I[0, 0])
    # a gain of 1e160 once overflowed eq. (16) to a level attitude: refused, as the scenarios refuse it
    for kw in ({"Kp": 1e160}, {"Dp": [1.0, 1.0, 1e7]}, {"Ki": 1e300}):
        with pytest.raises(InputError, match="beyond any vehicle's gain"):
            ImpedanceGains(**{"Kp": 16.0, "Dp": 12.0, "Ko": 1.0, "Do": 0.1, **kw})
    with pytest.raises(InputError, match="at least"):
        Impedance(M=1e-300, D=6.0, K=5.0)


def test_unbounded_work_is_refused_up_front_with_the_estimate():
    veh = load_preset()
    traj = Trajectory((Hold((0, 0, -1.0), 1.0),))
    ctrls = [ControllerParams.paper()] * 2
    tracemalloc.start()
    with pytest.raises(InputError, match=r"about [\d.]+ GB of memory"):
        run_closed_loop(PlantParams(veh), ctrls, traj, 1e6)
    with pytest.raises(InputError, match="plant steps"):
        run_closed_loop(
            PlantParams(veh), ctrls, traj, 100.0, plant_rate=1e5, log="metrics", limits=Limits(max_plant_steps=1e6)
        )
    # 1,000 vehicles with full traces over 3,000 s (~100 GB; one vehicle's would fit): refused, not allocated
    # (not 100,000 over 30 s: the same bytes, but 100,000 controllers take seconds to check and pack first)
    many = [ControllerParams.paper()] * 1_000
    with pytest.raises(InputError, match="GB of memory"):
        run_closed_loop(PlantParams(veh), many, traj, 3000.0)
    with pytest.raises(InputError, match="plant steps"):  # checked after the memory: one vehicle's traces fit
        run_closed_loop(PlantParams(veh), many[:1], traj, 3000.0, limits=Limits(max_plant_steps=1.0))
    _, peak = tracemalloc.get_traced_memory()
    tracemalloc.stop()
    assert peak < 500e6  # refused before the traces were allocated (they would take tens of GB)


def test_sensor_and_plant_values_are_checked():
    with pytest.raises(InputError, match="mocap_delay"):
        SensorParams(mocap_delay=50.0)
    with pytest.raises(InputError, match="gyro_noise"):
        SensorParams(gyro_noise=float("nan"))
    veh = load_preset()
    with pytest.raises(InputError, match="payload_offset_B"):
        PlantParams(veh, payload_offset_B=(0.0, 0.0))
    with pytest.raises(InputError, match="payload_mass"):
        PlantParams(veh, payload_mass=-0.1)
    with pytest.raises(InputError, match="ground"):
        PlantParams(veh, ground="yes")


# --------------------------------------------------------------------------- what used to be silently wrong


@pytest.mark.parametrize("mass,offset", [(0.5, (0.0, 0.0, 0.06)), (1.3, (0.0, 0.0, 0.03))])
def test_heavy_or_low_slung_payload_takes_off(mass, offset):
    spec = set_value(set_value(get("case-a-payload"), "payload.mass", mass), "payload.offset_B", list(offset))
    spec = set_value(spec, "duration", 12.0)
    r = simulate(spec, ["pdc"])
    assert r.failures == [None]
    assert r["p_W"][0, -1, 2] == pytest.approx(-1.0, abs=0.05)
    # it started resting on the payload, not buried in the ground
    assert r.config["start_lifted_m"][0] == pytest.approx(offset[2] if offset[2] > 0 else 0.0, abs=1e-12)


def test_tilt_limit_counts_as_limited():
    spec = set_value(set_value(get("case-a-payload"), "control.tilt_max_deg", 3.0), "duration", 12.0)
    spec = set_value(spec, "trajectory.start_on_ground", False)
    spec = set_value(set_value(spec, "disturbances", [{"kind": "constant", "force_W": [2.0, 0, 0]}]), "ideal", True)
    r = simulate(spec, ["pdc"])
    assert r["tilt_limited"][0].mean() > 0.5
    assert r.metrics is None
    from vtol_impedance.analysis.metrics import compute_metrics

    assert compute_metrics(r)[0]["sat_pct"] > 50.0
    rm = simulate(spec, ["pdc"], log="metrics")
    assert rm.metrics[0]["sat_pct"] == pytest.approx(compute_metrics(r)[0]["sat_pct"], rel=1e-9)


def test_the_plant_starts_at_the_planned_yaw():
    spec = set_value(set_value(get("case-a-payload"), "trajectory.yaw", 3.1), "duration", 3.0)
    r = simulate(spec, ["pdc"])
    yaw = np.unwrap(r["eta"][0, :, 2])
    assert np.abs(yaw - 3.1).max() < 0.01  # no unrequested turn


def test_reset_forgets_the_previous_flight_and_is_needed():
    p = ControllerParams.paper("pdc")
    ctrl = Controller(p)
    heavy = Measurement(np.array([0, 0, -1.0]), np.array([0, 0, 0.5]), np.zeros(3), np.zeros(3))
    for _ in range(100):  # the vehicle keeps sinking at 0.5 m/s faster than commanded: a large estimate
        out = ctrl.step(heavy._replace(v_W=np.array([0, 0, 0.5 + 0.01 * _])), Reference(np.array([0, 0, -1.0])))
    assert abs(out.f_hat_W[2]) > 0.1
    fresh = Controller(p)
    calm = Measurement(np.array([0, 0, -1.0]), np.zeros(3), np.zeros(3), np.zeros(3))
    stale = ctrl.step(calm, Reference(np.array([0, 0, -1.0])))
    ctrl.reset()
    a = ctrl.step(calm, Reference(np.array([0, 0, -1.0])))
    b = fresh.step(calm, Reference(np.array([0, 0, -1.0])))
    assert abs(stale.thrust - b.thrust) > 0.05  # without reset the old estimate is still in there
    assert a.thrust == b.thrust and np.array_equal(a.f_rotor, b.f_rotor)


def test_user_loop_api_gyro_rates_defaults_plain_floats_and_warnings(rng):
    p = ControllerParams.paper("pdc")
    for backend in ("numpy", "compiled"):
        a, b = Controller(p, backend=backend), Controller(p, backend=backend)
        eta = np.array([0.2, -0.3, 1.0])
        eta_dot = np.array([0.3, -0.2, 0.5])
        from vtol_impedance.model import euler_rate_matrix_Q

        omega_B = euler_rate_matrix_Q(eta) @ eta_dot
        oa = a.step(Measurement(np.zeros(3), np.zeros(3), eta, eta_dot), Reference(np.zeros(3)))
        ob = b.step(Measurement(np.zeros(3), np.zeros(3), eta, omega_B=omega_B), Reference(np.zeros(3)))
        np.testing.assert_allclose(ob.tau_B, oa.tau_B, rtol=1e-10, atol=1e-12)
        assert isinstance(ob.thrust, float) and isinstance(ob.saturated, bool)
        assert ob.tau_B.shape == (3,) and ob.f_rotor.shape == (4,)
        with pytest.raises(InputError, match="exactly one of eta_dot"):
            a.step(Measurement(np.zeros(3), np.zeros(3), eta), Reference(np.zeros(3)))
    ctrl = Controller(p)
    far = Measurement(np.array([30.0, 0, -1]), np.zeros(3), np.zeros(3), np.zeros(3))
    with warnings.catch_warnings(record=True) as w:
        warnings.simplefilter("always")
        for _ in range(5):
            ctrl.step(far, Reference(np.array([0, 0, -1.0])))
    causes = [str(x.message) for x in w if issubclass(x.category, ControllerWarning)]
    assert len(causes) == len(set(causes)) >= 1  # once per cause


def test_paper_gains_scale_with_mass():
    hexa = load_preset("hexarotor")
    p = ControllerParams.paper("pid", vehicle=hexa)
    np.testing.assert_allclose(p.gains.Kp / hexa.mass, 16.0 / 1.2)
    np.testing.assert_allclose(p.gains.Dp / hexa.mass, 12.0 / 1.2)
    np.testing.assert_allclose(p.gains.Ki / hexa.mass, 0.5 / 1.2)
    np.testing.assert_allclose(p.gains.Ko, 64.0 * np.diag(hexa.inertia))


def test_a_vehicle_file_describes_a_custom_multirotor(tmp_path):
    f = tmp_path / "mine.toml"
    f.write_text(
        'name = "mine"\nmass = 0.9\ninertia_diag = [3e-3, 3e-3, 5e-3]\nthrust_constant = 1e-5\n'
        "torque_constant = 1.5e-7\n"
        + "".join(
            f"[[rotors]]\nposition_B = [{x}, {y}, 0.0]\nspin = {s}\nmax_speed = 800.0\n"
            for x, y, s in ((0.15, 0.15, 1), (-0.15, -0.15, 1), (0.15, -0.15, -1), (-0.15, 0.15, -1))
        )
    )
    spec = set_value(set_value(get("case-a-payload"), "vehicle", str(f)), "duration", 10.0)
    r = simulate(spec, ["pdc"])
    assert r.failures == [None]
    assert r.config["controllers"][0]["vehicle"]["rotors"][0]["f_max"] == pytest.approx(1e-5 * 800.0**2)
    bad = tmp_path / "bad.toml"
    bad.write_text("mass = 1.0\ninertia_diag = [1e-3, 1e-3, 1e-3]\n[[rotors]]\nposition_B = [0.1, 0, 0]\n")
    with pytest.raises(InputError, match="spin"):
        load_toml_vehicle(bad)


@pytest.mark.parametrize(
    ("extra", "named"),
    [
        ('inertia = [[1e-3, 0, 0], [0, 1e-3, 0], [0, 0, 2e-3]]\n', "inertia or inertia_diag"),
        ("drag_factor = 0.02\ntorque_constant = 1e-7\nthrust_constant = 1e-5\nmax_speed = 800.0\n",
         "drag_factor or torque_constant"),
        ("f_max = 5.0\nmax_speed = 800.0\nthrust_constant = 1e-5\n", "f_max or max_speed"),
        ("torque_constant = 1e-7\n", "torque_constant needs thrust_constant"),
        ("thrust_constant = 1e-5\n", "alone it sets nothing"),
        ('layout = "hex"\narm_length = 0.5\nf_max = 3.0\n[[rotors]]\nposition_B = [0.1, 0.1, 0]\nspin = 1\n',
         "explicit [[rotors]] or the shorthand"),
    ],
)
def test_a_vehicle_file_that_says_one_thing_twice_is_refused(tmp_path, extra, named):
    """Two ways of giving one quantity (or explicit rotors and the layout shorthand) each dropped one of
    them in silence: a hexarotor file with four [[rotors]] flew those four with the Pelican's limits. Refused,
    naming both; a constant that nothing uses is refused too."""
    f = tmp_path / "twice.toml"
    f.write_text("mass = 1.0\ninertia_diag = [1e-3, 1e-3, 2e-3]\n" + extra)
    with pytest.raises(InputError, match=re.escape(named)):
        load_toml_vehicle(f)


def load_toml_vehicle(path):
    from vtol_impedance.model import load_preset as lp

    return lp(str(path))


def test_scenario_file_round_trips_its_config(tmp_path):
    f = tmp_path / "s.toml"
    f.write_text('base = "case-b-fan"\nname = "my-fan-v2"\n[payload]\nmass = 0.2\n')
    spec = load_toml(f)
    assert spec.name == "my-fan-v2" and spec.payload.mass == 0.2
    assert json.loads(json.dumps(spec.to_dict()))["payload"]["mass"] == 0.2


def test_an_error_while_unwinding_an_interrupt_is_still_an_interrupt(monkeypatch, tmp_path, capsys):
    """Ctrl-C while matplotlib writes a GIF: its writer's clean-up fails (IndexError) on the way out. The
    user pressed Ctrl-C: exit 130 and "interrupted", not an internal error."""
    import vtol_impedance.cli.run as run_command

    def interrupted_run(args, controllers):
        try:
            raise KeyboardInterrupt
        finally:
            [][0]  # noqa: B018 (a library's clean-up failing)

    monkeypatch.setattr(run_command, "cmd_run", interrupted_run)
    assert main(["run", "case-a-payload", "--out", str(tmp_path / "o")]) == 130
    err = capsys.readouterr().err
    assert "interrupted" in err and "internal error" not in err


def test_complex_boolean_and_text_numbers_are_refused_not_cast():
    """NumPy casts a complex number to its real part (with a warning) and True to 1.0: either would be a
    silent wrong number in a gain or a measurement."""
    from vtol_impedance import Controller

    for bad in ([16.0 + 1j, 16.0, 16.0], np.array([True, True, True]), True, np.array(["16", "16", "16"])):
        with pytest.raises(InputError, match="must be"):
            ImpedanceGains(Kp=bad, Dp=12.0, Ko=1.0, Do=0.1)
    c = Controller(ControllerParams.paper())
    ref = Reference(np.array([0, 0, -1.0]), np.zeros(3), np.zeros(3), 0.0, 0.0, 0.0)
    with pytest.raises(InputError, match="real numbers"):
        c.step(Measurement(np.array([0, 0, -1.0 + 0j]), np.zeros(3), np.zeros(3), np.zeros(3)), ref)
    with pytest.raises(InputError, match="must be numeric"):
        ImpedanceGains(Kp=[[16.0, 16.0], [16.0]], Dp=12.0, Ko=1.0, Do=0.1)


def test_a_controller_named_twice_on_the_command_line_is_refused(tmp_path, capsys):
    """The same flight twice under one label compares nothing; the API keeps copies (identical vehicles)."""
    for cmd in (["compare", "case-a-payload", "--controllers", "pd,pdc,pd", "--out", str(tmp_path / "o")],
                ["margins", "case-a-payload", "--controllers", "pd,pd"]):  # fmt: skip
        assert main(cmd) == 2
        assert "given more than once" in capsys.readouterr().err
    assert not (tmp_path / "o").exists()


def test_default_folders_never_mix_configurations(tmp_path, monkeypatch):
    """``results/<scenario>`` holds the registered scenario only: a scenario file without a name (it takes
    its base's) or sharing one with another file gets a folder of its own, a file equal to the registered
    scenario shares its folder, and ``margins`` with a ``--set`` does not replace the plain report."""
    monkeypatch.chdir(tmp_path)
    (tmp_path / "heavier.toml").write_text('base = "case-a-payload"\n[payload]\nmass = 0.2\n')
    (tmp_path / "lighter.toml").write_text('base = "case-a-payload"\n[payload]\nmass = 0.05\n')
    (tmp_path / "same.toml").write_text('base = "case-a-payload"\n')
    quick = ["--duration", "0.2", "--no-plots", "--quiet", "--controller", "pd"]
    for name in ("case-a-payload", "heavier.toml", "lighter.toml", "same.toml"):
        assert main(["run", name, *quick]) == 0
    runs = sorted(p.name for p in (tmp_path / "results").iterdir())
    assert len(runs) == 3 and "case-a-payload-v1+duration=0.2" in runs, runs
    assert all(r.startswith("case-a-payload-v1+") for r in runs)
    masses = {json.loads((tmp_path / "results" / r / "case-a-payload-v1.config.json").read_text())["scenario"]
              ["payload"]["mass"] for r in runs}  # fmt: skip
    assert masses == {0.11, 0.2, 0.05}
    for extra in ([], ["--set", "payload.mass=0.2"]):
        assert main(["margins", "case-a-payload", "--controllers", "pd", "--no-plots", "--quiet", *extra]) == 0
    assert len([p for p in (tmp_path / "results").iterdir() if p.name.startswith("margins-")]) == 2


def test_output_paths_that_cannot_hold_results_are_named_before_any_work(capsys, monkeypatch):
    """An empty --out (it meant the default folder), the root (its advice was a system folder) and a bench
    report into /proc (refused only after minutes of measuring) are refused up front."""
    assert main(["run", "case-a-payload", "--out", ""]) == 2
    assert "--out is empty" in capsys.readouterr().err
    assert main(["run", "case-a-payload", "--duration", "0.2", "--out", "/"]) == 2
    err = capsys.readouterr().err
    assert "mount point" in err and "--out /run" not in err
    import vtol_impedance.bench as bench

    def no_measuring(*args, **kw):
        raise AssertionError("bench measured before checking --out")

    monkeypatch.setattr(bench, "_child", no_measuring)
    monkeypatch.setattr(bench, "_batch", no_measuring, raising=False)
    assert main(["bench", "--quick", "--quiet", "--out", "/proc/x.json"]) == 2
    err = capsys.readouterr().err  # as root: the probe file fails; otherwise /proc is not writable
    assert "/proc" in err and "write into" in err


def test_a_lock_won_on_a_file_its_holder_removed_is_no_lock(tmp_path, monkeypatch):
    """Run B opened the lock file while run A held it; A finished (its file removed, its lock released) and
    run C took the lock on a new file at the same path. B's flock then succeeds on the removed file: it
    must still be refused, or B and C would write into one folder at once."""
    import vtol_impedance.io as vio

    folder = tmp_path / "res"
    a = vio.FolderLock(folder)
    stale = open(a.path, "a+")  # noqa: SIM115 (B's handle, opened before A finished)
    a.close()
    c = vio.FolderLock(folder)
    monkeypatch.setattr(vio, "open", lambda *args, **kw: stale, raising=False)
    with pytest.raises(InputError, match="another run is writing"):
        vio.FolderLock(folder)
    monkeypatch.undo()
    c.close()
    vio.FolderLock(folder).close()  # free again once C is done
