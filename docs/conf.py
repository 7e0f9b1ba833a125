"""Sphinx configuration of the vtol-impedance documentation.

Build (from the repository root, in the project's virtual environment with the ``docs`` extra)::

    python -m sphinx -W -b html docs docs/_build/html

The gallery's examples are executed during the build (short flights; a few minutes in all on two cores).
"""

from __future__ import annotations

import os
import sys
from pathlib import Path

DOCS = Path(__file__).resolve().parent
sys.path.insert(0, str(DOCS))  # sphinxext

import sphinxext  # noqa: E402

import vtol_impedance  # noqa: E402

os.environ.setdefault("MPLBACKEND", "Agg")

project = "vtol-impedance"
author = "the vtol-impedance developers"
copyright = "2026, the vtol-impedance developers"
release = vtol_impedance.__version__
version = ".".join(release.split(".")[:2])

extensions = [
    "sphinx.ext.autodoc",
    "sphinx.ext.autosummary",
    "sphinx.ext.mathjax",
    "sphinx-mathjax-offline",  # MathJax 3 copied into _static: maths render offline, no CDN
    "sphinx.ext.viewcode",
    "numpydoc",
    "myst_parser",
    "sphinx_gallery.gen_gallery",
]

source_suffix = {".rst": "restructuredtext", ".md": "markdown"}
root_doc = "index"
exclude_patterns = ["_build", "_gallery_src", "gallery", "README.md", "**/GALLERY_HEADER.rst"]
templates_path = ["_templates"]

# Maths: MathJax from the package sphinx-mathjax-offline, which copies it into _static/mathjax and points
# mathjax_path there (no page loads anything from the network; sphinxext.check_built_html fails the build
# on one that does, and tests/test_docs_offline.py builds a page with these settings).
# Markdown pages (MyST): $...$ maths, ::: fences for notes, heading anchors for links between pages.
myst_enable_extensions = ["dollarmath", "colon_fence", "deflist"]
myst_heading_anchors = 3

# API reference: one page per public name, generated from the lists in api/*.rst.
autosummary_generate = True
autosummary_imported_members = False
autodoc_typehints = "signature"
autodoc_member_order = "bysource"
autodoc_preserve_defaults = True
numpydoc_show_class_members = False
numpydoc_class_members_toctree = False
numpydoc_attributes_as_param_list = False
# Every documented object has a docstring (GL08), and its sections are known (GL06), in order (GL07) and document
# parameters that exist (PR02): checked while the reference is built.
numpydoc_validation_checks = {"GL06", "GL07", "GL08", "PR02"}
# Overrides of a documented base method (the disturbances' hooks) inherit its docstring.
numpydoc_validation_exclude = {r"\.__init__$", r"\.__call__$", r"\.__new__$", r"\.(encode|profile|starts_at)$"}

# Gallery: examples/*.py and docs/gallery/*.py, executed with short flights (sphinxext.GALLERY_ARGV).
sphinx_gallery_conf = {
    "examples_dirs": str(sphinxext.stage_gallery()),
    "gallery_dirs": "auto_examples",
    "filename_pattern": r"\.py$",
    "ignore_pattern": r"__init__\.py",
    "reset_argv": "sphinxext.reset_argv",
    "within_subsection_order": "sphinxext.gallery_order",
    "download_all_examples": False,
    "remove_config_comments": True,
    "show_signature": False,
    "min_reported_time": 1,
    "write_computation_times": False,
    "matplotlib_animations": False,
    "image_srcset": [],
}

html_theme = "pydata_sphinx_theme"
html_title = f"vtol-impedance {release}"
html_static_path = []
html_theme_options = {
    "github_url": "https://github.com/vtol-impedance/vtol-impedance",
    "navbar_align": "left",
    "show_toc_level": 2,
    "navigation_with_keys": False,
    "footer_start": ["copyright"],
    "footer_end": ["sphinx-version"],
}
html_context = {"default_mode": "light"}
html_show_sourcelink = False


def setup(app):
    app.connect("autodoc-process-docstring", sphinxext.fill_data_docstrings)
    app.connect("autodoc-skip-member", sphinxext.skip_namedtuple_aliases)
    app.add_role("source", sphinxext.source_role)
    app.connect("html-page-context", sphinxext.fix_viewcode_backlinks)
    app.connect("build-finished", sphinxext.check_built_html, priority=900)  # after the assets are copied
