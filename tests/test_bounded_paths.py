"""Bounded work, hostile paths and caches that cannot outlive their code (issue 35, items 5 and 6).

Every test here is fast: a refusal happens before any work, progress runs on a fake clock, and the design
cache is checked with a stand-in for the 5 s search (what is tested is the key, not the search).
"""

from __future__ import annotations

import importlib
import os
from pathlib import Path

import pytest

from vtol_impedance import io as vio
from vtol_impedance.errors import InputError

rd = importlib.import_module("vtol_impedance.robust.design")  # the package exports a function of that name

# --------------------------------------------------------------------------- caches keyed by code


@pytest.fixture
def counted_design(monkeypatch, tmp_path):
    """``design`` on a fresh disk cache with the search replaced by a counter (its result: a fixed Design)."""
    calls = []

    def fake_search(vehicle, kp, dp, rate, t):
        calls.append((kp, dp, rate))
        return rd.Design(10.0, 5.0, 12.5, 8.0, t, {}, {}, ("stand-in",))

    monkeypatch.setenv("VTOL_IMPEDANCE_CACHE", str(tmp_path / "cache"))
    monkeypatch.setattr(rd, "_design_search", fake_search)
    rd._design_cached.cache_clear()
    yield calls
    rd._design_cached.cache_clear()


def _design_once():
    from vtol_impedance.model.vehicle import load_preset

    return rd.design(load_preset("pelican"), 16.0, 12.0, 100.0)


def test_design_cache_is_read_while_the_code_is_unchanged(counted_design):
    _design_once()
    rd._design_cached.cache_clear()  # a new process: only the disk remembers
    _design_once()
    assert len(counted_design) == 1
    assert len(list((Path(os.environ["VTOL_IMPEDANCE_CACHE"]) / "designs").glob("*.json"))) == 1


def test_no_design_is_remembered_as_a_design_is(counted_design, monkeypatch):
    """Gains no bandwidth keeps stable: the search (the longest, as it looks for the Dp that would do) runs
    once; later calls, in this process or another one (the disk), raise the same DesignError."""

    def no_design(vehicle, kp, dp, rate, t):
        counted_design.append((kp, dp, rate))
        raise rd.DesignError("no attitude bandwidth keeps the position loop stable: Dp must come down")

    monkeypatch.setattr(rd, "_design_search", no_design)
    for fresh_process in (False, False, True):
        if fresh_process:
            rd._design_cached.cache_clear()
        with pytest.raises(rd.DesignError, match="Dp must come down"):
            _design_once()
    assert len(counted_design) == 1


def test_design_cache_is_recomputed_when_the_code_changes(counted_design, monkeypatch, tmp_path):
    _design_once()
    rd._design_cached.cache_clear()
    edited = tmp_path / "margins_edit.py"
    edited.write_text("# an edit of the margin code\n")
    monkeypatch.setattr(rd, "DESIGN_SOURCES", (*rd.DESIGN_SOURCES, edited))
    _design_once()
    assert len(counted_design) == 2
    edited.write_text("# another edit\n")  # same list, other content
    rd._design_cached.cache_clear()
    rd._code_key.cache_clear()
    _design_once()
    assert len(counted_design) == 3


def test_design_cache_is_recomputed_after_an_upgrade(counted_design, monkeypatch):
    import vtol_impedance

    _design_once()
    rd._design_cached.cache_clear()
    monkeypatch.setattr(vtol_impedance, "__version__", vtol_impedance.__version__ + ".post1")
    _design_once()
    assert len(counted_design) == 2


def test_design_sources_are_the_code_it_runs():
    names = {(p.parent.name, p.name) for p in rd.DESIGN_SOURCES}
    for needed in [("robust", "design.py"), ("robust", "linear.py"), ("robust", "margins.py"),
                   ("sim", "plant.py"), ("control", "impedance.py"), ("estimator", "momentum.py"),
                   ("compiled", "algebra.py")]:  # fmt: skip
        assert needed in names
    assert all(p.is_file() for p in rd.DESIGN_SOURCES)


def test_source_digest_follows_version_and_content(tmp_path, monkeypatch):
    import vtol_impedance

    f = tmp_path / "a.py"
    f.write_text("x = 1\n")
    d0 = vio.source_digest([f])
    assert vio.source_digest([f]) == d0
    f.write_text("x = 2\n")
    d1 = vio.source_digest([f])
    assert d1 != d0
    monkeypatch.setattr(vtol_impedance, "__version__", "99.0")
    assert vio.source_digest([f]) != d1


def test_compiled_cache_uses_the_same_key(tmp_path, monkeypatch):
    """The kernels' stamp is :func:`source_digest` of their sources: a changed source clears the cache."""
    import vtol_impedance.compiled as comp

    monkeypatch.delenv("NUMBA_CACHE_DIR", raising=False)
    fake = tmp_path / "compiled"
    (fake / "__pycache__").mkdir(parents=True)
    src = tmp_path / "kernel.py"
    src.write_text("def f(): pass\n")
    stale = fake / "__pycache__" / "engine.run_block-1.py312.nbi"
    stale.write_text("old machine code")
    monkeypatch.setattr(comp, "_HERE", fake)
    monkeypatch.setattr(comp, "_SOURCES", (src,))
    comp._refresh_cache()
    assert (fake / "__pycache__" / "kernels.stamp").read_text() == vio.source_digest([src])
    assert not stale.exists()
    stale.write_text("new machine code")
    comp._refresh_cache()  # unchanged source: kept
    assert stale.exists()
    src.write_text("def f(): return 1\n")
    comp._refresh_cache()
    assert not stale.exists()


# --------------------------------------------------------------------------- hostile files and paths


@pytest.fixture
def hostile(tmp_path):
    """A folder of bad paths: a link loop, a dangling link, a file where a folder is needed, deep TOML."""
    (tmp_path / "loop").symlink_to("loop")
    (tmp_path / "dangling.toml").symlink_to("nowhere.toml")
    (tmp_path / "afile").write_text("not a folder\n")
    (tmp_path / "deep.toml").write_text("x = " + "[" * 100_000 + "]" * 100_000 + "\n")
    (tmp_path / "tiny.toml").write_text(TINY_SWEEP)
    return tmp_path


#: A sweep of one point: loading it costs nothing.
TINY_SWEEP = 'name = "tiny"\nbase = "case-a-payload"\ncontrollers = ["pd"]\n[axes]\n"payload.mass" = [0.0]\n'


#: Every CLI path argument that reads a file, as (argv before the path, argv after it, what the file is).
READERS = [
    (["run"], [], "scenario file"),
    (["margins"], [], "scenario file"),
    (["sweep"], [], "sweep file"),
    (["tune"], [], "tuning file"),
    (["estimate", "--example", "csv", "--vehicle"], [], "vehicle file"),
]
#: Each kind of bad path: (name, path under the hostile folder, what the message must say).
KINDS = [
    ("loop", "loop/x.toml", "loop is a symbolic link loop"),
    ("dangling", "dangling.toml", "dangling.toml is a symbolic link to nowhere.toml, which does not exist"),
    ("file-as-folder", "afile/x.toml", "afile in its path, which is a file, not a folder"),
    ("deep", "deep.toml", "nested too deeply"),
]


def _cli(argv, capsys):
    from vtol_impedance.cli import main

    rc = main(argv)
    return rc, capsys.readouterr().err


@pytest.mark.parametrize("kind,rel,says", KINDS, ids=[k[0] for k in KINDS])
@pytest.mark.parametrize("before,after,what", READERS, ids=[r[2].split()[0] + "-" + r[0][0] for r in READERS])
def test_cli_names_a_bad_input_file(hostile, capsys, before, after, what, kind, rel, says):
    path = str(hostile / rel)
    rc, err = _cli([*before, path, *after, "--quiet"], capsys)
    assert rc == 2
    assert f"cannot read {what} {path}: " in err
    assert says in err
    assert "internal error" not in err and "staging" not in err


@pytest.mark.parametrize("kind,rel,says", [k for k in KINDS if k[0] != "deep"], ids=[k[0] for k in KINDS[:3]])
def test_cli_names_a_bad_log_file(hostile, capsys, kind, rel, says):
    path = str(hostile / rel)  # the file's suffix does not matter: it is never reached
    rc, err = _cli(["estimate", path, "--quiet"], capsys)
    assert rc == 2
    assert f"cannot read log file {path}: " in err
    assert says in err


OUT_KINDS = [
    ("loop", "loop", "loop is a symbolic link loop"),
    ("through-loop", "loop/run", "loop is a symbolic link loop"),
    ("dangling", "dangling.toml/run", "dangling.toml is a symbolic link to nowhere.toml, which does not exist"),
    ("file-as-folder", "afile/run", "afile in its path, which is a file, not a folder"),
]


@pytest.mark.parametrize("kind,rel,says", OUT_KINDS, ids=[k[0] for k in OUT_KINDS])
@pytest.mark.parametrize("cmd", [["margins", "case-a-payload"], ["sweep", "tiny.toml"]], ids=["margins", "sweep"])
# (the margins command refuses before linearising, the sweep before its pre-flight check)
def test_out_names_the_users_path(hostile, capsys, cmd, kind, rel, says):
    out = str(hostile / rel)
    cmd = [cmd[0], str(hostile / cmd[1])] if cmd[1].endswith(".toml") else cmd
    rc, err = _cli([*cmd, "--out", out, "--quiet", "--no-plots"] if cmd[0] == "margins" else
                   [*cmd, "--out", out, "--quiet"], capsys)  # fmt: skip
    assert rc == 2
    assert f"cannot use {out} as the output folder: " in err and says in err
    assert "staging" not in err and ".tmp" not in err


def test_out_in_an_unwritable_folder_is_named(hostile, capsys, monkeypatch):
    """Permission as a non-root user would meet it (root passes every access check, so it is simulated)."""
    locked = hostile / "locked"
    locked.mkdir()
    real = os.access

    def access(p, mode, **kw):
        return not (Path(p) == locked and mode & os.W_OK) and real(p, mode, **kw)

    monkeypatch.setattr(os, "access", access)
    rc, err = _cli(["margins", "case-a-payload", "--out", str(locked / "run"), "--quiet", "--no-plots"], capsys)
    assert rc == 2
    assert f"{locked} is not writable (permission denied)" in err


def test_unsearchable_parent_is_named(hostile, monkeypatch):
    locked = hostile / "locked"
    locked.mkdir()
    real = os.lstat

    def lstat(p, *a, **kw):
        if Path(p).parent == locked:
            raise PermissionError(13, "Permission denied", str(p))
        return real(p, *a, **kw)

    monkeypatch.setattr(os, "lstat", lstat)
    assert vio.explain_path(locked / "f.toml") == f"{locked} cannot be searched (permission denied), so " \
        f"{locked / 'f.toml'} cannot be reached"  # fmt: skip


@pytest.mark.skipif(os.geteuid() == 0, reason="root reads every file")
def test_unreadable_file_for_real(hostile, capsys):
    f = hostile / "secret.toml"
    f.write_text('name = "x"\n')
    f.chmod(0)
    rc, err = _cli(["run", str(f), "--quiet"], capsys)
    assert rc == 2 and "is not readable (permission denied)" in err


def test_set_value_nested_too_deeply_is_named(capsys):
    rc, err = _cli(["margins", "case-a-payload", "--set", "control.Kp=" + "[" * 5000 + "]" * 5000], capsys)
    assert rc == 2 and "nests arrays or tables too deeply" in err


def test_staging_and_temporary_names_map_to_the_users_path():
    assert vio.user_path("/r/.run.staging-ab12cd/x.json") == "/r/run/x.json"
    assert vio.user_path("/r/.run.old-ab12cd") == "/r/run"
    assert vio.user_path("/r/out/.bench.json.k2j3h4.tmp") == "/r/out/bench.json"
    assert vio.user_path("/r/plain/file.txt") == "/r/plain/file.txt"


def test_a_good_path_has_nothing_to_explain(tmp_path):
    f = tmp_path / "ok.toml"
    f.write_text("")
    assert vio.explain_path(f) is None
    assert vio.explain_path(tmp_path / "new" / "run", "folder") is None
    assert vio.explain_path(tmp_path / "missing.toml") == f"{tmp_path / 'missing.toml'} does not exist"


# --------------------------------------------------------------------------- bounded work with progress

from vtol_impedance.sweeps import budget  # noqa: E402


def _grid_toml(n: int) -> str:
    """Issue 35's sample: an ``n`` x ``n`` x ``n`` margin grid of case A, PD and PD+C (margins on)."""
    vals = lambda lo, step: ", ".join(f"{lo + step * i:.4g}" for i in range(n))  # noqa: E731
    return (
        'name = "grid"\nbase = "case-a-payload"\ncontrollers = ["pd", "pdc"]\n[axes]\n'
        f'"payload.mass" = [{vals(0.0, 0.01)}]\n"sensors.mocap_delay" = [{vals(0.0, 0.002)}]\n'
        f'"plant.inertia_scale" = [{vals(0.8, 0.04)}]\n'
    )


def test_a_3375_point_margin_grid_is_refused_before_any_work(tmp_path, capsys, monkeypatch):
    (tmp_path / "grid.toml").write_text(_grid_toml(15))

    def no_work(*a, **k):
        raise AssertionError("work started before the refusal")

    monkeypatch.setattr(rd, "_design_search", no_work)
    monkeypatch.setattr("vtol_impedance.sweeps.run.point_margins", no_work)
    monkeypatch.setattr("vtol_impedance.sweeps.spec.check", no_work)
    rc, err = _cli(["sweep", str(tmp_path / "grid.toml"), "--out", str(tmp_path / "out")], capsys)
    assert rc == 2
    # by hand: 6,750 flights of 30 s (case A: 1 s on the ground, 4 s take-off, 25 s hover) at 1,000
    # vehicle-s/s = 202.5 s; 3,375 x 2 margins at 0.2 s = 1,350 s; 3,375 checks at 0.01 s = 33.75 s;
    # 15 designs (one per latency) at 6 s = 90 s: 1,676 s = 28 min
    assert "sweep grid is estimated at 28 min, over the bound of 10 min" in err
    assert "--yes" in err and "--max-minutes" in err
    assert not (tmp_path / "out").exists()


def test_sweep_estimate_by_hand(monkeypatch):
    from vtol_impedance.sweeps import from_dict

    monkeypatch.setattr("os.cpu_count", lambda: 4)

    d = {"name": "s", "base": "case-a-payload", "controllers": ["pd", "pdc"], "seeds": 3, "set": {"duration": 100.0},
         "axes": {"payload.mass": [0.0, 0.1]}}  # fmt: skip
    s = from_dict(d, check_points=False)
    # 2 points x 3 seeds x 2 controllers x 100 s at 1,000 vehicle-s/s; 2 checks; 2 x 2 margins; one design
    hand = 12 * 100.0 / 1000.0 + 2 * 0.01 + 4 * 0.2 + 6.0
    assert budget.sweep_seconds(s) == pytest.approx(hand)
    assert budget.sweep_seconds(s, workers=2) == pytest.approx(hand / 2)
    assert budget.sweep_seconds(s, workers=1000) == pytest.approx(hand / 4)  # the local cluster's cap: the cores
    assert budget.sweep_seconds(s, backend="numpy") == pytest.approx(hand - 1.2 + 1200.0 / 0.4)
    d["axes"]["control.Kp,control.Dp"] = [[8.0, 10.0], [16.0, 12.0], [8.0, 10.0]]  # 2 distinct designs
    s = from_dict({**d, "margins": False}, check_points=False)
    assert budget.sweep_seconds(s) == pytest.approx(36 * 100.0 / 1000.0 + 6 * 0.01 + 2 * 6.0)


def test_tuning_estimate_by_hand(monkeypatch):
    from vtol_impedance.sweeps.tune import tuning_from_dict

    monkeypatch.setattr("os.cpu_count", lambda: 4)

    t = tuning_from_dict({
        "name": "t", "base": "case-a-payload", "controller": "pdc", "trials": 10, "population": 4,
        "set": {"duration": 50.0}, "search": {"control.Kp": {"min": 4.0, "max": 40.0}},
        "cost": {"min_phase_margin_deg": 20.0},
    }, check_corners=False)  # fmt: skip
    # per trial: 4 flights x 50 s at 1,000 vehicle-s/s, 4 margins, one design (Kp changes it); and the
    # three corners of the search box designed before the first trial
    assert budget.tuning_seconds(t, 10) == pytest.approx(3 * 6.0 + 10 * (0.2 + 4 * 0.2 + 6.0))
    assert budget.tuning_seconds(t, 10, workers=2) == pytest.approx(3 * 6.0 + 5 * (0.2 + 4 * 0.2 + 6.0))
    assert budget.tuning_seconds(t, 10, workers=64) == pytest.approx(3 * 6.0 + 2.5 * (0.2 + 4 * 0.2 + 6.0))


@pytest.mark.parametrize("bad", [0.0, -1.0, float("nan"), float("inf")])
def test_max_minutes_must_be_a_positive_number(bad):
    with pytest.raises(InputError, match="--max-minutes must be a positive number"):
        budget.check_budget(10.0, "x", bad)


def test_the_bound_and_its_confirmations():
    budget.check_budget(budget.MAX_MINUTES * 60.0, "at the bound")  # at the bound: runs
    with pytest.raises(budget.WorkBoundError, match="estimated at 11 min, over the bound of 10 min"):
        budget.check_budget(11 * 60.0, "sweep x")
    budget.check_budget(11 * 60.0, "sweep x", max_minutes=12)
    budget.check_budget(1e9, "sweep x", yes=True)
    with pytest.raises(budget.WorkBoundError, match="over the bound of 0.5 min"):
        budget.check_budget(31.0, "sweep x", max_minutes=0.5)


def test_cli_refuses_a_tiny_sweep_under_a_tiny_bound(tmp_path, capsys):
    (tmp_path / "tiny.toml").write_text(TINY_SWEEP)
    rc, err = _cli(["sweep", str(tmp_path / "tiny.toml"), "--max-minutes", "0.001", "--out", str(tmp_path / "o")],
                   capsys)  # fmt: skip
    assert rc == 2 and "over the bound of 0.001 min" in err and not (tmp_path / "o").exists()
    rc, err = _cli(["sweep", str(tmp_path / "tiny.toml"), "--max-minutes", "-3"], capsys)
    assert rc == 2 and "--max-minutes must be a positive number of minutes, got -3" in err


def test_a_bad_trial_count_is_refused_before_the_corners_are_designed(tmp_path, capsys, monkeypatch):
    def no_work(*a, **k):
        raise AssertionError("work started before the refusal")

    monkeypatch.setattr(rd, "_design_search", no_work)
    monkeypatch.setenv("VTOL_IMPEDANCE_CACHE", str(tmp_path / "cache"))  # nothing designed before
    rd._design_cached.cache_clear()
    (tmp_path / "t.toml").write_text(
        'name = "t"\nbase = "case-a-payload"\n[search]\n"control.Kp" = {min = 4.0, max = 40.0}\n'
    )
    rc, err = _cli(["tune", str(tmp_path / "t.toml"), "--trials", "0", "--out", str(tmp_path / "o")], capsys)
    assert rc == 2 and "--trials" in err and "work started" not in err and not (tmp_path / "o").exists()


def test_cli_refuses_a_tuning_before_designing_anything(tmp_path, capsys, monkeypatch):
    def no_work(*a, **k):
        raise AssertionError("work started before the refusal")

    monkeypatch.setattr(rd, "_design_search", no_work)
    (tmp_path / "t.toml").write_text(
        'name = "t"\nbase = "case-a-payload"\ncontroller = "pd"\ntrials = 5\npopulation = 1\n'
        '[search]\n"control.Kp" = {min = 4.0, max = 40.0}\n'
    )
    rc, err = _cli(["tune", str(tmp_path / "t.toml"), "--out", str(tmp_path / "o")], capsys)
    # by hand: 3 corners designed (18 s), then 5 trials of one 30 s flight (0.03 s) and one design (6 s)
    assert rc == 1 and "work started before the refusal" in err  # under 10 min: let through, to the work
    rc, err = _cli(["tune", str(tmp_path / "t.toml"), "--max-minutes", "0.5", "--out", str(tmp_path / "o")], capsys)
    assert rc == 2 and "tuning t is estimated at 48 s, over the bound of 0.5 min" in err
    assert not (tmp_path / "o").exists()


class _Clock:
    def __init__(self) -> None:
        self.t = 0.0

    def __call__(self) -> float:
        return self.t


def test_progress_lines_every_few_seconds_with_the_time_left():
    import io

    clock, out = _Clock(), io.StringIO()  # not a terminal
    p = budget.Progress(20, "flights", every_s=5.0, stream=out, clock=clock)
    for _ in range(20):  # one flight a second
        clock.t += 1.0
        p(1)
    lines = out.getvalue().splitlines()
    assert len(lines) == 4  # at 5, 10, 15 s and the end
    # at 5 s: 5 of 20 done at 1 flight/s: 15 s left
    assert lines[0] == "  flights 5/20      1.0/s  15 s left"
    assert lines[-1].startswith("  flights 20/20") and lines[-1].endswith("0 s left")


def test_progress_counts_every_unit_of_a_sweep(monkeypatch):
    """In this process the sweep reports each unit (not only each chunk): a tiny sweep on NumPy."""
    from vtol_impedance.sweeps import from_dict, run_units

    d = {"name": "s", "base": "case-a-payload", "controllers": ["pd", "pdc"], "seeds": 3, "margins": False,
         "set": {"duration": 0.05}, "axes": {"payload.mass": [0.0]}}  # fmt: skip
    s = from_dict(d, check_points=False)
    calls = []
    rows, _ = run_units(s, s.chunk_units(0), "numpy", calls.append)
    assert calls == [2, 2, 2] and len(rows["unit"]) == 6


def test_progress_counts_every_point_checked():
    """Checking a big grid's points designs their controllers: it reports each point too."""
    from vtol_impedance.sweeps import from_dict

    hand = {"wn_o": 17.5, "wn_o_yaw": 7.3, "attitude_filter_wn": 26.25, "estimator_wn": 8.0}  # no design needed
    d = {"name": "s", "base": "case-a-payload", "controllers": ["pd"], "set": {"control": hand},
         "axes": {"payload.mass": [0.0, 0.05, 0.1]}}  # fmt: skip
    calls = []
    from_dict(d, on_point=calls.append)
    assert calls == [1, 1, 1]
