"""Helpers of the documentation build (imported by ``conf.py`` and by ``tests/test_docs_api.py``).

- :func:`stage_gallery` copies ``examples/*.py`` and ``docs/gallery/*`` into one generated folder that
  sphinx-gallery executes, so the examples stay where users look for them and are run by the build.
- :func:`reset_argv` gives each gallery example its command-line arguments (short flights for the build).
- :func:`data_doc` finds the ``#:`` comment that documents a public constant, also when a package
  re-exports it from a submodule under another name; :func:`fill_data_docstrings` shows it in the
  reference (autodoc reads comments only in the module that it documents).
- :func:`check_built_html` runs when the HTML is written: every link between the site's pages must land
  on a page and an anchor that exist, and no page may load a script or style sheet from the network
  (the site, maths included, reads offline). Each finding is a warning, so ``-W`` fails the build.
"""

from __future__ import annotations

import html
import importlib
import pkgutil
import posixpath
import re
import shutil
from pathlib import Path
from typing import Any
from urllib.parse import unquote, urlsplit

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


_ID = re.compile(r"""\b(?:id|name)=["']([^"']+)["']""")
_LINK = re.compile(r"""<(a|link|script|img|source)\b([^>]*?)\b(?:href|src)=["']([^"']*)["']([^>]*)>""", re.IGNORECASE)


def broken_links(outdir: Path | str) -> list[tuple[str, str, str]]:
    """Links of the built HTML in ``outdir`` that break offline: ``(page, link, why)`` for each.

    A relative link must name a file of the site and, if it has a ``#anchor`` into an HTML page, an
    ``id`` (or ``name``) of that page. A script, style sheet or image loaded from ``http(s)://`` or ``//``
    is reported too: the site must read without the network. Links *to* other sites (an ``<a>`` to the
    repository) are what they are and not followed. The theme's templates copied into ``_static`` are
    not pages and are skipped.
    """
    root = Path(outdir)
    files = {f.relative_to(root).as_posix() for f in root.rglob("*") if f.is_file()}
    pages = sorted(f for f in files if f.endswith(".html") and not f.startswith("_static/"))
    texts: dict[str, str] = {}
    ids: dict[str, set[str]] = {}

    def text_of(page: str) -> str:
        if page not in texts:
            texts[page] = (root / page).read_text(encoding="utf-8", errors="replace")
        return texts[page]

    def ids_of(page: str) -> set[str]:
        if page not in ids:
            ids[page] = {html.unescape(i) for i in _ID.findall(text_of(page))}
        return ids[page]

    found: list[tuple[str, str, str]] = []
    for page in pages:
        here = posixpath.dirname(page)
        for tag, before, raw, after in _LINK.findall(text_of(page)):
            link = html.unescape(raw)
            parts = urlsplit(link)
            if parts.scheme or link.startswith("//"):
                loaded = tag.lower() != "a" and not (tag.lower() == "link" and "stylesheet" not in before + after)
                if loaded and parts.scheme in ("http", "https", ""):
                    found.append((page, link, "loaded from the network: the page must read offline"))
                continue
            if not parts.path and not parts.fragment:
                continue  # href="" or "?query"
            target = posixpath.normpath(posixpath.join(here, unquote(parts.path))) if parts.path else page
            if target not in files and f"{target}/index.html" in files:
                target = f"{target}/index.html"
            if target not in files:
                found.append((page, link, "no such file in the site"))
            elif parts.fragment and target.endswith(".html"):
                known = ids_of(target)
                if parts.fragment not in known and unquote(parts.fragment) not in known:
                    found.append((page, link, f"no id {unquote(parts.fragment)!r} in {target}"))
    return found


def check_built_html(app: Any, exception: Exception | None) -> None:
    """``build-finished``: warn (an error under ``-W``) for each link of :func:`broken_links`."""
    if exception is not None or app.builder.format != "html":
        return
    from sphinx.util import logging

    logger = logging.getLogger("vtol_impedance.docs")
    for page, link, why in broken_links(app.outdir):
        logger.warning("%s: link %r: %s", page, link, why, type="vtol", subtype="links")


_BACKLINK = re.compile(r'(<a class="viewcode-back" href=")([^"#]*)#([^"]*)(")')


def fix_viewcode_backlinks(app: Any, pagename: str, templatename: str, context: dict, doctree: Any) -> None:
    """``html-page-context``: on a highlighted source page, each "[docs]" link goes to the name as documented.

    viewcode writes every backlink of a module as ``<prefix>.<name>`` with one prefix per module, that of
    the first page that documented any of its objects; ``vtol_impedance.logs`` documents ``check_inertia``
    (defined in ``model/vehicle.py``), so every other object of that file linked to a
    ``#vtol_impedance.logs.<name>`` that its ``vtol_impedance.model`` page does not have. Each link now
    names the object that its target page documents.
    """
    if not pagename.startswith("_modules/") or "body" not in context:
        return
    entry = getattr(app.env, "_viewcode_modules", {}).get(pagename[len("_modules/") :].replace("/", "."))
    if not entry:
        return
    prefix = entry[3] + "."
    node_ids: dict[str, set[str]] = {}
    for obj in app.env.domains.python_domain.objects.values():
        node_ids.setdefault(obj.docname, set()).add(obj.node_id)
    here = posixpath.dirname(pagename)

    def retarget(m: re.Match) -> str:
        uri, anchor = m.group(2), m.group(3)
        docname = posixpath.normpath(posixpath.join(here, uri)).removesuffix(app.builder.link_suffix)
        known = node_ids.get(docname, set())
        if anchor in known or not anchor.startswith(prefix):
            return m.group(0)
        name = anchor[len(prefix) :]
        match = [i for i in known if i.endswith("." + name)]
        return f"{m.group(1)}{uri}#{match[0]}{m.group(4)}" if len(match) == 1 else m.group(0)

    context["body"] = _BACKLINK.sub(retarget, context["body"])


def source_role(
    name: str, rawtext: str, text: str, lineno: int, inliner: Any, options: Any = None, content: Any = None
):
    """``{source}`module.function``` (a leading ``~`` is allowed; or ``{source}`title <module.function>```):
    a link to the function on viewcode's highlighted page of its module, ``_modules/<module>.html#<function>``.

    The page and its anchor exist when the function is documented somewhere (``docs/compiled.md`` documents
    the compiled kernels); :func:`check_built_html` fails the build on a link that does not land.
    """
    from docutils import nodes
    from sphinx.util.nodes import split_explicit_title

    has_title, title, target = split_explicit_title(text)
    module, _, obj = target.lstrip("~").rpartition(".")
    docname = inliner.document.settings.env.docname
    page = "_modules/" + module.replace(".", "/") + ".html"
    uri = posixpath.relpath(page, posixpath.dirname(docname) or ".") + "#" + obj
    label = title if has_title else obj
    return [nodes.reference(rawtext, "", nodes.literal(label, label), refuri=uri, internal=True)], []
