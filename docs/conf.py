"""Sphinx configuration of the stcgym documentation (``make docs``).

The build needs no network: no intersphinx inventories, no remote assets; the theme (furo) is a
package dependency of the ``docs`` extra. Warnings are errors (``-W`` in the Makefile).
"""

from __future__ import annotations

import logging
import os
import sys
from pathlib import Path

from sphinx.ext import autosummary
from sphinx.util import logging as sphinx_logging

ROOT = Path(__file__).resolve().parents[1]
# the local extension below
sys.path.insert(0, str(Path(__file__).resolve().parent))
os.environ.setdefault("MPLBACKEND", "Agg")


class _AsSphinxInfo(logging.Handler):
    """Hands the ``stcgym`` logger's lines to Sphinx as information.

    The gallery's scripts run in this process, and the first of them compiles stcgym's
    kernels on an empty cache, which the library announces as a warning on the ``stcgym``
    logger (what a user waiting at a prompt should see). In a docs build that compile is
    expected: the line goes to the build's log as an info line, not as a WARNING, and not
    into the captured output of the example that happened to trigger it.
    """

    def emit(self, record: logging.LogRecord) -> None:
        sphinx_logging.getLogger("stcgym").info(self.format(record))


logging.getLogger("stcgym").addHandler(_AsSphinxInfo())
logging.getLogger("stcgym").propagate = False

project = "stcgym"
author = "the stcgym developers"
copyright = "2026, the stcgym developers"

extensions = [
    "myst_parser",
    "sphinx.ext.autodoc",
    "sphinx.ext.autosummary",
    "sphinx.ext.viewcode",
    "numpydoc",
    "sphinx_gallery.gen_gallery",
    "sphinx_copybutton",
]

source_suffix = {".md": "markdown", ".rst": "restructuredtext"}
root_doc = "index"
exclude_patterns = [
    "_build",
    "sg_execution_times.rst",
    "gallery/*.ipynb",
    "gallery/*.py",
    "gallery/*.md5",
    "**.codeobj.json",
]

# MyST: ::: fences, definition lists, heading anchors for links between pages. The pages
# and docstrings write equations as code (`theta += P phi e`): no maths renderer, no remote
# script.
myst_enable_extensions = ["colon_fence", "deflist"]
myst_heading_anchors = 3

# API reference: one page per public name, generated from the docstrings at build time
autosummary_generate = True
# A summary line in the API tables is a docstring's first sentence, cut at the first ". ";
# "Ding & Ma (2014) eq. (46)" does not end a sentence (tests/test_docs.py checks the tables).
autosummary.WELL_KNOWN_ABBREVIATIONS = (
    *autosummary.WELL_KNOWN_ABBREVIATIONS,
    "eq.",
    "eqs.",
)
autosummary_imported_members = True
# members inherited from a base class are not documented again on a subclass's page (an explicit
# "inherited-members": False here would also switch off the option where a page asks for it),
# except for the classes named in "documented_bases", whose public attributes live partly in a
# base class of their own: their pages list them all (_templates/autosummary/class.rst)
autodoc_default_options = {"members": True, "show-inheritance": True}
templates_path = ["_templates"]
autosummary_context = {
    "documented_bases": [
        "RecursiveEstimator",
        "SelfTuningController",
        "MultivariableSelfTuningController",
    ]
}
autodoc_typehints = "none"  # numpydoc's Parameters sections carry the types
autoclass_content = "class"
numpydoc_show_class_members = False
numpydoc_class_members_toctree = False
numpydoc_validation_checks: set[str] = set()

sphinx_gallery_conf = {
    "examples_dirs": str(ROOT / "examples"),
    "gallery_dirs": "gallery",
    "filename_pattern": r"/plot_",
    "download_all_examples": False,
    "remove_config_comments": True,
    "within_subsection_order": "FileNameSortKey",
    "show_memory": False,
    "abort_on_example_error": True,
    # its timing pages load jQuery, DataTables and Bootstrap from CDNs: no remote assets here
    "write_computation_times": False,
}

html_theme = "furo"
html_title = "stcgym"
html_static_path = ["_static"]
html_css_files = ["stcgym.css"]  # local, no remote assets
html_show_sourcelink = False
