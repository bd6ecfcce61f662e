"""Sphinx configuration of the thinfilm documentation (``python -m sphinx -W -b html docs OUT``).

The command-line and scene-spec references are generated from the code by the directives of
``docs/_ext/thinfilm_docs.py``; the tutorials (``docs/tutorials/*.md``) are MyST notebooks
executed at every build (myst-nb), at small sizes.
"""

import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE / "_ext"))

import mitsuba as mi  # noqa: E402

from thinfilm import __version__  # noqa: E402

# the plugin modules define their classes for a variant (their docstrings are the plugin
# reference); a scalar one needs no LLVM
mi.set_variant("scalar_spectral_polarized")

project = "thinfilm"
author = "the thinfilm authors"
copyright = "the thinfilm authors, BSD-3-Clause"
release = version = __version__

extensions = [
    "sphinx.ext.autodoc",
    "sphinx.ext.mathjax",
    "sphinx.ext.viewcode",
    "numpydoc",
    "myst_nb",
    "thinfilm_docs",
]

# Markdown pages and executed notebooks: myst-nb reads .md files (MyST) and runs those that
# declare a kernel; a failing cell fails the build.
source_suffix = {".rst": "restructuredtext", ".md": "myst-nb"}
myst_enable_extensions = ["dollarmath", "colon_fence"]
myst_heading_anchors = 3
nb_execution_mode = "force"
nb_execution_raise_on_error = True
nb_execution_timeout = 300
nb_execution_show_tb = True
nb_merge_streams = True

exclude_patterns = ["_build", "**/.ipynb_checkpoints", "_ext"]
suppress_warnings = ["myst.header"]   # headings that skip a level (the pages moved from the README)

# The API reference: the docstrings are numpydoc.
autodoc_member_order = "bysource"
autodoc_typehints = "none"
autodoc_mock_imports = []
numpydoc_show_class_members = False
numpydoc_xref_param_type = False
numpydoc_validation_checks = set()
# citations keep their labels: a module's references ([1]_) are cited by its functions too
numpydoc_citation_re = "(?!)"
# a module's references need not all be cited on the page
suppress_warnings += ["ref.citation", "ref.footnote"]

html_theme = "furo"
html_title = f"thinfilm {release}"
html_static_path = []
html_extra_path = []
nitpicky = False
