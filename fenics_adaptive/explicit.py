"""Lumped-mass central-difference time integration with energy bookkeeping.

Units: N, mm, s, tonne (energies in mJ = N mm).

Staggered scheme (velocities at half steps, variable step allowed):

    a_n       = (f_ext(t_n) - f_int(u_n)) / m                 (prescribed DOFs: their motion)
    v_{n+1/2} = v_{n-1/2} + (dt_{n-1/2} + dt_{n+1/2}) / 2 * a_n
    u_{n+1}   = u_n + dt_{n+1/2} * v_{n+1/2}

with optional mass-proportional damping c (1/s, per DOF) applied implicitly to v. The state lives
in DOLFINx vectors (the memory of the ghosted PETSc Vecs): owned entries are updated, then the
ghost entries of u are refreshed by a forward scatter, so any number of MPI ranks gives the same
result up to the summation order of the assembly.

Energies (global, on output steps): kinetic 1/2 v.M.v at full steps, internal work
sum 1/2 (f_n + f_{n+1}).du (elastic strain energy plus whatever the material dissipates), external
work of loads and of prescribed motions (reaction forces), damping work. Balance:
kinetic + internal - external + damping = 0 up to the scheme's O(dt^2) error.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
from dolfinx import fem
from mpi4py import MPI

from fenics_adaptive.errors import InputError
from fenics_adaptive.loading import COMPONENTS, ResolvedLoads, face_dofs
from fenics_adaptive.model import LayeredModel


@dataclass(frozen=True)
class SolverSettings:
    end_time: float  # s
    output_interval: float  # s between history rows
    safety_factor: float = 0.9  # on the element-size stable step
    time_step: float | None = None  # forced step (s); must not exceed the stable one
    mass_damping: float = 0.0  # 1/s, on every free DOF
    field_interval: float | None = None  # s between field outputs (None: none)


@dataclass(frozen=True)
class Probe:
    """What the history reports: the mean displacement of a face and the reaction force on a
    (constrained) face, both in one component, and the applied-load resultant in that component."""

    displacement_face: str
    reaction_face: str
    component: str


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
    dissipated_energy: float  # mJ, dissipated by materials (cohesive, damage)
    time_step: float  # s

    @property
    def energy_balance(self) -> float:
        return self.kinetic_energy + self.internal_energy + self.damping_energy - self.external_work


COLUMNS = [*HistoryRow.__dataclass_fields__, "energy_balance"]


class Diverged(RuntimeError):
    pass


@dataclass
class RunStats:
    steps: int = 0
    wall_time: float = 0.0
    time_step: float = 0.0
    stable_time_step: float = 0.0
    critical_cell: int = -1
    history: list[HistoryRow] = field(default_factory=list)


def choose_time_step(model: LayeredModel, settings: SolverSettings) -> tuple[float, float, int]:
    """(step used, stable step, critical cell). The stable step is safety * min(L_e / c)."""
    length_over_speed, cell = model.stable_time_step()
    stable = settings.safety_factor * length_over_speed
    if settings.time_step is None:
        return stable, stable, cell
    if settings.time_step > stable * (1.0 + 1e-12):
        raise InputError(
            "solver.time_step",
            f"{settings.time_step:.4g} s exceeds the stable step {stable:.4g} s (safety factor "
            f"{settings.safety_factor}); the run would blow up",
        )
    return settings.time_step, stable, cell


def run(
    model: LayeredModel,
    loads: ResolvedLoads,
    settings: SolverSettings,
    probe: Probe,
    on_history: Callable[[HistoryRow], None] | None = None,
    on_fields: Callable[[float], None] | None = None,
    on_progress: Callable[[float], None] | None = None,
    time_step: float | None = None,
    initial_displacement: np.ndarray | None = None,
) -> RunStats:
    """Integrate from t = 0 to ``settings.end_time``, starting at rest from
    ``initial_displacement`` (owned + ghost entries; default zero). ``time_step`` bypasses the
    stability check (for tests that show what an unstable step does)."""
    comm = model.comm
    n = model.n_owned_dofs
    dt, stable, cell = choose_time_step(model, settings)
    if time_step is not None:
        dt = time_step
    stats = RunStats(time_step=dt, stable_time_step=stable, critical_cell=cell)
    n_steps = max(1, math.ceil(settings.end_time / dt - 1e-9))

    # state and work arrays, allocated once (the loop below allocates nothing per step)
    u_vec = model.u.x
    u = u_vec.array[:n]
    v = np.zeros(n)
    f_int_vec = fem.Function(model.V).x
    f_int = f_int_vec.array[:n]
    f_ext_full = np.zeros_like(u_vec.array)
    f_ext = f_ext_full[:n]
    m = model.mass[:n]
    acc, du, f_int_old, f_ext_old = (np.zeros(n) for _ in range(4))
    damping = np.full(n, settings.mass_damping)
    damping[loads.constrained] = 0.0
    damped = settings.mass_damping > 0.0
    shrink, grow, v_mid = (np.zeros(n) for _ in range(3))

    fixed = loads.constrained
    n_fixed = len(fixed)
    u_now, u_next, v_fixed, a_fixed, reaction, reaction_old, du_fixed, scratch = (
        np.zeros(n_fixed) for _ in range(8)
    )

    component = COMPONENTS[probe.component]
    probe_dofs = face_dofs(model, probe.displacement_face, probe.component)
    n_probe = comm.allreduce(len(probe_dofs), op=MPI.SUM)
    in_reaction = np.isin(fixed, face_dofs(model, probe.reaction_face, probe.component))
    load_dofs = np.arange(component, n, 3)

    work_int = work_ext = work_damp = 0.0  # this rank's shares
    t = 0.0
    dt_prev = 0.0
    next_output = 0.0
    next_fields = 0.0 if (settings.field_interval and on_fields) else math.inf
    loads.prescribed_values(0.0, u_now)
    loads.prescribed_values(dt, u_next)
    u_vec.array[:] = 0.0 if initial_displacement is None else initial_displacement
    np.put(u, fixed, u_now)
    u_vec.scatter_forward()
    start = time.perf_counter()

    # a diverging run is reported by Diverged, not by floating-point warnings
    with np.errstate(over="ignore", invalid="ignore"):
        for step in range(n_steps + 1):
            # forces and acceleration at t_n
            model.internal_force(f_int_vec)
            loads.external_force(t, f_ext_full)
            np.subtract(f_ext, f_int, out=acc)
            acc /= m
            mean_dt = 0.5 * (dt_prev + dt)
            if n_fixed:
                # the acceleration that takes the prescribed DOFs exactly to u(t_{n+1})
                np.subtract(u_next, u_now, out=a_fixed)
                a_fixed /= dt
                np.take(v, fixed, out=v_fixed)
                a_fixed -= v_fixed
                a_fixed /= mean_dt
                np.put(acc, fixed, a_fixed)
                # reaction = m a + f_int - f_ext on the constrained DOFs
                np.take(m, fixed, out=reaction)
                reaction *= a_fixed
                reaction += np.take(f_int, fixed, out=scratch)
                reaction -= np.take(f_ext, fixed, out=scratch)

            # work over the step just made (trapezoidal in the forces)
            if step > 0:
                work_int += 0.5 * (np.dot(f_int_old, du) + np.dot(f_int, du))
                work_ext += 0.5 * (np.dot(f_ext_old, du) + np.dot(f_ext, du))
                if n_fixed:
                    np.take(du, fixed, out=du_fixed)
                    work_ext += 0.5 * (np.dot(reaction_old, du_fixed) + np.dot(reaction, du_fixed))
                # the internal work sums every DOF's force and motion: a single non-finite value
                # anywhere shows here, in the step it appears
                if not math.isfinite(work_int):
                    raise Diverged(
                        f"t = {t:.6g} s (step {step}): the solution is no longer finite; time step "
                        f"{dt:.4g} s, stable step {stable:.4g} s"
                    )

            if t >= next_output - 1e-9 * dt or step == n_steps:
                v_full = v + 0.5 * dt_prev * acc  # v_n from v_{n-1/2}
                local = np.array(
                    [
                        u[probe_dofs].sum(),
                        reaction[in_reaction].sum(),
                        f_ext[load_dofs].sum(),
                        0.5 * np.dot(m * v_full, v_full),
                        work_int,
                        work_ext,
                        work_damp,
                    ]
                )
                total = comm.allreduce(local, op=MPI.SUM)
                if not np.all(np.isfinite(total)):
                    raise Diverged(
                        f"t = {t:.6g} s (step {step}): the solution is no longer finite; time step "
                        f"{dt:.4g} s, stable step {stable:.4g} s"
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
                    dissipated_energy=0.0,
                    time_step=dt,
                )
                stats.history.append(row)
                if on_history is not None:
                    on_history(row)
                while next_output <= t + 1e-9 * dt:
                    next_output += settings.output_interval
            if t >= next_fields - 1e-9 * dt:
                on_fields(t)
                while next_fields <= t + 1e-9 * dt:
                    next_fields += settings.field_interval
            if step == n_steps:
                break

            # v_{n-1/2} -> v_{n+1/2}, with implicit mass-proportional damping where asked
            if damped:
                v_mid[:] = v
                np.multiply(damping, 0.5 * mean_dt, out=shrink)
                np.add(shrink, 1.0, out=grow)
                np.subtract(1.0, shrink, out=shrink)
                v *= shrink
                acc *= mean_dt
                v += acc
                v /= grow
                v_mid += v
                v_mid *= 0.5
                np.multiply(v_mid, v_mid, out=shrink)
                shrink *= m
                work_damp += mean_dt * np.dot(damping, shrink)
            else:
                acc *= mean_dt
                v += acc
            # u_n -> u_{n+1}; the prescribed DOFs land exactly on their prescribed values
            np.multiply(v, dt, out=du)
            u += du
            np.put(u, fixed, u_next)
            u_vec.scatter_forward()

            f_int_old[:] = f_int
            f_ext_old[:] = f_ext
            reaction_old[:] = reaction
            u_now[:] = u_next
            dt_prev = dt
            t = (step + 1) * dt
            loads.prescribed_values(t + dt, u_next)
            if on_progress is not None and step % 64 == 0:
                on_progress(t)

    stats.steps = n_steps
    stats.wall_time = time.perf_counter() - start
    return stats
