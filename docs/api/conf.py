"""Sphinx configuration of the nitsche API reference (built by `make docs`)."""
import os
import sys

sys.path.insert(0, os.path.abspath(os.path.join(__file__, "..", "..", "..")))
os.environ.setdefault("NITSCHE_JAX_CACHE", "off")  # importing nitsche writes no JAX cache

project = "nitsche"
author = "the nitsche authors"
copyright = "the nitsche authors, BSD-3-Clause"

extensions = ["sphinx.ext.autodoc", "sphinx.ext.viewcode"]

autodoc_default_options = {
    "members": True,
    "show-inheritance": True,
    "member-order": "bysource",
}
autodoc_typehints = "none"
autoclass_content = "both"        # a class's docstring and its __init__'s

html_theme = "alabaster"
html_static_path = []
html_title = "nitsche API reference"
exclude_patterns = ["_build"]
highlight_language = "none"


def plain_text(app, what, name, obj, options, lines):
    """The docstrings of nitsche are plain text, not reStructuredText: formulas such as
    |grad u|^2, [lambda - g/alpha]_+ and indented equations would be misread as markup.
    Each docstring is shown as written, as a literal block."""
    if any(line.strip() for line in lines):
        lines[:] = ["::", ""] + ["    " + line if line.strip() else "" for line in lines] + [""]


def setup(app):
    app.connect("autodoc-process-docstring", plain_text)
