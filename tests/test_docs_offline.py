"""The documentation reads offline: maths come from the site itself, not a CDN, and links between pages land.

A one-page project is built with the maths settings of ``docs/conf.py`` (its extensions that render maths,
MyST with its extensions, the theme): every script must be served from the site's ``_static``, none from
the network, and ``sphinxext.broken_links`` (the check the docs build runs on every page) must find
nothing. Where Debian's Chromium is installed (``.ci/run`` installs it) the page is also opened with every
request outside the site refused, and the equations must come out typeset, with the paper's numbers.
The link check itself is run on a small hand-made site with one fault of each kind.
"""

from __future__ import annotations

import ast
import importlib.util
import re
import shutil
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
DOCS = ROOT / "docs"
sys.path.insert(0, str(DOCS))
import sphinxext  # noqa: E402

CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")

PAGE = r"""# Maths offline

Inline $\dot q = \beta + w$, and eq. (6) as the docs write it:

(eq-6)=
```{math}
:nowrap:

\[ q = \begin{bmatrix} m I_3 & O_3 \\ O_3 & M(\eta) \end{bmatrix}
       \begin{bmatrix} \dot p \\ \dot\eta \end{bmatrix} \tag{6} \]
```

Back to [eq. (6)](#eq-6).
"""


def _conf_values() -> dict:
    """The literal settings of ``docs/conf.py`` (read, not executed: executing it stages the gallery)."""
    values = {}
    for node in ast.parse((DOCS / "conf.py").read_text(encoding="utf-8")).body:
        if isinstance(node, ast.Assign) and len(node.targets) == 1 and isinstance(node.targets[0], ast.Name):
            try:
                values[node.targets[0].id] = ast.literal_eval(node.value)
            except ValueError:
                pass
    return values


@pytest.fixture(scope="module")
def built(tmp_path_factory) -> Path:
    """The one-page site, built once for the tests of this file."""
    tmp_path = tmp_path_factory.mktemp("docs-offline")
    for module in ("sphinx", "myst_parser", "pydata_sphinx_theme"):
        pytest.importorskip(module, reason="needs the docs extra")
    from sphinx.application import Sphinx
    from sphinx.util.docutils import docutils_namespace

    conf = _conf_values()
    maths = [e for e in conf["extensions"] if "math" in e]
    assert maths, "docs/conf.py names no maths extension"
    missing = [e for e in maths if importlib.util.find_spec(e) is None]
    if missing:
        pytest.skip(f"needs the docs extra ({', '.join(missing)})")
    src = tmp_path / "src"
    src.mkdir()
    (src / "index.md").write_text(PAGE, encoding="utf-8")
    (src / "conf.py").write_text(
        f"extensions = {[*maths, 'myst_parser']!r}\n"
        f"myst_enable_extensions = {conf['myst_enable_extensions']!r}\n"
        f"html_theme = {conf['html_theme']!r}\n",
        encoding="utf-8",
    )
    out = tmp_path / "html"
    with docutils_namespace():  # Sphinx registers directives in docutils' global tables: leave them as found
        app = Sphinx(str(src), str(src), str(out), str(tmp_path / "doctrees"), "html", status=None, warningiserror=True)
        app.build()
    assert app.statuscode == 0
    return out


def test_maths_are_served_by_the_site_itself(built):
    out = built
    page = (out / "index.html").read_text(encoding="utf-8")
    scripts = re.findall(r"<script[^>]*\bsrc=\"([^\"]+)\"", page)
    mathjax = [s for s in scripts if "mathjax" in s.lower()]
    assert mathjax, f"no MathJax script on a page with maths: {scripts}"
    for src in scripts:
        assert "://" not in src and not src.startswith("//"), f"a script comes from the network: {src}"
    for src in mathjax:
        assert src.startswith("_static/"), src
        assert (out / src.split("?")[0]).is_file(), f"{src} is referenced but not in the site"
    assert sphinxext.broken_links(out) == []


@pytest.mark.skipif(CHROMIUM is None, reason="needs Debian's chromium (installed by .ci/run)")
def test_maths_typeset_with_the_network_refused(built):
    out = built
    from playwright.sync_api import sync_playwright

    refused: list[str] = []

    def only_files(route):
        if route.request.url.startswith("file:"):
            route.continue_()
        else:
            refused.append(route.request.url)
            route.abort()

    with sync_playwright() as p:
        browser = p.chromium.launch(executable_path=CHROMIUM, args=["--no-sandbox", "--disable-gpu"])
        try:
            page = browser.new_page()
            page.route("**/*", only_files)
            page.goto((out / "index.html").as_uri())
            page.wait_for_function("() => document.querySelectorAll('mjx-container').length >= 2", timeout=20_000)
            info = page.evaluate(
                """() => ({
                    typeset: document.querySelectorAll('mjx-container').length,
                    errors: [...document.querySelectorAll('mjx-merror')].map(e => e.getAttribute('data-mjx-error')),
                    raw: document.body.innerText.includes('\\\\begin{bmatrix}'),
                    display: [...document.querySelectorAll('mjx-container[display="true"]')].map(e => e.innerText),
                })"""
            )
        finally:
            browser.close()
    assert refused == []
    assert info["typeset"] == 2 and info["errors"] == [] and not info["raw"], info
    assert info["display"] and "6" in info["display"][0], info  # the paper's number, \tag{6}


def _site(root: Path, pages: dict[str, str]) -> Path:
    for name, body in pages.items():
        (root / name).parent.mkdir(parents=True, exist_ok=True)
        (root / name).write_text(f"<html><body>{body}</body></html>", encoding="utf-8")
    return root


def test_the_link_check_finds_what_breaks_offline(tmp_path):
    site = _site(
        tmp_path,
        {
            "index.html": '<h1 id="top">x</h1><a href="guide/a.html#b-c">ok</a> <a href="#top">ok</a>'
            '<a href="guide/a.html#nope">wrong anchor</a> <a href="gone.html">missing page</a>'
            '<a href="https://example.org/x.html#y">another site: not followed</a>'
            '<script src="_static/local.js"></script>'
            '<script src="https://cdn.example.org/mathjax.js"></script>'
            '<link rel="stylesheet" href="//cdn.example.org/katex.css">'
            '<link rel="canonical" href="https://example.org/">',
            "guide/a.html": '<span id="b-c"></span><a href="../index.html#top">up</a>'
            '<a href="../_modules/m.html#f">source</a>',
            "_modules/m.html": '<div class="viewcode-block" id="g"></div>',
            "_static/local.js": "",
            "_static/template.html": '<a href="{{ pathto(x) }}">a theme template, not a page</a>',
        },
    )
    found = {(page, link) for page, link, _ in sphinxext.broken_links(site)}
    assert found == {
        ("index.html", "guide/a.html#nope"),
        ("index.html", "gone.html"),
        ("index.html", "https://cdn.example.org/mathjax.js"),
        ("index.html", "//cdn.example.org/katex.css"),
        ("guide/a.html", "../_modules/m.html#f"),
    }
