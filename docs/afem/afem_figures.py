"""Drawing helpers shared by the AFEM tutorials of this folder (matplotlib only).

The tutorials run in two ways: as scripts (``python docs/afem/01_extra_nodes.py``, as the tests
do) and as notebooks executed by the documentation build. As scripts they draw with the Agg
backend, never on a display, and save each figure as ``<name>.png`` into the folder named by
the environment variable ``AFEM_FIGURES`` when it is set (the tests set it and check the files).
In a notebook the figures are shown inline, below the cell that draws them.

Lengths in mm.
"""

from __future__ import annotations

import itertools
import os
import sys
from pathlib import Path

import matplotlib

if "ipykernel" not in sys.modules:
    matplotlib.use("Agg")  # scripts never need a display

import matplotlib.pyplot as plt
import numpy as np

TUTORIAL_DIR = Path(__file__).resolve().parent  # the scripts' folder (seven_plies.toml is here)
FIGURE_DIR_VARIABLE = "AFEM_FIGURES"
SET_COLOURS = {"A": "tab:blue", "B": "tab:red"}  # extra nodes of set A and of set B
PLY_CMAP = plt.get_cmap("Pastel2")


def in_notebook() -> bool:
    """True when the tutorial runs in a Jupyter kernel (the documentation build)."""
    return "ipykernel" in sys.modules


def finish(fig: plt.Figure, name: str) -> Path | None:
    """Hand a finished figure over: in a notebook, leave it to be shown inline; as a script,
    save it as ``$AFEM_FIGURES/<name>.png`` if that variable is set, then close it.

    Returns the file written, or None."""
    fig.tight_layout()
    if in_notebook():
        return None
    path = None
    folder = os.environ.get(FIGURE_DIR_VARIABLE)
    if folder:
        path = Path(folder) / f"{name}.png"
        path.parent.mkdir(parents=True, exist_ok=True)
        fig.savefig(path, dpi=80)
    plt.close(fig)
    return path


def draw_plies(
    ax: plt.Axes,
    x_range: tuple[float, float],
    ply_fractions: np.ndarray,
    thickness: float,
    colours: list | None = None,
    labels: bool = True,
) -> None:
    """Side view of a laminate: one band per ply between x_range[0] and x_range[1] (mm).

    ply_fractions: (n_plies + 1,) thickness fractions of the ply boundaries, 0 to 1.
    thickness: laminate thickness (mm). colours: one face colour per ply (default: by ply)."""
    x0, x1 = x_range
    for k, (lo, hi) in enumerate(itertools.pairwise(ply_fractions)):
        colour = colours[k] if colours is not None else PLY_CMAP(k % PLY_CMAP.N)
        ax.fill_between([x0, x1], lo * thickness, hi * thickness, color=colour, lw=0)
        if labels:
            ax.text(
                x0 + 0.02 * (x1 - x0),
                0.5 * (lo + hi) * thickness,
                f"ply {k + 1}",
                va="center",
                fontsize=7,
                color="0.3",
            )
    for fraction in ply_fractions:
        ax.plot([x0, x1], [fraction * thickness] * 2, color="0.6", lw=0.5)
