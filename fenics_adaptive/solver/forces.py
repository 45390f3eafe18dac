"""The forces of a run at t_n: every force contributor, by kind, and the face loads, summed
into the time loop's work arrays.

Units: N, mm, s, tonne.

The contributors (``model.forces``) are the structure's (``Structure.contributors``: internal
forces, tie forces) and then the run's own (an impactor, a user's), whose states the solver's
checkpoint keeps. Each step: the INTERNAL contributors into f_int (local shares, the border's
transfer, the reverse scatter: ``LumpedBlocks.add_internal_forces``), the face loads and the
EXTERNAL contributors into f_ext (owned DOFs), the CONTACT contributors into arrays of their own
beside f_ext (computed before the internal forces, or the rest of them: the sums over the
ranks they start complete in the internal forces' reverse exchange; their ``complete`` hooks
run after it). On several ranks the internal
forces of the interior elements are computed while the halo exchange of the displacements is
under way, the rest after it (``evaluate``'s ``ready``), and the external forces while the
internal forces' shares travel to their owners (before they leave, with a selectively scaled
mass: its shares of the accelerations travel with them, ``evaluate``'s ``carry``). The arrays
are allocated when the blocks change (start, refinement), never in a step.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Sequence

import numpy as np

from fenics_adaptive.model.forces import ForceContributor, ForceKind, hooks, overrides
from fenics_adaptive.model.structure import Structure
from fenics_adaptive.parallel.redistribute import contributor_layouts
from fenics_adaptive.solver.blocks import BlockState


class RunForces:
    """The force contributors of one run on ``structure``: its own, then ``contributors``.

    ``contributors`` lists them all in that order, ``added`` the run's own (a list the history
    recorder may hold: changed in place)."""

    def __init__(self, structure: Structure, contributors: Iterable[ForceContributor] = ()):
        self.structure = structure
        self.added: list[ForceContributor] = []
        self.contributors: list[ForceContributor] = []
        self._group([*contributors])
        self._contact_force: list[np.ndarray] = []
        self._f_ext_full = np.zeros_like(structure.blocks[0].u.array)  # base, owned + ghosts

    def add(self, contributor: ForceContributor) -> None:
        """One more contributor of the run. Raises ValueError if its name is taken."""
        self._group([*self.added, contributor])

    def _group(self, added: list[ForceContributor]) -> None:
        """The run's own contributors ``added``; every contributor of the run and by kind (the
        order of summation); the ``advance`` hooks of those that have one. Raises ValueError
        if two have the same name (their states would share keys)."""
        contributors = [*self.structure.contributors, *added]
        names = [c.name for c in contributors]
        if len(set(names)) < len(names):
            raise ValueError(f"force contributors need unique names (got {names})")
        self.added[:] = added
        self.contributors[:] = contributors
        by_kind = {kind: [c for c in contributors if c.kind is kind] for kind in ForceKind}
        self.internal = by_kind[ForceKind.INTERNAL]
        self.external = by_kind[ForceKind.EXTERNAL]
        self.contact = by_kind[ForceKind.CONTACT]
        self._moving = hooks(contributors, "advance")
        self._pending = hooks(contributors, "pending_request")
        # the contributors that add a force after the forces' exchange (``complete``)
        self.late = [c for c in self.contact if overrides(c, "complete")]
        self._moved = hooks(contributors, "moved")
        # the internal forces in two parts around the halo exchange (those that can split),
        # or whole
        self._interior = hooks(self.internal, "add_interior_force")
        self._whole = [c.add_force for c in self.internal]
        self._boundary = [
            c.add_boundary_force if overrides(c, "add_interior_force") else c.add_force
            for c in self.internal
        ]

    def prepare(self, blocks: Sequence[BlockState], dt: float, element_step: float) -> None:
        """At the start of a run: the arrays for ``blocks``, the contributors told the time step
        dt (s) and the structure's stable step without the safety factor (s)."""
        self.resize(blocks)
        for prepare in hooks(self.contributors, "prepare"):
            prepare(dt, element_step)

    def resize(self, blocks: Sequence[BlockState]) -> None:
        """The contact contributors' arrays (owned DOFs per block) for ``blocks``, if there are
        contact contributors."""
        self._contact_force = [np.zeros(b.block.n_owned) for b in blocks] if self.contact else []

    def evaluate(
        self,
        t: float,
        blocks: Sequence[BlockState],
        ready: Callable[[], None] | None = None,
        progress: Callable[[], None] = lambda: None,
        carry: Callable[[list[np.ndarray] | None], np.ndarray] | None = None,
    ) -> list[np.ndarray] | None:
        """Collective: at time t (s), f_int into the blocks' ``f``, f_ext into their ``f_ext``;
        returns the contact force per block (N, owned DOFs), None without contact
        contributors. ``ready``: finishes the halo exchange of the displacements under way
        (None: none is); the INTERNAL contributors that can compute their interior elements
        (``add_interior_force``) before it, calling ``progress`` (it lets MPI move the
        exchange's messages), the rest of them after. ``carry(contact force)``: called once
        every force this rank computes before the exchange is in (the external ones too,
        then), returns an array of base DOFs to sum on the owners in the forces' exchange (a
        scaled mass's shares of the accelerations: ``solver.blocks.BlockState``)."""
        base, extra = blocks
        lumped = self.structure.lumped
        f_base, f_extra = lumped.cleared_internal_forces()
        internal = self._whole
        if ready is not None:
            for add in self._interior:
                add(t, f_base, f_extra, progress)
            ready()
            internal = self._boundary
        # the contact forces before the rest of the internal ones: the sums over the ranks
        # they start (a free body's force, the lever's saddle) complete in the internal forces'
        # reverse exchange instead of waiting on their own
        for forces in self._contact_force:
            forces.fill(0.0)
        for contributor in self.contact:
            contributor.add_force(t, *self._contact_force)
        for add in internal:
            add(t, f_base, f_extra)
        if carry is not None:  # everything first, then the one exchange
            self._external_forces(t, base, extra)
            carried = carry(self._contact_force or None)
            lumped.start_summing(carried)  # (nothing that can raise runs before its finish)
            lumped.finish_summing(self.pending_requests(), carried)
        else:
            lumped.start_summing()
            try:  # the external forces while the internal forces' shares travel
                self._external_forces(t, base, extra)
            finally:  # (an exchange left open would refuse the next one)
                lumped.finish_summing(self.pending_requests())
        if not self.contact:
            return None
        for contributor in self.late:
            contributor.complete(t, *self._contact_force)
        return self._contact_force

    def _external_forces(self, t: float, base: BlockState, extra: BlockState) -> None:
        """f_ext at time t (s) into both blocks: the face loads (extra nodes: of refined cells
        on a loaded side face), then the EXTERNAL contributors."""
        loads = self.structure.loads
        if loads.load_vectors:
            loads.external_force(t, self._f_ext_full, extra.f_ext)
            base.f_ext[:] = self._f_ext_full[: base.block.n_owned]
        else:  # no face loads: the contributors add to zero
            base.f_ext.fill(0.0)
            extra.f_ext.fill(0.0)
        for contributor in self.external:
            contributor.add_force(t, base.f_ext, extra.f_ext)

    @property
    def contact_force(self) -> list[np.ndarray] | None:
        """The CONTACT contributors' force per block at the last ``evaluate`` (N, owned
        DOFs), None without contact contributors."""
        return self._contact_force if self.contact else None

    def pending_requests(self) -> list:
        """The nonblocking reductions the contributors started and have not completed (a free
        body's force, the lever's hinge), for the next exchange to wait on in its own call."""
        return [r for r in (pending() for pending in self._pending) if r]

    def moved(self) -> None:
        """The owned DOFs hold u_{n+1}, their ghosts not yet: the contributors that need a
        sum of owned displacements over the ranks (the lever's hinge) start it, for the halo
        exchange to complete."""
        for moved in self._moved:
            moved()

    def advance(self, mean_dt: float, dt: float) -> None:
        """The structure moved by dt (s): the contributors with degrees of freedom of their own
        follow (``mean_dt``: (dt_{n-1/2} + dt) / 2, s)."""
        for advance in self._moving:
            advance(mean_dt, dt)

    def state(self) -> dict[str, np.ndarray]:
        """The run's own contributors' states, as ``<name>_<key>`` (the structure's are the
        structure's: ``Structure.state``)."""
        return {f"{c.name}_{k}": v for c in self.added for k, v in c.state().items()}

    def layout(self, structure) -> dict:
        """How the rows of ``state()``'s arrays are indexed (``parallel.redistribute``), each
        contributor's by its ``layout(structure)``. Raises ``NotMovable`` for a contributor
        with a state and no layout."""
        return contributor_layouts(self.added, structure)

    def restore(self, state: dict) -> None:
        """Each of the run's own contributors from its ``<name>_*`` entries of ``state``."""
        for contributor in self.added:
            prefix = f"{contributor.name}_"
            own = {k.removeprefix(prefix): v for k, v in state.items() if k.startswith(prefix)}
            if own:
                contributor.restore(own)
