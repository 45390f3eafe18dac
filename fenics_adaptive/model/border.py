"""Extra nodes on the border of a refined region: constrained to the unrefined neighbour.

An extra node exists as soon as one cell around its column is refined at its interface. A
neighbouring cell that is not refined there interpolates its field linearly between the nodes it
does have. If the extra node moved freely the two cells would disagree along their shared
column. The refined region would then end in a partial hinge through the thickness, a crack
through the plies on one side of the interface. In four-point bending that made the beam
collapse as soon as a region refined.

So a border extra node is *constrained*, like a hanging node. Its *masters* are the nodes of its
column that every cell around the column has: the two base nodes, and the extra nodes of
interfaces refined in all of those cells (the *free* nodes). The constrained node follows the
piecewise-linear field through those masters. Every cell around the column then sees the same
field along it, whatever its own refinement. Forces and lumped masses of a constrained node go to
its masters with the interpolation weights. This row-sum lumping keeps mass and momentum. Its
motion is set from theirs after every step.

A set-B node (upper side of a strong interface) is free only when every cell around is strong
there. Until then it follows set A, so the crack is closed at the front of the strong region.

When the last cell around a column refines, the node is freed. It already sits where the new
cell's field puts it, so freeing it changes no strain energy. Only the lumped masses move, and
``Structure.refine`` books that.

Prescribed DOFs (a face motion, the symmetry interface) keep their prescription and are not
constrained.

MPI: the counts of refined cells per column are summed over ranks. Every rank holding a
constrained node also holds its masters: the cell that uses the node has the column's base
nodes, and a free extra node is used by every cell of the column. So forces are transferred on
each rank's partial sums before the reverse scatter, and motions are set on owned and ghost
entries from the forward-scattered masters, with no extra communication.

Units: none (weights are fractions of the thickness).
"""

from __future__ import annotations

from dataclasses import dataclass

import numba
import numpy as np
from dolfinx import la
from mpi4py import MPI

from fenics_adaptive.adaptivity import enrichment as enr
from fenics_adaptive.element.geometry import thickness_weight
from fenics_adaptive.settings.kinds import InterfaceState


@dataclass(frozen=True)
class BorderConstraints:
    """Constrained DOFs of this rank's extra nodes (owned and ghosts).

    ``dofs``: their combined flat DOF indices (3 n_base + 3 local extra index + component);
    ``masters`` (k, 2): combined flat DOF indices of the masters; ``weights`` (k, 2), summing to
    1 (a single master has weight 0 on the second, which repeats the first);
    ``free_b``: keys of the set-B nodes that are free (every cell around is strong)."""

    dofs: np.ndarray
    masters: np.ndarray
    weights: np.ndarray
    free_b: frozenset[int]

    @classmethod
    def empty(cls) -> BorderConstraints:
        return cls(np.zeros(0, np.int64), np.zeros((0, 2), np.int64), np.zeros((0, 2)), frozenset())

    def __len__(self) -> int:
        return len(self.dofs)


def column_counts(comm, base_map, bottom_local: np.ndarray, state: np.ndarray) -> np.ndarray:
    """Collective. For every local base node (owned and ghosts) used as a column bottom:
    (number of cells around it, cells weak or strong at each interface, cells strong at each
    interface), summed over ranks: shape (n_local_base, 1 + 2 n_interfaces), int32.

    Only the interfaces refined somewhere are counted (the others are zero): a 16-ply plate
    refined at three interfaces sums 7 columns, not 31, and the transient memory shrinks
    with it (60 MiB on a 40 000-cell plate before)."""
    n_interfaces = state.shape[1]
    local = (state >= InterfaceState.WEAK).any(axis=0).astype(np.int32)
    used = np.empty_like(local)
    comm.Allreduce(local, used, op=MPI.MAX)
    active = np.flatnonzero(used)
    n_active = len(active)
    counts = la.vector(base_map, bs=1 + 2 * n_active)
    table = counts.array.reshape(-1, 1 + 2 * n_active)
    per_cell = np.hstack(  # (n_cells, 1 + 2 n_active): the cell, refined, strong
        [
            np.ones((len(state), 1)),
            state[:, active] >= InterfaceState.WEAK,
            state[:, active] == InterfaceState.STRONG,
        ]
    )
    corners = bottom_local.ravel()  # each cell's bottom nodes, cell by cell
    for column in range(per_cell.shape[1]):
        weights = np.repeat(per_cell[:, column], bottom_local.shape[1])
        table[:, column] += np.bincount(corners, weights, minlength=len(table))
    counts.scatter_reverse(la.InsertMode.add)
    counts.scatter_forward()
    out = np.zeros((len(table), 1 + 2 * n_interfaces), dtype=np.int32)
    out[:, 0] = np.rint(table[:, 0])
    out[:, 1 + active] = np.rint(table[:, 1 : 1 + n_active])
    out[:, 1 + n_interfaces + active] = np.rint(table[:, 1 + n_active :])
    return out


def border_constraints(
    counts: np.ndarray,
    extra: enr.ExtraNodes,
    top_of: np.ndarray,
    fractions: np.ndarray,
    n_base: int,
    prescribed: np.ndarray,
) -> BorderConstraints:
    """The constraints of this rank's extra nodes from the column counts (``column_counts``).

    ``top_of``: the top base node of each local base node that is a column's bottom
    (``CellColumnTable.top_of``); ``fractions``: thickness fractions of the ply boundaries
    (0 .. 1, n_plies + 1);
    ``prescribed``: bool per local extra DOF (owned and ghosts), True where a motion holds it."""
    n_interfaces = extra.n_interfaces
    n_plies = n_interfaces + 1
    n = len(extra.index)
    keys = np.fromiter(extra.index.keys(), dtype=np.int64, count=n)
    local = np.fromiter(extra.index.values(), dtype=np.int64, count=n)
    g, interface, node_set = enr.key_arrays(keys, n_interfaces)
    bottom = extra.local_base_nodes(g)
    # free[s][b, j - 1]: node set s of interface j above base node b is active in every cell
    # around the column (the column count's entry equals the number of cells)
    cells_around = counts[:, :1]
    free = (
        counts[:, 1 : 1 + n_interfaces] == cells_around,
        counts[:, 1 + n_interfaces :] == cells_around,
    )
    free_a = free[enr.SET_A][bottom]  # (n, n_interfaces)
    free_b = free[enr.SET_B][bottom]
    rows = np.arange(n)
    own = np.where(node_set == enr.SET_A, free_a[rows, interface - 1], free_b[rows, interface - 1])
    free_keys = keys[own & (node_set == enr.SET_B)]

    # a constrained set B whose set A is free follows it; any other constrained node lies on
    # the straight line between the nearest free set-A nodes below and above (or the column's
    # bottom and top base nodes)
    c = np.flatnonzero(~own)
    follows_a = (node_set[c] == enr.SET_B) & free_a[c, interface[c] - 1]
    below = np.zeros(len(c), dtype=np.int64)
    above = np.full(len(c), n_plies, dtype=np.int64)
    for j in range(1, n_plies):  # ascending: the last free one below wins
        below = np.where((j < interface[c]) & free_a[c, j - 1], j, below)
    for j in range(n_interfaces, 0, -1):  # descending: the last free one above wins
        above = np.where((j > interface[c]) & free_a[c, j - 1], j, above)

    def node(at: np.ndarray, level: np.ndarray, sets: np.ndarray) -> np.ndarray:
        """Combined local index of extra nodes (g of ``at``, interface ``level``, ``sets``)."""
        if len(at) == 0:
            return np.zeros(0, dtype=np.int64)
        return n_base + extra.locate(enr.extra_keys(g[at], level, sets, n_interfaces))

    lower = bottom[c].copy()
    has_below = below > 0
    at = c[has_below]
    lower_set = np.where(free_b[at, below[has_below] - 1], enr.SET_B, enr.SET_A)
    lower[has_below] = node(at, below[has_below], lower_set)
    upper = np.empty(len(c), dtype=np.int64)
    at_top = above == n_plies
    upper[at_top] = top_of[bottom[c[at_top]]]
    upper[~at_top] = node(c[~at_top], above[~at_top], np.full(int((~at_top).sum()), enr.SET_A))
    s = thickness_weight(np.asarray(fractions, dtype=float), interface[c], below, above)
    weights = np.column_stack([1.0 - s, s])
    if follows_a.any():
        at = c[follows_a]
        lower[follows_a] = upper[follows_a] = node(at, interface[at], np.zeros(len(at), int))
        weights[follows_a] = (1.0, 0.0)

    # per DOF, node by node (the index's order) and x, y, z; the prescribed ones are left out
    dofs = 3 * (n_base + local[c])[:, None] + np.arange(3)
    masters = 3 * np.stack([lower, upper], axis=1)[:, None, :] + np.arange(3)[None, :, None]
    keep = ~np.asarray(prescribed, dtype=bool)[dofs - 3 * n_base]
    return BorderConstraints(
        dofs[keep].astype(np.int64),
        masters[keep].reshape(-1, 2).astype(np.int64),
        np.broadcast_to(weights[:, None, :], (len(c), 3, 2))[keep].reshape(-1, 2).copy(),
        frozenset(free_keys.tolist()),
    )


def transfer_masses(
    constraints: BorderConstraints,
    mass_base: la.Vector,
    mass_extra: la.Vector,
    n_base: int,
) -> tuple[np.ndarray, np.ndarray]:
    """Collective. Lumped masses with the constrained DOFs' masses moved to their masters:
    (base, extra) arrays of the owned DOFs. ``mass_*``: the assembled masses (owned entries
    complete). Each owned constrained DOF hands its mass over once, on its owner."""
    n_base_dofs = 3 * n_base
    out = []
    scratch = [la.vector(v.index_map, bs=3) for v in (mass_base, mass_extra)]
    delta_base, delta_extra = (v.array for v in scratch)
    constrained = constraints.dofs - n_base_dofs
    owned = constrained < 3 * mass_extra.index_map.size_local  # a ghost's owner transfers it
    constrained = constrained[owned]
    m = mass_extra.array[constrained]
    # masters are never constrained themselves: the constrained entries only lose their mass
    delta_extra[constrained] -= m
    # constraint by constraint, master by master (the order of the sums at a shared master)
    masters = constraints.masters[owned].ravel()
    shares = (constraints.weights[owned] * m[:, None]).ravel()
    in_base = masters < n_base_dofs
    np.add.at(delta_base, masters[in_base], shares[in_base])
    np.add.at(delta_extra, masters[~in_base] - n_base_dofs, shares[~in_base])
    for vector, delta in zip((mass_base, mass_extra), scratch, strict=True):
        delta.scatter_reverse(la.InsertMode.add)
        n_owned = 3 * vector.index_map.size_local
        out.append(vector.array[:n_owned] + delta.array[:n_owned])
    return out[0], out[1]


@numba.njit(cache=True)
def transfer_forces(dofs, masters, weights, n_base_dofs, f_base, f_extra):
    """Move the constrained DOFs' forces (this rank's partial sums) to their masters."""
    for k in range(dofs.shape[0]):
        c = dofs[k] - n_base_dofs
        value = f_extra[c]
        f_extra[c] = 0.0
        for j in range(2):
            master = masters[k, j]
            if master < n_base_dofs:
                f_base[master] += weights[k, j] * value
            else:
                f_extra[master - n_base_dofs] += weights[k, j] * value


@numba.njit(cache=True)
def _interpolated(k, masters, weights, n_base_dofs, x_base, x_extra):
    """The value of constrained DOF k on the straight line through its masters."""
    value = 0.0
    for j in range(2):
        master = masters[k, j]
        if master < n_base_dofs:
            value += weights[k, j] * x_base[master]
        else:
            value += weights[k, j] * x_extra[master - n_base_dofs]
    return value


@numba.njit(cache=True)
def follow_masters(dofs, masters, weights, n_base_dofs, x_base, x_extra, offsets):
    """Set the constrained DOFs of x (displacement or velocity) from their masters, plus
    ``offsets`` (the displacement's, ``record_offsets``; zeros for a velocity)."""
    for k in range(dofs.shape[0]):
        value = _interpolated(k, masters, weights, n_base_dofs, x_base, x_extra)
        x_extra[dofs[k] - n_base_dofs] = value + offsets[k]


@numba.njit(cache=True)
def record_offsets(dofs, masters, weights, n_base_dofs, x_base, x_extra, offsets):
    """offsets[k]: how far constrained DOF k of the displacement x is from the straight line
    through its masters. Recorded when the constraints are rebuilt and kept until the next
    rebuild: a new border node stays where its refinement put it (the refining element's
    field, enhanced thickness strain included, ``Structure._activate_weak``), a node that was
    constrained already keeps its offset, and ``follow_masters`` moves them with the masters."""
    for k in range(dofs.shape[0]):
        value = _interpolated(k, masters, weights, n_base_dofs, x_base, x_extra)
        offsets[k] = x_extra[dofs[k] - n_base_dofs] - value
