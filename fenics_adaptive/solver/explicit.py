"""Lumped-mass central-difference time integration with energy bookkeeping.

Units: N, mm, s, tonne (energies in mJ = N mm).

Staggered scheme (velocities at half steps, variable step allowed):

    a_n       = (f_ext(t_n) - f_int(u_n)) / m                 (prescribed DOFs: their motion)
    v_{n+1/2} = v_{n-1/2} + (dt_{n-1/2} + dt_{n+1/2}) / 2 * a_n
    u_{n+1}   = u_n + dt_{n+1/2} * v_{n+1/2}

with optional mass-proportional damping c (1/s, per DOF) applied implicitly to v. The DOFs come
in blocks (``structure.Block``: base nodes, extra nodes of the enrichment), each in DOLFINx
vectors (the memory of the ghosted PETSc Vecs): owned entries are updated, then the ghost entries
of u are refreshed by a forward scatter, so any number of MPI ranks gives the same result up to
the summation order of the assembly.

Energies (global, on output steps): kinetic 1/2 v.M.v at full steps; internal work
sum 1/2 (f_n + f_{n+1}).du (strain energy plus what materials dissipate); external work of loads
and of prescribed motions (reaction forces); damping work; the mechanical energy that
refinement adds or removes (kinetic: it redistributes lumped masses; strain and cohesive: what
new nodes change, also added to the internal work). Balance:
kinetic + internal + damping - external - refinement = 0 up to the scheme's O(dt^2) error.
Dissipated = internal work - solid strain energy - recoverable cohesive energy. A second
balance from the states (``HistoryRow.state_energy_balance``) replaces the internal work by the
strain and stored cohesive energy plus the dissipation the damage laws report themselves
(``cohesive_dissipation``, ``ply_dissipation``): it checks the materials' bookkeeping too.

Guards (``guards``): the run stops as failed (``ElementInverted``, ``EnergyBalanceError``, both
``Diverged``) when an element inverts (checked every 64 steps and on output steps) or when
|energy balance| exceeds ``energy_error_limit`` x the largest energy of the run so far (on
output steps, from step ``guards.ENERGY_MIN_STEPS``); an explicit impactor penalty above the
largest stable one for the step is refused (``Contact.check_penalty``).
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
from mpi4py import MPI

from fenics_adaptive.errors import InputError
from fenics_adaptive.model.contact import Contact
from fenics_adaptive.model.loading import COMPONENTS, face_dofs
from fenics_adaptive.model.structure import Block, Structure
from fenics_adaptive.settings.solver import Probe, SolverSettings
from fenics_adaptive.solver import guards


@dataclass
class HistoryRow:
    time: float
    displacement: float  # mm, mean over the probe face
    reaction_force: float  # N, force the supports apply to the body on the reaction face
    applied_force: float  # N, resultant of the face loads
    kinetic_energy: float  # mJ
    internal_energy: float  # mJ, work of the internal forces
    external_work: float  # mJ, work of loads and prescribed motions
    damping_energy: float  # mJ, dissipated by mass damping
    dissipated_energy: float  # mJ, dissipated by materials (ply and cohesive damage)
    refinement_energy: float  # mJ, kinetic + strain + cohesive energy changed by refinements
    delaminated_area: float  # mm^2, failed cohesive elements
    time_step: float  # s
    contact_force: float = 0.0  # N, z component of the force the structure applies to the impactor
    impactor_displacement: float = 0.0  # mm, z displacement of the impactor
    impact_work: float = 0.0  # mJ, energy the impactor gave up (kinetic + penalty, from t = 0)
    cohesive_dissipation: float = 0.0  # mJ, summed from the cohesive law's damage increments
    ply_dissipation: float = 0.0  # mJ, summed from the ply damage law's increments
    # mJ: kinetic + strain + stored cohesive + cohesive and ply dissipation + damping - external
    # - impact - refinement energy - the strain and cohesive energy at t = 0 (from the states)
    state_energy_balance: float = 0.0

    @property
    def energy_balance(self) -> float:
        return (
            self.kinetic_energy
            + self.internal_energy
            + self.damping_energy
            - self.external_work
            - self.impact_work
            - self.refinement_energy
        )


COLUMNS = [*HistoryRow.__dataclass_fields__, "energy_balance"]


class Diverged(RuntimeError):
    pass


class ElementInverted(Diverged):
    """An element inverted (det F <= 0 at an integration point): the run stops as failed."""


class EnergyBalanceError(Diverged):
    """|energy_balance| beyond ``SolverSettings.energy_error_limit`` x the largest energy."""


class Interrupted(RuntimeError):
    """The run was asked to stop (SIGINT, SIGTERM) and stopped after writing a checkpoint."""

    def __init__(self, t: float, step: int):
        super().__init__(f"interrupted at t = {t:.6g} s (step {step}); a checkpoint was written")
        self.t, self.step = t, step


# What a checkpoint keeps of each block: every array the next step reads (u and v with their
# ghosts; the rest owned), so that a resumed run repeats the uninterrupted one bit for bit.
BLOCK_ARRAYS = ("u_all", "v_all", "du", "f_old", "f_ext_old", "reaction_old")
SOLVER_SCALARS = (
    "t",
    "step",
    "dt",
    "dt_prev",
    "stable",
    "next_output",
    "next_fields",
    "work_int",
    "work_ext",
    "work_damp",
    "initial_energy",
    "tied",
    "refinements",
    "initial_potential",
    "largest_energy",
    "initial_balance",
)


RUNAWAY = 100.0  # kinetic energy beyond this multiple of the work put in means instability


@dataclass
class RunStats:
    steps: int = 0
    wall_time: float = 0.0
    time_step: float = 0.0
    stable_time_step: float = 0.0
    critical: str = ""
    refinements: int = 0
    history: list[HistoryRow] = field(default_factory=list)


def choose_time_step(structure: Structure, settings: SolverSettings) -> tuple[float, float, str]:
    """(step used, stable step, where the limit is). Stable = safety * min(L_e / c, cohesive)."""
    limit, where = structure.stable_time_step()
    stable = settings.safety_factor * limit
    if settings.time_step is None:
        return stable, stable, where
    if settings.time_step > stable * (1.0 + 1e-12):
        raise InputError(
            "solver.time_step",
            f"{settings.time_step:.4g} s exceeds the stable step {stable:.4g} s (safety factor "
            f"{settings.safety_factor}, limited by {where}); the run would blow up",
        )
    return settings.time_step, stable, where


class _BlockState:
    """Work arrays of one block, allocated once per layout of the block."""

    def __init__(self, block: Block, damping: float, old: _BlockState | None = None):
        n = block.n_owned
        self.block = block
        self.u = block.u.array[:n]
        self.v = block.v.array[:n]
        self.f = block.f.array[:n]
        self.m = block.mass
        # constrained DOFs (border extra nodes) have no mass of their own: they follow masters
        self.inv_m = np.divide(1.0, self.m, out=np.zeros(n), where=self.m > 0.0)
        self.acc, self.du, self.f_old, self.f_ext, self.f_ext_old = (np.zeros(n) for _ in range(5))
        self.damping = np.full(n, damping)
        self.damping[block.fixed] = 0.0
        self.shrink, self.grow, self.v_mid = (np.zeros(n) for _ in range(3))
        k = len(block.fixed)
        self.u_now, self.u_next, self.v_fixed, self.a_fixed = (np.zeros(k) for _ in range(4))
        self.reaction, self.reaction_old, self.du_fixed, self.scratch = (
            np.zeros(k) for _ in range(4)
        )
        if old is not None:  # the block grew: carry the old DOFs' history over
            n_old = len(old.du)
            for name in ("du", "f_old", "f_ext_old"):
                getattr(self, name)[:n_old] = getattr(old, name)
            _, new_at, old_at = np.intersect1d(
                block.fixed, old.block.fixed, assume_unique=True, return_indices=True
            )
            self.reaction_old[new_at] = old.reaction_old[old_at]


def run(
    structure: Structure,
    settings: SolverSettings,
    probe: Probe,
    on_history: Callable[[HistoryRow], None] | None = None,
    on_fields: Callable[[float], None] | None = None,
    on_progress: Callable[[float], None] | None = None,
    on_step: Callable[[float, Structure], bool] | None = None,
    on_refined: Callable[[float, float, str], None] | None = None,
    time_step: float | None = None,
    initial_displacement: np.ndarray | None = None,
    initial_velocity: np.ndarray | None = None,
    checkpoint: Callable[[dict], None] | None = None,
    stop_requested: Callable[[], bool] | None = None,
    resume: dict | None = None,
    contact: Contact | None = None,
) -> RunStats:
    """Integrate from t = 0 to ``settings.end_time``, starting from ``initial_displacement`` and
    ``initial_velocity`` (base DOFs, owned + ghost entries; default zero; the velocity is taken
    as v_{-1/2}).

    ``on_step(t, structure)`` runs before every step and returns True if it changed the
    structure (refinement): the blocks are then rebuilt, the stable step recomputed, the
    stabilisation of the new refinement started (``Structure.start_stabilisation(t)``: damping
    windows, tie forces), and ``on_refined(t, new step, what limits it)`` is told.
    ``time_step`` bypasses the stability check (for tests that show what an unstable step
    does).

    Checkpoints: every ``settings.checkpoint_interval`` steps and after the last step (if
    that is set), and, in any case, when
    ``stop_requested()`` turns True on any rank (polled every 64 steps), ``checkpoint(state)``
    gets the solver state (``SOLVER_SCALARS`` and per block ``BLOCK_ARRAYS``) to store with the
    structure's; after a stop it raises ``Interrupted``. ``resume``: such a state, to continue
    from (the structure must already be restored to the same moment).

    ``contact``: a rigid impactor hitting the top face (``contact.Contact``), integrated with
    the structure; its forces are not external work: the history reports the energy the
    impactor gave up as ``impact_work``."""
    comm = structure.comm
    loads = structure.loads
    dt, stable, where = choose_time_step(structure, settings)
    if time_step is not None:
        dt = time_step
    forced = settings.time_step is not None or time_step is not None
    stats = RunStats(time_step=dt, stable_time_step=stable, critical=where)

    states = [_BlockState(b, settings.mass_damping) for b in structure.blocks]
    base = states[0]
    if resume is None:
        base.block.u.array[:] = 0.0 if initial_displacement is None else initial_displacement
        base.block.v.array[:] = 0.0 if initial_velocity is None else initial_velocity
        if initial_displacement is None and initial_velocity is None:
            # from rest means the extra nodes too (a structure run before, e.g. by a timing
            # harness, keeps their last motion otherwise: energy the balance never saw put in)
            for state in states[1:]:
                state.block.u.array[:] = 0.0
                state.block.v.array[:] = 0.0
    n_motions = len(structure.motions)
    motion_now, motion_next = np.zeros(n_motions), np.zeros(n_motions)
    f_ext_full = np.zeros_like(base.block.u.array)
    damped = settings.mass_damping > 0.0
    contact_force = np.zeros(base.block.n_owned)  # impactor on the base DOFs (owned), N
    impactor_initial = [0.0]  # mJ: the impactor's kinetic + penalty energy at t = 0
    if contact is not None:
        contact.limit_penalty(dt)
        contact.check_penalty(dt, stable / settings.safety_factor)
        z0 = contact.centre[2]
    inversion = guards.InversionGuard(structure)
    energy_limit = settings.energy_error_limit
    largest = [0.0]  # mJ: the largest energy of the run so far (energy guard)
    initial_potential = [0.0]  # mJ: strain + stored cohesive energy at t = 0
    # mJ: energy_balance at t = 0, the initial kinetic energy (an initial velocity): the guard
    # judges the change from it
    initial_balance = [0.0]

    def raise_if_inverted(message: str | None, anywhere: bool) -> None:
        """``message``: this rank's; ``anywhere``: some rank has one (known to all ranks).
        Collective when anywhere (the message of the lowest rank that has one)."""
        if not anywhere:
            return
        if comm.size > 1:
            message = next(m for m in comm.allgather(message) if m is not None)
        raise ElementInverted(message)

    component = COMPONENTS[probe.component]
    probe_dofs = face_dofs(
        structure.base, probe.displacement_face, probe.component, x_range=probe.displacement_x
    )
    n_probe = comm.allreduce(len(probe_dofs), op=MPI.SUM)
    reaction_motions = np.array(
        [
            m.face == probe.reaction_face and m.component == probe.component
            for m in structure.motions
        ],
        dtype=bool,
    )
    load_dofs = np.arange(component, base.block.n_owned, 3)

    def set_prescribed(t_now: float, step: float) -> None:
        for k, motion in enumerate(structure.motions):
            motion_now[k] = motion.displacement(t_now)
            motion_next[k] = motion.displacement(t_now + step)
        for state in states:
            np.take(motion_now, state.block.fixed_motion, out=state.u_now)
            np.take(motion_next, state.block.fixed_motion, out=state.u_next)

    def forces_and_accelerations() -> None:
        """f_int, f_ext, accelerations and reactions at t_n for the current structure."""
        structure.internal_force()
        loads.external_force(t, f_ext_full)
        base.f_ext[:] = f_ext_full[: base.block.n_owned]
        if structure.ties or tied[0]:
            states[1].f_ext.fill(0.0)
            structure.add_tie_forces(t, states[1].f_ext)
            tied[0] = bool(structure.ties)
        mean_dt = 0.5 * (dt_prev + dt)
        if contact is not None:
            contact.set_forces(base.block.u.array, contact_force)
        for state in states:
            np.subtract(state.f_ext, state.f, out=state.acc)
            if contact is not None and state is base:
                state.acc += contact_force
            state.acc *= state.inv_m
            if len(state.block.fixed):
                fixed = state.block.fixed
                # the acceleration that takes the prescribed DOFs exactly to u(t_{n+1})
                np.subtract(state.u_next, state.u_now, out=state.a_fixed)
                state.a_fixed /= dt
                np.take(state.v, fixed, out=state.v_fixed)
                state.a_fixed -= state.v_fixed
                state.a_fixed /= mean_dt
                np.put(state.acc, fixed, state.a_fixed)
                # reaction = m a + f_int - f_ext on the prescribed DOFs
                np.take(state.m, fixed, out=state.reaction)
                state.reaction *= state.a_fixed
                state.reaction += np.take(state.f, fixed, out=state.scratch)
                state.reaction -= np.take(state.f_ext, fixed, out=state.scratch)
                if contact is not None and state is base:
                    state.reaction -= np.take(contact_force, fixed, out=state.scratch)

    def likely_cause() -> str:
        """What most likely made a run with a stable element step blow up, for messages."""
        causes = []
        if contact is not None:
            causes.append(
                f"the contact penalty (impactor.penalty = {contact.penalty:.4g} N/mm) too stiff "
                "for it?"
            )
        if structure.comm.allreduce(len(structure.cohesive), op=MPI.SUM):
            causes.append("a cohesive penalty too stiff for it?")
        if structure.ply_damage:
            causes.append("a damaged material?")
        return " ".join(causes) or "an unstable time step?"

    tied = [False]  # tie forces were applied last step (their f_ext must be cleared once)
    not_finite = [False]  # this rank has seen a non-finite internal work

    def where_fastest() -> str:
        """Collective: where the largest (or a non-finite) velocity is, for error messages."""
        best = (-1.0, "")
        for index, state in enumerate(states):
            speed = np.abs(state.v)
            speed[~np.isfinite(speed)] = np.inf
            if len(speed) and speed.max() > best[0]:
                dof = int(np.argmax(speed))
                best = (float(speed[dof]), structure.describe_dof(index, dof))
        speed, text = max(comm.allgather(best))
        return f"at {text} (|v| = {speed:.3g} mm/s)"

    damping_changes = [math.inf]  # next time a stabilisation damping window closes

    def refresh_damping() -> None:
        """Per-DOF damping: the global coefficient plus the open stabilisation windows."""
        windows = structure.active_damping(t)
        for index, state in enumerate(states):
            state.damping[:] = settings.mass_damping
            for window in windows:
                if window.block == index:
                    state.damping[window.dofs] += window.coefficient
            state.damping[state.block.fixed] = 0.0
        damping_changes[0] = min((w.until for w in windows), default=math.inf)

    initial_energy = [0.0]  # kinetic + strain energy at t = 0
    work_int = work_ext = work_damp = 0.0  # this rank's shares
    t = 0.0
    dt_prev = 0.0
    next_output = 0.0
    next_fields = 0.0 if (settings.field_interval and on_fields) else math.inf
    step = 0
    if resume is not None:
        t, step, dt, dt_prev, stable = (resume[k] for k in ("t", "step", "dt", "dt_prev", "stable"))
        step = int(step)
        next_output, next_fields = resume["next_output"], resume["next_fields"]
        work_int, work_ext, work_damp = (resume[k] for k in ("work_int", "work_ext", "work_damp"))
        initial_energy[0] = resume["initial_energy"]
        initial_potential[0] = float(resume["initial_potential"])
        largest[0] = float(resume["largest_energy"])
        initial_balance[0] = float(resume["initial_balance"])
        tied[0] = bool(resume["tied"])
        stats.refinements = int(resume["refinements"])
        stats.time_step, stats.stable_time_step = dt, stable
        if contact is not None:
            contact.restore({k: resume[f"impactor_{k}"] for k in ("centre", "velocity")})
            impactor_initial[0] = float(resume["impactor_initial"])
            z0 = float(resume["impactor_z0"])
        for index, state in enumerate(states):
            state.block.u.array[:] = resume[f"block{index}_u_all"]
            state.block.v.array[:] = resume[f"block{index}_v_all"]
            for name in BLOCK_ARRAYS[2:]:
                getattr(state, name)[:] = resume[f"block{index}_{name}"]
        refresh_damping()
    set_prescribed(t, dt)
    for state in states:
        np.put(state.u, state.block.fixed, state.u_now)
        state.block.u.scatter_forward()
    checkpoint_every = settings.checkpoint_interval if checkpoint is not None else None

    def write_checkpoint() -> None:
        scalars = (t, step, dt, dt_prev, stable, next_output, next_fields, work_int, work_ext)
        scalars += (work_damp, initial_energy[0], float(tied[0]), stats.refinements)
        scalars += (initial_potential[0], largest[0], initial_balance[0])
        state_now = dict(zip(SOLVER_SCALARS, scalars, strict=True))
        for index, state in enumerate(states):
            state_now[f"block{index}_u_all"] = state.block.u.array
            state_now[f"block{index}_v_all"] = state.block.v.array
            for name in BLOCK_ARRAYS[2:]:
                state_now[f"block{index}_{name}"] = getattr(state, name)
        if contact is not None:
            for name, value in contact.state().items():
                state_now[f"impactor_{name}"] = value
            state_now["impactor_initial"] = impactor_initial[0]
            state_now["impactor_z0"] = z0
        checkpoint(state_now)

    start = time.perf_counter()

    # a diverging run is reported by Diverged, not by floating-point warnings
    with np.errstate(over="ignore", invalid="ignore"):
        while True:
            forces_and_accelerations()

            # work over the step just made (trapezoidal in the forces)
            if step > 0:
                for state in states:
                    work_int += 0.5 * (np.dot(state.f_old, state.du) + np.dot(state.f, state.du))
                    work_ext += 0.5 * (
                        np.dot(state.f_ext_old, state.du) + np.dot(state.f_ext, state.du)
                    )
                    if len(state.block.fixed):
                        np.take(state.du, state.block.fixed, out=state.du_fixed)
                        work_ext += 0.5 * (
                            np.dot(state.reaction_old, state.du_fixed)
                            + np.dot(state.reaction, state.du_fixed)
                        )
                # the internal work sums every DOF's force and motion: a single non-finite
                # value anywhere shows here, in the step it appears
                # (in parallel the other ranks learn it at the next poll, every 64 steps)
                if not math.isfinite(work_int):
                    not_finite[0] = True
                    if comm.size == 1:
                        raise Diverged(
                            f"t = {t:.6g} s (step {step}): the solution is no longer finite "
                            f"{where_fastest()}; time step {dt:.4g} s, stable step {stable:.4g} s"
                        )

            # refinement between steps: the work of the last step was counted with the old
            # structure's forces above; the new one starts from its own forces at t_n
            if on_step is not None and on_step(t, structure):
                stats.refinements += 1
                # the strain and cohesive energy the refinement changed count as internal work
                # (booked once, on rank 0), so that the dissipated energy does not jump
                if comm.rank == 0:
                    work_int += structure.last_refinement_potential
                states = [
                    _BlockState(b, settings.mass_damping, old)
                    for b, old in zip(structure.blocks, states, strict=True)
                ]
                base = states[0]
                inversion.refresh()
                limit, where = structure.stable_time_step()
                stable = settings.safety_factor * limit
                stats.stable_time_step, stats.critical = stable, where
                if not forced:
                    dt = stable
                elif dt > stable * (1.0 + 1e-12):
                    raise Diverged(
                        f"t = {t:.6g} s: after refinement the stable step is {stable:.4g} s "
                        f"({where}), below the forced step {dt:.4g} s"
                    )
                set_prescribed(t, dt)
                structure.start_stabilisation(t)
                refresh_damping()
                forces_and_accelerations()  # of the refined structure, at t_n
                if on_refined is not None:
                    on_refined(t, dt, where)

            n_steps_done = step
            if t >= next_output - 1e-9 * dt or t >= settings.end_time - 1e-9 * dt:
                inverted = inversion.check(t)
                kinetic = 0.0
                reaction = 0.0
                for state in states:
                    v_full = state.v + 0.5 * dt_prev * state.acc  # v_n from v_{n-1/2}
                    kinetic += 0.5 * np.dot(state.m * v_full, v_full)
                    on_face = reaction_motions[state.block.fixed_motion]
                    reaction += state.reaction[on_face].sum()
                local = np.array(
                    [
                        base.u[probe_dofs].sum(),
                        reaction,
                        base.f_ext[load_dofs].sum(),
                        kinetic,
                        work_int,
                        work_ext,
                        work_damp,
                        float(inverted is not None),
                    ]
                )
                total = comm.allreduce(local, op=MPI.SUM)
                raise_if_inverted(inverted, total[7] > 0.0)
                if not np.all(np.isfinite(total)):
                    raise Diverged(
                        f"t = {t:.6g} s (step {step}): the solution is no longer finite "
                        f"{where_fastest()}; time step {dt:.4g} s, stable step {stable:.4g} s"
                    )
                solid, cohesive = structure.energies()
                cohesive_dissipation, ply_dissipation = structure.damage_dissipation()
                impactor_energy = contact.energy(dt_prev) if contact is not None else 0.0
                if step == 0:  # an initial velocity or displacement brings energy along
                    initial_energy[0] = total[3] + solid + cohesive + impactor_energy
                    impactor_initial[0] = impactor_energy
                    initial_potential[0] = solid + cohesive
                    # the energy the run starts with (an impactor's kinetic energy) sets the
                    # scale of the energy guard too: impact_work is a difference of two values
                    # of it, whose round-off would otherwise be judged against the little
                    # energy transferred at the first contact
                    largest[0] = abs(initial_energy[0])
                # runaway: the motion holds far more energy than was ever put in
                kinetic, put_in = total[3], abs(total[5]) + initial_energy[0]
                if step > 0 and kinetic > RUNAWAY * max(put_in, 1e-300):
                    raise Diverged(
                        f"t = {t:.6g} s (step {step}): kinetic energy {kinetic:.4g} mJ exceeds "
                        f"{RUNAWAY:g} x the work put in ({put_in:.4g} mJ), fastest "
                        f"{where_fastest()}: the run is unstable "
                        f"(time step {dt:.4g} s, stable step {stable:.4g} s, limited by {where}; "
                        f"{likely_cause()})"
                    )
                row = HistoryRow(
                    time=t,
                    displacement=total[0] / max(n_probe, 1),
                    reaction_force=total[1],
                    applied_force=total[2],
                    kinetic_energy=total[3],
                    internal_energy=total[4],
                    external_work=total[5],
                    damping_energy=total[6],
                    dissipated_energy=total[4] - solid - cohesive,
                    refinement_energy=structure.refinement_energy,
                    delaminated_area=structure.delaminated_area(),
                    time_step=dt,
                )
                if contact is not None:
                    row.contact_force = float(contact.force[2])
                    row.impactor_displacement = float(contact.centre[2] - z0)
                    row.impact_work = impactor_initial[0] - impactor_energy
                row.cohesive_dissipation = cohesive_dissipation
                row.ply_dissipation = ply_dissipation
                row.state_energy_balance = (
                    row.kinetic_energy
                    + solid
                    + cohesive
                    - initial_potential[0]
                    + cohesive_dissipation
                    + ply_dissipation
                    + row.damping_energy
                    - row.external_work
                    - row.impact_work
                    - row.refinement_energy
                )
                if step == 0:
                    initial_balance[0] = row.energy_balance
                stats.history.append(row)
                if on_history is not None:
                    on_history(row)
                # the energy guard: the row that breaks it is in the history
                largest[0] = max(
                    largest[0],
                    guards.largest_energy(
                        row.external_work, row.impact_work, row.kinetic_energy, row.internal_energy
                    ),
                )
                error = row.energy_balance - initial_balance[0]
                if guards.energy_error(error, largest[0], energy_limit, step):
                    raise EnergyBalanceError(
                        f"t = {t:.6g} s (step {step}): energy balance error "
                        f"{error:.4g} mJ exceeds {energy_limit:g} x the largest "
                        f"energy of the run, {largest[0]:.4g} mJ (solver.energy_error_limit); "
                        f"fastest {where_fastest()}; {likely_cause()}"
                    )
                while next_output <= t + 1e-9 * dt:
                    next_output += settings.output_interval
            if t >= next_fields - 1e-9 * dt:
                on_fields(t)
                while next_fields <= t + 1e-9 * dt:
                    next_fields += settings.field_interval
            if t >= settings.end_time - 1e-9 * dt:
                break

            mean_dt = 0.5 * (dt_prev + dt)
            if t >= damping_changes[0]:
                refresh_damping()
            for state in states:
                # v_{n-1/2} -> v_{n+1/2}, with implicit mass-proportional damping where asked
                if damped or damping_changes[0] < math.inf:
                    state.v_mid[:] = state.v
                    np.multiply(state.damping, 0.5 * mean_dt, out=state.shrink)
                    np.add(state.shrink, 1.0, out=state.grow)
                    np.subtract(1.0, state.shrink, out=state.shrink)
                    state.v *= state.shrink
                    state.acc *= mean_dt
                    state.v += state.acc
                    state.v /= state.grow
                    state.v_mid += state.v
                    state.v_mid *= 0.5
                    np.multiply(state.v_mid, state.v_mid, out=state.shrink)
                    state.shrink *= state.m
                    work_damp += mean_dt * np.dot(state.damping, state.shrink)
                else:
                    state.acc *= mean_dt
                    state.v += state.acc
                # u_n -> u_{n+1}; the prescribed DOFs land exactly on their prescribed values
                np.multiply(state.v, dt, out=state.du)
                state.u += state.du
                np.put(state.u, state.block.fixed, state.u_next)
                state.block.u.scatter_forward()
                state.f_old[:] = state.f
                state.f_ext_old[:] = state.f_ext
                state.reaction_old[:] = state.reaction
            structure.follow_border()
            if contact is not None:
                contact.advance(mean_dt, dt)

            dt_prev = dt
            t += dt
            step += 1
            set_prescribed(t, dt)
            if step % 64 == 0:
                if on_progress is not None:
                    on_progress(t)
                stop = stop_requested is not None and stop_requested()
                inverted = inversion.check(t)
                if comm.size > 1:
                    flags = np.array([stop, not_finite[0], inverted is not None], dtype=np.int32)
                    comm.Allreduce(MPI.IN_PLACE, flags, op=MPI.MAX)
                    stop = bool(flags[0])
                    if flags[1]:
                        raise Diverged(
                            f"t = {t:.6g} s (step {step}): the solution is no longer finite "
                            f"{where_fastest()}; time step {dt:.4g} s, stable step {stable:.4g} s"
                        )
                    raise_if_inverted(inverted, bool(flags[2]))
                else:
                    raise_if_inverted(inverted, inverted is not None)
                if stop:
                    if checkpoint is not None:
                        write_checkpoint()
                    raise Interrupted(t, step)
            # periodic, and the last state (a restart with a later end time extends the run)
            if checkpoint_every and (
                step % checkpoint_every == 0 or t >= settings.end_time - 1e-9 * dt
            ):
                write_checkpoint()

    stats.steps = n_steps_done
    stats.wall_time = time.perf_counter() - start
    return stats
