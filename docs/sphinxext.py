"""Helpers of the documentation build (imported by ``conf.py`` and by ``tests/test_docs_api.py``).

- :func:`stage_gallery` copies ``examples/*.py`` and ``docs/gallery/*`` into one generated folder that
  sphinx-gallery executes, so the examples stay where users look for them and are run by the build.
- :func:`reset_argv` gives each gallery example its command-line arguments (short flights for the build).
- :func:`data_doc` finds the ``#:`` comment that documents a public constant, also when a package
  re-exports it from a submodule under another name; :func:`fill_data_docstrings` shows it in the
  reference (autodoc reads comments only in the module that it documents).
"""

from __future__ import annotations

import importlib
import pkgutil
import shutil
from pathlib import Path
from typing import Any

DOCS = Path(__file__).resolve().parent
ROOT = DOCS.parent
GALLERY_STAGE = DOCS / "_gallery_src"

#: Arguments each gallery example runs with during the build (see the example's ``--help``): short flights.
GALLERY_ARGV = {
    "controller_in_your_loop.py": ["--seconds", "3"],
    "estimate_from_a_log.py": ["--duration", "12", "--out", "_results/example-estimate"],
}

#: Order of the gallery: the paper first, then your own loop, interaction, margins, logs, tuning.
GALLERY_ORDER = (
    "paper_cases.py",
    "controller_in_your_loop.py",
    "reject_or_comply.py",
    "stability_margins.py",
    "estimate_from_a_log.py",
    "attitude_filter_bandwidth.py",
)


def stage_gallery() -> Path:
    """Copy the examples and the gallery-only scripts into :data:`GALLERY_STAGE`; return it."""
    if GALLERY_STAGE.exists():
        shutil.rmtree(GALLERY_STAGE)
    GALLERY_STAGE.mkdir()
    for src in sorted((DOCS / "gallery").iterdir()):
        if src.is_file():
            shutil.copy2(src, GALLERY_STAGE / src.name)
    for src in sorted((ROOT / "examples").glob("*.py")):
        shutil.copy2(src, GALLERY_STAGE / src.name)
    return GALLERY_STAGE


def reset_argv(gallery_conf: dict[str, Any], script_vars: dict[str, Any]) -> list[str]:
    """sphinx-gallery hook: ``sys.argv[1:]`` for one example."""
    return list(GALLERY_ARGV.get(Path(script_vars["src_file"]).name, []))


def gallery_order(filename: str) -> tuple[int, str]:
    """sphinx-gallery sort key: :data:`GALLERY_ORDER`, then any other example by name."""
    name = Path(filename).name
    return (GALLERY_ORDER.index(name) if name in GALLERY_ORDER else len(GALLERY_ORDER), name)


def _submodules(package: str) -> list[str]:
    pkg = importlib.import_module(package)
    names = [package]
    if hasattr(pkg, "__path__"):
        names += [m.name for m in pkgutil.walk_packages(pkg.__path__, package + ".")]
    return names


def data_doc(module: str, name: str) -> str | None:
    """The ``#:`` comment (or string after the assignment) of the constant ``module.name``.

    Looked up first in ``module`` itself, then in the submodule that binds the same object, whatever
    name it has there (``vtol_impedance.sim.DISTURBANCE_KINDS`` is ``sim.disturbances.KINDS``).
    """
    from sphinx.pycode import ModuleAnalyzer

    obj = getattr(importlib.import_module(module), name)
    for modname in _submodules(module):
        try:
            mod = importlib.import_module(modname)
            docs = ModuleAnalyzer.for_module(modname).find_attr_docs()
        except Exception:  # a module that needs an optional extra, or has no source
            continue
        for (scope, attr), lines in docs.items():
            if scope == "" and getattr(mod, attr, None) is obj and "".join(lines).strip():
                return "\n".join(lines).strip()
    return None


def fill_data_docstrings(app: Any, what: str, name: str, obj: Any, options: Any, lines: list[str]) -> None:
    """``autodoc-process-docstring``: a constant gets the comment of the module that defines it (a package
    re-exporting it has none), never the docstring of its type (``dict``, ``ndarray``)."""
    if what != "data":
        return
    module, _, attr = name.rpartition(".")
    doc = data_doc(module, attr)
    if doc:
        lines[:] = [*doc.splitlines(), ""]
    elif " ".join("".join(lines).split()) == " ".join((type(obj).__doc__ or "").split()):
        lines[:] = []


def skip_namedtuple_aliases(app: Any, what: str, name: str, obj: Any, skip: bool, options: Any) -> bool | None:
    """``autodoc-skip-member``: leave out the generated "Alias for field number N" of NamedTuple fields
    (the class docstring describes its fields)."""
    doc = getattr(obj, "__doc__", None) or ""
    if isinstance(doc, str) and doc.startswith("Alias for field number"):
        return True
    return None
