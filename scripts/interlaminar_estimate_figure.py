"""The figure of docs/config.md's interface-stress indicator: the interlaminar stress estimate of
unrefined cells (``indicators.interlaminar_stresses``, what ``[indicators] interface_stress``
judges) against the layerwise (LW) model's interface tractions, along the beam, on five static
cases that load an interface through different paths:

- a cantilever under a tip shear ([0/90]2s): bending shear, from equilibrium recovery;
- four-point bending on rigid rollers ([0/90]2s): shear between the rollers, none between the
  noses, and the rollers' pressure on the faces;
- a DCB arm opening (12 x 0 degrees, the arms' ends pulled apart): peel, from the cell's own
  sigma_zz and the supports' forces on its faces;
- an ENF ahead of its insert film (the adaptive model refined under the film, LW with the same
  film): the shear that drives mode II, in the unrefined cells ahead of the crack;
- a clamped square plate under a top pressure ([0/90]2s): shear and the pressure's peel.

LW references: ``comparison.interface_tractions`` (the force the plies above an interface put
on its nodes per unit area), and for the ENF the tractions of the cohesive elements
(``static_runner.cohesive_tractions``: penalty times opening). All static
(``static_runner.solve_config``), serial.

    .venv/bin/python scripts/interlaminar_estimate_figure.py docs/images/interlaminar_estimate.png

Units: N, mm, MPa.
"""

import copy
import sys
from pathlib import Path

from mpi4py import MPI  # noqa: F401  (first: DOLFINx finds libmpi through it)

# isort: split
import tomllib

import matplotlib
import numpy as np

matplotlib.use("Agg")
import matplotlib.pyplot as plt

from fenics_adaptive.analysis import comparison as cmp
from fenics_adaptive.settings.config import parse_config
from fenics_adaptive.static_runner import cohesive_tractions, interlaminar_estimate, solve_config

ROOT = Path(__file__).parents[1]
IM7 = {"E1": 161000.0, "E2": 11400.0, "G12": 5170.0, "nu12": 0.32, "nu23": 0.43, "rho": 1.58e-9}
CROSS = [0.0, 90.0, 0.0, 90.0, 90.0, 0.0, 90.0, 0.0]
OUTPUT = {"interval": 1e-6, "displacement_face": "x0", "reaction_face": "x1", "component": "z"}


def beam(kind, angles, length, nx, ny=1, width=2.0, reaction="x1", **tables) -> dict:
    data = {
        "model": {"kind": kind, "points_per_ply": 2},
        "mesh": {"length": length, "width": width, "nx": nx, "ny": ny},
        "materials": {"im7": dict(IM7)},
        "laminate": {"material": "im7", "ply_thickness": 0.25, "angles": list(angles)},
        "solver": {"end_time": 1.0e-6},
        "output": dict(OUTPUT, reaction_face=reaction),
        **copy.deepcopy(tables),
    }
    if kind == "layerwise":
        data["mesh"]["layers"] = [1] * len(angles)
    return data


def roller(name, x, face, z, motion="fixed", **path):
    return {"name": name, "shape": "cylinder", "axis": "y", "radius": 2.0,
            "position": [x, 1.0, z], "face": face, "motion": motion, **path}  # fmt: skip


def cantilever_shear(kind):
    load = [{"face": "x0", "force": [0.0, 0.0, -10.0], "curve": [[0.0, 1.0]]}]
    return beam(kind, CROSS, 20.0, 40, clamp=[{"face": "x1"}], load=load)


def four_point_bending(kind):
    push = {"displacement": [0.0, 0.0, -0.05], "curve": [[0.0, 1.0]]}
    rigid = [roller("left", 2.0, "bottom", -2.0001), roller("right", 38.0, "bottom", -2.0001),
             roller("nose_left", 14.0, "top", 4.0001, "prescribed", **push),
             roller("nose_right", 26.0, "top", 4.0001, "prescribed", **push)]  # fmt: skip
    hold = [
        {"face": "bottom", "x": 20.0, "component": "x", "displacement": 0.0,
         "curve": [[0.0, 1.0]]},
        {"face": "y0", "component": "y", "displacement": 0.0, "curve": [[0.0, 1.0]]},
    ]  # fmt: skip
    return beam(kind, CROSS, 40.0, 80, reaction="y0", rigid=rigid, prescribed=hold)


def dcb_opening(kind):
    pull = [
        {"face": "top", "x": 0.0, "component": "z", "displacement": 0.01, "curve": [[0.0, 1.0]]},
        {"face": "bottom", "x": 0.0, "component": "z", "displacement": -0.01,
         "curve": [[0.0, 1.0]]},
    ]  # fmt: skip
    return beam(kind, [0.0] * 12, 10.0, 20, clamp=[{"face": "x1"}], prescribed=pull)


def enf(kind):
    data = tomllib.loads((ROOT / "tests" / "data" / "enf.toml").read_text())
    if kind != "layerwise":
        data["model"]["kind"] = "adaptive"
        del data["mesh"]["layers"]
    return data


def pressure_plate(kind):
    load = [{"face": "top", "pressure": 0.1, "curve": [[0.0, 1.0]]}]
    clamp = [{"face": face} for face in ("x0", "x1", "y0", "y1")]
    return beam(kind, CROSS, 20.0, 20, ny=20, width=20.0, clamp=clamp, load=load)


def cell_centres(structure) -> np.ndarray:
    return structure.X_base[structure.bottom_local].mean(axis=1)


def lw_tractions(structure, interface: int) -> tuple[np.ndarray, np.ndarray]:
    """(x of the node lines, (sigma_zz, tau_xz, tau_yz)) at ``interface`` of a bonded LW."""
    lines, traction = cmp.interface_tractions(structure)[interface]
    order = np.argsort(lines)
    return lines[order], traction[order]


def lw_cohesive_tractions(structure, u: np.ndarray, interface: int):
    """(x, (sigma_zz, tau_xz, tau_yz)) of the intact cohesive elements at ``interface``."""
    centres, _, tractions = cohesive_tractions(structure, u)
    at = (structure.cohesive.interface == interface) & ~structure.cohesive.inserted()
    order = np.argsort(centres[at, 0])
    return centres[at, 0][order], tractions[at][order]


CASES = [
    # title, config, interface, component (0: sigma_zz, 1: tau_xz), all width means
    ("cantilever, tip shear [0/90]2s", cantilever_shear, 4, 1),
    ("four-point bending on rollers", four_point_bending, 1, 1),
    ("DCB arm opening, 12 x 0", dcb_opening, 6, 0),
    ("ENF, ahead of the 20 mm film", enf, 2, 1),
    ("clamped plate, 0.1 MPa pressure", pressure_plate, 4, 1),
]


def main(path: str) -> None:
    fig, axes = plt.subplots(1, len(CASES), figsize=(19, 3.8), layout="constrained")
    for ax, (title, make, interface, component) in zip(axes, CASES, strict=True):
        esl_data, lw_data = make("esl"), make("layerwise")
        structure, system, solution = solve_config(parse_config(esl_data))
        estimate = interlaminar_estimate(structure, system, solution)[:, interface, component]
        centres = cell_centres(structure)
        keep = structure.refinement.unrefined_cells()
        lw, _, lw_solution = solve_config(parse_config(lw_data))
        if len(lw.cohesive):
            x_lw, traction = lw_cohesive_tractions(lw, lw_solution.u, interface)
        else:
            x_lw, traction = lw_tractions(lw, interface)
        # the LW tractions are width means per node line: so are the estimate's points
        x, column = np.unique(np.round(centres[keep, 0], 9), return_inverse=True)
        mean = np.bincount(column, weights=estimate[keep]) / np.bincount(column)
        label = "sigma_zz" if component == 0 else "tau_xz"
        ax.plot(x_lw, traction[:, component], "k-", lw=2, label=f"LW {label}")
        ax.plot(x, mean, "o", ms=3.5, color="tab:orange", label="ESL estimate")
        ax.set_title(f"{title}\ninterface {interface}", fontsize=9)
        ax.set_xlabel("x (mm)")
        ax.set_ylabel(f"{label} (MPa)")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)
    fig.savefig(path, dpi=130)
    print(f"wrote {path}")


if __name__ == "__main__":
    main(sys.argv[1] if len(sys.argv) > 1 else "interlaminar_estimate.png")
