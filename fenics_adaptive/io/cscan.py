"""Delamination maps: the damage of each delaminating interface seen from above, as an
ultrasonic C-scan shows it, and the delaminated area of each interface.

Units: N, mm, s, tonne (areas mm^2).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from fenics_adaptive.element.geometry import quad_areas
from fenics_adaptive.io.output import pyplot


def interface_damage(structure) -> dict[int, tuple[np.ndarray, np.ndarray]]:
    """Per delaminating interface (this rank's cohesive elements): the in-plane centres (n, 2)
    of its cohesive elements (mm) and their mean damage (n,)."""
    cohesive = structure.cohesive
    if not len(cohesive):
        return {}
    X = structure.gather(cohesive.nodes[:, :4], "X").mean(axis=1)[:, :2]
    damage = cohesive.damage[cohesive.damage_row].mean(axis=1)
    return {
        int(i): (X[cohesive.interface == i], damage[cohesive.interface == i])
        for i in np.unique(cohesive.interface)
    }


def delaminated_area_per_interface(structure) -> dict[str, float]:
    """{interface: area (mm^2) of its cohesive elements that have failed (mean damage 1)} on
    this rank, each element taken with the mean area of the plate's cells."""
    cell_area = float(quad_areas(structure.X_base[structure.bottom_local]).mean())
    return {
        str(i): float((damage >= 1.0).sum() * cell_area)
        for i, (_, damage) in interface_damage(structure).items()
    }


def plot_cscan(
    maps: dict[str, dict], refined: dict[str, np.ndarray], size: tuple[float, float], path: Path
) -> None:
    """Damage of each interface seen from above, one row per run (``maps``: run name ->
    ``interface_damage``; ``refined``: run name -> centres (n, 2) of its refined cells, drawn
    faintly for the adaptive run; ``size``: the plate's length and width, mm)."""
    plt = pyplot()
    runs = [n for n in ("adaptive", "layerwise") if n in maps]
    interfaces = sorted({i for n in runs for i in maps[n]})
    if not runs or not interfaces:
        return
    fig, axes = plt.subplots(
        len(runs), len(interfaces), figsize=(3.4 * len(interfaces), 3.2 * len(runs)),
        layout="constrained", squeeze=False,
    )  # fmt: skip
    for r, name in enumerate(runs):
        for c, interface in enumerate(interfaces):
            ax = axes[r, c]
            xy, damage = maps[name].get(interface, (np.zeros((0, 2)), np.zeros(0)))
            ax.set_facecolor("0.92")
            shown = ax.scatter(
                xy[:, 0], xy[:, 1], c=damage, s=4, marker="s", vmin=0, vmax=1, cmap="inferno_r"
            )
            if name == "adaptive" and name in refined:
                hull = refined[name]
                ax.plot(hull[:, 0], hull[:, 1], ",", color="tab:blue", alpha=0.3)
            ax.set_xlim(0, size[0])
            ax.set_ylim(0, size[1])
            ax.set_aspect("equal")
            ax.set_title(f"{name}: interface {interface}", fontsize=9)
    fig.colorbar(shown, ax=axes, label="cohesive damage (1 = delaminated)")
    fig.savefig(path, dpi=150)
    plt.close(fig)
