"""One static solve from a config: mesh -> model -> loads at their final value -> static
equilibrium (``solver.equilibrium``) -> the output folder a run writes. The command
``fenics-adaptive static CASE.toml --out DIR``: the elastic check users do before a dynamic run.

Units: N, mm, s, tonne (stress MPa, energy mJ).

The same model as ``fenics-adaptive run`` builds: ESL, adaptive with its initial refinement
(``[interfaces] initial``, the cells under insert films) and layerwise, at t = the end time
(loads, prescribed displacements and driven rigid bodies at their final values). What is made
linear, said in the log and in ``summary.json`` ("static.linearised"):

- small strains (a config with ``kinematics = "finite"`` is solved with small strains);
- no ply damage (the plies elastic; their Hashin exposure is in the ply output);
- cohesive elements with their initial stiffness, no damage onset: an intact interface is a
  linear spring layer. Insert films are open or closed by the solution: closed faces carry the
  law's compression branch (frictionless penalty contact), open ones nothing;
- rigid bodies fixed or driven (at their position at the end time) are frictionless penalty
  contacts (their ``penalty``, else C33 x node area / thickness); a free body (mass and
  velocity, an [impactor]) has no static equilibrium and is refused.

Written: ``history.csv`` (one row at the end time), ``summary.json`` ("analysis": "static"),
the field files a run writes (``displacement.xdmf``, ``elements.pvd``, ``cohesive.pvd``,
``plies.pvd``, one frame) and, for ESL and adaptive models, ``interlaminar_stresses.csv``: the
interlaminar stress estimate the refinement indicators use (``indicators.interlaminar_stresses``)
at every ply interface of every cell. One MPI rank (the probed tangent is serial).
"""

from __future__ import annotations

import csv
import dataclasses
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
from mpi4py import MPI

from fenics_adaptive.adaptivity.indicators import interlaminar_stresses
from fenics_adaptive.element.geometry import quad_areas
from fenics_adaptive.errors import InputError
from fenics_adaptive.io import output
from fenics_adaptive.io.run_folder import RunFolder
from fenics_adaptive.model.contact import Contact
from fenics_adaptive.model.diagnostics import delaminated_areas
from fenics_adaptive.model.loading import COMPONENTS, face_dofs, on_top_or_bottom
from fenics_adaptive.runner import model_summary, versions
from fenics_adaptive.settings.config import RunConfig
from fenics_adaptive.settings.kinds import Kinematics, ModelKind, RigidMotion
from fenics_adaptive.settings.materials import P_KN, P_KS
from fenics_adaptive.simulation import build_structure, film_fronts
from fenics_adaptive.solver import equilibrium
from fenics_adaptive.solver.history import HistoryRow

INTERLAMINAR_FILE = "interlaminar_stresses.csv"


def linearised(config: RunConfig) -> tuple[RunConfig, list[str]]:
    """The config the static solve builds (small strains, no ply damage) and what was changed,
    one sentence each. Raises InputError for a free rigid body (no static equilibrium)."""
    if config.impactor is not None:
        raise InputError(
            "impactor",
            "a free impactor has no static equilibrium; for a static check make it a "
            '[[rigid]] body with motion = "fixed" or "prescribed"',
        )
    for body in config.rigid_bodies:
        if body.motion == RigidMotion.FREE:
            raise InputError(
                f"rigid.{body.name}.motion",
                'a free body has no static equilibrium; use "fixed" or "prescribed" for a '
                "static check",
            )
    if config.lever is not None:  # its saddle's height depends on the hinge's displacement
        raise InputError(
            "lever",
            "the static solve has no lever (its saddle moves with the hinge); run the MMB "
            "explicitly (fenics-adaptive run), slowly enough to be quasi-static",
        )
    changes = []
    if config.kinematics != Kinematics.SMALL:
        changes.append("finite kinematics solved with small strains")
    if config.ply_damage:
        changes.append("ply damage off (plies elastic, [[matrix_strength]] unused)")
    if config.cohesive is not None:
        changes.append("cohesive elements at their initial stiffness, no damage onset")
    if config.delaminations:
        changes.append("insert films open, or closed in frictionless contact")
    if config.rigid_bodies:
        changes.append("rigid bodies at their end-time position, frictionless penalty contact")
    if any(body.friction > 0.0 for body in config.rigid_bodies):
        changes.append("the rigid bodies' friction left out (one increment has no slip history)")
    bodies = tuple(dataclasses.replace(body, friction=0.0) for body in config.rigid_bodies)
    small = dataclasses.replace(
        config,
        kinematics=Kinematics.SMALL,
        ply_damage=False,
        matrix_strength=(),
        rigid_bodies=bodies,
    )
    return small, changes


def static_config(
    config: RunConfig,
    out_dir: str | Path,
    comm: MPI.Comm = MPI.COMM_WORLD,
    log: Callable[[str], None] | None = print,
    overwrite: bool = False,
) -> dict:
    """Solve the config statically at its end time and write the results into ``out_dir`` (a
    run folder, as ``runner.execute`` treats it); returns the summary. Raises InputError on
    more than one MPI rank, for a free rigid body or a bad ``out_dir``; RuntimeError if the
    contacts do not settle; numpy.linalg.LinAlgError if the model is not held."""
    if comm.size > 1:
        raise InputError(
            "static", f"runs on one MPI rank (this is {comm.size}): start it without mpiexec"
        )
    say = log if log is not None else (lambda _: None)
    out_dir = Path(out_dir)
    folder = RunFolder(out_dir, comm, overwrite)
    folder.check(True)  # before the model is built
    structure, system, changes = build_static(config, comm)
    t, contacts = system.t, system.contacts
    summary = {
        "status": "running",
        "analysis": "static",
        "config": config.source,
        "units": "N, mm, s, tonne (MPa, mJ)",
        "model": model_summary(config, structure, comm),
        "mpi_ranks": comm.size,
        "versions": versions(),
    }
    model = summary["model"]
    say(
        f"{config.kind} model: {model['cells']} cells, {model['dofs']} DOFs, "
        f"{model['extra_nodes_at_start']} extra nodes, {model['cohesive_elements_at_start']} "
        f"cohesive elements; static at t = {t:.6g} s"
    )
    for change in changes:
        say(f"linearised: {change}")
    folder.open(True)
    try:
        start = time.perf_counter()
        solution = equilibrium.solve(system)
        wall = time.perf_counter() - start
        row, reaction = _history_row(config, system, solution, contacts)
        summary.update(_static_summary(system, solution, row, reaction, contacts, changes, wall))
        _write(config, out_dir, structure, system, solution, row, contacts, folder)
        summary["status"] = "completed"
        output.write_summary(out_dir, summary, comm, folder.record)
    except BaseException as error:
        summary["status"] = "failed"
        summary["error"] = f"{type(error).__name__}: {error}"
        output.write_summary(out_dir, summary, comm, folder.record)
        raise
    finally:
        folder.close()
    static = summary["static"]
    say(
        f"done: {static['newton_iterations']} Newton step(s), {static['force_evaluations']} "
        f"force evaluations in {wall:.1f} s, relative residual {static['relative_residual']:.2e}"
        f"; results in {out_dir}"
    )
    return summary


def build_static(config: RunConfig, comm: MPI.Comm = MPI.COMM_WORLD):
    """(structure, static problem, what was linearised) of a config: the structure of
    ``linearised(config)`` as a run starts it (with the band its indicators refine ahead of
    the insert films at t = 0, ``simulation.film_fronts``), its loads and motions at the end
    time, the config's rigid bodies there. Raises InputError as ``linearised`` does."""
    linear, changes = linearised(config)
    structure = build_structure(linear, comm)
    # the band a run's indicators refine ahead of its films at t = 0, as the run starts
    structure.refine(film_fronts(linear, structure), 0.0)
    t = config.solver.end_time
    contacts = [_contact_at(body, structure, t) for body in config.rigid_bodies]
    return structure, equilibrium.StaticSystem(structure, t, contacts), changes


def solve_config(config: RunConfig, comm: MPI.Comm = MPI.COMM_WORLD):
    """The static solution of a config without writing anything: (structure, system, solution
    (``equilibrium.Equilibrium``)); the displacement is left in the structure. Raises as
    ``static_config`` does."""
    structure, system, _ = build_static(config, comm)
    return structure, system, equilibrium.solve(system)


def interlaminar_estimate(structure, system, solution) -> np.ndarray:
    """(n_cells, n_plies + 1, 3): the interlaminar stress estimate of the refinement indicators
    (``indicators.interlaminar_stresses``, MPa) of a static solution, with the forces of the
    motions on the top and bottom faces and of the rigid bodies taken in."""
    n_base_dofs = system.n_base_dofs
    face_force = np.zeros(n_base_dofs)
    on_faces = np.array([on_top_or_bottom(m.face) for m in structure.motions], dtype=bool)
    if len(on_faces):
        held = system.fixed[on_faces[system.fixed_motion]]
        held = held[held < n_base_dofs]
        face_force[held] = (solution.resisting_force - system.f_ext)[held]
    if system.contacts:
        system.set_displacement(solution.u)
        face_force += system.contact_force()[:n_base_dofs]
        for contact in system.contacts:  # (a body on every node presses edges too)
            if contact.every_node:
                contact.take_out_of(face_force)
    return interlaminar_stresses(structure, system.t, face_force=face_force)


def cohesive_tractions(structure, u: np.ndarray):
    """The tractions the cohesive elements carry in a static solution: (centres (n, 3) mm,
    reference areas (n,) mm^2, tractions (n, 3) (sigma_zz, tau_xz, tau_yz) MPa): the penalties
    times the mean opening of each element's four node pairs, in the reference frame (the
    solution's displacements are small); a failed element (an insert film) carries only
    compression. ``u``: the displacement, combined DOFs (mm)."""
    cohesive = structure.cohesive
    displacement = u.reshape(-1, 3)
    nodes = cohesive.nodes
    opening = (displacement[nodes[:, 4:]] - displacement[nodes[:, :4]]).mean(axis=1)
    X = structure.gather(nodes[:, :4], "X")
    K_n, K_s = cohesive.params[P_KN], cohesive.params[P_KS]
    failed = cohesive.failed()
    normal = np.where(failed, np.minimum(opening[:, 2], 0.0), opening[:, 2])
    shear = np.where(failed[:, None], 0.0, opening[:, :2])
    tractions = np.column_stack([K_n * normal, K_s * shear])
    return X.mean(axis=1), quad_areas(X), tractions


def _contact_at(body, structure, t: float) -> Contact:
    """The contact of a fixed or driven rigid body at its position at time t (s), with its
    own penalty or the natural one (no time step caps it here)."""
    contact = Contact.on(body, structure)
    contact.centre[:] = contact.origin + contact.path * body.path_scale(t)
    contact.t = t
    return contact


def _history_row(config, system, solution, contacts) -> tuple[HistoryRow, np.ndarray]:
    """The history row of the solution and the reaction force (N, combined DOFs: what the
    prescribed motions apply, f_int - f_contact - f_ext on their DOFs, zero elsewhere)."""
    structure, probe = system.structure, config.probe
    u, f = solution.u, solution.resisting_force
    component = COMPONENTS[probe.component]
    reaction = np.zeros(system.n)
    reaction[system.fixed] = (f - system.f_ext)[system.fixed]
    on_face = np.array(
        [m.face == probe.reaction_face and m.component == probe.component
         for m in structure.motions],
        dtype=bool,
    )  # fmt: skip
    held = system.fixed[on_face[system.fixed_motion]] if len(on_face) else system.fixed[:0]
    dofs = face_dofs(structure.base, probe.displacement_face, probe.component,
                     x_range=probe.displacement_x)  # fmt: skip
    solid, cohesive = structure.internal_forces.energies()
    # Clapeyron: the work of loads and prescribed motions applied in proportion
    work = 0.5 * float(system.f_ext @ u + reaction[system.fixed] @ u[system.fixed])
    delaminated, grown = delaminated_areas(structure)
    row = HistoryRow(
        time=system.t,
        displacement=float(u[dofs].mean()) if len(dofs) else 0.0,
        reaction_force=float(reaction[held].sum()),
        applied_force=float(system.f_ext[component::3].sum()),
        kinetic_energy=0.0,
        internal_energy=solid + cohesive,
        external_work=work,
        damping_energy=0.0,
        dissipated_energy=0.0,
        refinement_energy=0.0,
        delaminated_area=delaminated,
        time_step=0.0,
        crack_growth_area=grown,
    )
    for contact in contacts:
        moved = contact.centre - contact.origin
        force, penalty, _, _ = contact.totals_over_ranks()
        # Clapeyron again: a driven body gives half its force times its travel, less what its
        # penalty spring keeps
        row.impact_work += -0.5 * float(force @ moved) - penalty
        # along the body's direction (z; a plane's minus its normal), as the explicit history
        row.bodies[f"{contact.body.name}_force"] = float(contact.direction @ force)
        row.bodies[f"{contact.body.name}_displacement"] = float(contact.direction @ moved)
    return row, reaction


def _static_summary(system, solution, row, reaction, contacts, changes, wall) -> dict:
    """The summary entries of a static solution."""
    structure = system.structure
    cohesive = structure.cohesive
    films = np.flatnonzero(cohesive.inserted()) if len(cohesive) else np.zeros(0, np.int64)
    penetration = 0.0
    if len(films):  # how far closed film faces overlap (mm): the penalty's compliance
        u = system.displacement().reshape(-1, 3)
        nodes = cohesive.nodes[films]
        penetration = float(max(0.0, -(u[nodes[:, 4:], 2] - u[nodes[:, :4], 2]).min()))
    return {
        "static": {
            "time_s": system.t,
            "linearised": changes,
            "newton_iterations": solution.iterations,
            "force_evaluations": solution.force_evaluations,
            "relative_residual": solution.residual,
            "stiffness_asymmetry": solution.tangent.asymmetry() if len(solution.tangent.values)
            else 0.0,
            "applied_force_N": system.f_ext.reshape(-1, 3).sum(axis=0).tolist(),
            "reaction_force_N": reaction.reshape(-1, 3).sum(axis=0).tolist(),
            "strain_energy_mJ": row.internal_energy,
            "half_external_work_mJ": row.external_work,
            "insert_film_penetration_mm": penetration,
            "wall_time_s": wall,
        },
        "final": {
            "time_s": row.time,
            "displacement_mm": row.displacement,
            "reaction_force_N": row.reaction_force,
            "applied_force_N": row.applied_force,
        },
        "rigid_bodies": {
            c.body.name: {
                "force_N": c.totals_over_ranks()[0].tolist(),
                "displacement_mm": row.bodies[f"{c.body.name}_displacement"],
            }
            for c in contacts
        },
    }  # fmt: skip


def _write(config, out_dir, structure, system, solution, row, contacts, folder) -> None:
    """history.csv, the field files (one frame) and the interlaminar stresses."""
    comm = structure.comm
    bodies = [f"{c.body.name}_{what}" for c in contacts for what in ("force", "displacement")]
    folder.record(out_dir / "history.partial.csv", out_dir / "history.csv")
    history = output.HistoryWriter(out_dir, comm, [], bodies)
    history(row)
    history.close(completed=True)
    fields = output.FieldOutputs(out_dir, structure, folder.record, config.fields)
    fields(system.t)
    fields.close()
    if config.kind != ModelKind.LAYERWISE or len(structure.cohesive):
        folder.record(out_dir / INTERLAMINAR_FILE)
        layerwise = config.kind == ModelKind.LAYERWISE
        _write_interlaminar(out_dir / INTERLAMINAR_FILE, structure, system, solution, layerwise)


def _write_interlaminar(path: Path, structure, system, solution, layerwise: bool) -> None:
    """The interlaminar stresses (MPa) of a static solution, a row each: of an ESL or
    adaptive model per cell and ply boundary (``interface`` 0: the bottom face .. n_plies: the
    top face), the estimate the indicators use, at the cell's centre; of a layerwise model per
    cohesive element (``element``), the traction it carries (``cohesive_tractions``)."""
    header = ["x_mm", "y_mm", "interface", "sigma_zz_MPa", "tau_xz_MPa", "tau_yz_MPa"]
    rows = []
    if layerwise:
        centres, _, tractions = cohesive_tractions(structure, solution.u)
        header.insert(0, "element")
        for element, interface in enumerate(structure.cohesive.interface):
            rows.append([element, *centres[element, :2], int(interface), *tractions[element]])
    else:
        header.insert(0, "cell")
        estimate = interlaminar_estimate(structure, system, solution)
        centres = structure.cell_vertices().mean(axis=1)
        for cell in range(estimate.shape[0]):
            for boundary in range(estimate.shape[1]):
                rows.append([cell, *centres[cell, :2], boundary, *estimate[cell, boundary]])
    with open(path, "w", newline="") as file:
        writer = csv.writer(file)
        writer.writerow(header)
        for row in rows:
            writer.writerow([row[0], *(f"{v:.9g}" for v in row[1:3]), row[3],
                             *(f"{v:.9g}" for v in row[4:])])  # fmt: skip
