"""The sample logs that ship with the package: each recovers the simulated flight's known wrench (through
G(s), SciPy's lsim), the generator reproduces them, ``--example`` finds them, and the logs guide's estimate
commands run as written."""

from __future__ import annotations

import re
import shlex
from pathlib import Path

import numpy as np
import pytest
import scipy.signal

from vtol_impedance.cli import main
from vtol_impedance.errors import InputError
from vtol_impedance.logs import estimate_file, read_any, samples

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def truth():
    tr = samples.truth()
    sys_g = scipy.signal.lti([100.0], [1.0, 20.0, 100.0])  # eq. (10), wn = 10, zeta = 1
    g = {k: np.stack([scipy.signal.lsim(sys_g, tr[k][:, j], tr["t_s"])[1] for j in range(3)], -1)
         for k in ("f_lumped_W", "f_rotor_W")}  # fmt: skip
    return tr["t_s"], g


@pytest.mark.parametrize("name", samples.names())
def test_every_sample_recovers_the_known_wrench(name, truth):
    t_true, g = truth
    ro = {"conventions": "auto"} if name == "ros-csv" else {}
    e = estimate_file(samples.path(name), mass=samples.MASS_KG, read_options=ro)
    t = e.t - samples.CLOCK_OFFSET_S[name] * (1.0 if name != "ros-csv" else 0.0)
    if name == "ros-csv":
        assert e.info["conventions"]["chosen"]["time_unit"] == "ms"
    target = g["f_rotor_W"] if "rotor speeds" in e.info["thrust"] else g["f_lumped_W"]
    ref = np.stack([np.interp(t, t_true, target[:, j]) for j in range(3)], -1)
    sel = t > 6.0  # after the take-off
    err = np.linalg.norm(e.f_W - ref, axis=-1)[sel]
    assert np.median(err) < 0.045 and np.percentile(err, 95) < 0.12, (name, np.median(err))
    np.testing.assert_allclose(e.f_W[sel].mean(0), ref[sel].mean(0), atol=0.04)
    assert e.f_W[sel, 2].mean() > 0.9  # the payload's weight, about +1.06 N down


def test_the_ros_sample_needs_its_conventions():
    with pytest.raises(InputError, match="contradicts physics.*--time-unit ms"):
        read_any(samples.path("ros-csv"))


def test_the_generator_reproduces_the_shipped_files(tmp_path):
    """Byte for byte on this machine; elsewhere the simulation's last bits may differ, so then the values."""
    from vtol_impedance.logs.samples.generate import generate

    made = {p.name: p for p in generate(tmp_path)}
    assert set(made) == {f for f, _ in samples.SAMPLES.values()} | {samples.TRUTH_FILE}
    for fname, p in made.items():
        shipped = samples.folder() / fname
        if p.read_bytes() == shipped.read_bytes():
            continue
        if fname.endswith(".csv"):
            a = np.genfromtxt(p, delimiter=",", skip_header=1)
            b = np.genfromtxt(shipped, delimiter=",", skip_header=1)
            np.testing.assert_allclose(a, b, rtol=1e-5, atol=1e-6)
        else:
            ra, rb = read_any(p, conventions="unchecked")[0], read_any(shipped, conventions="unchecked")[0]
            for sa, sb in zip(ra.signals(), rb.signals(), strict=True):
                np.testing.assert_allclose(sa.t, sb.t)
                np.testing.assert_allclose(sa.values, sb.values, rtol=1e-4, atol=1e-5)


def test_example_list_and_unknown_name(capsys, tmp_path):
    assert main(["estimate", "--example", "list"]) == 0
    out = capsys.readouterr().out
    assert all(n in out for n in samples.names())
    rc = main(["estimate", "--example", "nope", "--mass", "1.2", "--out", str(tmp_path / "o")])
    err = capsys.readouterr().err
    assert rc == 2 and "no sample log 'nope'; the samples are: csv, ros-csv" in err and "Traceback" not in err
    assert main(["estimate", "--mass", "1.2"]) == 2  # neither a log nor an example


def _readme_commands() -> list[str]:
    """The sample-log commands of the logs guide (they were the README's before it became a door)."""
    text = (ROOT / "docs" / "guide" / "logs.md").read_text()
    section = text[text.index("## Sample logs") : text.index("## Where each signal comes from")]
    cmds = []
    for block in re.findall(r"```bash\n(.*?)```", section, re.S):
        for line in block.splitlines():
            line = line.split("#")[0].strip()
            if line.startswith("vtol-impedance estimate"):
                cmds.append(line)
    return cmds


def test_the_readme_estimate_commands_run_as_written(tmp_path, capsys):
    cmds = _readme_commands()
    assert len(cmds) >= 6
    for i, cmd in enumerate(cmds):
        argv = shlex.split(cmd)[1:]
        if "list" not in argv:
            argv += ["--out", str(tmp_path / f"run{i}"), "--no-plots"]
        rc = main(argv)
        err = capsys.readouterr().err
        assert rc == 0, (cmd, err)
        assert "WARNING" not in err, (cmd, err)
