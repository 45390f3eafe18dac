"""The one interface of everything that puts a nodal force on the structure.

Units: N, mm, s, tonne (forces N, energies mJ = N mm).

A force contributor adds its force, says the energy it stores and keeps its state; the solver
sums every contributor each step. The structure's own are its internal forces and tie forces
(``Structure.contributors``): every solid (sub)element, unrefined cells whole and the refined
cells' subelements, through the batched elastic kernel (``internal_forces.ElasticSolid``) or,
with ply damage, the damage-aware one (``internal_forces.DamagedSolid``), the cohesive elements
(``internal_forces.CohesiveElements``) and the tie forces of new strong interfaces
(``tie_forces.TieForces``). A run adds more (``ExplicitSolver(contributors=...)``,
``Simulation.add_contributor``): a rigid impactor (``contact.Contact``), or one of a user's own.

The interface (``ForceContributor``; subclass ``Contributor`` to get the optional hooks):

- ``name``: unique in a run; the prefix of its state's keys in a checkpoint.
- ``kind`` (``ForceKind``): where the force goes, in the balance of momentum and of energy.
  INTERNAL: into f_int (m a = f_ext - f_int), its work is internal work. EXTERNAL: into f_ext,
  its work is external work. CONTACT: on the base DOFs beside f_ext, its work is what the
  impactor gives up (``impact_work``).
- ``add_force(t, f_base, f_extra)``: add the force at time t (s) into flat arrays (N, x y z
  interleaved) of the base and the extra DOFs. INTERNAL contributors add this rank's share
  into the local arrays (owned and ghost entries), like element assembly: after every INTERNAL
  contributor has added, the force of each constrained extra DOF on the border of a refined
  region goes to its masters and the shares of shared DOFs are summed on their owners
  (``LumpedBlocks.add_internal_forces``). That border transfer is no contributor: it is a map
  applied to the sum of all of them, so it runs after them. EXTERNAL and CONTACT contributors
  add into the owned entries, complete (a DOF's force on its owner only). Called every step:
  allocate nothing, loop over elements in compiled code only.
- ``energy()``: this rank's share (mJ) of the energy it holds at the state of its last
  ``add_force``. For INTERNAL contributors the recoverable energy (strain, cohesive): the rest
  of their work is dissipated (the history's ``dissipated_energy``); for the others the energy
  of what they hold (an impactor: kinetic + penalty). Called on output steps.
- ``state()`` / ``restore(state)``: what a restart needs to continue exactly, as named arrays
  (scalars 0-d), on the same rank of the same model. The structure's contributors are
  checkpointed with the structure (``Structure.state``), a run's with the solver.

Optional hooks (``Contributor`` has them as no-ops; the solver calls only those a contributor
overrides, so an unused hook costs nothing per step): ``prepare(dt, element_step)`` at the start
of a run, ``advance(mean_dt, dt)`` after each step (a contributor with degrees of freedom of its
own), ``report(row, first)`` its columns of a history row, ``suspect()`` what of it to suspect
when a run blows up (called on every rank: may use collectives), ``refined()`` after the
structure was refined (rebuild what depends on its cells), ``pending_request()`` a nonblocking
reduction its ``add_force`` (or ``moved``) started (an ``mpi4py`` request; a free rigid body's
force summed over the ranks): the solver completes it in the wait of the next of its two
exchanges (the internal forces' reverse exchange, the displacements' halo exchange), so that
it costs no synchronisation of its own (the contributor must complete it itself, with a
``Wait`` that is then a no-op, before it reads the result); ``moved()`` between
the update of the owned displacements and the halo exchange (start a sum of them there), and,
for CONTACT contributors, ``complete(t, f_base, f_extra)`` after the internal forces' reverse
exchange (CONTACT contributors are evaluated before the internal forces, so that a sum they
start completes in that exchange); for INTERNAL contributors of many elements,
``add_interior_force`` (with a ``progress`` callable) and ``add_boundary_force``, ``add_force``
in two parts: on several ranks
the solver computes the first while the displacements of the ghost nodes are on their way (the
elements whose nodes are all ``ready``: ``internal_forces.NodeArrays.interior``), then lets the
other contributors add their forces, then the second (a contributor without them is computed
whole, after the exchange).

The order of the contributors of one kind is the order of summation, so a run's history does
not depend on anything but the list. A linear spring of stiffness k (N/mm) to ground on some
owned DOFs, as a user would write it::

    class Springs(Contributor):
        name, kind = "springs", ForceKind.EXTERNAL

        def __init__(self, simulation, dofs, k):
            self.u, self.dofs, self.k = simulation.u, dofs, k

        def add_force(self, t, f_base, f_extra):
            f_base[self.dofs] -= self.k * self.u[self.dofs]

        def energy(self):
            return 0.5 * self.k * float(self.u[self.dofs] @ self.u[self.dofs])

(``tests/test_contributors.py`` runs it against the closed form; a real one would keep its
work arrays instead of the temporaries of ``f_base[dofs] -= ...``.)
"""

from __future__ import annotations

from collections.abc import Callable
from enum import Enum
from typing import Protocol, runtime_checkable

import numpy as np


class ForceKind(Enum):
    """Where a contributor's force goes in the balance of momentum and of energy."""

    INTERNAL = "internal"  # into f_int: its work is internal work
    EXTERNAL = "external"  # into f_ext: its work is external work
    CONTACT = "contact"  # on the base DOFs beside f_ext: work the impactor gives up


@runtime_checkable
class ForceContributor(Protocol):
    """A source of nodal force, with the energy it stores and the state it keeps."""

    name: str
    kind: ForceKind

    def add_force(self, t: float, f_base: np.ndarray, f_extra: np.ndarray) -> None:
        """Add this contributor's force at time t (s) into this rank's base and extra DOF
        arrays (N, flat): the local entries (owned and ghost) for INTERNAL contributors, the
        owned entries otherwise."""
        ...

    def energy(self) -> float:
        """mJ: the energy it holds now (strain, recoverable cohesive, penalty, kinetic), this
        rank's share."""
        ...

    def state(self) -> dict[str, np.ndarray]:
        """What a restart needs to continue it exactly, as named arrays (scalars 0-d)."""
        ...

    def restore(self, state: dict[str, np.ndarray]) -> None:
        """Continue from ``state()`` taken from the same contributor on the same rank."""
        ...


class Contributor:
    """Base of a contributor with the solver's optional hooks, all no-ops: subclass it and
    define ``name``, ``kind``, ``add_force`` and, where it has them, ``energy``, ``state`` and
    ``restore``."""

    name: str = ""
    kind: ForceKind = ForceKind.EXTERNAL

    def add_force(self, t: float, f_base: np.ndarray, f_extra: np.ndarray) -> None:
        raise NotImplementedError(f"{type(self).__name__} must define add_force")

    def energy(self) -> float:
        return 0.0

    def state(self) -> dict[str, np.ndarray]:
        return {}

    def restore(self, state: dict[str, np.ndarray]) -> None:
        pass

    def prepare(self, dt: float, element_step: float) -> None:
        """The time step dt (s) was chosen at the start of a run; ``element_step``: the
        structure's stable step without the safety factor (s). A contributor that limits the
        step (a penalty) checks itself here."""

    def advance(self, mean_dt: float, dt: float) -> None:
        """The structure moved from t_n to t_n + dt (s); ``mean_dt``: (dt_{n-1/2} + dt) / 2
        (s). A contributor with degrees of freedom of its own (a rigid impactor) integrates
        them here with the same central-difference scheme."""

    def report(self, row, first: bool) -> None:
        """Fill this contributor's columns of a history row (``explicit.HistoryRow``);
        ``first``: the row at t = 0."""

    def suspect(self) -> str:
        """Collective: what of this contributor to suspect when a run blows up ("" for
        nothing)."""
        return ""

    def refined(self) -> None:
        """Collective: the structure was refined; rebuild what depends on its cells."""

    def moved(self) -> None:
        """The owned DOFs hold u_{n+1}, their ghosts not yet (between the update and the halo
        exchange): start a nonblocking sum of owned displacements over the ranks here
        (``pending_request``) for ``add_force`` to read."""

    def complete(self, t: float, f_base: np.ndarray, f_extra: np.ndarray) -> None:
        """CONTACT contributors: after the internal forces' reverse exchange (whose wait
        completed ``pending_request``), add what needs that sum (the lever's hinge force) into
        the same arrays as ``add_force``. Define ``late_force_shape`` with it."""

    # the size of the force the last ``complete`` added (N per unit of ``late_force_shape``)
    late_force_size: float = 0.0

    def late_force_shape(self, n_owned: int) -> np.ndarray:
        """A contributor with ``complete``: the fixed shape w of the force it adds there
        (owned base DOFs, ``n_owned`` of them); each ``complete`` adds ``late_force_size`` x
        w. A selectively scaled mass takes that force's accelerations as its size times the
        response to w (``mass_scaling.SelectiveMass.responses``): a force of another shape
        would need an exchange of its own."""
        raise NotImplementedError(
            f"{type(self).__name__} adds a force in complete() but gives no late_force_shape"
        )

    def add_interior_force(
        self, t: float, f_base: np.ndarray, f_extra: np.ndarray, progress: Callable[[], None]
    ) -> None:
        """INTERNAL contributors: the part of ``add_force`` that reads only the ``ready`` nodes
        (``internal_forces.NodeArrays``: owned, not bound to masters), computed while the halo
        exchange of the displacements is under way (the ghosts' displacements are those of the
        last step); call ``progress()`` about every millisecond of work, so that MPI moves the
        messages meanwhile (``parallel.Halo.progress``). Define ``add_boundary_force`` with
        it."""

    def add_boundary_force(self, t: float, f_base: np.ndarray, f_extra: np.ndarray) -> None:
        """The part of ``add_force`` that ``add_interior_force`` left, after the exchange."""
        self.add_force(t, f_base, f_extra)

    def pending_request(self):
        """The nonblocking MPI request the last ``add_force`` or ``moved`` started and has not
        completed (``mpi4py.MPI.REQUEST_NULL`` or None if none): the solver's next exchange
        waits on it in the same call."""
        return None


def overrides(contributor, name: str) -> bool:
    """Whether ``contributor``'s class has its own hook ``name`` (not ``Contributor``'s)."""
    default = getattr(Contributor, name)
    return getattr(type(contributor), name, default) is not default


def hooks(contributors, name: str) -> list:
    """The bound hook ``name`` of each contributor that has its own (not ``Contributor``'s
    no-op), in order: what the solver calls."""
    return [getattr(c, name) for c in contributors if overrides(c, name)]
