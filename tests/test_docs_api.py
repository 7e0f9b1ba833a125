"""The API reference is complete: every public name has a docstring and a place in ``docs/api/*.rst``.

Public names are a package's ``__all__``; a module without ``__all__`` (``io``, ``errors``,
``conventions``) exports what it defines at top level without a leading underscore. A function or class
needs its own docstring, in numpydoc form where it has sections; a constant needs a ``#:`` comment where
it is assigned (the reference shows it; a package that re-exports a constant is followed to the module
that defines it). No Sphinx is needed: the docs build (``.ci/run``) checks the same with numpydoc's
validation and builds the pages; this test fails first, and fast.
"""

from __future__ import annotations

import ast
import importlib
import inspect
import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
API = ROOT / "docs" / "api"
PACKAGES = (
    "model",
    "estimator",
    "control",
    "runtime",
    "records",
    "sim",
    "robust",
    "scenarios",
    "analysis",
    "logs",
    "live",
    "sweeps",
    "tunepage",
    "io",
    "errors",
    "conventions",
)

# numpydoc's sections (https://numpydoc.readthedocs.io/en/latest/format.html).
SECTIONS = {
    "Parameters", "Returns", "Yields", "Receives", "Other Parameters", "Raises", "Warns", "Warnings",
    "See Also", "Notes", "References", "Examples", "Attributes", "Methods",
}  # fmt: skip
PARAM_SECTIONS = {"Parameters", "Other Parameters", "Attributes", "Returns", "Yields", "Receives"}


def _source_tree(modname: str) -> tuple[ast.Module, list[str]]:
    path = Path(importlib.import_module(modname).__file__)
    text = path.read_text(encoding="utf-8")
    return ast.parse(text), text.splitlines()


def _defined_names(modname: str) -> list[str]:
    """Top-level functions, classes and assigned names of a module, without a leading underscore."""
    tree, _ = _source_tree(modname)
    names: list[str] = []
    for node in tree.body:
        if isinstance(node, ast.FunctionDef | ast.ClassDef):
            names.append(node.name)
        elif isinstance(node, ast.Assign):
            names += [t.id for t in node.targets if isinstance(t, ast.Name)]
        elif isinstance(node, ast.AnnAssign) and isinstance(node.target, ast.Name):
            names.append(node.target.id)
    return [n for n in dict.fromkeys(names) if not n.startswith("_")]


def public_names(package: str) -> list[str]:
    """The public names of ``vtol_impedance.<package>``."""
    mod = importlib.import_module(f"vtol_impedance.{package}")
    if hasattr(mod, "__all__"):
        return list(mod.__all__)
    return _defined_names(mod.__name__)


def _doc_comment(modname: str, name: str) -> str | None:
    """The ``#:`` comment above (or beside) the assignment of ``name`` in ``modname``, or the string
    right after it; for a name the module imports (``from .x import KINDS as DISTURBANCE_KINDS``), that
    of the module it comes from."""
    tree, lines = _source_tree(modname)
    for i, node in enumerate(tree.body):
        targets = []
        if isinstance(node, ast.Assign):
            targets = [t.id for t in node.targets if isinstance(t, ast.Name)]
        elif isinstance(node, ast.AnnAssign) and isinstance(node.target, ast.Name):
            targets = [node.target.id]
        if name in targets:
            above, k = [], node.lineno - 2
            while k >= 0 and lines[k].lstrip().startswith("#:"):
                above.insert(0, lines[k].lstrip()[2:].strip())
                k -= 1
            inline = lines[node.lineno - 1].partition("#:")[2].strip()
            after = tree.body[i + 1] if i + 1 < len(tree.body) else None
            string = (
                after.value.value
                if isinstance(after, ast.Expr) and isinstance(getattr(after, "value", None), ast.Constant)
                and isinstance(after.value.value, str) else ""
            )  # fmt: skip
            return " ".join(above) or inline or string.strip() or None
        if isinstance(node, ast.ImportFrom) and node.level >= 1:
            for alias in node.names:
                if (alias.asname or alias.name) == name:
                    base = modname if Path(importlib.import_module(modname).__file__).name == "__init__.py" else (
                        modname.rpartition(".")[0]
                    )  # fmt: skip
                    for _ in range(node.level - 1):
                        base = base.rpartition(".")[0]
                    source = f"{base}.{node.module}" if node.module else base
                    return _doc_comment(source, alias.name)
    return None


def _own_docstring(obj: object) -> str:
    """The object's own docstring: not a class's inherited one, nor the signature that dataclasses and
    NamedTuples write when there is none."""
    if inspect.isclass(obj):
        doc = obj.__dict__.get("__doc__") or ""
        if re.match(rf"^{re.escape(obj.__name__)}\(.*\)$", doc.strip(), re.S):
            return ""
        return doc
    return getattr(obj, "__doc__", None) or ""


def _listed(package: str) -> set[str]:
    """Names the reference page of ``package`` lists in its autosummary tables."""
    text = (API / f"{package}.rst").read_text(encoding="utf-8")
    assert f".. currentmodule:: vtol_impedance.{package}" in text, f"api/{package}.rst sets no currentmodule"
    names: set[str] = set()
    lines = text.splitlines()
    for i, line in enumerate(lines):
        if line.strip() != ".. autosummary::":
            continue
        for entry in lines[i + 1 :]:
            if entry and not entry.startswith("   "):
                break
            item = entry.strip()
            if item and not item.startswith(":"):
                names.add(item.lstrip("~"))
    return names


def _signature_names(obj: object) -> set[str] | None:
    target = obj.__init__ if inspect.isclass(obj) else obj
    try:
        params = inspect.signature(target).parameters
    except (TypeError, ValueError):
        return None
    if any(p.kind is inspect.Parameter.VAR_KEYWORD for p in params.values()):
        return None
    return set(params)


def docstring_problems(qualname: str, obj: object) -> list[str]:
    """What is malformed in the numpydoc sections of ``obj``'s docstring (empty: nothing)."""
    doc = inspect.cleandoc(_own_docstring(obj))
    lines = doc.splitlines()
    problems: list[str] = []
    sections: list[tuple[str, list[str]]] = []
    i = 0
    while i < len(lines):
        head = lines[i].strip()
        if i + 1 < len(lines) and head and set(lines[i + 1].strip()) == {"-"} and lines[i + 1].strip():
            if len(lines[i + 1].strip()) != len(head):
                problems.append(f"{qualname}: the underline of section {head!r} is not as long as its title")
            body = []
            i += 2
            while i < len(lines) and not (
                i + 1 < len(lines) and lines[i].strip() and set(lines[i + 1].strip()) == {"-"}
            ):
                body.append(lines[i])
                i += 1
            sections.append((head, body))
            continue
        i += 1
    signature = _signature_names(obj)
    for head, body in sections:
        if head not in SECTIONS:
            problems.append(f"{qualname}: unknown section {head!r} (numpydoc knows {', '.join(sorted(SECTIONS))})")
            continue
        if head not in PARAM_SECTIONS:
            continue
        entries = [(k, line) for k, line in enumerate(body) if line.strip() and not line.startswith((" ", "\t"))]
        for k, line in entries:
            name, sep, kind = line.partition(" : ")
            described = k + 1 < len(body) and body[k + 1].startswith((" ", "\t")) and body[k + 1].strip()
            if sep and (len(kind) > 60 or kind.rstrip().endswith(".")):
                problems.append(f"{qualname}, {head}: {line.strip()!r} puts a description where its type belongs")
            elif not described and head != "Returns":
                problems.append(f"{qualname}, {head}: {name.strip()!r} has no description on the next, indented line")
            if head in ("Parameters", "Other Parameters") and signature is not None:
                for one in (n.strip().lstrip("*") for n in name.split(",")):
                    if one and one not in signature:
                        problems.append(f"{qualname}, {head}: {one!r} is not a parameter of the signature")
    return problems


def _public_objects(package: str) -> list[tuple[str, object]]:
    mod = importlib.import_module(f"vtol_impedance.{package}")
    return [(f"vtol_impedance.{package}.{n}", getattr(mod, n)) for n in public_names(package)]


def _documented_members(cls: type) -> list[tuple[str, object]]:
    """The public methods and properties a class defines itself (what the reference shows of it)."""
    out = []
    for name, member in vars(cls).items():
        if name.startswith("_"):
            continue
        fn = member.fget if isinstance(member, property) else getattr(member, "__func__", member)
        if inspect.isfunction(fn) and (fn.__doc__ or "").strip():
            out.append((f"{cls.__qualname__}.{name}", fn))
    return out


@pytest.mark.parametrize("package", PACKAGES)
def test_every_public_name_has_a_docstring(package):
    missing = []
    for qualname, obj in _public_objects(package):
        if inspect.isclass(obj) or inspect.isroutine(obj):
            if not _own_docstring(obj).strip():
                missing.append(f"{qualname} has no docstring")
        elif not _doc_comment(f"vtol_impedance.{package}", qualname.rpartition(".")[2]):
            missing.append(f"{qualname} (a constant) has no '#:' comment where it is assigned")
    assert not missing, "\n".join(missing)


@pytest.mark.parametrize("package", PACKAGES)
def test_the_reference_lists_every_public_name(package):
    listed = _listed(package)
    public = set(public_names(package))
    assert not public - listed, f"docs/api/{package}.rst does not list {sorted(public - listed)}"
    assert not listed - public, f"docs/api/{package}.rst lists names that are not public: {sorted(listed - public)}"


@pytest.mark.parametrize("package", PACKAGES)
def test_docstring_sections_are_numpydoc(package):
    problems = []
    for qualname, obj in _public_objects(package):
        if inspect.isclass(obj) or inspect.isroutine(obj):
            problems += docstring_problems(qualname, obj)
        if inspect.isclass(obj):
            problems += [p for name, fn in _documented_members(obj) for p in docstring_problems(name, fn)]
    assert not problems, "\n".join(problems)


def test_every_package_has_a_reference_page_in_the_index():
    index = (API / "index.rst").read_text(encoding="utf-8")
    toctree = {line.strip() for line in index.splitlines() if line.startswith("   ") and line.strip()[:1] != ":"}
    pages = {p.stem for p in API.glob("*.rst")} - {"index"}
    assert pages == set(PACKAGES), f"api pages {sorted(pages)} against packages {sorted(PACKAGES)}"
    assert toctree >= set(PACKAGES), f"api/index.rst does not list {sorted(set(PACKAGES) - toctree)}"


# The checks above must be able to fail: each is run here on a small broken example.


def _broken(x, y):
    """Sum.

    Parameters
    ----------
    x : the first value.
    z : float
        Not a parameter.

    Return
    ------
    The sum.
    """


def test_the_checks_catch_what_they_are_for():
    problems = "\n".join(docstring_problems("_broken", _broken))
    assert "puts a description where its type belongs" in problems
    assert "'z' is not a parameter" in problems
    assert "unknown section 'Return'" in problems
    assert _own_docstring(type("NoDoc", (), {})) == ""
    from dataclasses import dataclass

    @dataclass
    class Bare:
        a: int

    assert _own_docstring(Bare) == ""  # the generated "Bare(a: int)" is not a docstring
    assert _doc_comment("vtol_impedance.sim", "DISTURBANCE_KINDS")  # followed to sim.disturbances.KINDS
    assert _doc_comment("vtol_impedance.io", "atomic_path") is None  # a function, not a documented constant
