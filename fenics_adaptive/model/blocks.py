"""The two blocks of DOFs the explicit solver integrates (base nodes, extra nodes) and what they
carry besides the fields: the assembled lumped masses, the internal-force vectors, the border
constraints with the masses the solver divides by, and the prescribed DOFs.

Units: N, mm, s, tonne.

``LumpedBlocks`` owns those vectors and sums the internal-force contributors into them
(``add_internal_forces``: the contributors' shares, the border's transfer, the reverse
exchange, both blocks in one message per neighbour: ``halo``, a ``parallel.Halo``, which the
solver's forward exchange of the displacements uses too); the structure tells it when the
extra nodes changed (``resize_extra``), how the masses moved (``add_mass_change``, from
``subelement_mass_change``) and the new border and prescriptions (``rebuild``). The totals
(mass, momentum, kinetic energy) are computed from the blocks alone.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass

import numpy as np
from dolfinx import common, fem, la
from mpi4py import MPI

from fenics_adaptive.adaptivity import enrichment as enr
from fenics_adaptive.element.rules import RuleTable
from fenics_adaptive.model.border import (
    BorderConstraints,
    follow_masters,
    record_offsets,
    transfer_forces,
    transfer_masses,
)
from fenics_adaptive.model.forces import ForceContributor
from fenics_adaptive.parallel.halo import Halo
from fenics_adaptive.parallel.reductions import dot


@dataclass
class Block:
    """DOFs the solver integrates together: the base nodes, or the extra nodes. Vectors hold
    owned then ghost entries; ``mass``, ``fixed`` refer to owned DOFs (block-unrolled, 3 per
    node)."""

    u: la.Vector
    v: la.Vector
    f: la.Vector  # internal force, owned entries complete after add_internal_forces
    mass: np.ndarray
    fixed: np.ndarray
    fixed_motion: np.ndarray  # index into Structure.motions

    @property
    def n_owned(self) -> int:
        return len(self.mass)


class LumpedBlocks:
    """The base and extra blocks with their assembled lumped masses (tonne per DOF), internal
    force vectors (N) and border constraints.

    Parameters: ``V`` the base model's vector space, ``base_mass`` its assembled lumped masses
    (all local DOFs), ``extra_map`` the index map of the extra nodes, ``fixed`` /
    ``fixed_motion`` the base block's prescribed owned DOFs and the motion of each.
    """

    def __init__(
        self,
        V: fem.FunctionSpace,
        base_mass: np.ndarray,
        extra_map: common.IndexMap,
        fixed: np.ndarray,
        fixed_motion: np.ndarray,
    ):
        self.comm = V.mesh.comm
        self.base_map = V.dofmap.index_map
        self.n_base = V.dofmap.index_map.size_local + V.dofmap.index_map.num_ghosts
        self.halo: Halo | None = None
        # the forces' reverse exchange that also sums a base-layout array (``carry_base``)
        self._carrying: Halo | None = None
        self.f_base = fem.Function(V, name="internal_force").x
        self.mass_base = fem.Function(V, name="mass").x
        self.mass_base.array[:] = base_mass
        self.base_fixed, self.base_fixed_motion = fixed, fixed_motion
        self.mass_extra: la.Vector | None = None
        self.f_extra: la.Vector
        self.border = BorderConstraints.empty()
        self.offsets = self._no_offsets = np.zeros(0)  # mm per constrained DOF (rebuild)
        self.base_block: Block | None = None
        self.extra_block: Block | None = None
        self.resize_extra(extra_map)

    @property
    def blocks(self) -> list[Block]:
        """[base block, extra block] (after ``rebuild``)."""
        return [self.base_block, self.extra_block]

    def resize_extra(self, extra_map: common.IndexMap) -> None:
        """Collective: new force and (assembled) mass vectors of the extra nodes after their
        set changed (new nodes are numbered after the old owned ones, which keep their masses),
        and the halo exchange of both blocks (``halo``)."""
        if self.halo is not None:
            self.halo.free()
        # one exchange for both blocks: a step waits once for the displacements' ghosts and
        # once for the forces summed on their owners, however many blocks move
        self.halo = Halo(self.comm, [self.base_map, extra_map], [3, 3])
        self._extra_map = extra_map
        if self._carrying is not None:
            self.carry_base()
        old_mass = self.mass_extra
        self.f_extra = la.vector(extra_map, bs=3)
        # the force vectors' arrays, taken once (each .array of a DOLFINx vector costs 2 us)
        self._f_arrays = (self.f_base.array, self.f_extra.array)
        self.mass_extra = la.vector(extra_map, bs=3)
        if old_mass is not None:
            n_old = old_mass.index_map.size_local * 3
            self.mass_extra.array[:n_old] = old_mass.array[:n_old]

    def add_mass_change(self, delta: np.ndarray) -> None:
        """Collective: add ``delta`` (tonne per node, at combined local nodes: i < n_base base
        node i, else extra node i - n_base) to the assembled masses of all three components;
        the contributions to shared nodes are summed on their owner, then forward-scattered."""
        delta_base, delta_extra = delta[: self.n_base], delta[self.n_base :]
        for part, target in ((delta_base, self.mass_base), (delta_extra, self.mass_extra)):
            scratch = la.vector(target.index_map, bs=3)
            scratch.array.reshape(-1, 3)[:] = part[:, None]
            scratch.scatter_reverse(la.InsertMode.add)
            n_owned = target.index_map.size_local * 3
            target.array[:n_owned] += scratch.array[:n_owned]
            target.scatter_forward()

    def rebuild(
        self,
        border: BorderConstraints,
        prescribed: np.ndarray,
        base_fields: tuple[la.Vector, la.Vector],
        extra_fields: tuple[la.Vector, la.Vector],
    ) -> None:
        """Collective: take the border constraints ``border``, move the constrained masses to
        their masters (the masses the solver divides by), put the constrained nodes (u and v)
        on their masters and make the blocks. ``prescribed``: the motion of each local extra
        DOF, -1 if free; ``*_fields``: the blocks' (displacement, velocity) vectors."""
        self.border = border
        self._border_args = (border.dofs, border.masters, border.weights, 3 * self.n_base)
        self._no_offsets = np.zeros(len(border))
        self.offsets = np.zeros(len(border))
        mass_base, mass_extra = transfer_masses(
            border, self.mass_base, self.mass_extra, self.n_base
        )
        (u_base, v_base), (u_extra, v_extra) = base_fields, extra_fields
        self.record_offsets(u_base.array, u_extra.array)
        self.follow_border(v_base.array, v_extra.array)
        n_owned = self.mass_extra.index_map.size_local * 3
        fixed = np.flatnonzero(prescribed[:n_owned] >= 0).astype(np.int32)
        self.base_block = Block(
            *base_fields, self.f_base, mass_base, self.base_fixed, self.base_fixed_motion
        )
        self.extra_block = Block(
            *extra_fields, self.f_extra, mass_extra, fixed, prescribed[fixed].astype(np.int32)
        )

    def follow_border(
        self, base: np.ndarray, extra: np.ndarray, displacement: bool = False
    ) -> None:
        """Put the constrained extra DOFs of ``extra`` (a field of all local extra DOFs, flat)
        where their masters in ``base`` / ``extra`` are: on their straight line, plus the
        recorded offsets for the ``displacement`` (``record_offsets``)."""
        if len(self.border):
            offsets = self.offsets if displacement else self._no_offsets
            follow_masters(*self._border_args, base, extra, offsets)

    def record_offsets(self, u_base: np.ndarray, u_extra: np.ndarray) -> None:
        """Record how far each constrained DOF of the displacement is from its masters'
        straight line (``border.record_offsets``), after a rebuild; a restart puts the
        checkpoint's back (``Structure.restore``). Velocities carry no offset (the offsets are
        constant)."""
        if len(self.border):
            record_offsets(*self._border_args, u_base, u_extra, self.offsets)

    def add_internal_forces(
        self, t: float, contributors: Iterable[ForceContributor], also: Sequence = ()
    ) -> None:
        """Collective: f_int at time t (s) of the INTERNAL ``contributors`` into both force
        vectors (N): cleared, each contributor's share added into the local entries in order,
        the constrained DOFs' forces moved to their masters (the border's transfer), the
        shares summed on their owners (owned entries complete; one reverse exchange for both
        blocks, whose wait completes the MPI requests ``also`` too)."""
        f_base, f_extra = self.cleared_internal_forces()
        for contributor in contributors:
            contributor.add_force(t, f_base, f_extra)
        self.start_summing()
        self.finish_summing(also)

    def cleared_internal_forces(self) -> tuple[np.ndarray, np.ndarray]:
        """The local (owned + ghost) flat internal-force arrays of the base and extra DOFs,
        zeroed, for the contributors to add their shares into (then ``start_summing``)."""
        f_base, f_extra = self._f_arrays
        f_base.fill(0.0)
        f_extra.fill(0.0)
        return f_base, f_extra

    def carry_base(self) -> None:
        """Collective: from now on the forces' reverse exchange can carry one more array of
        base DOFs, summed on the owners with the forces in the same messages (``carried`` of
        ``start_summing``: a selectively scaled mass's shares of the accelerations)."""
        if self._carrying is not None:
            self._carrying.free()
        self._carrying = Halo(self.comm, [self.base_map, self._extra_map, self.base_map], [3, 3, 3])

    def start_summing(self, carried: np.ndarray | None = None) -> None:
        """Collective: the constrained DOFs' forces moved to their masters (the border's
        transfer), the ghost shares sent to their owners; the owned entries are complete after
        ``finish_summing``. ``carried``: an array of all local base DOFs whose ghost entries
        travel with them (after ``carry_base``), summed on the owners alike."""
        f_base, f_extra = self._f_arrays
        if len(self.border):
            transfer_forces(*self._border_args, f_base, f_extra)
        if carried is None:
            self.halo.reverse_start(self._f_arrays)
        else:
            self._carrying.reverse_start((f_base, f_extra, carried))

    def finish_summing(self, also: Sequence = (), carried: np.ndarray | None = None) -> None:
        """Wait for the shares ``start_summing`` sent (and the MPI requests ``also``, in the
        same call) and add them on their owners (``carried``: the array given to
        ``start_summing``)."""
        if carried is None:
            self.halo.reverse_finish(self._f_arrays, also)
        else:
            self._carrying.reverse_finish((*self._f_arrays, carried), also)

    def owned_dofs(self, nodes: np.ndarray) -> list[np.ndarray]:
        """Collective: the owned DOFs (base block, extra block; block-unrolled, sorted) of the
        combined local ``nodes`` (i < n_base: base node i, else extra node i - n_base); a node
        that is a ghost here is marked on its owner by a reverse scatter."""
        nodes = np.asarray(nodes, dtype=np.int64)
        is_base = nodes < self.n_base
        out = []
        for target, marked in (
            (self.mass_base, nodes[is_base]),
            (self.mass_extra, nodes[~is_base] - self.n_base),
        ):
            marks = la.vector(target.index_map, bs=3)
            marks.array.reshape(-1, 3)[marked] = 1.0
            marks.scatter_reverse(la.InsertMode.add)
            n_owned = target.index_map.size_local * 3
            out.append(np.flatnonzero(marks.array[:n_owned] > 0).astype(np.int32))
        return out

    def total_mass(self) -> float:
        """Collective: the mass (tonne) the solver integrates, over all ranks."""
        local = sum(block.mass[::3].sum() for block in self.blocks)
        return self.comm.allreduce(local, op=MPI.SUM)

    def kinetic_energy(self) -> float:
        """Collective: 1/2 v.M v (mJ) over both blocks and all ranks."""
        local = 0.0
        for block in self.blocks:
            v = block.v.array[: block.n_owned]
            local += 0.5 * dot(block.mass * v, v)
        return self.comm.allreduce(local, op=MPI.SUM)

    def momentum(self) -> np.ndarray:
        """Collective: the linear momentum (3,) tonne mm/s over both blocks and all ranks."""
        local = np.zeros(3)
        for block in self.blocks:
            v = block.v.array[: block.n_owned].reshape(-1, 3)
            local += (block.mass[::3, None] * v).sum(axis=0)
        return self.comm.allreduce(local, op=MPI.SUM)


def subelement_mass_change(
    cells: np.ndarray,
    old_states: np.ndarray,
    new_states: np.ndarray,
    subelement_nodes: Callable[[np.ndarray, np.ndarray, np.ndarray, np.ndarray], np.ndarray],
    positions: Callable[[np.ndarray], np.ndarray],
    rule_table: RuleTable,
    n_nodes: int,
) -> np.ndarray:
    """Lumped-mass change (tonne per combined local node, ``n_nodes`` of them) when ``cells``
    go from interface states ``old_states`` to ``new_states`` (rows per cell): each cell's old
    (sub)element masses taken off its nodes, the new ones put on. ``subelement_nodes(states,
    first, stop, cells)`` gives the (m, 8) nodes of subelements plies first:stop,
    ``positions(nodes)`` their reference positions (mm)."""
    cells = np.asarray(cells, dtype=np.int64)
    parts = []
    for states, sign in ((old_states, -1.0), (new_states, 1.0)):
        rows, first, stop = enr.subelement_table(states)
        nodes = subelement_nodes(states[rows], first, stop, cells[rows])
        parts.append((rows, first, stop, nodes, np.full(len(rows), sign)))
    # cell by cell, old then new: the order the sums have always been taken in
    order = np.argsort(np.concatenate([parts[0][0], parts[1][0]]), kind="stable")
    first, stop, nodes, signs = (
        np.concatenate([parts[0][k], parts[1][k]])[order] for k in (1, 2, 3, 4)
    )
    delta = np.zeros(n_nodes)
    if len(nodes):
        masses = rule_table.lumped_masses(positions(nodes), first, stop)
        masses *= signs[:, None]
        np.add.at(delta, nodes.ravel(), masses.ravel())  # in order, as a loop would
    return delta
