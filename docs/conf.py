"""Sphinx configuration of the SS-NeRF documentation: MyST Markdown pages, the furo theme (nerfstudio's own stack).

`make docs` builds it into `docs/_build/html` with warnings as errors. The registry table, the two methods' settings
and the API reference are read from the code at build time (`_ext/ssnerf_docs.py`, autodoc).
"""

from __future__ import annotations

import sys
from pathlib import Path

DOCS = Path(__file__).resolve().parent
sys.path.insert(0, str(DOCS / "_ext"))
sys.path.insert(0, str(DOCS.parent))

project = "SS-NeRF for nerfstudio"
author = "the SS-NeRF plugin's authors"
copyright = "2026, " + author

extensions = ["myst_parser", "sphinx.ext.autodoc", "ssnerf_docs"]
source_suffix = {".md": "markdown"}
root_doc = "index"
exclude_patterns = ["_build", "results/**/*.json"]
myst_heading_anchors = 3
smartquotes = False
myst_enable_extensions = ["colon_fence"]

html_theme = "furo"
html_title = project
html_static_path: list = []

autodoc_member_order = "bysource"
autodoc_typehints = "signature"
autodoc_class_signature = "separated"
autodoc_preserve_defaults = True
