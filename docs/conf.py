"""Sphinx configuration of the uavdyn documentation site.

Build (from the repository root, with the ``docs`` extra installed)::

    python -m sphinx -W --keep-going -b html docs docs/_build/html
"""

from __future__ import annotations

import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))  # document the checkout even without an editable install

from uavdyn import __version__  # noqa: E402

project = "uavdyn"
author = "uavdyn contributors"
copyright = "uavdyn contributors, BSD-3-Clause"
release = __version__
version = ".".join(__version__.split(".")[:2])

extensions = [
    "myst_parser",
    "sphinx.ext.autodoc",
    "sphinx.ext.napoleon",
]

source_suffix = {".rst": "restructuredtext", ".md": "markdown"}
root_doc = "index"

# Only pages are sources: the build output, and the folders of generated figures and JSON
# (benchmarks, validation, MPC demo, Monte-Carlo envelopes, tutorial figures).
# benchmarks/bench_hybrid.md is a bare table (it is also pasted into the README); the page
# benchmarks/hybrid_correction.md gives it a title and includes it; benchmarks/knockout.md
# does the same for the bare tables benchmarks/bench_knockout.md and
# benchmarks/bench_knockout_60_sorties.md, benchmarks/bench_knockout_before_sortie_weights.md,
# benchmarks/bench_knockout_output_penalty.md, benchmarks/bench_knockout_before_damping_prior.md
# and benchmarks/knockout_patience/patience20.md, and the T-28's benchmarks/knockout_t28/*.md.
exclude_patterns = [
    "_build",
    "benchmarks/bench_hybrid.md",
    "benchmarks/bench_knockout.md",
    "benchmarks/bench_knockout_60_sorties.md",
    "benchmarks/bench_knockout_before_sortie_weights.md",
    "benchmarks/bench_knockout_output_penalty.md",
    "benchmarks/bench_knockout_before_damping_prior.md",
    "benchmarks/knockout_patience/patience20.md",
    "benchmarks/knockout_restarts/*.md",
    "benchmarks/knockout_start_fit/*.md",
    "benchmarks/knockout_fade/*.md",
    "benchmarks/knockout_t28/*.md",
    "**/*.json",
    "mpc/*",
    "montecarlo/*",
    "tutorials/real_log/*",
]

# MyST: GitHub-style anchors for headings down to level 4, so the pages' in-page links
# (``[Limits](#limits)``) resolve in the site as they do on GitHub.
myst_heading_anchors = 4

# autodoc + napoleon: NumPy-style docstrings only; each sub-package page documents its
# ``__all__`` (imported names included), in source order.
napoleon_google_docstring = False
napoleon_numpy_docstring = True
napoleon_use_rtype = False
autodoc_member_order = "bysource"
autodoc_typehints = "signature"  # the docstrings' Parameters sections carry the types too
autodoc_preserve_defaults = True  # show ``tableau=RK4``, not the tableau's repr
autodoc_default_options = {"members": True}

html_theme = "alabaster"
html_title = f"uavdyn {release}"
html_theme_options = {"description": "Nonlinear longitudinal UAV flight dynamics"}
