"""Sphinx configuration: Markdown pages (myst-parser), the Python API from the docstrings
(autodoc), the command line from the real parser (sphinx-argparse), the reference tables from
the code's own tables (_ext/twin_tables.py). Laid out so that ROS's rosdoc2 can build it (a
plain Sphinx project in doc/). Build: ``scripts/docs`` (warnings are errors)."""

import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(Path(__file__).resolve().parent / '_ext'))

project = 'servovalve_twin'
author = 'servovalve_twin maintainers'
extensions = ['myst_parser', 'sphinx.ext.autodoc', 'sphinx.ext.napoleon', 'sphinxarg.ext',
              'twin_tables']
source_suffix = {'.md': 'markdown', '.rst': 'restructuredtext'}
exclude_patterns = ['_build']
myst_heading_anchors = 3
myst_enable_extensions = ['colon_fence']
autodoc_member_order = 'bysource'
autodoc_typehints = 'none'
html_theme = 'alabaster'
suppress_warnings = ['myst.header']
