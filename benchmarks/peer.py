"""Peer benchmark (issue 17 item 7): the same DCB in fenics-adaptive and in Akantu, interleaved.

    .venv/bin/python benchmarks/peer.py              # both meshes, 3 interleaved repetitions
    .venv/bin/python benchmarks/peer.py --quick      # the base mesh, one repetition, short
    .venv/bin/python benchmarks/peer.py --repeat 5 --larger-steps 4000

The specimen is the DCB of ``demos/fracture_tests.toml`` made short (``studies.dcb_quick``'s
loading) on a grid of 80 x 1 x 4 hexahedra: 80 mm long, 25.4 mm wide, two arms of 1.56 mm
(four plies of 0.39 mm each, two cells per arm), an insert film of 20 mm from the load line and
60 mm of bond, clamped at x = 0, the arms' end lines at x = 80 mm pulled apart. Both codes get
the same nodes, the same ply (AS4/PEEK, fibres along x), the same interface (an intrinsic
bilinear cohesive law, mode I: peak traction N at the opening N / K_n, GIc), the same opening
history and the same time step (fenics-adaptive's stable step, below Akantu's). fenics-adaptive
runs its layerwise model (the solid-shell element, two plies pre-integrated per cell, cohesive
elements on the bond and the film); Akantu 5.0.7 runs its fully integrated hexahedra
(``elastic_orthotropic``) and ``cohesive_bilinear`` elements on the bond (the film a cut).

Each run is its own process (``--worker``), so that its peak resident memory is its own;
the two codes alternate, ``--repeat`` times; the step time is each run's own clock over its
time loop, divided by its steps (set-up and, for fenics-adaptive, numba's compilation outside:
the kernels are warmed by a first, untimed run). Reported per code: microseconds per
hexahedron-step (median), peak memory (median), and on the base mesh the force against
corrected beam theory (``analysis.lefm.dcb_force``): peak over the analytic initiation force,
and the mean, least and largest ratio on the propagation branch. A second, 4 x larger mesh
(160 x 2 x 4, the same beam in 0.5 mm cells) is timed over ``--larger-steps`` steps.

Akantu comes from its PyPI wheel (``requirements/akantu.txt``) in a separate environment,
``.venv-akantu``, which this script creates on its first run (network needed once). It is an
optional benchmark dependency: neither the tests nor the demos need it. Results:
``benchmarks/results/peer.md`` and ``peer.json``.

Units: N, mm, s, tonne; times in microseconds, memory in MiB.
"""

from __future__ import annotations

import argparse
import copy
import dataclasses
import json
import os
import platform
import statistics
import subprocess
import sys
import tempfile
import tomllib
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
AKANTU_VENV = ROOT / ".venv-akantu"
AKANTU_REQUIREMENTS = ROOT / "requirements" / "akantu.txt"
RESULTS = ROOT / "benchmarks" / "results"

# the specimen: mm
LENGTH, FILM = 80.0, 20.0
# the runs of each repetition, in order: this code, Akantu on the same ply, and Akantu with its
# cheapest solid (isotropic elastic: not the ply; its cost alone, no force comparison)
CODES = ("fenics-adaptive", "akantu", "akantu, isotropic")


def base_config(nx: int, ny: int) -> dict:
    """The peer DCB as a fenics-adaptive config table: ``nx`` x ``ny`` cells in-plane, four
    cell layers (two plies each), the film over the last ``FILM`` mm."""
    sys.path.insert(0, str(ROOT))
    from fenics_adaptive.analysis.studies import dcb_quick

    data = dcb_quick(tomllib.loads((ROOT / "demos" / "fracture_tests.toml").read_text()))
    data = copy.deepcopy(data)
    data["mesh"].update(length=LENGTH, nx=nx, ny=ny, layers=[2, 2, 2, 2])
    data["delamination"][0].update(x_min=LENGTH - FILM, x_max=LENGTH)
    data["output"].pop("fields_interval", None)
    return data


def akantu_case(config, data: dict, nx: int, ny: int, time_step: float, steps: int) -> dict:
    """What ``benchmarks/akantu_dcb.py`` needs: the grid, the ply, the interface, the load."""
    ply = config.laminate.plies[0].material
    cohesive = config.cohesive
    top = next(p for p in data["prescribed"] if p["face"] == "x1&top")
    return {
        "L": LENGTH,
        "W": float(data["mesh"]["width"]),
        "H": float(config.laminate.thickness),
        "film": FILM,
        "nx": nx,
        "ny": ny,
        "nz": 4,
        "ply": {
            "rho": ply.rho,
            "E1": ply.E1,
            "E2": ply.E2,
            "G12": ply.G12,
            "nu12": ply.nu12,
            "nu23": ply.nu23,
            "G23": ply.shear_modulus_23,
        },
        "cohesive": {"N": cohesive.N, "K_n": cohesive.K_n, "GIc": cohesive.GIc, "beta": 1.0},
        "time_step": time_step,
        "steps": steps,
        "velocity": float(top["velocity"]),
        "rise_time": float(top["rise_time"]),
        "output_interval": float(data["output"]["interval"]),
    }


# ------------------------------------------------------------------------------ workers
def resident_memory_mib(key: str = "VmHWM") -> float:
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith(key + ":"):
            return int(line.split()[1]) / 1024.0
    return float("nan")


def ours_worker(job: dict) -> dict:
    """One fenics-adaptive run of the peer DCB (``job``: nx, ny, steps or None for the whole
    run, warm: run a few steps first so that numba compiles outside the clock)."""
    import mpi4py  # noqa: F401  (before dolfinx)

    sys.path.insert(0, str(ROOT))
    from fenics_adaptive.settings.config import parse_config
    from fenics_adaptive.simulation import build_structure
    from fenics_adaptive.solver import explicit

    data = base_config(job["nx"], job["ny"])
    config = parse_config(data, source="benchmarks/peer.py")
    structure = build_structure(config)
    dt, _, _ = explicit.choose_time_step(structure, config.solver)
    settings = config.solver
    if job.get("steps"):
        settings = dataclasses.replace(settings, end_time=job["steps"] * dt)
    if job.get("warm"):  # compile and load every kernel the run uses, then start again
        warm = dataclasses.replace(config.solver, end_time=20 * dt, output_interval=20 * dt)
        explicit.run(build_structure(config), warm, config.probe, time_step=dt)
    stats = explicit.run(structure, settings, config.probe, time_step=dt)
    rows = stats.history
    return {
        "code": "fenics-adaptive",
        "hexahedra": int(structure.base.n_owned_cells),
        "cohesive_elements": len(structure.cohesive),
        "time_step": dt,
        "steps": int(stats.steps),
        "seconds_per_step": stats.wall_time / max(stats.steps, 1),
        "peak_memory_mib": resident_memory_mib(),
        "history": {
            "time": [r.time for r in rows],
            "displacement": [float(r.displacement) for r in rows],
            "reaction_force": [float(r.reaction_force) for r in rows],
        },
    }


def run_worker(kind: str, job: dict) -> dict:
    """Run one job in a fresh process and return its JSON line."""
    with tempfile.TemporaryDirectory() as work:
        if kind == "ours":
            command = [sys.executable, __file__, "--worker", json.dumps(job)]
        else:
            command = [
                str(AKANTU_VENV / "bin" / "python"),
                str(ROOT / "benchmarks" / "akantu_dcb.py"),
                json.dumps(job),
                work,
            ]
        result = subprocess.run(command, capture_output=True, text=True, cwd=work)
        if result.returncode != 0:
            raise RuntimeError(f"{kind} run failed:\n{result.stderr[-3000:]}")
        return json.loads(result.stdout.strip().splitlines()[-1])


def ensure_akantu() -> None:
    """Create ``.venv-akantu`` with the pinned Akantu wheel unless it imports already."""
    python = AKANTU_VENV / "bin" / "python"
    if (
        python.exists()
        and subprocess.run([python, "-c", "import akantu"], capture_output=True).returncode == 0
    ):
        return
    print(f"peer: creating {AKANTU_VENV} ({AKANTU_REQUIREMENTS.name}; network needed once)")
    base = getattr(sys, "_base_executable", sys.executable)
    subprocess.run([base, "-m", "venv", str(AKANTU_VENV)], check=True)
    subprocess.run(
        [python, "-m", "pip", "install", "-q", "-r", str(AKANTU_REQUIREMENTS)], check=True
    )


# ------------------------------------------------------------------------------ comparison
def against_lefm(config, run: dict) -> dict:
    """Force of a run's history against corrected beam theory's (``lefm.dcb_force``, the crack
    a0 + chi h): the peak over the initiation force; on the propagation branch (opening past
    1.2 x the initiation opening) the mean, least and largest ratio."""
    import numpy as np

    from fenics_adaptive.analysis.lefm import (
        arm_thickness,
        dcb_force,
        dcb_initiation_force,
        root_rotation_correction,
    )

    material = config.laminate.plies[0].material
    b, GIc = config.mesh.width, config.cohesive.GIc
    h = arm_thickness(config.laminate, config.delaminations[0].interface)
    crack = FILM + root_rotation_correction(material) * h
    opening = 2.0 * np.abs(np.asarray(run["history"]["displacement"]))
    force = np.abs(np.asarray(run["history"]["reaction_force"]))
    initiation = dcb_initiation_force(material.E1, b, h, GIc, crack)
    EI = material.E1 * b * h**3 / 12.0
    opening_at_initiation = 2.0 * initiation * crack**3 / (3.0 * EI)
    branch = opening > 1.2 * opening_at_initiation
    ratio = force[branch] / dcb_force(opening[branch], material.E1, b, h, GIc, crack)
    return {
        "peak_over_initiation": float(force.max() / initiation),
        "branch_points": int(branch.sum()),
        "branch_mean": float(ratio.mean()) if branch.any() else None,
        "branch_min": float(ratio.min()) if branch.any() else None,
        "branch_max": float(ratio.max()) if branch.any() else None,
    }


def summarise(runs: list[dict]) -> dict:
    first = runs[0]
    return {
        "code": first["code"],
        "hexahedra": first["hexahedra"],
        "cohesive_elements": first["cohesive_elements"],
        "time_step": first["time_step"],
        "steps": first["steps"],
        "us_per_hex_step": [1e6 * r["seconds_per_step"] / r["hexahedra"] for r in runs],
        "peak_memory_mib": [r["peak_memory_mib"] for r in runs],
    }


def table(results: dict) -> str:
    lines = [
        "| mesh | code | hexahedra | steps | µs per hex-step (median; all) | peak memory MiB "
        "(median) | peak / initiation | branch force / LEFM mean (min-max) |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for mesh, codes in results.items():
        for name in CODES:
            s = codes[name]
            times = s["us_per_hex_step"]
            lefm = s.get("lefm") or {}
            if lefm.get("branch_mean") is not None:
                branch = (
                    f"{lefm['branch_mean']:.3f} ({lefm['branch_min']:.3f}-{lefm['branch_max']:.3f})"
                )
                peak = f"{lefm['peak_over_initiation']:.3f}"
            else:
                branch = peak = "-"
            lines.append(
                f"| {mesh} | {s['code']} | {s['hexahedra']} | {s['steps']} | "
                f"{statistics.median(times):.3f} ({', '.join(f'{t:.3f}' for t in times)}) | "
                f"{statistics.median(s['peak_memory_mib']):.0f} | {peak} | {branch} |"
            )
        ours = statistics.median(codes["fenics-adaptive"]["us_per_hex_step"])
        ratios = ", ".join(
            f"{name} {statistics.median(codes[name]['us_per_hex_step']) / ours:.2f}"
            for name in CODES[1:]
        )
        memory = statistics.median(codes["fenics-adaptive"]["peak_memory_mib"]) / statistics.median(
            codes["akantu"]["peak_memory_mib"]
        )
        lines.append(
            f"| {mesh} | per hex-step, Akantu / fenics-adaptive: **{ratios}**; peak memory, "
            f"fenics-adaptive / Akantu: **{memory:.2f}** | | | | | | |"
        )
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--repeat", type=int, default=3, help="interleaved runs per code")
    parser.add_argument(
        "--larger-steps",
        type=int,
        default=3000,
        help="steps timed on the 4 x larger mesh (0: skip it)",
    )
    parser.add_argument(
        "--quick",
        action="store_true",
        help="base mesh only, one repetition of 2000 steps (no LEFM)",
    )
    parser.add_argument("--worker", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.worker:
        print(json.dumps(ours_worker(json.loads(args.worker))))
        return

    import mpi4py  # noqa: F401  (before dolfinx)

    sys.path.insert(0, str(ROOT))
    from fenics_adaptive.settings.config import parse_config

    ensure_akantu()
    meshes = {"80 x 1 x 4": (80, 1, None)}
    if args.quick:
        meshes["80 x 1 x 4"] = (80, 1, 2000)
        args.repeat = 1
    elif args.larger_steps:
        meshes["160 x 2 x 4"] = (160, 2, args.larger_steps)
    results = {}
    for mesh, (nx, ny, steps) in meshes.items():
        data = base_config(nx, ny)
        config = parse_config(copy.deepcopy(data), source="benchmarks/peer.py")
        runs = {name: [] for name in CODES}
        for repetition in range(args.repeat):
            ours = run_worker("ours", {"nx": nx, "ny": ny, "steps": steps, "warm": True})
            runs["fenics-adaptive"].append(ours)
            case = akantu_case(config, data, nx, ny, ours["time_step"], ours["steps"])
            runs["akantu"].append(peer := run_worker("akantu", case))
            runs["akantu, isotropic"].append(run_worker("akantu", case | {"isotropic": True}))
            print(
                f"{mesh}, run {repetition + 1}/{args.repeat}: fenics-adaptive "
                f"{1e6 * ours['seconds_per_step'] / ours['hexahedra']:.3f} µs per hex-step, "
                f"Akantu {1e6 * peer['seconds_per_step'] / peer['hexahedra']:.3f}",
                flush=True,
            )
        results[mesh] = {}
        for name, code_runs in runs.items():
            results[mesh][name] = summarise(code_runs)
            if steps is None and name != "akantu, isotropic":
                results[mesh][name]["lefm"] = against_lefm(config, code_runs[0])
    text = table(results)
    print(text)
    if not args.quick:
        RESULTS.mkdir(parents=True, exist_ok=True)
        machine = f"{platform.processor() or platform.machine()}, {os.cpu_count()} CPUs"
        (RESULTS / "peer.md").write_text(
            f"Peer benchmark (`benchmarks/peer.py`), {machine}; µs per hexahedron-step, "
            f"{args.repeat} interleaved runs per code.\n\n{text}\n"
        )
        (RESULTS / "peer.json").write_text(json.dumps(results, indent=1))


if __name__ == "__main__":
    main()
