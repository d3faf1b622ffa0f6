"""Sphinx configuration: the user guide (``docs/*.md``, via myst-parser) and the API reference (autodoc).

Build: ``python -m sphinx -W --keep-going -b html docs /tmp/docs-html`` (``pip install '.[docs]'``).
"""

import os
import sys

sys.path.insert(0, os.path.abspath(".."))  # the springsim package of this checkout

project = "springsim"
author = "springsim contributors"
copyright = "springsim contributors"  # noqa: A001 (Sphinx's name)
release = version = "0.1.0"

extensions = [
    "sphinx.ext.autodoc",
    "sphinx.ext.napoleon",  # numpydoc-style docstrings (Parameters, Returns, Raises, ...)
    "sphinx.ext.mathjax",
    "sphinx.ext.viewcode",
    "myst_parser",  # the Markdown user guide in docs/*.md
]

source_suffix = {".rst": "restructuredtext", ".md": "markdown"}
root_doc = "index"
exclude_patterns = ["_build"]

# autodoc: the distributed backend imports petsc4py and mpi4py only inside functions, but mock them in case.
autodoc_mock_imports = ["petsc4py", "mpi4py"]
autodoc_member_order = "bysource"
autodoc_typehints = "description"
autodoc_typehints_format = "short"
autodoc_default_options = {"members": True, "show-inheritance": True}
autoclass_content = "both"  # the class docstring and __init__'s

napoleon_google_docstring = False
napoleon_numpy_docstring = True
napoleon_use_rtype = False
napoleon_use_ivar = True

myst_heading_anchors = 3

html_theme = "alabaster"
html_title = "springsim"


def _outside_links_as_paths(app, docname, source):
    """Show Markdown links to files outside ``docs/`` (``../BENCHMARKS.md#frame-cost``) as their paths.

    They work on the repository's web view; the HTML reference has no page for them.
    """
    import re

    source[0] = re.sub(r"\[([^\]]+)\]\(\.\./([^)\s]+)\)", r"\1 (``\2``)", source[0])


def setup(app):
    app.connect("source-read", _outside_links_as_paths)
