"""Sphinx configuration of jaxslam's documentation.

Before a build it writes the result tables from ``benchmarks/results/``
(``generate_tables.py``) and the parameter reference from
:func:`jaxslam.app.params.parameter_reference` (``generate_parameters.py``), and copies
the notebooks from ``notebooks/`` (rendered with the outputs stored in them by ``docs/execute_notebooks.py``; the
build does not run them).
"""

from __future__ import annotations

import shutil
import sys
from pathlib import Path

DOCS = Path(__file__).resolve().parent
ROOT = DOCS.parent
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(DOCS))

import generate_parameters  # noqa: E402
import generate_tables  # noqa: E402

import jaxslam  # noqa: E402

generate_tables.write_all()
generate_parameters.write()
_notebooks = DOCS / "_notebooks"
_notebooks.mkdir(exist_ok=True)
for _nb in sorted((ROOT / "notebooks").glob("*.ipynb")):
    if not (_notebooks / _nb.name).exists() or (_notebooks / _nb.name).read_bytes() != _nb.read_bytes():
        shutil.copyfile(_nb, _notebooks / _nb.name)

project = "jaxslam"
author = "the jaxslam authors"
release = version = jaxslam.__version__
copyright = "the jaxslam authors"

extensions = [
    "myst_nb",
    "sphinx.ext.autodoc",
    "sphinx.ext.autosummary",
    "sphinx.ext.napoleon",
    "sphinx.ext.mathjax",
    "sphinx.ext.viewcode",
    "sphinxcontrib.bibtex",
]
source_suffix = {".rst": "restructuredtext", ".md": "myst-nb", ".ipynb": "myst-nb"}
exclude_patterns = ["_build", "_generated", "README.md", "**.ipynb_checkpoints"]
templates_path = ["_templates"]

# Notebooks: rendered with their stored outputs (docs/execute_notebooks.py; the particle sweeps
# take minutes each, so the build does not run them; tests/test_notebooks.py checks they are current).
nb_execution_mode = "off"
nb_merge_streams = True  # a loop's printed lines in one output box, not one box per print
myst_enable_extensions = ["dollarmath", "amsmath", "colon_fence", "deflist"]
myst_heading_anchors = 3

autosummary_generate = True
autosummary_imported_members = False
# A package documents what it defines; what it re-exports is documented once, where it is defined.
autodoc_default_options = {"members": True, "undoc-members": False, "show-inheritance": False,
                           "ignore-module-all": True}
autodoc_typehints = "description"
autodoc_member_order = "bysource"
napoleon_google_docstring = True
napoleon_numpy_docstring = False
napoleon_use_rtype = False
napoleon_use_ivar = True  # NamedTuple fields: autodoc documents them as members already

bibtex_bibfiles = ["references.bib"]
bibtex_default_style = "plain"
bibtex_reference_style = "author_year"

nitpicky = True
# Types of other libraries that have no inventory here (the build reads no network).
nitpick_ignore_regex = [
    (r"py:.*", r"(jax|jaxlib|numpy|np|jnp|chex|optax|scipy|matplotlib|rerun|rr|rosbags|tqdm)(\..*)?"),
    (r"py:.*", r"(Array|ArrayLike|PRNGKey|NDArray|DTypeLike|Path|PathLike|Callable|Any|Sequence|Mapping|Iterable|Iterator)"),
    (r"py:.*", r"(typing|collections|pathlib|os|io|argparse|dataclasses|enum|types|numbers|threading|atexit)(\..*)?"),
    (r"py:class", r"(optional|callable|array|arrays|array_like|ndarray|int|float|bool|str|dict|list|tuple)"),
]

html_theme = "sphinx_book_theme"
html_title = "jaxslam"
html_static_path = ["_static"]
html_css_files = ["custom.css"]
html_theme_options = {
    "show_toc_level": 2,
    "navigation_with_keys": False,
    "home_page_in_toc": True,
}
