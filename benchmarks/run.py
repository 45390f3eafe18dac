"""Benchmarks: what the adaptive element costs, measured side by side.

    .venv/bin/python benchmarks/run.py             # every benchmark, default sizes
    .venv/bin/python benchmarks/run.py --quick     # small sizes (a smoke run, ~1 min)
    .venv/bin/python benchmarks/run.py --only kernels,step

Each figure is the median of ``--repeat`` (default 5) timed repetitions after a warm-up call;
numba's first-call compile time is measured separately and reported in its own column, never in
a timing. Problem sizes are flags. The table goes to the terminal and, with the machine it ran
on, to ``benchmarks/results/latest.md`` and ``latest.json`` (``quick.*`` with ``--quick``); a
run with ``--only`` replaces the rows of its benchmarks there and keeps the others.
CI does not run this: timings are not tests.

Rows (issue 5's targets in brackets):

- ``kernel``: internal force of unrefined cells of the TCB beam scaled up (eight 0.256 mm plies,
  0.5 mm cells, ny = 10): the UFL/FFCx form, the numba kernel, and the numba kernel with the ply
  damage update. An integration-point update is one (ply, in-plane point) of the 8 x 2 x 2
  layered rule of a cell [>= 15 M/s elastic, >= 8 M/s with damage];
- ``step``: a whole explicit step, unrefined and fully refined (weak at interface 4, strong at 2
  and 6 in every cell) [unrefined/refined <= 0.70], and the share of the step that is not force
  computation [<= 20 %];
- ``overhead``: the step of a 100-cell ESL beam less its internal force: the fixed cost of a
  step (issue 17) [<= 20 us];
- ``startup``: a fresh process that imports the package, builds that beam and takes its first
  step, caches warm (issue 17) [<= 1 s from the first import to the end of the first step];
  also the whole process (the interpreter's start and exit too) and the resident memory;
- ``mass``: the step with lumped and selectively scaled masses, ESL and layerwise, on the TCB
  beam of 0.064 mm plies (issue 17) [the scaled update costs <= 10 % of the step];
- ``scaling``: unrefined step time per cell at growing sizes [within 15 % of linear];
- ``mpi``: the unrefined step on 1 and 2 ranks, 4 000 cells and ``--mpi-cells`` [speed-up
  >= 1.7 (issue 5) at 200 000 cells; issue 23: >= 1 at 4 000, >= 1.15 at 200 000; same
  history];
- ``memory``: peak resident memory of the impact plate (``demos/plate_impact.toml``): ESL,
  adaptive with the central 10 % of cells refined, layerwise [adaptive <= 0.4 x LW]; also net
  of what every process holds whatever the plate's size (measured on a 100-cell plate first);
- ``refined``: a refined cell against the layerwise cells and cohesive elements it replaces,
  elastic and with ply damage, the TCB demo refined from the start against its layerwise
  reference, and where a refined cell's time goes (issue 21; ``benchmarks/refined.py``)
  [strong cell <= 1.1 x, TCB step <= 1.0 x];
- ``plate``: the impact plate run past its peak force, adaptive against layerwise [wall time
  <= 0.35 x LW, peak contact force within 2 %], the adaptive run's share of wall time in the
  indicators [<= 5 %, issue 16] and in refining, the structure's and the solver's reaction
  (``summary.json`` ``adaptivity_cost``).

The peer comparison (the same DCB in Akantu 5.0.7, interleaved) is its own script,
``benchmarks/peer.py``: it needs a second environment with Akantu's wheel, which it makes.

Units: seconds, cells, integration points.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import resource
import statistics
import subprocess
import sys
import tempfile
import time
import tomllib
from pathlib import Path

import mpi4py  # noqa: F401  (before dolfinx)
import numpy as np
from mpi4py import MPI

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

from refined import bench_refined, force_profile, profile_rows  # noqa: E402

from fenics_adaptive.analysis.studies import plate_impact_variant  # noqa: E402
from fenics_adaptive.analysis.timing import time_call, time_per_step  # noqa: E402
from fenics_adaptive.model.assembly import SubelementSet, add_subelement_forces  # noqa: E402
from fenics_adaptive.runner import execute  # noqa: E402
from fenics_adaptive.settings.config import parse_config  # noqa: E402
from fenics_adaptive.settings.kinds import InterfaceState  # noqa: E402
from fenics_adaptive.settings.solver import Probe, SolverSettings  # noqa: E402
from fenics_adaptive.simulation import build_structure  # noqa: E402
from fenics_adaptive.solver import explicit  # noqa: E402

# plies x in-plane points: the "points" of the throughput column are ply-points whatever the
# through-thickness rule (the pre-integrated one evaluates 3 heights for 8 plies), so that rows
# of different rules compare as cost per cell
POINTS_PER_CELL = 8 * 2 * 2
FAILURE = {"XT": 1500.0, "XC": 1200.0, "YT": 50.0, "YC": 200.0, "S12": 80.0, "G2c": 0.3, "G6c": 0.8}


def beam_config(n_cells: int, kind: str = "adaptive", ply_damage: bool = False) -> dict:
    """The TCB beam with about ``n_cells`` cells (ny = 10 across, nx along), unloaded except
    for a slow opening of the arms so that the forces are not trivially zero."""
    data = tomllib.loads((ROOT / "demos" / "tcb.toml").read_text())
    data.pop("refinement", None)
    ny = 10 if n_cells >= 1000 else 1
    nx = max(n_cells // ny, 2)
    data["mesh"].update(nx=nx, ny=ny, length=0.5 * nx, width=0.5 * ny)
    data["solver"]["end_time"] = 1.0
    data["output"]["interval"] = 1.0
    data["output"].pop("fields_interval", None)
    if ply_damage:
        data["model"]["ply_damage"] = True
        data["materials"]["prototype"]["failure"] = dict(FAILURE)
    if kind == "layerwise":
        data["model"]["kind"] = "layerwise"
        data["mesh"]["layers"] = [2, 2, 2, 2]
        data["interfaces"] = {"delaminate": [2, 6], "symmetry": [4]}
    return data


def refine_all(structure) -> None:
    cells = range(structure.base.n_owned_cells)
    structure.refine([(c, 4, InterfaceState.WEAK) for c in cells])
    structure.refine([(c, i, InterfaceState.STRONG) for c in cells for i in (2, 6)])


def deform(structure, seed: int = 0) -> None:
    """A smooth bending-like displacement (0.01 % strain scale): every point does real work."""
    X = structure.X_base
    u = structure.base.u.x.array.reshape(-1, 3)
    u[:, 2] = 1e-4 * X[:, 0] ** 2 / max(X[:, 0].max(), 1.0)
    u[:, 0] = -2e-4 * (X[:, 2] - X[:, 2].mean()) * X[:, 0] / max(X[:, 0].max(), 1.0)
    structure.follow_border()


def timed(call, repeat: int) -> tuple[float, float]:
    """(median seconds of ``repeat`` calls after a first one, first-call seconds)."""
    return time_call(call, repeat, statistic=statistics.median)


# ------------------------------------------------------------------------------ benchmarks
def bench_kernels(n_cells: int, repeat: int) -> list[dict]:
    """Internal force of unrefined cells, three ways: the UFL/FFCx form, the numba kernel
    (each cell one subelement holding all 8 plies), the numba kernel with the ply damage
    update; the first two also without the enhanced thickness strain, for its cost.
    Integration-point updates per second per core."""
    rows = [row for model in ELASTIC_VARIANTS for row in _elastic_rows(n_cells, repeat, model)]
    rows += _curved_rows(n_cells, repeat)
    # ply damage integrates ply by ply: two points per ply (exact bending, the default) and one
    for points, label in ((2, ""), (1, ", 1 point per ply")):
        data = beam_config(n_cells, ply_damage=True)
        data["model"]["points_per_ply"] = points
        damaged = build_structure(parse_config(data))
        deform(damaged)
        median, first = timed(damaged.internal_force, repeat)
        n = damaged.base.n_owned_cells
        rows.append(_kernel_row(f"numba kernel, with ply damage update{label}", n, median, first))
    rows.append(_cohesive_row(n_cells, repeat))
    return rows


def _cohesive_row(n_cells: int, repeat: int) -> dict:
    """The cohesive elements of the layerwise TCB beam (two delaminating interfaces): their
    force with the damage and dissipation update, per element (the ``cells`` column counts
    cohesive elements)."""
    structure = build_structure(parse_config(beam_config(n_cells, kind="layerwise")))
    deform(structure)
    cohesive = next(c for c in structure.internal_forces.contributors if c.name == "cohesive")
    f_base = np.zeros_like(structure.base.u.x.array)
    f_extra = np.zeros_like(structure.extra.vectors["u"].array)
    median, first = timed(lambda: cohesive.add_force(0.0, f_base, f_extra), repeat)
    row = _kernel_row("numba cohesive elements", len(structure.cohesive), median, first)
    row["million_points_per_s"] = 4 * len(structure.cohesive) / median / 1e6
    return row


# [model] settings of the elastic kernel rows against the defaults, with their row labels: what
# the enhanced thickness strain costs, and the through-thickness rules (the default pre-integrated
# three points against two and one Gauss points in each of the 8 plies)
ELASTIC_VARIANTS = {
    "": {},
    ", compatible thickness strain": {"enhanced_strain": False},
    ", 2 points per ply": {"thickness_integration": "plies", "points_per_ply": 2},
    ", 1 point per ply": {"thickness_integration": "plies", "points_per_ply": 1},
}


def _elastic_rows(n_cells: int, repeat: int, variant: str) -> list[dict]:
    """The UFL/FFCx and the numba elastic rows of ``bench_kernels`` for one of
    ``ELASTIC_VARIANTS``."""
    data = beam_config(n_cells)
    data["model"].update(ELASTIC_VARIANTS[variant])
    structure = build_structure(parse_config(data))
    deform(structure)
    n = structure.base.n_owned_cells
    f = np.zeros_like(structure.base.u.x.array)
    label = variant
    median, first = timed(lambda: structure.base.add_internal_force(f), repeat)
    rows = [_kernel_row(f"UFL/FFCx form, elastic{label}", n, median, first)]

    rule = structure.rule_table.index(0, structure.laminate.n_plies)
    cells = SubelementSet(
        np.hstack([structure.bottom_local, structure.top_local]).astype(np.int32),
        np.full(n, rule, dtype=np.int64),
        structure.subelements.rules,
    )
    X_extra = np.zeros((0, 3))
    u = structure.base.u.x.array.reshape(-1, 3)
    fb = f.reshape(-1, 3)
    median, first = timed(
        lambda: add_subelement_forces(cells, structure.X_base, X_extra, u, X_extra, fb, X_extra),
        repeat,
    )
    rows.append(_kernel_row(f"numba kernel, elastic{label}", n, median, first))
    return rows


def tube_cells(n_cells: int, n_around: int = 72, radius: float = 10.0) -> np.ndarray:
    """Vertices (n, 8, 3) of about ``n_cells`` cells of a 2 mm tube wall, ``n_around`` round
    (their directors turn by 360 / n_around degrees across a cell), 0.9 mm long."""
    n_along = max(n_cells // n_around, 1)
    xi, eta, zeta = (np.array([(k >> b) & 1 for k in range(8)], float) for b in range(3))
    i, j = np.divmod(np.arange(n_along * n_around), n_around)
    theta = (j[:, None] + eta) * 2.0 * np.pi / n_around
    r = radius - 1.0 + 2.0 * zeta
    return np.stack([0.9 * (i[:, None] + xi), r * np.sin(theta), r * np.cos(theta)], axis=-1)


def _curved_rows(n_cells: int, repeat: int) -> list[dict]:
    """The numba elastic kernel on a tube's cells (8 plies, the default rule, in their frames):
    with the thickness strain sampled on their bent vertical edges, and on the same cells with
    parallel vertical edges (no correction): what the correction costs."""
    structure = build_structure(parse_config(beam_config(8)))
    rules = structure.subelements.rules
    rule = structure.rule_table.index(0, structure.laminate.n_plies)
    bent = tube_cells(n_cells)
    parallel = bent.copy()
    parallel[:, 4:] = bent[:, :4] + (bent[:, 4:] - bent[:, :4]).mean(axis=1)[:, None, :]
    n = len(bent)
    cells = SubelementSet(
        np.arange(8 * n, dtype=np.int32).reshape(n, 8),
        np.full(n, rule, dtype=np.int64),
        rules,
        frames=np.tile(np.eye(3), (n, 1, 1)),  # a shell's frames: turned, here by nothing
    )
    u = np.random.default_rng(0).normal(scale=1e-3, size=(8 * n, 3))
    f = np.zeros((8 * n, 3))
    none = np.zeros((0, 3))
    rows = []
    for X, label in ((bent, "bent 5 degrees"), (parallel, "parallel")):
        X_base = X.reshape(-1, 3)
        median, first = timed(
            lambda X_base=X_base: add_subelement_forces(cells, X_base, none, u, none, f, none),
            repeat,
        )
        rows.append(
            _kernel_row(f"numba kernel, elastic, tube cells, directors {label}", n, median, first)
        )
    return rows


def _kernel_row(name: str, n_cells: int, seconds: float, first: float) -> dict:
    return {
        "benchmark": "kernel",
        "case": name,
        "cells": n_cells,
        "seconds": seconds,
        "us_per_cell": 1e6 * seconds / n_cells,
        "million_points_per_s": n_cells * POINTS_PER_CELL / seconds / 1e6,
        "compile_s": max(first - seconds, 0.0),
    }


def step_time(structure, steps: int, repeat: int) -> tuple[float, float]:
    """(seconds per explicit step, seconds per internal-force evaluation), medians."""
    probe = Probe("x1&top", "x1&top", "z")
    step, _ = time_per_step(structure, probe, steps, repeat, statistic=statistics.median)
    force, _ = timed(structure.internal_force, repeat)
    return step, force


def bench_step(n_cells: int, steps: int, repeat: int) -> list[dict]:
    """A whole explicit step, unrefined and fully refined, and the share of the step that is
    not force computation."""
    rows = []
    for state in ("unrefined", "refined"):
        start = time.perf_counter()
        structure = build_structure(parse_config(beam_config(n_cells)))
        if state == "refined":
            refine_all(structure)
        setup = time.perf_counter() - start
        step, force = step_time(structure, steps, repeat)
        rows.append(
            {
                "benchmark": "step",
                "case": state,
                "cells": structure.comm.allreduce(structure.base.n_owned_cells),
                "ranks": structure.comm.size,
                "seconds": step,
                "us_per_cell": 1e6 * step / structure.base.n_owned_cells,
                "force_seconds": force,
                "non_force_fraction": max(step - force, 0.0) / step,
                "setup_s": setup,
            }
        )
    rows[0]["unrefined_over_refined"] = rows[0]["seconds"] / rows[1]["seconds"]
    return rows


def bench_overhead(steps: int, repeat: int) -> list[dict]:
    """The fixed cost of a step: a 100-cell ESL beam (ny = 1), the whole step and its internal
    force; what is not force is the per-step overhead (issue 17: <= 20 us)."""
    data = beam_config(100)
    data["model"]["kind"] = "esl"
    for name in ("interfaces", "cohesive"):
        data.pop(name, None)
    structure = build_structure(parse_config(data))
    step, force = step_time(structure, max(steps, 2000), repeat)
    return [
        {
            "benchmark": "overhead",
            "case": "100-cell ESL beam",
            "cells": structure.comm.allreduce(structure.base.n_owned_cells),
            "seconds": step,
            "us_per_cell": 1e6 * step / structure.base.n_owned_cells,
            "force_seconds": force,
            "overhead_us": 1e6 * (step - force),
        }
    ]


# the start-up worker: a fresh interpreter, its clock started before the first import
STARTUP_WORKER = """
import time
started = time.perf_counter()
import dataclasses, json, sys
import mpi4py.MPI
from fenics_adaptive.settings.config import parse_config
from fenics_adaptive.simulation import build_structure
from fenics_adaptive.solver import explicit
imported = time.perf_counter()
config = parse_config(json.loads(sys.argv[1]), source="startup")
structure = build_structure(config)
built = time.perf_counter()
dt, _, _ = explicit.choose_time_step(structure, config.solver)
settings = dataclasses.replace(config.solver, end_time=dt, output_interval=dt)
stats = explicit.run(structure, settings, config.probe, time_step=dt)
stepped = time.perf_counter()
rss = [line for line in open("/proc/self/status") if line.startswith("VmRSS:")]
print(json.dumps({"import_s": imported - started, "build_s": built - imported,
                  "first_step_s": stepped - built, "steps": stats.steps,
                  "rss_MiB": int(rss[0].split()[1]) / 1024.0}))
"""


def bench_startup(repeat: int) -> list[dict]:
    """Start-up of the 100-cell ESL beam of ``overhead``: ``repeat`` fresh processes after one
    that fills the caches, each timing its imports, the model's build and its run to the end of
    the first step (median of each part, and of their sum); the resident memory then."""
    data = beam_config(100)
    data["model"]["kind"] = "esl"
    for name in ("interfaces", "cohesive"):
        data.pop(name, None)
    command = [sys.executable, "-c", STARTUP_WORKER, json.dumps(data)]
    runs = []
    for k in range(repeat + 1):
        spawned = time.perf_counter()
        done = subprocess.run(command, capture_output=True, text=True, cwd=ROOT)
        if done.returncode:
            raise RuntimeError(f"startup worker failed:\n{done.stderr}")
        if k:  # the first one fills numba's cache (a fresh clone compiles there)
            run = json.loads(done.stdout.strip().splitlines()[-1])
            runs.append(run | {"process_s": time.perf_counter() - spawned})
    median = {key: statistics.median(r[key] for r in runs) for key in runs[0]}
    total = statistics.median(r["import_s"] + r["build_s"] + r["first_step_s"] for r in runs)
    return [
        {
            "benchmark": "startup",
            "case": "100-cell ESL beam, import to first step",
            "cells": 100,
            "seconds": total,
            "import_s": median["import_s"],
            "build_s": median["build_s"],
            "first_step_s": median["first_step_s"],
            # the whole process, the interpreter's start and exit included
            "process_s": median["process_s"],
            "resident_MiB": median["rss_MiB"],
        }
    ]


def bench_mass(n_cells: int, steps: int, repeat: int) -> list[dict]:
    """The explicit step with lumped and with selectively scaled masses, ESL and layerwise
    (one mesh layer per ply), on the TCB beam of plies 0.064 mm thick (0.512 mm under 0.5 mm
    cells): the cost of a step, the step, the wall time per simulated microsecond."""
    rows = []
    for kind in ("esl", "layerwise"):
        data = beam_config(n_cells, kind="esl" if kind == "esl" else "layerwise")
        data["laminate"]["ply_thickness"] = 0.064
        if kind == "esl":
            data["model"]["kind"] = "esl"
            for name in ("interfaces", "cohesive"):
                data.pop(name, None)
        else:
            data["mesh"]["layers"] = [1] * 8
        pair = []
        for scaling in ("none", "selective"):
            structure = build_structure(parse_config(data))
            probe = Probe("x1&top", "x1&top", "z")
            start = time.perf_counter()
            settings = SolverSettings(end_time=1.0, output_interval=1.0, mass_scaling=scaling)
            explicit.prepare_mass(structure, settings, refines=False)
            built = time.perf_counter() - start
            step, dt = time_per_step(
                structure, probe, steps, repeat, statistics.median, mass_scaling=scaling
            )
            pair.append(
                {
                    "benchmark": "mass",
                    "case": f"{kind}, {scaling}",
                    "cells": structure.comm.allreduce(structure.base.n_owned_cells),
                    "seconds": step,
                    "time_step_s": dt,
                    "wall_s_per_simulated_us": step / dt * 1e-6,
                    "mass_setup_s": built,
                }
            )
        lumped, scaled = pair
        scaled["step_cost_over_lumped"] = scaled["seconds"] / lumped["seconds"]
        scaled["time_to_solution_over_lumped"] = (
            scaled["wall_s_per_simulated_us"] / lumped["wall_s_per_simulated_us"]
        )
        rows += pair
    return rows


def bench_scaling(sizes: list[int], steps: int, repeat: int) -> list[dict]:
    """Unrefined step time per cell at growing sizes (linear growth: constant per-cell time)."""
    rows = []
    for n in sizes:
        structure = build_structure(parse_config(beam_config(n)))
        step, _ = step_time(structure, steps, repeat)
        rows.append(
            {
                "benchmark": "scaling",
                "case": f"{n} cells",
                "cells": structure.base.n_owned_cells,
                "seconds": step,
                "us_per_cell": 1e6 * step / structure.base.n_owned_cells,
            }
        )
    base = rows[0]["us_per_cell"]
    for row in rows:
        row["per_cell_relative_to_smallest"] = row["us_per_cell"] / base
    return rows


def bench_mpi(n_cells: int, steps: int, repeat: int) -> list[dict]:
    """The unrefined step on 1 and 2 MPI ranks (subprocesses), and whether their force
    histories agree."""
    rows = []
    for ranks in (1, 2):
        command = [sys.executable, __file__, "--only", "mpi-worker", "--cells", str(n_cells)]
        command += ["--steps", str(steps), "--repeat", str(repeat)]
        if ranks > 1:
            command = [str(Path(sys.executable).parent / "mpiexec"), "-n", str(ranks), *command]
        done = subprocess.run(command, capture_output=True, text=True, check=True)
        rows.append(json.loads(done.stdout.strip().splitlines()[-1]))
    rows[1]["speed_up"] = rows[0]["seconds"] / rows[1]["seconds"]
    rows[1]["history_difference"] = float(
        np.max(np.abs(np.array(rows[0]["history"]) - np.array(rows[1]["history"])))
        / max(np.max(np.abs(rows[0]["history"])), 1e-300)
    )
    for row in rows:
        row.pop("history")
    return rows


def mpi_worker(n_cells: int, steps: int, repeat: int) -> None:
    comm = MPI.COMM_WORLD
    structure = build_structure(parse_config(beam_config(n_cells)), comm)
    step, _ = step_time(structure, steps, repeat)
    # a short loaded history to compare between rank counts
    config = parse_config(beam_config(n_cells))
    fresh = build_structure(config, comm)
    dt, _, _ = explicit.choose_time_step(fresh, config.solver)
    settings = SolverSettings(end_time=200 * dt, output_interval=20 * dt)
    stats = explicit.run(fresh, settings, config.probe, time_step=dt)
    history = [r.reaction_force for r in stats.history]
    step = comm.allreduce(step, op=MPI.MAX)
    if comm.rank == 0:
        print(
            json.dumps(
                {
                    "benchmark": "mpi",
                    "case": f"{comm.size} rank(s)",
                    "cells": n_cells,
                    "ranks": comm.size,
                    "seconds": step,
                    "history": history,
                }
            )
        )


def plate_config(name: str, end_time: float | None = None) -> dict:
    """The impact plate of ``demos/plate_impact.toml`` as the demo runs it (esl, adaptive,
    layerwise)."""
    base = tomllib.loads((ROOT / "demos" / "plate_impact.toml").read_text())
    data = plate_impact_variant(base, name)
    if end_time is not None:
        data["solver"]["end_time"] = end_time
    return data


def bench_plate(end_time: float, repeat: int) -> list[dict]:
    """The impact plate to ``end_time`` (past the peak force), adaptive against the layerwise
    reference: wall time, peak contact force, refined fraction; then where the adaptive
    plate's internal force goes in its final state (``refined.force_profile``) against its
    mean step."""
    rows, profile = [], []
    # once untimed first: numba loads each kernel from its disk cache at the kernel's first
    # call in a process (about 10 ms each), which would land in the timed run's first
    # indicator evaluations, refinements and steps (the rows are "after a warm-up")
    with tempfile.TemporaryDirectory() as scratch:
        warm_up = parse_config(plate_config("adaptive", end_time), source="warm-up")
        execute(warm_up, Path(scratch) / "plate", show_progress=False, log=None)
    for name in ("adaptive", "layerwise"):
        config = parse_config(plate_config(name, end_time), source=name)
        summary, structure = execute(
            config, ROOT / "benchmarks" / "results" / f"plate_{name}", show_progress=False, log=None
        )
        refined = (structure.interface_state != InterfaceState.NONE).any(axis=1).mean()
        rows.append(
            {
                "benchmark": "plate",
                "case": name,
                "cells": structure.base.n_owned_cells,
                "seconds": summary["wall_time_s"],
                "peak_contact_N": summary["peak_contact_force_N"],
                "refined_fraction": float(refined) if structure.interface_state.size else 0.0,
            }
        )
        if name == "adaptive":
            cost = summary["adaptivity_cost"]
            rows[-1]["indicator_share"] = cost["indicator_wall_s"] / summary["wall_time_s"]
            refining = cost["refinement_wall_s"] + cost["reaction_wall_s"]
            rows[-1]["refinement_share"] = refining / summary["wall_time_s"]
            seconds = force_profile(structure, repeat)
            seconds["mean explicit step of the run"] = summary["time_per_step_s"]
            profile = profile_rows("adaptive, final state", structure, seconds, "plate")
            step_row = profile[-1]  # the step is not a part of the force: the other way round
            del step_row["share_of_force"]
            step_row["force_share_of_step"] = seconds["whole internal force"] / step_row["seconds"]
    adaptive, layerwise = rows
    adaptive["wall_over_layerwise"] = adaptive["seconds"] / layerwise["seconds"]
    adaptive["peak_vs_layerwise"] = adaptive["peak_contact_N"] / layerwise["peak_contact_N"] - 1
    return rows + profile


def bench_memory(n_cells: int) -> list[dict]:
    """Peak resident memory of a process that builds the impact plate with about ``n_cells``
    cells and takes 10 steps (subprocesses): ESL, adaptive with the central 10 % of the cells
    strongly refined at its three interfaces, layerwise. Each process first runs the same case
    on a 100-cell plate and reports its resident memory after that: the interpreter, DOLFINx,
    the loaded FFCx and numba kernels, Gmsh, whatever the size (``fixed``). The net ratio
    compares what grows with the model: peak - fixed."""
    rows = []
    for case in ("esl", "adaptive_10pct", "layerwise"):
        command = [sys.executable, __file__, "--only", "memory-worker", "--case", case]
        command += ["--cells", str(n_cells)]
        done = subprocess.run(command, capture_output=True, text=True, check=True)
        rows.append(json.loads(done.stdout.strip().splitlines()[-1]))
    lw = rows[-1]
    for row in rows:
        row["relative_to_layerwise"] = row["peak_MiB"] / lw["peak_MiB"]
        row["net_relative_to_layerwise"] = (row["peak_MiB"] - row["fixed_MiB"]) / (
            lw["peak_MiB"] - lw["fixed_MiB"]
        )
    return rows


def resident_memory_mib(key: str = "VmHWM") -> float:
    """This process's peak (``VmHWM``) or current (``VmRSS``) resident memory (MiB). VmHWM,
    not ru_maxrss: Linux carries the latter over from the parent through exec, so a small child
    would report its parent's."""
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith(f"{key}:"):
            return float(line.split()[1]) / 1024.0
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0  # not Linux: KiB


def memory_worker(case: str, n_cells: int) -> None:
    imports = resident_memory_mib("VmRSS")  # everything imported, nothing built
    memory_case(case, 100)  # compiles and loads every kernel, mesher and form the case uses
    fixed = resident_memory_mib("VmRSS")
    n = memory_case(case, n_cells)
    peak = resident_memory_mib("VmHWM")
    row = {"benchmark": "memory", "case": case, "cells": n, "peak_MiB": peak}
    print(json.dumps(row | {"imports_MiB": imports, "fixed_MiB": fixed}))


def memory_case(case: str, n_cells: int) -> int:
    """Build the memory benchmark's plate with about ``n_cells`` cells, refine it as ``case``
    says, take 10 steps; returns its cells."""
    name = {"esl": "esl", "adaptive_10pct": "esl", "layerwise": "layerwise"}[case]
    data = plate_config(name)
    data.pop("impactor")
    side = max(round(n_cells**0.5), 2)
    data["mesh"].update(nx=side, ny=side)
    structure = build_structure(parse_config(data))
    if case == "adaptive_10pct":
        centre = structure.X_base[structure.bottom_local].mean(axis=1)[:, :2]
        distance = np.abs(centre - centre.mean(axis=0)).max(axis=1)
        cells = np.flatnonzero(distance <= np.quantile(distance, 0.1))
        interfaces = data["interfaces"]["delaminate"]
        structure.refine([(int(c), i, InterfaceState.STRONG) for c in cells for i in interfaces])
    step_time(structure, 10, 1)
    return structure.base.n_owned_cells


# ------------------------------------------------------------------------------ reporting
def machine() -> str:
    cpu = "unknown CPU"
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    return f"{cpu}, {os.cpu_count()} cores, Python {platform.python_version()}"


def table(rows: list[dict]) -> str:
    lines = [
        "| benchmark | case | cells | time (s) | us/cell | figure |",
        "|---|---|---|---|---|---|",
    ]
    for r in rows:
        figure = []
        for key, fmt in (
            ("million_points_per_s", "{:.1f} M points/s"),
            ("compile_s", "compile {:.1f} s"),
            ("unrefined_over_refined", "unrefined/refined {:.2f}"),
            ("non_force_fraction", "non-force {:.0%}"),
            ("setup_s", "setup {:.0f} s"),
            ("per_cell_relative_to_smallest", "per cell x{:.2f}"),
            ("speed_up", "speed-up {:.2f}"),
            ("history_difference", "history diff {:.1e}"),
            ("peak_MiB", "{:.0f} MiB"),
            ("peak_contact_N", "peak contact {:.1f} N"),
            ("refined_fraction", "refined {:.1%}"),
            ("wall_over_layerwise", "wall/LW {:.2f}"),
            ("peak_vs_layerwise", "peak vs LW {:+.2%}"),
            ("fixed_MiB", "{:.0f} MiB fixed"),
            ("relative_to_layerwise", "x{:.2f} of LW"),
            ("net_relative_to_layerwise", "net of the fixed x{:.2f}"),
            ("overhead_us", "overhead {:.0f} us per step"),
            ("import_s", "imports {:.2f} s"),
            ("build_s", "build {:.2f} s"),
            ("first_step_s", "first step {:.2f} s"),
            ("process_s", "whole process {:.2f} s"),
            ("resident_MiB", "{:.0f} MiB resident"),
            ("time_step_s", "step {:.3g} s"),
            ("wall_s_per_simulated_us", "{:.3g} s per simulated us"),
            ("mass_setup_s", "scaled mass built in {:.1f} s"),
            ("step_cost_over_lumped", "step cost x{:.2f}"),
            ("time_to_solution_over_lumped", "time to solution x{:.2f}"),
            ("layerwise_us_per_cell", "LW {:.2f} us/cell"),
            ("over_layerwise", "x{:.2f} of LW"),
            ("energy_difference", "energy diff {:.1e}"),
            ("share_of_force", "{:.0%} of the force"),
            ("force_share_of_step", "internal force {:.0%} of it"),
            ("indicator_share", "indicators {:.1%} of the wall time"),
            ("refinement_share", "refining {:.1%}"),
        ):
            if key in r:
                figure.append(fmt.format(r[key]))
        seconds = f"{r['seconds']:.4g}" if "seconds" in r else "-"
        us = f"{r['us_per_cell']:.2f}" if "us_per_cell" in r else "-"
        lines.append(
            f"| {r['benchmark']} | {r['case']} | {r['cells']} | {seconds} | {us} | "
            f"{', '.join(figure)} |"
        )
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "--only", default="kernels,step,overhead,startup,mass,scaling,mpi,memory,refined,plate"
    )
    parser.add_argument("--quick", action="store_true", help="small sizes, a smoke run")
    parser.add_argument("--cells", type=int, default=None, help="cells of the step benchmark")
    parser.add_argument("--kernel-cells", type=int, default=100_000)
    parser.add_argument("--scaling", default="10000,100000,400000")
    parser.add_argument("--mpi-cells", type=int, default=200_000)
    parser.add_argument("--memory-cells", type=int, default=40_000)
    parser.add_argument("--mass-cells", type=int, default=20_000, help="cells per mesh layer")
    parser.add_argument("--refined-cells", type=int, default=20_000)
    parser.add_argument("--plate-end-time", type=float, default=3.0e-4, help="s")
    parser.add_argument("--steps", type=int, default=20, help="explicit steps per repetition")
    parser.add_argument("--repeat", type=int, default=5)
    parser.add_argument("--case", default="esl")
    parser.add_argument("--out", default=ROOT / "benchmarks" / "results")
    args = parser.parse_args()
    cells = args.cells or 100_000
    if args.quick:
        cells = args.cells or 2_000
        args.kernel_cells, args.scaling, args.mpi_cells, args.plate_end_time = (
            2_000,
            "1000,4000",
            4_000,
            2.0e-5,
        )
        args.memory_cells = 2_500
        args.refined_cells = 1_000
        args.mass_cells = 2_000
    only = args.only.split(",")
    if only == ["mpi-worker"]:
        return mpi_worker(cells, args.steps, args.repeat)
    if only == ["memory-worker"]:
        return memory_worker(args.case, args.cells or args.memory_cells)

    rows: list[dict] = []
    started = time.perf_counter()
    jobs = {
        "kernels": lambda: bench_kernels(args.kernel_cells, args.repeat),
        "step": lambda: bench_step(cells, args.steps, args.repeat),
        "overhead": lambda: bench_overhead(args.steps, args.repeat),
        "mass": lambda: bench_mass(args.mass_cells, args.steps, args.repeat),
        "scaling": lambda: bench_scaling(
            [int(n) for n in args.scaling.split(",")], args.steps, args.repeat
        ),
        "mpi": lambda: [
            row
            for cells in sorted({4000, args.mpi_cells})
            for row in bench_mpi(cells, args.steps, args.repeat)
        ],
        "memory": lambda: bench_memory(args.memory_cells),
        "startup": lambda: bench_startup(args.repeat),
        "refined": lambda: bench_refined(args.refined_cells, args.steps, args.repeat),
        "plate": lambda: bench_plate(args.plate_end_time, args.repeat),
    }
    for name in only:
        if name not in jobs:
            parser.error(f"--only: unknown benchmark {name!r} (choose from {', '.join(jobs)})")
        print(f"running {name} ...", file=sys.stderr, flush=True)
        rows += jobs[name]()
        print(table(rows), file=sys.stderr, flush=True)
    print(table(rows))
    for row in rows:
        row["date"] = time.strftime("%Y-%m-%d")
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    stem = "quick" if args.quick else "latest"  # a smoke run leaves the real table alone
    if not args.quick:
        rows = merged_rows(out / "latest.json", rows, list(jobs))
    dates = sorted({row.get("date", "earlier") for row in rows})
    header = (
        f"Machine: {machine()}. Median of {args.repeat} repetitions after a warm-up. "
        f"Rows measured on {', '.join(dates)}; the last run ({', '.join(only)}) took "
        f"{time.perf_counter() - started:.0f} s.\n\n"
    )
    (out / f"{stem}.md").write_text(header + table(rows) + "\n")
    (out / f"{stem}.json").write_text(
        json.dumps({"machine": machine(), "rows": rows}, indent=2) + "\n"
    )


# row["benchmark"] of each job
JOB_ROWS = {
    "kernels": "kernel",
    "step": "step",
    "overhead": "overhead",
    "mass": "mass",
    "scaling": "scaling",
    "mpi": "mpi",
    "memory": "memory",
    "startup": "startup",
    "refined": "refined",
    "plate": "plate",
}


def merged_rows(previous: Path, rows: list[dict], job_order: list[str]) -> list[dict]:
    """``rows`` plus the rows of ``previous`` (a latest.json) for the benchmarks this run did
    not repeat, in the jobs' order: ``--only kernels`` updates the kernel rows and keeps the
    rest of the committed table."""
    if not previous.exists():
        return rows
    fresh = {row["benchmark"] for row in rows}
    kept = [
        row for row in json.loads(previous.read_text())["rows"] if row["benchmark"] not in fresh
    ]
    order = [JOB_ROWS[job] for job in job_order]
    return sorted(kept + rows, key=lambda row: order.index(row["benchmark"]))


if __name__ == "__main__":
    main()
