"""The history rows of a run and the energy bookkeeping behind them.

Units: N, mm, s, tonne (energies in mJ = N mm). ``HistoryRecorder`` makes the row of t_n from
the time loop's state (``explicit.SolverState``) and work arrays (``blocks.BlockState``): the
sums over ranks (probe displacement, reaction, applied load, kinetic energy, the work sums,
the contributors' energy), the energy balance terms, the energies at t = 0 the balances and
the energy guard start from, and the guards the sums can trip (inversion, finiteness,
runaway). The module-level docstring of ``explicit`` states the balances.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Protocol

import numpy as np
from mpi4py import MPI

from fenics_adaptive.model.diagnostics import local_damage_dissipation, local_delaminated_areas
from fenics_adaptive.model.forces import ForceContributor, ForceKind, hooks
from fenics_adaptive.model.loading import COMPONENTS, face_dofs
from fenics_adaptive.model.structure import Structure
from fenics_adaptive.parallel.reductions import summed
from fenics_adaptive.settings.solver import Probe
from fenics_adaptive.solver.blocks import BlockState

if TYPE_CHECKING:
    from fenics_adaptive.solver.explicit import SolverState
    from fenics_adaptive.solver.guards import InversionGuard


@dataclass
class HistoryRow:
    """The run's state at one output time (s): one row of the history, units by field."""

    time: float
    displacement: float  # mm, mean over the probe face
    reaction_force: float  # N, force the supports apply to the body on the reaction face
    applied_force: float  # N, resultant of the face loads (on base and extra nodes)
    kinetic_energy: float  # mJ, the scheme's: 1/2 v(n+1/2).M.v(n-1/2) at a constant step
    internal_energy: float  # mJ, work of the internal forces
    external_work: float  # mJ, work of loads and prescribed motions
    damping_energy: float  # mJ, dissipated by mass damping
    dissipated_energy: float  # mJ, dissipated by materials (ply and cohesive damage)
    refinement_energy: float  # mJ, kinetic + strain + cohesive energy changed by refinements
    delaminated_area: float  # mm^2, failed cohesive elements (insert films included)
    time_step: float  # s
    contact_force: float = 0.0  # N, z component of the force the structure applies to the impactor
    impactor_displacement: float = 0.0  # mm, z displacement of the impactor
    # mJ, the work of the rigid bodies' contact forces on the structure since t = 0 (net of
    # what their friction dissipated)
    impact_work: float = 0.0
    # mJ, the work the tie forces of new strong interfaces did on the structure since t = 0
    # (a part of external_work: an artificial constraint's, of either sign)
    tie_work: float = 0.0
    cohesive_dissipation: float = 0.0  # mJ, summed from the cohesive law's damage increments
    ply_dissipation: float = 0.0  # mJ, summed from the ply damage law's increments
    fibre_dissipation: float = 0.0  # mJ, the broken fibres' share of ply_dissipation
    eroded_energy: float = 0.0  # mJ, strain energy the eroded elements held when they went
    # mJ: kinetic + strain + stored cohesive + cohesive and ply dissipation + eroded + damping
    # - external - impact - refinement energy - the strain and cohesive energy at t = 0 (from
    # the states)
    state_energy_balance: float = 0.0
    crack_growth_area: float = 0.0  # mm^2, failed cohesive elements outside the insert films
    # per [[rigid]] body: "<name>_force" (N, z, the force the structure applies to it) and
    # "<name>_displacement" (mm, z, of its centre since t = 0), a plane's along minus its
    # normal (``RigidBody.direction``); with friction
    # "<name>_friction_energy" (mJ, dissipated since t = 0)
    bodies: dict[str, float] = field(default_factory=dict)

    @property
    def energy_balance(self) -> float:
        """mJ: kinetic + internal + damping - external - impact - refinement energy (0 up to
        the scheme's error)."""
        return (
            self.kinetic_energy
            + self.internal_energy
            + self.damping_energy
            - self.external_work
            - self.impact_work
            - self.refinement_energy
        )


# the columns every history has (the rigid bodies' come after them, ``bodies``)
COLUMNS = [*(n for n in HistoryRow.__dataclass_fields__ if n != "bodies"), "energy_balance"]


class HistoryGuards(Protocol):
    """The run's stops as failed that the history sums can trip (``explicit``'s guards)."""

    def runaway(self, kinetic: float, put_in: float) -> None: ...

    def not_finite(self) -> None: ...

    def inverted(self, message: str | None, anywhere: bool) -> None: ...


class HistoryRecorder:
    """Makes the history rows of one structure's run.

    ``structure``: the model (its internal forces' stored energies, its damage);
    ``probe``: the faces and component the row reports; ``contributors``: the run's force
    contributors beside the structure's (read at each row: those of kind INTERNAL store
    strain energy, the energy the others hold counts in the energy at t = 0; those with a
    ``report`` hook fill their columns); ``guards``: told of inversion, non-finite sums and a
    runaway. Collective to construct (the probe face's DOF count is summed over ranks)."""

    def __init__(
        self,
        structure: Structure,
        probe: Probe,
        contributors: Sequence[ForceContributor],
        guards: HistoryGuards,
    ):
        self.structure = structure
        self.comm = structure.comm
        self.contributors = contributors
        self.guards = guards
        # the owned DOFs the history sums (probe face, loads) and which prescribed motions make
        # the reaction force
        self.probe_dofs = face_dofs(
            structure.base, probe.displacement_face, probe.component, x_range=probe.displacement_x
        )
        self.n_probe = self.comm.allreduce(len(self.probe_dofs), op=MPI.SUM)
        self.reaction_motions = np.array(
            [
                m.face == probe.reaction_face and m.component == probe.component
                for m in structure.motions
            ],
            dtype=bool,
        )
        n_owned = structure.blocks[0].n_owned
        self.component = COMPONENTS[probe.component]
        self.load_dofs = np.arange(self.component, n_owned, 3)

    def row(
        self, s: SolverState, blocks: Sequence[BlockState], inversion: InversionGuard
    ) -> HistoryRow:
        """Collective: the history row of t_n (``s``: the loop's state, whose energies at
        t = 0 are set on step 0; ``blocks``: its work arrays; ``inversion``: checked first),
        after the guards on inversion, finiteness and runaway."""
        structure = self.structure
        total = self.sums(s, blocks, inversion)
        solid, cohesive = total[10:12]
        if any(c.kind is ForceKind.INTERNAL for c in self.contributors):
            solid += total[9]  # a run's own internal forces: their energy is strain energy
        cohesive_dissipation, ply_dissipation, fibre_dissipation, eroded = total[12:16]
        delaminated, grown = total[16:18]
        if s.step == 0:  # an initial velocity or displacement brings energy along
            s.initial_energy = total[3] + solid + cohesive + total[8]
            s.initial_potential = solid + cohesive
            # the energy the run starts with (an impactor's kinetic energy) sets the scale of
            # the energy guard too: impact_work is a difference of two values of it, whose
            # round-off would otherwise be judged against the little energy transferred at
            # the first contact
            s.largest_energy = abs(s.initial_energy)
        row = HistoryRow(
            time=s.t,
            displacement=total[0] / max(self.n_probe, 1),
            reaction_force=total[1],
            applied_force=total[2],
            kinetic_energy=total[3],
            internal_energy=total[4],
            external_work=total[5],
            damping_energy=total[6],
            dissipated_energy=total[4] - solid - cohesive,
            refinement_energy=structure.refinement_energy,
            delaminated_area=delaminated,
            time_step=s.dt,
            crack_growth_area=grown,
            tie_work=total[18],
        )
        for report in hooks(self.contributors, "report"):
            report(row, s.step == 0)
        # put in: by loads and motions, brought along at t = 0, given by rigid bodies
        self.guards.runaway(abs(total[3]), abs(total[5]) + s.initial_energy + abs(row.impact_work))
        row.cohesive_dissipation = cohesive_dissipation
        row.ply_dissipation = ply_dissipation
        row.fibre_dissipation = fibre_dissipation
        row.eroded_energy = eroded
        row.state_energy_balance = (
            row.kinetic_energy
            + solid
            + cohesive
            - s.initial_potential
            + cohesive_dissipation
            + ply_dissipation
            + eroded
            + row.damping_energy
            - row.external_work
            - row.impact_work
            - row.refinement_energy
        )
        if s.step == 0:
            s.initial_balance = row.energy_balance
        return row

    def sums(
        self, s: SolverState, blocks: Sequence[BlockState], inversion: InversionGuard
    ) -> np.ndarray:
        """Collective, one reduction: the sums over ranks of (probe displacement, reaction,
        applied load, kinetic energy, internal, external and damping work
        (``BlockState.energies_at_step``: the scheme's own at t_n), inverted, the energy the
        run's contributors hold, the strain energy of its INTERNAL ones, the structure's solid
        and cohesive energies (``InternalForces.energies``), its cohesive, ply and fibre
        dissipation and eroded energy (``diagnostics.damage_dissipation``), its delaminated and
        grown areas (``diagnostics.delaminated_areas``), the work of its ties
        (``StabilisationState.tie_work``)); raises (``guards``) if an element
        inverted or a sum is not finite."""
        base = blocks[0]
        inverted = inversion.check(s.t)
        kinetic = damping = reaction = 0.0
        mean_dt = 0.5 * (s.dt_prev + s.dt)
        for state in blocks:
            block_kinetic, block_damping = state.energies_at_step(mean_dt, s.dt)
            kinetic += block_kinetic
            damping += block_damping
            on_face = self.reaction_motions[state.block.fixed_motion]
            reaction += state.reaction[on_face].sum()
        local = np.array(
            [
                base.u[self.probe_dofs].sum(),
                reaction,
                # the loads on the base DOFs, and on the extra DOFs from the loads themselves
                # (the extra block's f_ext also holds the tie forces, which are no load)
                base.f_ext[self.load_dofs].sum()
                + self.structure.loads.extra_resultant(s.t)[self.component],
                kinetic + s.kinetic_offset,
                s.work_int,
                s.work_ext,
                s.work_damp + damping,
                float(inverted is not None),
                sum(c.energy() for c in self.contributors if c.kind is not ForceKind.INTERNAL),
                sum(c.energy() for c in self.contributors if c.kind is ForceKind.INTERNAL),
                *self.structure.internal_forces.local_energies(),
                *local_damage_dissipation(self.structure),
                *local_delaminated_areas(self.structure),
                self.structure.stabilisation_state.tie_work,
            ]
        )
        total = summed(self.comm, local)
        self.guards.inverted(inverted, total[7] > 0.0)
        if not np.all(np.isfinite(total)):
            self.guards.not_finite()
        return total
