"""The owned cells of a one-cell-through-the-thickness (or layered) mesh as columns of base nodes,
and the node lists of the (sub)elements and cohesive elements refinement cuts them into.

Node indices: base nodes are DOLFINx local nodes (owned then ghosts); *combined local* indices
(i < n_base: base node i, else extra node i - n_base) as ``enrichment`` defines them.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from fenics_adaptive.adaptivity import enrichment as enr
from fenics_adaptive.model.forms import LayeredModel


class CellColumnTable:
    """Bottom and top base nodes of every owned cell of ``base`` (a column of the mesh): local
    (``bottom_local``, ``top_local`` (n_cells, 4) int32), the bottom ones also global
    (``bottom_global``), the original cell numbers (``original_cell``, the same on any number
    of ranks) and the top node of each bottom one (``top_of``, over the local base nodes: -1
    for a node that is no column's bottom)."""

    def __init__(self, base: LayeredModel):
        n_cells = base.n_owned_cells
        index_map = base.V.dofmap.index_map
        self.n_base = index_map.size_local + index_map.num_ghosts
        local_to_global = index_map.local_to_global(np.arange(self.n_base, dtype=np.int32))
        nodes = base.V.dofmap.list[:n_cells]
        self.bottom_local = np.ascontiguousarray(nodes[:, :4], dtype=np.int32)
        self.top_local = np.ascontiguousarray(nodes[:, 4:], dtype=np.int32)
        self.bottom_global = local_to_global[self.bottom_local].astype(np.int64)
        self.original_cell = np.asarray(
            base.mesh.topology.original_cell_index[:n_cells], dtype=np.int64
        )
        self.top_of = np.full(self.n_base, -1, dtype=np.int64)
        self.top_of[self.bottom_local.ravel()] = self.top_local.ravel()

    def cell(self, cell: int) -> enr.CellColumns:
        """The four columns of one owned cell."""
        return enr.CellColumns(
            self.bottom_local[cell], self.top_local[cell], self.bottom_global[cell]
        )

    def cells_holding(self, node: int) -> np.ndarray:
        """Owned cells one of whose vertices is base node ``node`` (local)."""
        return np.flatnonzero(((self.bottom_local == node) | (self.top_local == node)).any(axis=1))

    def subelement_nodes(
        self,
        states: np.ndarray,
        first: np.ndarray,
        stop: np.ndarray,
        cells: np.ndarray,
        locate: Callable[[np.ndarray], np.ndarray],
    ) -> np.ndarray:
        """(m, 8) combined local nodes of the subelements holding plies first:stop of ``cells``
        whose interfaces are in ``states``; ``locate``: extra keys to local extra indices."""
        return enr.subelement_nodes_many(
            states,
            first,
            stop,
            self.bottom_local[cells],
            self.top_local[cells],
            self.bottom_global[cells],
            locate,
            self.n_base,
        )

    def cohesive_nodes(
        self,
        interfaces: np.ndarray,
        cells: np.ndarray,
        n_interfaces: int,
        locate: Callable[[np.ndarray], np.ndarray],
    ) -> np.ndarray:
        """(m, 8) combined local nodes (lower face, upper face) of the cohesive elements at
        ``interfaces`` (1-based) of ``cells``."""
        return enr.cohesive_nodes_many(
            interfaces, self.bottom_global[cells], n_interfaces, locate, self.n_base
        ).reshape(-1, 8)

    def node_requests(
        self,
        cells: np.ndarray,
        interface: int,
        node_set: int,
        n_interfaces: int,
        values: dict[str, np.ndarray],
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(keys, tie-breaks, values (n, 9)) of the 4 new extra nodes of each of ``cells`` at an
        interface, one per node, from their u, v, X (each (n_cells, 4, 3)): where cells share a
        node, the one with the lowest original cell number sets its values (the same on every
        rank, as ``ExtraNodes.activate`` also breaks ties across ranks)."""
        keys = enr.extra_keys(self.bottom_global[cells], interface, node_set, n_interfaces)
        keys = keys.ravel()
        ties = np.repeat(self.original_cell[cells].astype(np.int64), 4)
        rows = np.concatenate([values["u"], values["v"], values["X"]], axis=2).reshape(-1, 9)
        chosen = enr.lowest_tie_per_key(keys, ties)
        return keys[chosen], ties[chosen], rows[chosen]
