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
                   ("sim", "plant.py"), ("control", "impedance.py"), ("estimator", "momentum.py")]:  # fmt: skip
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
