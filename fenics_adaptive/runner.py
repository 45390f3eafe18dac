"""One run from a config: mesh -> model -> loads -> explicit solver -> output folder.

Units: N, mm, s, tonne.
"""

from __future__ import annotations

import math
import platform
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import dolfinx
import numba
from mpi4py import MPI

import fenics_adaptive
from fenics_adaptive import explicit, output
from fenics_adaptive.config import RunConfig
from fenics_adaptive.loading import ResolvedLoads, resolve
from fenics_adaptive.model import LayeredModel, build_model
from meshes.beam import BeamMesh, layered_mesh


@dataclass
class Problem:
    config: RunConfig
    beam: BeamMesh
    model: LayeredModel
    loads: ResolvedLoads
    time_step: float
    stable_time_step: float
    critical_cell: int


def build_problem(config: RunConfig, comm: MPI.Comm = MPI.COMM_WORLD) -> Problem:
    """Everything up to, not including, the time loop. Raises InputError for a config that
    cannot run (e.g. a forced time step above the stable one)."""
    layers = config.layer_laminates()
    beam = layered_mesh(
        comm,
        config.mesh.length,
        config.mesh.width,
        config.mesh.nx,
        config.mesh.ny,
        [laminate.thickness for laminate in layers],
    )
    model = build_model(beam, layers, config.points_per_ply)
    loads = resolve(model, config.motions, config.loads)
    dt, stable, cell = explicit.choose_time_step(model, config.solver)
    return Problem(config, beam, model, loads, dt, stable, cell)


def run_config(
    config: RunConfig,
    out_dir: str | Path,
    comm: MPI.Comm = MPI.COMM_WORLD,
    show_progress: bool = True,
    log: Callable[[str], None] | None = print,
) -> dict:
    """Run a config and write its results into ``out_dir``; returns the summary."""
    problem = build_problem(config, comm)
    say = log if (log is not None and comm.rank == 0) else (lambda _: None)
    model = problem.model
    n_cells = comm.allreduce(model.mesh.topology.index_map(3).size_local, op=MPI.SUM)
    n_nodes = model.V.dofmap.index_map.size_global
    n_steps = math.ceil(config.solver.end_time / problem.time_step - 1e-9)
    say(
        f"{config.kind} model: {n_cells} cells, {n_nodes} nodes ({3 * n_nodes} DOFs), "
        f"{config.laminate.n_plies} plies, {len(problem.beam.layer_z) - 1} cell layer(s), "
        f"{comm.size} MPI rank(s)"
    )
    say(
        f"time step {problem.time_step:.4e} s (stable {problem.stable_time_step:.4e} s with "
        f"safety factor {config.solver.safety_factor}), {n_steps} steps to "
        f"{config.solver.end_time:.4e} s"
    )

    out_dir = Path(out_dir)
    if comm.rank == 0:
        out_dir.mkdir(parents=True, exist_ok=True)
    comm.barrier()
    output.clear_previous_results(out_dir, comm)
    history = output.HistoryWriter(out_dir, comm)
    fields = output.FieldWriter(out_dir, [model.u]) if config.solver.field_interval else None
    progress = output.Progress(config.solver.end_time, comm) if show_progress else None
    summary = {
        "status": "running",
        "config": config.source,
        "units": "N, mm, s, tonne (MPa, mJ)",
        "model": {
            "kind": config.kind,
            "cells": n_cells,
            "nodes": n_nodes,
            "dofs": 3 * n_nodes,
            "plies": config.laminate.n_plies,
            "cell_layers": len(problem.beam.layer_z) - 1,
            "thickness_mm": config.laminate.thickness,
            "total_mass_tonne": model.total_mass(),
        },
        "time_step": {
            "used_s": problem.time_step,
            "stable_s": problem.stable_time_step,
            "safety_factor": config.solver.safety_factor,
            "critical_cell": problem.critical_cell,
        },
        "mpi_ranks": comm.size,
        "versions": {
            "fenics_adaptive": fenics_adaptive.__version__,
            "dolfinx": dolfinx.__version__,
            "numba": numba.__version__,
            "python": platform.python_version(),
        },
    }
    start = time.perf_counter()
    try:
        stats = explicit.run(
            model,
            problem.loads,
            config.solver,
            config.probe,
            on_history=history,
            on_fields=fields,
            on_progress=progress,
        )
    except BaseException as error:
        history.close(completed=False)
        if fields is not None:
            fields.close()
        summary["status"] = "failed"
        summary["error"] = f"{type(error).__name__}: {error}"
        summary["wall_time_s"] = time.perf_counter() - start
        output.write_summary(out_dir, summary, comm)
        raise
    finally:
        if progress is not None:
            progress.done()
    history.close(completed=True)
    if fields is not None:
        fields.close()

    rows = stats.history
    peak = max(rows, key=lambda r: abs(r.reaction_force))
    scale = max(max(abs(r.external_work) for r in rows), 1e-300)
    summary.update(
        {
            "status": "completed",
            "steps": stats.steps,
            "wall_time_s": stats.wall_time,
            "time_per_step_s": stats.wall_time / max(stats.steps, 1),
            "peak_reaction_force_N": peak.reaction_force,
            "displacement_at_peak_mm": peak.displacement,
            "final": {
                "time_s": rows[-1].time,
                "displacement_mm": rows[-1].displacement,
                "reaction_force_N": rows[-1].reaction_force,
                "kinetic_energy_mJ": rows[-1].kinetic_energy,
                "internal_energy_mJ": rows[-1].internal_energy,
                "external_work_mJ": rows[-1].external_work,
                "damping_energy_mJ": rows[-1].damping_energy,
            },
            "max_energy_balance_error_relative": max(abs(r.energy_balance) for r in rows) / scale,
        }
    )
    output.write_summary(out_dir, summary, comm)
    if comm.rank == 0:
        output.plot_history(rows, out_dir, title=Path(config.source).stem)
    say(
        f"done: {stats.steps} steps in {stats.wall_time:.1f} s "
        f"({1e6 * stats.wall_time / max(stats.steps, 1):.0f} us/step); results in {out_dir}"
    )
    return summary
