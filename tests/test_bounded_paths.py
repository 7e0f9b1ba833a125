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
