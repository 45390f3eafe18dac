"""Sphinx configuration of the fenics-adaptive documentation site (`make docs`).

The AFEM tutorials are the percent-format scripts of docs/afem/ themselves: MyST-NB reads them
through Jupytext and executes them at build time, so the site shows the numbers and figures the
scripts compute and check (the tests run the same files). The config reference is generated from
fenics_adaptive.settings.schema, the module the config parser reads its keys from.
"""

import shutil
import sys
from pathlib import Path

DOCS = Path(__file__).resolve().parent
ROOT = DOCS.parent
sys.path[:0] = [str(ROOT), str(DOCS / "_ext")]

import fenics_adaptive  # noqa: E402

project = "fenics-adaptive"
author = "the fenics-adaptive developers"
copyright = "2026, the fenics-adaptive developers"
release = fenics_adaptive.__version__
version = release

extensions = [
    "myst_nb",
    "sphinx.ext.autodoc",
    "sphinx.ext.autosummary",
    "sphinx.ext.mathjax",
    "sphinx.ext.viewcode",
    "afem_site",
]

# The tutorials: one Python source each, read as a Jupyter notebook (percent format).
nb_custom_formats = {".py": "afem_site.read_percent_script"}
# .rst first: autosummary writes its generated API pages with the first suffix
source_suffix = {".rst": "restructuredtext", ".md": "myst-nb", ".py": "myst-nb"}
exclude_patterns = ["_build", "_ext", "conf.py", "afem/afem_figures.py", "**/.ipynb_checkpoints"]

nb_execution_mode = "force"  # every build runs every tutorial: the site cannot show stale output
nb_execution_raise_on_error = True  # a failing check in a tutorial fails the build
nb_execution_timeout = 300  # s per tutorial
nb_execution_show_tb = True
nb_merge_streams = True

myst_enable_extensions = ["dollarmath", "amsmath", "colon_fence", "deflist"]
myst_heading_anchors = 3

# API reference: one page per public module, from the docstrings. The pages are build output:
# written afresh each build, so that a module moved or removed leaves no stale page behind.
shutil.rmtree(DOCS / "api" / "generated", ignore_errors=True)
autosummary_generate = True
# "ignore-module-all": the package's public names (``fenics_adaptive.__all__``) are documented
# where they are defined, not a second time as members of the package (one target per name)
autodoc_default_options = {
    "members": True,
    "undoc-members": False,
    "show-inheritance": False,
    "ignore-module-all": True,
}
autodoc_typehints = "description"
autodoc_member_order = "bysource"

nitpicky = True
# Types from libraries whose inventories the (offline) build does not load.
nitpick_ignore_regex = [
    (r"py:.*", r"(np|numpy|npt|dolfinx|fem|la|mesh|mpi4py|MPI|petsc4py|PETSc|ufl|basix)\..*"),
    (r"py:.*", r"(common|numba|gmsh|collections\.abc|typing|pathlib|enum|dataclasses)\..*"),
    (r"py:.*", r"argparse\..*"),
    (r"py:.*", r"(ndarray|ArrayLike|NDArray|Path)"),
    # pieces of string annotations that Sphinx splits at the brackets
    (r"py:.*", r".*[\[\]'].*"),
    # type aliases of annotations (documented in their modules' docstrings)
    (r"py:class", r"(Refiner|Request)"),
]

html_theme = "furo"
html_title = "fenics-adaptive"
html_static_path = []
templates_path = []
