"""A corpus of bad inputs, by kind (command line, TOML files, flight logs, the Python API, the live link),
each with the outcome it must get: refused with a clear message that names the value, before any work
and without a traceback. A few correct but unusual inputs sit beside them and must be accepted: refusing
a correct input is a failure too. The kinds are listed in ``docs/guide/bad-inputs.md``.

Each case is one row: ``(kind, id, how to run it, what the message must contain)``. A command-line case
must exit with 2 (a usage error), print ``error:`` (or argparse's usage error) and no traceback or
"internal error"; an API case must raise the package's documented exception (:class:`InputError` and its
family) whose message contains the fragment.
"""

from __future__ import annotations

import dataclasses
import math
import re
import shutil
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pytest

import vtol_impedance
from vtol_impedance import control, estimator, logs, model, robust, scenarios, sim
from vtol_impedance.cli import main
from vtol_impedance.errors import VtolImpedanceError
from vtol_impedance.logs.samples import path as sample_path

SAMPLE_CSV = sample_path("csv")


@dataclass(frozen=True)
class Case:
    """One bad input: ``argv`` for the command line (``{tmp}`` is the case's folder), or ``call`` for the API;
    ``files`` written into the case's folder first (text, bytes, or a function of the folder)."""

    kind: str
    id: str
    match: str
    argv: tuple[str, ...] = ()
    call: Callable[[Path], object] | None = None
    files: dict[str, object] = field(default_factory=dict)


CASES: list[Case] = []


def cli(kind: str, id: str, match: str, *argv: str, files: dict | None = None) -> None:
    CASES.append(Case(kind, id, match, argv=tuple(argv), files=files or {}))


def api(id: str, match: str, call: Callable[[Path], object], kind: str = "api") -> None:
    CASES.append(Case(kind, id, match, call=call))


RUN = ("run", "case-a-payload", "--duration", "0.3", "--no-plots", "--quiet", "--out", "{tmp}/o")
EST = ("estimate", "--example", "csv", "--mass", "1.2", "--no-plots", "--quiet", "--out", "{tmp}/o")

# --------------------------------------------------------------------------- command line: run, paper, margins
for i, (extra, msg) in enumerate(
    [
        (("--duration", "inf"), "--duration"),
        (("--duration", "1e400"), "--duration"),
        (("--duration", "-inf"), "--duration"),
        (("--seed", "1.5"), "--seed"),
        (("--seed", "abc"), "--seed"),
        (("--seed", "1e30"), "--seed"),
        (("--set", "payload.mass"), "KEY=VALUE"),
        (("--set", "=3"), "dotted name"),
        (("--set", "payload.mass="), "payload.mass"),
        (("--set", "payload..mass=1"), "payload..mass"),
        (("--set", "payload.mass=1e999"), "payload.mass"),
        (("--set", "payload.mass=-0.1"), "payload.mass"),
        (("--set", "payload.mass=inf"), "payload.mass"),
        (("--set", "control.Kp=[16,16]"), "control.Kp"),
        (("--set", "control.Kp=[]"), "control.Kp"),
        (("--set", "control.Kp=nan"), "control.Kp"),
        (("--set", "control.Dp=-12"), "control.Dp"),
        (("--set", "control.estimator_wn=-1"), "estimator_wn"),
        (("--set", "control.estimator_wn=0"), "estimator_wn"),
        (("--set", "control.estimator_zeta=0"), "estimator_zeta"),
        (("--set", "control.estimator_order=0"), "estimator_order"),
        (("--set", "control.wn_o=-8"), "wn_o"),
        (("--set", "sensors.mocap_delay=-0.01"), "mocap_delay"),
        (("--set", "plant_rate=0"), "plant_rate"),
        (("--set", "plant_rate=-1000"), "plant_rate"),
        (("--set", "payload.offset_B=[nan,0,0]"), "payload.offset_B"),
        (("--set", "payload.offset_B=[0,0,0,0]"), "payload.offset_B"),
        (("--set", 'vehicle=""'), "vehicle"),
        (("--set", "plant.inertia_scale=[1,1]"), "inertia_scale"),
        (("--set", "plant.inertia_scale=[0,1,1]"), "inertia_scale"),
        (("--set", "plant.rotor_tau_up=-0.01"), "rotor_tau_up"),
        (("--set", "nosuchkey=1"), "nosuchkey"),
        (("--set", "payload.mass={a=1}"), "payload.mass"),
        (("--set", "trajectory.altitude=nan"), "trajectory.altitude"),
        (("--backend", "gpu"), "invalid choice"),
        (("--plant", "gazebo"), "invalid choice"),
    ]
):
    cli("cli", f"run-{i}-{extra[-1][:20]}", msg, *RUN, *extra)

cli("cli", "run-empty-scenario", "scenario", "run", "", "--out", "{tmp}/o", "--quiet")
cli("cli", "run-scenario-is-a-folder", "scenario", "run", "{tmp}", "--out", "{tmp}/o", "--quiet")
cli("cli", "run-circle-negative-speed", "trajectory.speed", "run", "case-c-circle", "--set", "trajectory.speed=-0.5",
    "--out", "{tmp}/o", "--quiet", "--no-plots")  # fmt: skip
cli("cli", "run-circle-zero-radius", "trajectory.radius", "run", "case-c-circle", "--set", "trajectory.radius=0",
    "--out", "{tmp}/o", "--quiet", "--no-plots")  # fmt: skip
for i, (extra, msg) in enumerate(
    [
        (("--jobs", "0"), "--jobs"),
        (("--jobs", "-2"), "--jobs"),
        (("--jobs", "two"), "--jobs"),
        (("--tuning", "magic"), "invalid choice"),
        (("--duration", "0"), "--duration"),
    ]
):
    cli("cli", f"paper-{i}", msg, "paper", "--quiet", "--no-plots", "--out", "{tmp}/o", *extra)
for i, (extra, msg) in enumerate(
    [
        (("--controllers", ""), "controller"),
        (("--controllers", "pd,lqr"), "lqr"),
        (("--controllers", "pd,pd"), "pd"),
        (("--set", "control.Kp=-1"), "control.Kp"),
    ]
):
    cli("cli", f"margins-{i}", msg, "margins", "case-a-payload", "--quiet", "--no-plots", "--out", "{tmp}/o", *extra)
cli("cli", "margins-unknown-scenario", "valid scenarios", "margins", "case-q", "--quiet", "--out", "{tmp}/o")

# --------------------------------------------------------------------------- command line: estimate's options
for i, (extra, msg) in enumerate(
    [
        (("--mass", "-1"), "mass"),
        (("--mass", "0"), "mass"),
        (("--mass", "nan"), "mass"),
        (("--mass", "inf"), "mass"),
        (("--mass", "1e-9"), "mass"),  # a unit slip: the fits would be confident nonsense
        (("--inertia", "1,2"), "--inertia"),
        (("--inertia", "a,b,c"), "--inertia"),
        (("--inertia", "-0.01,0.01,0.02"), "inertia"),
        (("--inertia", "0.01,0.01,0.05"), "inertia"),
        (("--rate", "0"), "rate"),
        (("--rate", "-100"), "rate"),
        (("--rate", "nan"), "rate"),
        (("--max-gap", "-1"), "gap"),
        (("--start", "10", "--end", "5"), "start"),
        (("--start", "nan"), "start"),
        (("--hover-thrust", "1.5"), "hover"),
        (("--hover-thrust", "0"), "hover"),
        (("--hover-thrust", "-0.4"), "hover"),
        (("--hover-segment", "5"), "--hover-segment"),
        (("--hover-segment", "5,2"), "hover"),
        (("--torque-scale", "1,2"), "--torque-scale"),
        (("--wn", "0"), "wn"),
        (("--wn", "-5"), "wn"),
        (("--zeta", "-1"), "zeta"),
        (("--order", "0"), "order"),
        (("--order", "2.5"), "--order"),
        (("--velocity-delay", "-0.1"), "delay"),
        (("--attitude-delay", "nan"), "delay"),
        (("--rotor-tau", "-0.01"), "tau"),
        (("--column", "vx"), "--column"),
        (("--column", "nosuchrole=vx"), "nosuchrole"),
        (("--column", "vx=no_such_column"), "no_such_column"),
        (("--quiet-segment", "3"), "--quiet-segment"),
        (("--thrust-coefficient", "-1"), "coefficient"),
        (("--vehicle", "no-such-preset"), "no-such-preset"),
        (("--vehicle", "/no/such/vehicle.toml"), "vehicle.toml"),
        (("--thrust-from", "magic"), "invalid choice"),
        (("--conventions", "maybe"), "invalid choice"),
    ]
):
    cli("cli", f"estimate-{i}-{extra[0]}", msg, *EST, *extra)
cli("cli", "estimate-no-log", "log", "estimate", "--quiet", "--out", "{tmp}/o")
cli("cli", "estimate-torque-scale-unused", "torque scale", "estimate", "--example", "csv", "--vehicle", "pelican",
    "--torque-scale", "0,0,0", "--no-plots", "--quiet", "--out", "{tmp}/o")  # the moment comes from the rotors
cli("cli", "estimate-unknown-example", "nope", "estimate", "--example", "nope", "--quiet", "--out", "{tmp}/o")
cli("cli", "estimate-missing-file", "does not exist", "estimate", "{tmp}/missing.csv", "--quiet", "--out", "{tmp}/o")
cli("cli", "estimate-folder", "not a file", "estimate", "{tmp}", "--quiet", "--out", "{tmp}/o")
cli("cli", "estimate-log-and-example", "not both", "estimate", "{tmp}/x.csv", "--example", "csv", "--quiet",
    files={"x.csv": "t_s\n"})  # fmt: skip

# --------------------------------------------------------------------------- command line: sweep, tune, bench
SWEEP_OK = 'name = "s"\nbase = "case-a-payload"\n[set]\nduration = 0.2\n[axes]\n"payload.mass" = [0.0, 0.1]\n'
for i, (extra, msg) in enumerate(
    [
        (("--workers", "0"), "workers"),
        (("--workers", "-1"), "workers"),
        (("--metric", "no_such_metric"), "no_such_metric"),
    ]
):
    cli("cli", f"sweep-{i}", msg, "sweep", "{tmp}/s.toml", "--quiet", "--no-report", "--out", "{tmp}/o", *extra,
        files={"s.toml": SWEEP_OK})  # fmt: skip
cli("cli", "sweep-missing-file", "s-missing", "sweep", "{tmp}/s-missing.toml", "--quiet", "--out", "{tmp}/o")
cli("cli", "sweep-report-missing-folder", "no-such-sweep", "sweep-report", "{tmp}/no-such-sweep", "--quiet")
cli("cli", "sweep-report-empty-folder", "sweep", "sweep-report", "{tmp}/empty", "--quiet", files={"empty/.keep": ""})
TUNE_OK = ('name = "t"\nbase = "case-a-payload"\ncontroller = "pdc"\ntrials = 2\nseed = 1\npopulation = 1\n'
           '[set]\nduration = 0.2\n[search]\n"control.Kp" = {min = 4.0, max = 40.0}\n')  # fmt: skip
for i, (extra, msg) in enumerate([(("--trials", "0"), "trials"), (("--trials", "-5"), "trials")]):
    cli("cli", f"tune-{i}", msg, "tune", "{tmp}/t.toml", "--quiet", "--out", "{tmp}/o", *extra,
        files={"t.toml": TUNE_OK})  # fmt: skip
cli("cli", "bench-empty-out", "--out", "bench", "--quick", "--out", "", "--quiet")

# --------------------------------------------------------------------------- command line: paths
cli("cli", "out-below-a-file", "afile", *RUN[:-1], "{tmp}/afile/o", files={"afile": "x"})
cli("cli", "out-is-a-file", "afile", *RUN[:-1], "{tmp}/afile", files={"afile": "x"})

# --------------------------------------------------------------------------- TOML: scenario files
SCEN = 'base = "case-a-payload"\nname = "x-v1"\nduration = 0.3\n'
for i, (body, msg) in enumerate(
    [
        ("", "base"),
        ('base = "case-a-payload"\nname = "x-v1"\nduration = "long"\n', "duration"),
        ('base = "case-a-payload"\nname = "x-v1"\nduration = -1\n', "duration"),
        ('base = "case-a-payload"\nname = "x-v1"\nduration = inf\n', "duration"),
        ('base = "case-a-payload"\nname = "x-v1"\nduration = nan\n', "duration"),
        (SCEN + "[payload]\nmass = -1\n", "payload.mass"),
        (SCEN + "[payload]\nmass = inf\n", "payload.mass"),
        (SCEN + "[payload]\noffset_B = [0, 0]\n", "payload.offset_B"),
        (SCEN + "[control]\nKp = [16, 16]\n", "control.Kp"),
        (SCEN + "[control]\nKpp = 16\n", "Kpp"),
        (SCEN + '[[disturbances]]\nkind = "constant"\nforce_W = [1, 2]\n', "force_W"),
        (SCEN + '[[disturbances]]\nkind = "constant"\nforce_W = [1, 2, nan]\n', "force_W"),
        (SCEN + '[[disturbances]]\nkind = "push"\nt_on = 2.0\nduration = -1.0\n', "duration"),
        (SCEN + '[[disturbances]]\nkind = "push"\nt_on = -1.0\n', "t_on"),
        (SCEN + '[[disturbances]]\nkind = "sinusoid"\nfreq_hz = -1\n', "freq"),
        (SCEN + '[[disturbances]]\nkind = "noise"\nf_lo = 5.0\nf_hi = 1.0\n', "f_"),
        (SCEN + '[[disturbances]]\nkind = "wind"\nspeed_W = [nan, 0, 0]\n', "speed"),
        (SCEN + "[trajectory]\naltitude = nan\n", "altitude"),
        (SCEN + "[sensors]\nmocap_noise_p = -0.001\n", "mocap_noise_p"),
        (SCEN + "[plant]\ninertia_scale = [1, 1, -1]\n", "inertia_scale"),
        (SCEN + "[plant]\nrotor_tau_up = -0.01\n", "rotor_tau_up"),
        ('base = "case-a-payload"\nbase = "case-b-fan"\n', "cannot read scenario file"),
        ('base = "case-a-payload"\nname = "x y/z"\n', "scenario name"),
        ("\x00\x01\x02garbage", "cannot read scenario file"),
        ('base = "case-a-payload"\nname = "x-v1"\n[a]\nb = 1\n', "unknown key"),
        ('base = "case-a-payload"\nname = "x-v1"\nplant_rate = 999.5\n', "plant_rate"),
        ('base = "case-a-payload"\nname = "x-v1"\nvehicle = "no-such-file.toml"\n', "no-such-file.toml"),
    ]
):
    cli("toml", f"scenario-{i}", msg, "run", "{tmp}/s.toml", "--quiet", "--no-plots", "--out", "{tmp}/o",
        files={"s.toml": body})  # fmt: skip
cli("toml", "scenario-not-utf8", "s.toml", "run", "{tmp}/s.toml", "--quiet", "--out", "{tmp}/o",
    files={"s.toml": b'base = "case-a-payload"\nname = "\xff\xfe"\n'})  # fmt: skip
cli("toml", "scenario-base-is-itself", "s.toml", "run", "{tmp}/s.toml", "--quiet", "--out", "{tmp}/o",
    files={"s.toml": 'base = "s.toml"\nname = "x-v1"\n'})  # fmt: skip

# --------------------------------------------------------------------------- TOML: vehicle files
VEH = 'name = "v"\nmass = 1.4\ninertia_diag = [0.011, 0.011, 0.021]\ndrag_factor = 0.016\n'
ROTOR = "[[rotors]]\nposition_B = [{x}, {y}, 0.0]\nspin = {s}\nf_max = 8.0\n"
QUAD = "".join(ROTOR.format(x=x, y=y, s=s) for x, y, s in ((0.16, 0.16, 1), (-0.16, -0.16, 1), (0.16, -0.16, -1),
                                                            (-0.16, 0.16, -1)))  # fmt: skip
for i, (body, msg) in enumerate(
    [
        (VEH.replace("1.4", "0") + QUAD, "mass"),
        (VEH.replace("1.4", "-1.4") + QUAD, "mass"),
        (VEH.replace("1.4", '"heavy"') + QUAD, "mass"),
        (VEH.replace("[0.011, 0.011, 0.021]", "[0.011, 0.011]") + QUAD, "inertia"),
        (VEH.replace("[0.011, 0.011, 0.021]", "[0.011, 0.011, 0.05]") + QUAD, "inertia"),
        (VEH.replace("[0.011, 0.011, 0.021]", "[0.011, -0.011, 0.021]") + QUAD, "inertia"),
        (VEH.replace("0.016", "-0.016") + QUAD, "drag_factor"),
        (VEH + ROTOR.format(x=0.16, y=0.0, s=1) * 4, "rotor"),  # all at one place: no roll/pitch authority
        (VEH + QUAD.replace("f_max = 8.0", "f_max = -8.0"), "f_max"),
        (VEH + QUAD.replace("spin = 1", "spin = 2"), "spin"),
        (VEH + QUAD.replace("[0.16, 0.16, 0.0]", "[0.16, 0.16]"), "position_B"),
        (VEH + 'layout = "octo"\narm_length = 0.2\nf_max = 7.0\n', "layout"),
        (VEH + 'layout = "x"\narm_length = -0.2\nf_max = 7.0\n', "arm_length"),
        (VEH + 'layout = "x"\narm_length = 0.2\nf_max = 7.0\nf_min = 8.0\n', "f_min"),
        (VEH + QUAD + "wingspan = 2\n", "wingspan"),
    ]
):
    cli("toml", f"vehicle-{i}", msg, *RUN, "--set", "vehicle={tmp}/v.toml", files={"v.toml": body})

# --------------------------------------------------------------------------- TOML: sweep and tuning files
for i, (body, msg) in enumerate(
    [
        ('name = "s"\nbase = "case-a-payload"\n', "axes"),
        ('name = "s"\nbase = "case-a-payload"\n[axes]\n"payload.mass" = []\n', "payload.mass"),
        ('name = "s"\nbase = "case-a-payload"\n[axes]\n"payload.mass" = ["a", "b"]\n', "payload.mass"),
        ('name = "s"\nbase = "case-a-payload"\n[axes]\n"payload.mass" = [0.1, nan]\n', "payload.mass"),
        ('name = "s"\nbase = "case-a-payload"\n[axes]\n"payload.weight" = [0.1, 0.2]\n', "payload.weight"),
        ('name = "s"\nbase = "case-a-payload"\nseeds = 0\n[axes]\n"payload.mass" = [0.1]\n', "seeds"),
        ('name = "s"\nbase = "case-a-payload"\nchunk = -1\n[axes]\n"payload.mass" = [0.1]\n', "chunk"),
        (
            'name = "s"\nbase = "case-a-payload"\n[axes]\n"payload.mass" = {min = 0.3, max = 0.1, n = 3}\n',
            "payload.mass",
        ),
        (
            'name = "s"\nbase = "case-a-payload"\n[axes]\n"payload.mass" = {min = 0.0, max = 0.1, n = 0}\n',
            "payload.mass",
        ),
        ('name = "s"\nbase = "case-a-payload"\ncontrollers = ["lqr"]\n[axes]\n"payload.mass" = [0.1]\n', "lqr"),
        ('name = "s"\nbase = "no-such-scenario"\n[axes]\n"payload.mass" = [0.1]\n', "no-such-scenario"),
        ('name = "../up"\nbase = "case-a-payload"\n[axes]\n"payload.mass" = [0.1]\n', "name"),
    ]
):
    cli("toml", f"sweep-{i}", msg, "sweep", "{tmp}/s.toml", "--quiet", "--no-report", "--out", "{tmp}/o",
        files={"s.toml": body})  # fmt: skip
for i, (body, msg) in enumerate(
    [
        (TUNE_OK.replace("min = 4.0, max = 40.0", "min = 40.0, max = 4.0"), "control.Kp"),
        (TUNE_OK.replace("min = 4.0, max = 40.0", "min = -4.0, max = 40.0, log = true"), "control.Kp"),
        (TUNE_OK.replace('"control.Kp"', '"control.Kpp"'), "Kpp"),
        (TUNE_OK.replace("trials = 2", "trials = 0"), "trials"),
        (TUNE_OK.replace("population = 1", "population = 0"), "population"),
        (TUNE_OK.replace('controller = "pdc"', 'controller = "lqr"'), "lqr"),
        (TUNE_OK.replace("[search]\n", "").replace('"control.Kp" = {min = 4.0, max = 40.0}\n', ""), "search"),
    ]
):
    cli("toml", f"tune-{i}", msg, "tune", "{tmp}/t.toml", "--quiet", "--out", "{tmp}/o", files={"t.toml": body})


# --------------------------------------------------------------------------- flight logs
def _sample_rows() -> tuple[str, list[str]]:
    lines = SAMPLE_CSV.read_text(encoding="utf-8").splitlines()
    return lines[0], lines[1:]


def _csv_with(edit: Callable[[str, list[str]], tuple[str, list[str]]]) -> Callable[[Path], str]:
    def make(folder: Path) -> str:
        header, rows = edit(*_sample_rows())
        return header + "\n" + "\n".join(rows) + "\n"

    return make


def _set_column(name: str, value: str, every: int = 1) -> Callable[[str, list[str]], tuple[str, list[str]]]:
    def edit(header: str, rows: list[str]) -> tuple[str, list[str]]:
        j = header.split(",").index(name)
        out = []
        for k, r in enumerate(rows):
            cells = r.split(",")
            if k % every == 0:
                cells[j] = value
            out.append(",".join(cells))
        return header, out

    return edit


def _drop_column(name: str) -> Callable[[str, list[str]], tuple[str, list[str]]]:
    def edit(header: str, rows: list[str]) -> tuple[str, list[str]]:
        j = header.split(",").index(name)
        keep = lambda s: ",".join(c for k, c in enumerate(s.split(",")) if k != j)  # noqa: E731
        return keep(header), [keep(r) for r in rows]

    return edit


LOGS: list[tuple[str, dict[str, object], str]] = [
    ("empty-csv", {"log.csv": ""}, "log.csv"),
    ("header-only-csv", {"log.csv": _csv_with(lambda h, r: (h, []))}, "no data rows"),
    ("one-row-csv", {"log.csv": _csv_with(lambda h, r: (h, r[:1]))}, "1 sample"),
    ("binary-garbage-csv", {"log.csv": bytes(range(256)) * 40}, "log.csv"),
    ("text-in-a-number-column", {"log.csv": _csv_with(_set_column("vx", "fast", every=7))}, "vx"),
    ("a-column-all-nan", {"log.csv": _csv_with(_set_column("vz", "nan"))}, "vz"),
    ("a-column-all-inf", {"log.csv": _csv_with(_set_column("wx", "inf"))}, "wx"),
    ("velocity-missing", {"log.csv": _csv_with(_drop_column("vy"))}, "vy"),
    ("time-missing", {"log.csv": _csv_with(_drop_column("t_s"))}, "t_s"),
    ("time-backwards", {"log.csv": _csv_with(lambda h, r: (h, r[::-1]))}, "time"),
    ("time-all-equal", {"log.csv": _csv_with(_set_column("t_s", "1767225600.0"))}, "time|samples"),
    ("quaternion-zero", {"log.csv": _csv_with(_set_column("q0", "0.0"))}, "quaternion"),
    (
        "semicolon-separated",
        {"log.csv": _csv_with(lambda h, r: (h.replace(",", ";"), [x.replace(",", ";") for x in r]))},
        "column",
    ),
    ("velocity-1e6", {"log.csv": _csv_with(_set_column("vx", "1e6", every=3))}, "vx|velocity|physics"),
    ("ulog-garbage", {"log.ulg": b"ULog\x01\x12\x35" + bytes(2000)}, "log.ulg"),
    ("ulog-text", {"log.ulg": "not a ulog at all\n" * 50}, "log.ulg"),
    ("ulog-truncated", {"log.ulg": lambda d: sample_path("px4").read_bytes()[:3000]}, "log.ulg"),
    ("bin-garbage", {"log.bin": bytes(range(256)) * 40}, "log.bin"),
    ("bin-empty", {"log.bin": b""}, "log.bin"),
    ("tlog-garbage", {"log.tlog": bytes(range(256)) * 40}, "log.tlog"),
    ("tlog-empty", {"log.tlog": b""}, "log.tlog"),
    ("tlog-truncated", {"log.tlog": lambda d: sample_path("tlog").read_bytes()[:2000]}, "log.tlog"),
    ("unknown-extension", {"log.xyz": "t_s,vx\n0,0\n"}, "log.xyz"),
]
for id_, files, msg in LOGS:
    name = next(iter(files))
    cli("log", id_, msg, "estimate", "{tmp}/" + name, "--mass", "1.2", "--quiet", "--no-plots", "--out", "{tmp}/o",
        files=files)  # fmt: skip


# --------------------------------------------------------------------------- the Python API
def _quad():
    return model.load_preset("pelican")


def _gains(**kw):
    return control.ImpedanceGains(**{"Kp": 16.0, "Dp": 12.0, "Ko": 0.2, "Do": 0.05, **kw})


I_PAPER = [3.4e-3, 3.4e-3, 4.7e-3]
api("VehicleParams-negative-mass", "mass", lambda d: dataclasses.replace(_quad(), mass=-1.0))
api("load_preset-unknown", "no-such", lambda d: model.load_preset("no-such"))
api("load_preset-number", "preset", lambda d: model.load_preset(3))
api("rotation_zyx-shape", "eta", lambda d: model.rotation_zyx([1.0, 2.0]))
api("body_moment_from_euler-at-90-deg", "pitch|singular",
    lambda d: model.body_moment_from_euler([0.0, 0.0, 1.0], [0.0, math.pi / 2, 0.0]))  # fmt: skip
api("ImpedanceGains-Kp-two", "Kp", lambda d: _gains(Kp=[16.0, 16.0]))
api("ImpedanceGains-Kp-text", "Kp", lambda d: _gains(Kp="abc"))
api("ImpedanceGains-Kp-nan", "Kp", lambda d: _gains(Kp=math.nan))
api("ImpedanceGains-Dp-negative", "Dp", lambda d: _gains(Dp=-1.0))
api("ControllerParams-Ts-zero", "Ts", lambda d: control.ControllerParams.paper("pdc", Ts=0.0))
api("ControllerParams-unknown-preset", "lqr", lambda d: control.ControllerParams.paper("lqr"))
api("EstimatorParams-wn-negative", "wn", lambda d: estimator.EstimatorParams(wn=-10.0))
api("EstimatorParams-zeta-zero", "zeta", lambda d: estimator.EstimatorParams(zeta=0.0))
api("EstimatorParams-order-zero", "order", lambda d: estimator.EstimatorParams(order=0))
api("EstimatorParams-order-float", "order", lambda d: estimator.EstimatorParams(order=2.5))
api("EstimatorParams-order-bool", "order", lambda d: estimator.EstimatorParams(order=True, prototype="binomial"))
api("EstimatorParams-order-bool-zeta", "order", lambda d: estimator.EstimatorParams(order=True))
api("simulate-unknown-scenario", "case-z", lambda d: scenarios.simulate("case-z"))
api("simulate-unknown-controller", "lqr", lambda d: scenarios.simulate("case-a-payload", variants=["lqr"]))
api("simulate-log-underscore", "decimate:5_0", lambda d: scenarios.simulate("case-a-payload", log="decimate:5_0"))
api("simulate-log-space", "decimate: 5", lambda d: scenarios.simulate("case-a-payload", log="decimate: 5"))
api("equivalent_rotor_tau-negative", "tau", lambda d: robust.equivalent_rotor_tau(-0.01, 0.02))
api("margins-a-string", "loop", lambda d: robust.margins("loop"))
api("designed_controller-Kp-two", "Kp", lambda d: robust.designed_controller(_quad(), "pdc", [16.0, 16.0], 12.0))
api("designed_controller-Kp-text", "Kp", lambda d: robust.designed_controller(_quad(), "pdc", "abc", 12.0))
api("read_log-a-number", "12345", lambda d: logs.read_log(12345))
api("read_log-missing", "missing.csv", lambda d: logs.read_log(d / "missing.csv"))
api("Result.load-missing", "nothing.npz", lambda d: sim.Result.load(d / "nothing.npz"))
api("Controller-vehicle-a-string", "ControllerParams", lambda d: vtol_impedance.Controller("pelican-but-a-string"))
api("Estimator-negative-mass", "mass", lambda d: vtol_impedance.Estimator(-1.0, I_PAPER, 0.01))
api("Estimator-Ts-negative", "Ts", lambda d: vtol_impedance.Estimator(1.2, I_PAPER, -0.01))
api("PlantParams-vehicle-none", "vehicle", lambda d: sim.PlantParams(None))
api("Push-negative-duration", "duration", lambda d: sim.Push(force_W=[1.0, 0.0, 0.0], t_on=2.0, duration=-1.0))
api("Push-before-the-start", "t_on", lambda d: sim.Push(force_W=[1.0, 0.0, 0.0], t_on=-2.0, duration=1.0))
api("StepWrench-off-before-on", "t_off", lambda d: sim.StepWrench(force_W=[1.0, 0.0, 0.0], t_on=2.0, t_off=1.0))
api("ConstantWrench-shape", "force", lambda d: sim.ConstantWrench(force_W=[1.0, 0.0]))

# --------------------------------------------------------------------------- the live link (options and addresses)
LIVE = ("live", "--duration", "0.5", "--display", "none", "--out", "{tmp}/o", "--connect-timeout", "0.2")
for i, (extra, msg) in enumerate(
    [
        (("--connect", "bogus"), "bogus"),
        (("--connect", "udpin:127.0.0.1:70000"), "70000"),
        (("--connect", "udpin:127.0.0.1:-1"), "-1"),
        (("--connect", "tcp:"), "tcp:"),
        (("--mass", "-1"), "mass"),
        (("--mass", "nan"), "mass"),
        (("--inertia", "1,2"), "--inertia"),
        (("--rate", "0"), "rate"),
        (("--rate", "-50"), "rate"),
        (("--wn", "-1"), "wn"),
        (("--zeta", "0"), "zeta"),
        (("--duration", "-1"), "--duration"),
        (("--duration", "nan"), "--duration"),
        (("--hover-thrust", "2"), "--hover-thrust"),
        (("--max-thrust", "-5"), "--max-thrust"),
        (("--rotor-tau", "-0.02"), "tau"),
        (("--max-gap", "0"), "gap"),
        (("--connect-timeout", "-1"), "timeout"),
        (("--connect-timeout", "0"), "--connect-timeout"),  # the flag as typed, not the field behind it
        (("--out", "/etc/passwd/x"), "/etc/passwd"),  # before the link: it named a missing heartbeat instead
        (("--system", "300"), "--system"),
        (("--system", "-1"), "--system"),
        (("--comply", "1,1,0"), "--control"),
        (("--control", "pdc", "--fence", "1"), "--fence"),
        (("--control", "pdc", "--fence", "-1,0.5"), "--fence"),
        (("--control", "pdc", "--tilt-max", "100"), "tilt"),
        (("--control", "pdc", "--watchdog", "0"), "watchdog"),
        (("--control", "comply", "--comply", "2,0,0"), "comply"),
        (("--control", "comply", "--impedance", "0,6,5"), "--impedance"),
        (("--control", "pdc", "--kp", "-1"), "kp"),
        (("--control", "pdc", "--max-speed", "0"), "speed"),
        (("--control", "pdc", "--handshake-timeout", "-1"), "handshake"),
        (("--vehicle", "no-such-preset"), "no-such-preset"),
    ]
):
    cli("live", f"live-{i}-{extra[0]}", msg, *LIVE, *(extra if extra[0] == "--connect" else
                                                     ("--connect", "udpin:127.0.0.1:14999", *extra)))  # fmt: skip
SIMAP = ("sim-autopilot", "case-a-payload", "--connect", "udpout:127.0.0.1:14998", "--duration", "0.5")
for i, (extra, msg) in enumerate(
    [
        (("--latency", "-1"), "latency"),
        (("--latency", "nan"), "latency"),
        (("--autopilot", "betaflight"), "invalid choice"),
        (("--duration", "-2"), "duration"),
        (("--latency", "5", "--duration", "2"), "latency"),
        (("--loss", "1.5"), "loss"),
        (("--speed", "0"), "speed"),
        (("--duration", "1e9"), "--duration"),  # its disturbances drawn up front: 745 GiB, a MemoryError
    ]
):
    cli("live", f"sim-autopilot-{i}", msg, *SIMAP, *extra)
cli(
    "live",
    "sim-autopilot-bad-address",
    "bogus",
    "sim-autopilot",
    "case-a-payload",
    "--connect",
    "bogus",
    "--duration",
    "0.5",
)


# --------------------------------------------------------------------------- running the corpus
def _write(folder: Path, files: dict[str, object]) -> None:
    for name, content in files.items():
        path = folder / name
        path.parent.mkdir(parents=True, exist_ok=True)
        if callable(content):
            content = content(folder)
        if isinstance(content, bytes):
            path.write_bytes(content)
        else:
            path.write_text(str(content), encoding="utf-8")


def _ids(cases: list[Case]) -> list[str]:
    return [f"{c.kind}:{c.id}" for c in cases]


def test_the_corpus_is_large_and_every_kind_is_there():
    kinds = {c.kind for c in CASES}
    assert kinds == {"cli", "toml", "log", "api", "live"}
    assert len(CASES) >= 150, len(CASES)
    assert len(set(_ids(CASES))) == len(CASES), "two cases share an id"


@pytest.mark.parametrize("case", CASES, ids=_ids(CASES))
def test_a_bad_input_is_refused_with_its_name(case: Case, tmp_path, capsys):
    _write(tmp_path, case.files)
    if case.call is not None:
        with pytest.raises(VtolImpedanceError) as info:
            case.call(tmp_path)
        assert re.search(case.match, str(info.value), re.IGNORECASE), str(info.value)
        return
    argv = [a.replace("{tmp}", str(tmp_path)) for a in case.argv]
    try:
        rc = main(argv)
    except SystemExit as e:  # argparse's own usage errors
        rc = e.code
    err = capsys.readouterr().err
    assert rc == 2, (rc, err)
    assert "Traceback" not in err and "internal error" not in err, err
    assert re.search(case.match, err, re.IGNORECASE), err
    out = tmp_path / "o"
    assert not out.exists() or not any(out.iterdir()), "a refused run wrote results"


# --------------------------------------------------------------------------- correct but unusual: accepted
def _bom(folder: Path) -> bytes:
    return b"\xef\xbb\xbf" + SAMPLE_CSV.read_bytes()


def _crlf(folder: Path) -> bytes:
    return SAMPLE_CSV.read_bytes().replace(b"\n", b"\r\n")


def _extra_columns(folder: Path) -> str:
    header, rows = _sample_rows()
    return header + ",battery_v,note_code\n" + "\n".join(r + ",15.9,3" for r in rows) + "\n"


def _spaces_in_header(folder: Path) -> str:
    header, rows = _sample_rows()
    return ", ".join(header.split(",")) + "\n" + "\n".join(rows) + "\n"


def _rotor_speeds_only_at_the_start(folder: Path) -> str:
    """An ESC stream that ran for the first 30 rows only (asked for while a ground station probed)."""
    header, rows = _sample_rows()
    cols = header.split(",")
    rpm = [j for j, c in enumerate(cols) if c.startswith("rpm")]
    out = []
    for k, r in enumerate(rows):
        cells = r.split(",")
        if k >= 30:
            for j in rpm:
                cells[j] = ""
        out.append(",".join(cells))
    return header + "\n" + "\n".join(out) + "\n"


ACCEPTED = [
    ("csv-with-a-byte-order-mark", _bom),
    ("csv-with-crlf-line-ends", _crlf),
    ("csv-with-extra-columns", _extra_columns),
    ("csv-with-spaces-after-commas", _spaces_in_header),
]


def test_a_short_optional_stream_is_left_out_not_the_log(tmp_path):
    """Rotor speeds for 30 rows only: the log is estimated from its commands, and the note says why the rotor
    speeds are not used (the whole log was refused: "the rotor speeds has 30 samples")."""
    from vtol_impedance.logs import estimate_file

    log = tmp_path / "log.csv"
    log.write_text(_rotor_speeds_only_at_the_start(tmp_path), encoding="utf-8")
    est = estimate_file(log, 1.2)
    assert est.info.get("thrust_coefficient") is None and np.isfinite(est.f_W).all()
    assert any("30 sample(s), too few to use" in n and "left out" in n for n in est.notes), est.notes
    ref = estimate_file(SAMPLE_CSV, 1.2, thrust_from="commands")
    np.testing.assert_allclose(est.f_W, ref.f_W, atol=1e-9)


@pytest.mark.parametrize("maker", [m for _, m in ACCEPTED], ids=[i for i, _ in ACCEPTED])
def test_a_correct_but_unusual_log_is_accepted(maker, tmp_path, capsys):
    from vtol_impedance.logs import estimate_file

    log = tmp_path / "log.csv"
    content = maker(tmp_path)
    log.write_bytes(content if isinstance(content, bytes) else content.encode("utf-8"))
    est = estimate_file(log, 1.2)
    assert len(est.t) > 500 and np.isfinite(est.f_W).all()
    ref = estimate_file(SAMPLE_CSV, 1.2)
    np.testing.assert_allclose(est.f_W, ref.f_W, atol=1e-9)


def test_a_scenario_file_with_unusual_but_valid_toml_is_accepted(tmp_path):
    """Comments, inline tables, integers where floats are meant, literal strings and a CRLF file."""
    from vtol_impedance.scenarios import load_toml

    body = ("# comment\r\nbase = 'case-a-payload'   # literal string\r\nname = \"x-v1\"\r\nduration = 1\r\n"
            "payload = { mass = 0, offset_B = [0, 0, 0] }\r\n")  # fmt: skip
    f = tmp_path / "s.toml"
    f.write_bytes(body.encode())
    spec = load_toml(f)
    assert spec.duration == 1.0 and spec.payload.mass == 0.0


def test_a_vehicle_file_without_geometry_flies_the_announced_defaults(tmp_path, capsys):
    """A vehicle file that gives only the body: each filled-in key is named once on the command line, and the
    run's configuration records the vehicle it flew (the Pelican's arm and rotors, as announced)."""
    import json

    (tmp_path / "v.toml").write_text(VEH.replace("drag_factor = 0.016\n", ""), encoding="utf-8")
    argv = [a.replace("{tmp}", str(tmp_path)) for a in RUN] + ["--set", f"vehicle={tmp_path}/v.toml", "--ideal"]
    assert main(argv) == 0
    err = capsys.readouterr().err
    for key, value in (("layout", "'plus'"), ("arm_length", "0.21"), ("f_max", "7.0"), ("drag_factor", "0.016")):
        assert err.count(f"no {key} given, flying the Pelican's {key} = {value}") == 1, err
    config = json.loads(next((tmp_path / "o").glob("*.config.json")).read_text())
    rotors = config["controllers"][0]["vehicle"]["rotors"]  # the nominal model the controller was given
    assert len(rotors) == 4 and {r["f_max"] for r in rotors} == {7.0}
    assert sorted(abs(c) for r in rotors for c in r["position_B"][:2]) == [0.0] * 4 + [0.21] * 4


def test_a_complete_vehicle_file_is_silent(tmp_path, recwarn):
    from vtol_impedance.model import VehicleDefaultWarning, load_preset, preset_names

    (tmp_path / "v.toml").write_text(VEH + QUAD.replace("f_max = 8.0", "f_max = 8.0\nf_min = 0.0"), encoding="utf-8")
    load_preset(str(tmp_path / "v.toml"))
    for name in preset_names():
        load_preset(name)
    assert not [w for w in recwarn if issubclass(w.category, VehicleDefaultWarning)]


def test_no_case_leaves_a_staging_folder(tmp_path):
    """Refusals are made before any folder is staged (the corpus above checks the results folder)."""
    case = next(c for c in CASES if c.id == "estimate-0---mass")
    argv = [a.replace("{tmp}", str(tmp_path)) for a in case.argv]
    assert main(argv) == 2
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]
    shutil.rmtree(tmp_path, ignore_errors=True)
