"""The peer benchmark's Akantu side: one explicit run of the DCB that ``benchmarks/peer.py``
describes, in Akantu 5.0.7 (its Python wheel), printed as one JSON line.

    .venv-akantu/bin/python benchmarks/akantu_dcb.py '<case as JSON>' WORKDIR

Runs in the separate Akantu environment that ``peer.py`` makes (numpy and akantu only: nothing
of fenics-adaptive is imported here). The case gives the mesh (a structured grid of hexahedra,
``nx`` x ``ny`` x ``nz`` over L x W x H), the ply (transversely isotropic, fibres along x), the
interface (intrinsic bilinear cohesive elements on the bonded mid-plane; the insert film is a
cut: its mid-plane nodes are doubled), the clamp at x = 0, the opening of the arms' end lines at
x = L (velocity ``velocity`` reached with a smoothstep over ``rise_time``, the same profile as
the fenics-adaptive run's ``profile = "smooth"``), the time step and the number of steps.

Units: N, mm, s, tonne (stress MPa, density tonne/mm^3, fracture energy N/mm).
"""

from __future__ import annotations

import json
import sys
import time
from pathlib import Path

import numpy as np


def opening_of_one_arm(t: float, velocity: float, rise_time: float) -> float:
    """Displacement (mm) of a load line at t (s): the integral of a velocity that rises from 0
    to ``velocity`` (mm/s) with a smoothstep 3 s^2 - 2 s^3 over ``rise_time`` (s), then stays."""
    if t < rise_time:
        s = t / rise_time
        return velocity * rise_time * (s**3 - 0.5 * s**4)
    return velocity * (0.5 * rise_time + (t - rise_time))


def write_mesh(path: Path, case: dict) -> None:
    """Gmsh 2.2 ASCII: hexahedra of one physical volume "ply"; the mid-plane nodes over the
    film (x > L - film, the crack-tip line excepted) doubled for the upper arm (a cut)."""
    L, W, H, film = case["L"], case["W"], case["H"], case["film"]
    nx, ny, nz = case["nx"], case["ny"], case["nz"]
    xs, ys, zs = np.linspace(0, L, nx + 1), np.linspace(0, W, ny + 1), np.linspace(0, H, nz + 1)
    mid = nz // 2
    ids: dict[tuple[int, int, int, bool], int] = {}
    nodes = []
    for k in range(nz + 1):
        for j in range(ny + 1):
            for i in range(nx + 1):
                twins = [False, True] if k == mid and xs[i] > L - film + 1e-9 else [False]
                for upper in twins:
                    ids[i, j, k, upper] = len(nodes) + 1
                    nodes.append((xs[i], ys[j], zs[k]))

    def node(i: int, j: int, k: int, upper: bool) -> int:
        return ids.get((i, j, k, upper), ids[i, j, k, False])

    lines = [
        "$MeshFormat",
        "2.2 0 8",
        "$EndMeshFormat",
        "$PhysicalNames",
        "1",
        '3 1 "ply"',
        "$EndPhysicalNames",
        "$Nodes",
        str(len(nodes)),
    ]
    lines += [f"{n} {x:.17g} {y:.17g} {z:.17g}" for n, (x, y, z) in enumerate(nodes, 1)]
    lines += ["$EndNodes", "$Elements", str(nx * ny * nz)]
    element = 0
    for k in range(nz):
        upper = k >= mid  # the upper arm's elements use the twins on the cut
        for j in range(ny):
            for i in range(nx):
                corners = [(i, j), (i + 1, j), (i + 1, j + 1), (i, j + 1)]
                hexahedron = [node(a, b, k, upper) for a, b in corners]
                hexahedron += [node(a, b, k + 1, upper) for a, b in corners]
                element += 1
                lines.append(f"{element} 5 2 1 1 " + " ".join(map(str, hexahedron)))
    lines.append("$EndElements")
    path.write_text("\n".join(lines) + "\n")


def write_materials(path: Path, case: dict) -> None:
    """Akantu's input file: the ply (elastic_orthotropic, axes = the global ones; with
    ``isotropic``, Akantu's isotropic ``elastic`` of E2 and nu12 instead) and the interface
    (cohesive_bilinear: peak traction N at the opening N / K_n, G_c = GIc)."""
    m, c = case["ply"], case["cohesive"]
    if case.get("isotropic"):  # Akantu's cheapest solid: not the ply, for the cost alone
        solid = f"""  material elastic [
    name = ply
    rho = {m["rho"]!r}
    E = {m["E2"]!r}
    nu = {m["nu12"]!r}
  ]"""
    else:
        solid = f"""  material elastic_orthotropic [
    name = ply
    rho = {m["rho"]!r}
    E1 = {m["E1"]!r}
    E2 = {m["E2"]!r}
    E3 = {m["E2"]!r}
    nu12 = {m["nu12"]!r}
    nu13 = {m["nu12"]!r}
    nu23 = {m["nu23"]!r}
    G12 = {m["G12"]!r}
    G13 = {m["G12"]!r}
    G23 = {m["G23"]!r}
    n1 = [1, 0, 0]
    n2 = [0, 1, 0]
    n3 = [0, 0, 1]
  ]"""
    path.write_text(f"""model solid_mechanics_model_cohesive [
{solid}
  material cohesive_bilinear [
    name = interface
    sigma_c = {c["N"]!r}
    delta_0 = {c["N"] / c["K_n"]!r}
    beta = {c["beta"]!r}
    G_c = {c["GIc"]!r}
    penalty = {c["K_n"]!r}
  ]
]
""")


def resident_memory_mib(key: str = "VmHWM") -> float:
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith(key + ":"):
            return int(line.split()[1]) / 1024.0
    return float("nan")


def run(case: dict, workdir: Path) -> dict:
    started = time.perf_counter()
    import akantu as aka

    write_mesh(workdir / "dcb.msh", case)
    write_materials(workdir / "material.dat", case)
    aka.parseInput(str(workdir / "material.dat"))
    mesh = aka.Mesh(3)
    mesh.read(str(workdir / "dcb.msh"))
    model = aka.SolidMechanicsModelCohesive(mesh)
    L, H, film = case["L"], case["H"], case["film"]
    inserter = model.getElementInserter()
    half_cell = 0.25 * H / case["nz"]
    inserter.setLimit(aka._z, 0.5 * H - half_cell, 0.5 * H + half_cell)
    inserter.setLimit(aka._x, -1.0, L - film + 1e-6)  # the bond; the film is a cut
    model.initFull(_analysis_method=aka._explicit_lumped_mass, _is_extrinsic=False)
    dt = case["time_step"]
    if dt > model.getStableTimeStep():
        raise SystemExit(f"time step {dt} above Akantu's stable step {model.getStableTimeStep()}")
    model.setTimeStep(dt)

    X = mesh.getNodes()
    u = model.getDisplacement()

    blocked = model.getBlockedDOFs()
    tol = 1e-9 * L
    clamp = np.flatnonzero(np.abs(X[:, 0]) < tol)
    end = np.abs(X[:, 0] - L) < tol
    top = np.flatnonzero(end & (np.abs(X[:, 2] - H) < tol))
    bottom = np.flatnonzero(end & (np.abs(X[:, 2]) < tol))
    blocked[clamp, :] = True
    blocked[top, 2] = True
    blocked[bottom, 2] = True
    set_up = time.perf_counter() - started

    f_int = model.getInternalForce()
    velocity, rise = case["velocity"], case["rise_time"]
    every = max(round(case["output_interval"] / dt), 1)
    history = {"time": [], "displacement": [], "reaction_force": []}
    steps = case["steps"]
    clock = 0.0
    for n in range(1, steps + 1):
        t = n * dt
        w = opening_of_one_arm(t, velocity, rise)
        u[top, 2] = w
        u[bottom, 2] = -w
        tick = time.perf_counter()
        model.solveStep()
        clock += time.perf_counter() - tick
        if n % every == 0 or n == steps:
            history["time"].append(t)
            history["displacement"].append(float(u[top, 2].mean()))
            # the load line's reaction: what the internal forces of the arm pull back with
            history["reaction_force"].append(-float(f_int[top, 2].sum()))
    material = "isotropic elastic" if case.get("isotropic") else "elastic_orthotropic"
    return {
        "code": f"akantu {getattr(aka, '__version__', '?')} ({material})",
        "hexahedra": int(mesh.getNbElement(type=aka._hexahedron_8)),
        "cohesive_elements": int(mesh.getNbElement(type=aka._cohesive_3d_8)),
        "nodes": int(mesh.getNbNodes()),
        "time_step": dt,
        "steps": steps,
        "seconds_per_step": clock / steps,
        "set_up_seconds": set_up,
        "peak_memory_mib": resident_memory_mib(),
        "history": history,
    }


if __name__ == "__main__":
    print(json.dumps(run(json.loads(sys.argv[1]), Path(sys.argv[2]))))
