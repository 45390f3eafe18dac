"""The demos: literate scripts, each a study that runs, plots and ends with its check.

From a source tree run one as a script (``.venv/bin/python demos/tcb.py --out results/tcb``);
installed, the package holds them as ``fenics_adaptive.demos`` with their configs, and
``fenics-adaptive demo tcb --out results/tcb`` runs the same script. ``fenics-adaptive demo``
alone lists them.
"""

from __future__ import annotations

import ast
from pathlib import Path

HERE = Path(__file__).parent
# in the order of the README
NAMES = (
    "esl_cantilever",
    "tcb",
    "four_point_bending",
    "plate_impact",
    "tube_crush",
    "tube_impact",
    "crash_impact",
    "esl_vs_lw",
    "fracture_tests",
)


def describe(name: str) -> str:
    """The first line of demo ``name``'s docstring, read without importing it."""
    text = ast.get_docstring(ast.parse((HERE / f"{name}.py").read_text())) or ""
    return text.splitlines()[0].lstrip("# ").strip() if text else ""
