"""One halo exchange for several ghosted blocks of DOFs, split into a start and a finish.

Units: none (it moves numbers).

DOLFINx scatters one vector at a time and waits before it returns: a step of a refined model
(base nodes and extra nodes, displacements forward and forces back) waited four times for its
neighbours. ``Halo`` packs every block's values for a neighbour into one message and sends them
with one neighbourhood collective (``MPI_Ineighbor_alltoallv`` on a graph communicator of the
ranks that share a node), so that a step waits twice: once for the displacements' ghosts, once
for the forces summed on their owners. The exchange is split (``forward_start`` /
``forward_finish``, likewise reverse) so that work can run while the messages travel, and the
finish waits on other pending requests in the same call (``also``): a nonblocking reduction
started earlier (a free rigid body's force, the solver's poll) completes there instead of
costing a synchronisation of its own.

The values move as DOLFINx's scatters move them: forward, each ghost entry takes its owner's
value; reverse, each ghost entry is added to its owner's (in the order of the neighbours, then
of the ghosts), and the ghost entries keep their values. ``tests/test_halo.py`` holds both to
DOLFINx's ``scatter_forward`` / ``scatter_reverse(add)``.

On one rank there is nothing to exchange and every method returns at once; on several, the
construction and every start are collective over the communicator, whatever a rank holds (a
rank without neighbours takes part with empty messages), and every rank must finish what it
started. The solver computes its interior elements between the start and the finish of the
displacements' exchange, calling ``progress`` between chunks of them, and its external loads
between those of the forces' (``solver.forces.RunForces.evaluate``).
"""

from __future__ import annotations

from collections.abc import Sequence

import numba
import numpy as np
from dolfinx import common
from mpi4py import MPI

__all__ = ["Halo"]


@numba.njit(cache=True)
def _pack(values, indices, buffer, positions):  # pragma: no cover (compiled)
    for j in range(len(indices)):
        buffer[positions[j]] = values[indices[j]]


@numba.njit(cache=True)
def _unpack_set(buffer, positions, values, indices):  # pragma: no cover (compiled)
    for j in range(len(indices)):
        values[indices[j]] = buffer[positions[j]]


@numba.njit(cache=True)
def _unpack_add(buffer, positions, values, indices):  # pragma: no cover (compiled)
    for j in range(len(indices)):
        values[indices[j]] += buffer[positions[j]]


def _expand(nodes: np.ndarray, bs: int) -> np.ndarray:
    """Node indices -> their DOF indices, block-unrolled (node i: bs i ... bs i + bs - 1)."""
    return (bs * nodes[:, None] + np.arange(bs)).ravel().astype(np.int64)


class _Pattern:
    """Who sends what to whom in the forward direction for one index map: per neighbour (in the
    order of ``neighbours``) the owned nodes a neighbour ghosts (sent) and the ghost nodes that
    neighbour owns (received), in the order both sides agree on (the ghost holder's)."""

    def __init__(self, index_map: common.IndexMap, neighbours: np.ndarray, comm: MPI.Comm):
        n_owned = index_map.size_local
        owners = np.asarray(index_map.owners, dtype=np.int64)
        ghosts = np.asarray(index_map.ghosts, dtype=np.int64)
        # ghosts grouped by owner rank, in their local order within a group
        by_owner = np.argsort(owners, kind="stable")
        counts = np.bincount(owners, minlength=comm.size).astype(np.int64)
        asked = np.zeros(comm.size, dtype=np.int64)
        comm.Alltoall(counts, asked)  # how many of my owned nodes each rank ghosts
        wanted = np.empty(asked.sum(), dtype=np.int64)
        send_displs = np.concatenate([[0], np.cumsum(counts)[:-1]])
        recv_displs = np.concatenate([[0], np.cumsum(asked)[:-1]])
        comm.Alltoallv(
            [ghosts[by_owner], (counts, send_displs), MPI.INT64_T],
            [wanted, (asked, recv_displs), MPI.INT64_T],
        )
        first = index_map.local_range[0]
        self.sent = [wanted[recv_displs[p] : recv_displs[p] + asked[p]] - first for p in neighbours]
        ghost_order = n_owned + by_owner
        self.received = [
            ghost_order[send_displs[p] : send_displs[p] + counts[p]] for p in neighbours
        ]


def neighbour_ranks(index_maps: Sequence[common.IndexMap], comm: MPI.Comm) -> np.ndarray:
    """Collective: the ranks this one shares a node with, in any of ``index_maps`` (owners of
    its ghosts and holders of ghosts of its nodes; the relation made symmetric), ascending."""
    mine = np.zeros(comm.size, dtype=np.int32)
    for index_map in index_maps:
        mine[np.asarray(index_map.owners, dtype=np.int64)] = 1
    theirs = np.zeros(comm.size, dtype=np.int32)
    comm.Alltoall(mine, theirs)  # theirs[p]: rank p ghosts some node of mine
    return np.flatnonzero(mine | theirs).astype(np.int32)


class Halo:
    """The forward and reverse halo exchange of several blocks at once.

    ``index_maps``, ``block_sizes``: one per block (the arrays exchanged hold, per block, owned
    then ghost entries of ``index_map`` with ``block_size`` values per node, flat, as a DOLFINx
    vector's ``array`` does). Collective; build it again when an index map changes (``free()``
    the old one). On one rank it holds nothing and does nothing.
    """

    def __init__(
        self,
        comm: MPI.Comm,
        index_maps: Sequence[common.IndexMap],
        block_sizes: Sequence[int],
    ):
        self.comm = comm
        self.n_blocks = len(index_maps)
        # local entries per block (owned + ghost values): what the arrays must hold
        self.sizes = [
            bs * (m.size_local + m.num_ghosts)
            for m, bs in zip(index_maps, block_sizes, strict=True)
        ]
        self.active = comm.size > 1
        self._freed = False
        self._request = MPI.REQUEST_NULL
        self._direction = ""
        if not self.active:
            return
        neighbours = neighbour_ranks(index_maps, comm)
        self.neighbours = neighbours
        patterns = [_Pattern(m, neighbours, comm) for m in index_maps]
        # per neighbour: the blocks' values one after the other (forward: owned values out,
        # ghost values in; reverse: the other way round)
        n = len(neighbours)
        out_counts = np.zeros(n, dtype=np.int64)
        in_counts = np.zeros(n, dtype=np.int64)
        for pattern, bs in zip(patterns, block_sizes, strict=True):
            out_counts += np.array([bs * len(s) for s in pattern.sent], dtype=np.int64)
            in_counts += np.array([bs * len(r) for r in pattern.received], dtype=np.int64)
        # (a rank with no neighbour, e.g. no cells, has empty counts and takes part all the same)
        out_displs = np.cumsum(out_counts) - out_counts
        in_displs = np.cumsum(in_counts) - in_counts
        out_fill, in_fill = out_displs.copy(), in_displs.copy()
        # per block: (owned DOFs, their positions in the outgoing buffer; ghost DOFs, their
        # positions in the incoming buffer) of the forward exchange
        self._owned, self._owned_at, self._ghost, self._ghost_at = [], [], [], []
        for pattern, bs in zip(patterns, block_sizes, strict=True):
            owned, owned_at, ghost, ghost_at = [], [], [], []
            for k in range(n):
                dofs = _expand(pattern.sent[k], bs)
                owned.append(dofs)
                owned_at.append(out_fill[k] + np.arange(len(dofs)))
                out_fill[k] += len(dofs)
                dofs = _expand(pattern.received[k], bs)
                ghost.append(dofs)
                ghost_at.append(in_fill[k] + np.arange(len(dofs)))
                in_fill[k] += len(dofs)
            for store, parts in (
                (self._owned, owned),
                (self._owned_at, owned_at),
                (self._ghost, ghost),
                (self._ghost_at, ghost_at),
            ):
                store.append(
                    np.concatenate(parts).astype(np.int64) if parts else np.zeros(0, np.int64)
                )
        self._owned_buffer = np.zeros(out_counts.sum())
        self._ghost_buffer = np.zeros(in_counts.sum())
        owned_spec = (out_counts.astype(np.int32), out_displs.astype(np.int32))
        ghost_spec = (in_counts.astype(np.int32), in_displs.astype(np.int32))
        # compiled here (from the cache after the first run), not in the first step
        none, nowhere = np.zeros(0), np.zeros(0, dtype=np.int64)
        _pack(none, nowhere, none, nowhere)
        _unpack_set(none, nowhere, none, nowhere)
        _unpack_add(none, nowhere, none, nowhere)
        self._graph = comm.Create_dist_graph_adjacent(
            neighbours.tolist(), neighbours.tolist(), reorder=False
        )
        # the message specifications, built once (mpi4py reads them at every call)
        self._forward_args = (
            [self._owned_buffer, owned_spec, MPI.DOUBLE],
            [self._ghost_buffer, ghost_spec, MPI.DOUBLE],
        )
        self._reverse_args = (
            [self._ghost_buffer, ghost_spec, MPI.DOUBLE],
            [self._owned_buffer, owned_spec, MPI.DOUBLE],
        )

    @property
    def ghost_values(self) -> int:
        """How many values this rank receives in a forward exchange (the halo's size)."""
        return len(self._ghost_buffer) if self.active else 0

    @property
    def shared_values(self) -> int:
        """How many values this rank sends in a forward exchange."""
        return len(self._owned_buffer) if self.active else 0

    def _check(self, arrays: Sequence[np.ndarray]) -> None:
        """Refuse what the compiled packing would not: a freed halo, arrays of other sizes
        than the index maps', a second exchange before the first finished."""
        if self._freed:
            raise RuntimeError("Halo used after free(): build a new one for the new index maps")
        if [len(a) for a in arrays] != self.sizes:
            raise ValueError(
                f"Halo of blocks of {self.sizes} entries given {[len(a) for a in arrays]}"
            )
        if self._request:
            raise RuntimeError(f"Halo: the {self._direction} exchange under way is not finished")

    def _complete(self, direction: str, also: Sequence[MPI.Request]) -> bool:
        """Wait for the ``direction`` exchange under way and ``also`` in one call; False on
        one rank (nothing exchanged: ``also`` alone completed)."""
        if not self.active:
            if also:
                MPI.Request.Waitall(list(also))
            return False
        if self._direction != direction or not self._request:
            raise RuntimeError(f"Halo: no {direction} exchange under way")
        MPI.Request.Waitall([self._request, *also])
        self._request = MPI.REQUEST_NULL
        return True

    def forward_start(self, arrays: Sequence[np.ndarray]) -> None:
        """Collective: start sending the owned values of ``arrays`` (one per block) that other
        ranks hold as ghosts. Do not write the arrays' ghost entries until ``forward_finish``."""
        if not self.active:
            return
        self._check(arrays)
        for values, owned, at in zip(arrays, self._owned, self._owned_at, strict=True):
            _pack(values, owned, self._owned_buffer, at)
        self._request = self._graph.Ineighbor_alltoallv(*self._forward_args)
        self._direction = "forward"

    def forward_finish(
        self, arrays: Sequence[np.ndarray], also: Sequence[MPI.Request] = ()
    ) -> None:
        """Wait for the forward exchange (and the requests ``also``, in the same call) and put
        the owners' values into the ghost entries of ``arrays``."""
        if not self._complete("forward", also):
            return
        for values, ghost, at in zip(arrays, self._ghost, self._ghost_at, strict=True):
            _unpack_set(self._ghost_buffer, at, values, ghost)

    def forward(self, arrays: Sequence[np.ndarray], also: Sequence[MPI.Request] = ()) -> None:
        """Collective: ``forward_start`` then ``forward_finish``."""
        self.forward_start(arrays)
        self.forward_finish(arrays, also)

    def reverse_start(self, arrays: Sequence[np.ndarray]) -> None:
        """Collective: start sending the ghost entries of ``arrays`` to their owners. Do not
        write the arrays' owned entries shared with other ranks until ``reverse_finish``."""
        if not self.active:
            return
        self._check(arrays)
        for values, ghost, at in zip(arrays, self._ghost, self._ghost_at, strict=True):
            _pack(values, ghost, self._ghost_buffer, at)
        self._request = self._graph.Ineighbor_alltoallv(*self._reverse_args)
        self._direction = "reverse"

    def reverse_finish(
        self, arrays: Sequence[np.ndarray], also: Sequence[MPI.Request] = ()
    ) -> None:
        """Wait for the reverse exchange (and ``also``) and add what the other ranks held as
        ghosts into the owned entries of ``arrays`` (the ghost entries keep their values)."""
        if not self._complete("reverse", also):
            return
        for values, owned, at in zip(arrays, self._owned, self._owned_at, strict=True):
            _unpack_add(self._owned_buffer, at, values, owned)

    def reverse(self, arrays: Sequence[np.ndarray], also: Sequence[MPI.Request] = ()) -> None:
        """Collective: ``reverse_start`` then ``reverse_finish``."""
        self.reverse_start(arrays)
        self.reverse_finish(arrays, also)

    def progress(self) -> None:
        """Let MPI move the messages of the exchange under way, completing nothing
        (``MPI_Request_get_status``). Without a progress thread MPICH moves a message longer
        than its eager limit (a few KiB between the processes of a node: a halo of some
        hundred nodes) only inside MPI calls of both its sender and its receiver: a rank
        that computes between ``*_start`` and ``*_finish`` calls this every millisecond or so,
        or its neighbours wait in their finish until it arrives at its own."""
        if self._request:
            self._request.Get_status()

    def free(self) -> None:
        """Collective: release the graph communicator; the halo refuses to be used after."""
        if self.active and not self._freed:
            self._graph.Free()
        self._freed = True

    def __del__(self):
        # DOLFINx frees its scatterers' communicators in their destructors alike; at the
        # interpreter's exit MPI may be gone already
        if getattr(self, "active", False) and not self._freed and not MPI.Is_finalized():
            self._graph.Free()
            self._freed = True
