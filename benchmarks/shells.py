"""Curved shells (issue 19): the shell obstacle course and a laminated panel, static.

Units: N, mm (the obstacle course's own consistent units for its two classics).

- Scordelis-Lo roof (MacNeal and Harder 1985; Belytschko et al. 1985): R 25, L 50, 80 degrees,
  t 0.25, E 4.32e8, nu 0, gravity 90 per unit area, rigid diaphragms at the ends; a quarter
  meshed n x n; the vertical displacement at the middle of the free edge against 0.3024;
- pinched cylinder with rigid diaphragms: R 300, L 600, t 3, E 3e6, nu 0.3, two opposite
  loads P = 1 at mid-length; an eighth n x n; the displacement under the load against
  1.8248e-5;
- both with one ESL cell through the thickness, isotropic: one ply, and four plies of the
  same material at 0/90/0/90 (the same stiffness, integrated ply by ply);
- a laminated cylindrical panel under pressure ([0/90]2s, R/h = 50, clamped round its edges):
  the ESL, the adaptive model weakly refined at every ply interface from the start, and the
  layerwise model of one cell per ply on the same mesh: the refined element equals LW, the
  ESL deflection against LW's.

Writes ``benchmarks/results/shells.md`` and the convergence plot
``docs/images/shell_obstacle_course.png``. About a minute.

    .venv/bin/python benchmarks/shells.py
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

from mpi4py import MPI  # first: the DOLFINx wheel finds libmpi through it

# isort: split
import numpy as np

from fenics_adaptive.analysis.obstacle_course import pinched_cylinder, scordelis_lo
from fenics_adaptive.io.output import pyplot
from fenics_adaptive.settings.config import parse_config
from fenics_adaptive.static_runner import solve_config

ROOT = Path(__file__).resolve().parents[1]
MESHES = (4, 8, 16, 32)


PANEL = {
    "mesh": {"kind": "panel", "radius": 100.0, "length": 100.0, "angle": 60.0,
             "n_around": 12, "n_along": 12},
    "materials": {"cfrp": {"E1": 1.3e5, "E2": 9.0e3, "G12": 5.0e3, "G23": 3.5e3,
                           "nu12": 0.3, "nu23": 0.45, "rho": 1.6e-9}},
    "laminate": {"material": "cfrp", "ply_thickness": 0.25,
                 "angles": [0, 90, 0, 90, 90, 0, 90, 0]},
    "clamp": [{"face": name} for name in ("x0", "x1", "theta0", "theta1")],
    "load": [{"face": "top", "pressure": 0.05, "rise_time": 1.0e-3}],
    "solver": {"end_time": 1.0e-3},
    "output": {"interval": 1.0e-3, "displacement_face": "top", "reaction_face": "x0",
               "component": "z"},
}  # fmt: skip


def laminated_panel(kind: str) -> tuple[float, np.ndarray]:
    """(the deflection at the panel's centre (mm), the base displacement) of the [0/90]2s
    panel under 0.05 MPa, as ``kind`` models it."""
    data = {k: dict(v) if isinstance(v, dict) else v for k, v in PANEL.items()}
    data["model"] = {"kind": kind}
    if kind == "adaptive":
        data["interfaces"] = {"refine": list(range(1, 8)), "initial": "weak"}
    if kind == "layerwise":
        data["mesh"] = dict(data["mesh"], layers=[1] * 8)
    structure, _, _ = solve_config(parse_config(data), MPI.COMM_SELF)
    x = structure.X_base
    u = structure.base.u.x.array.reshape(-1, 3)[: len(x)]
    # the crown at mid-length, its nodes on the bottom and top faces (every model has them)
    line = np.flatnonzero((np.abs(x[:, 0] - 50.0) < 1e-6) & (np.abs(x[:, 1]) < 1e-6))
    centre = line[[np.argmin(x[line, 2]), np.argmax(x[line, 2])]]
    return float(u[centre, 2].mean()), (x, u.copy())


def main() -> None:
    start = time.perf_counter()
    rows = {}
    for name, case in (("Scordelis-Lo roof", scordelis_lo), ("pinched cylinder", pinched_cylinder)):
        for plies in (1, 4):
            rows[(name, plies)] = [case(n, plies) for n in MESHES]
            print(name, plies, [f"{r:.4f}" for r in rows[(name, plies)]], file=sys.stderr)
    deflection = {}
    fields = {}
    for kind in ("esl", "adaptive", "layerwise"):
        deflection[kind], fields[kind] = laminated_panel(kind)
        print(kind, deflection[kind], file=sys.stderr)
    # the layerwise and the refined model at the base nodes (the same places)
    (xa, ua), (xl, ul) = fields["adaptive"], fields["layerwise"]
    lw_node = {tuple(p): i for i, p in enumerate(np.round(xl, 9).tolist())}
    same = np.array([lw_node[tuple(p)] for p in np.round(xa, 9).tolist()])
    refined_vs_lw = float(np.abs(ua - ul[same]).max() / np.abs(ul).max())
    lines = [
        "# Curved shells: the obstacle course and a laminated panel (benchmarks/shells.py)",
        "",
        "Displacement / reference, one ESL cell through the thickness, meshes n x n of the "
        "modelled part (a quarter of the roof, an eighth of the cylinder).",
        "",
        "| case | plies | " + " | ".join(f"{n} x {n}" for n in MESHES) + " |",
        "|---|---|" + "---|" * len(MESHES),
    ]
    for (name, plies), ratios in rows.items():
        lines.append(f"| {name} | {plies} | " + " | ".join(f"{r:.4f}" for r in ratios) + " |")
    lines += [
        "",
        "Laminated cylindrical panel ([0/90]2s, 2 mm, R 100 mm, 60 degrees, 100 mm long, clamped "
        "round its edges, 0.05 MPa, 12 x 12 cells): deflection at the centre (mm).",
        "",
        "| model | deflection | / layerwise |",
        "|---|---|---|",
    ]
    for kind, value in deflection.items():
        lines.append(f"| {kind} | {value:.6e} | {value / deflection['layerwise']:.5f} |")
    lines += [
        "",
        f"Refined from the start against layerwise, largest difference of the displacement at the "
        f"refined model's base nodes (bottom and top faces) / largest: {refined_vs_lw:.2e}.",
        "",
        f"Wall time {time.perf_counter() - start:.0f} s.",
    ]
    out = ROOT / "benchmarks" / "results" / "shells.md"
    out.write_text("\n".join(lines) + "\n")
    print("\n".join(lines))
    plt = pyplot()
    fig, ax = plt.subplots(figsize=(6, 4), layout="constrained")
    for (name, plies), ratios in rows.items():
        style = "-o" if plies == 1 else "--s"
        ax.plot(MESHES, ratios, style, label=f"{name}, {plies} ply" + ("s" if plies > 1 else ""))
    ax.axhline(1.0, color="k", lw=0.8)
    ax.axhspan(0.98, 1.02, color="0.9", zorder=0, label="within 2 %")
    ax.set_xscale("log", base=2)
    ax.set_xticks(MESHES, [str(n) for n in MESHES])
    ax.set_xlabel("cells per side of the modelled part")
    ax.set_ylabel("displacement / reference")
    ax.set_title("Shell obstacle course, ESL solid shell")
    ax.legend()
    ax.grid(alpha=0.3)
    fig.savefig(ROOT / "docs" / "images" / "shell_obstacle_course.png", dpi=150)


if __name__ == "__main__":
    main()
