"""Through-thickness enrichment (augmented FEM): refinement state, extra nodes and the
gather/scatter maps of refined cells. Paper: "Adaptive element kinematics", Eqs. (1)-(7),
Figure 2.

Units: mm for coordinates.

Vocabulary.
- A *cell* is an ESL hexahedron: 8 base nodes, bottom 0-3 and top 4-7, vertex a + 4 straight
  above vertex a. Its *column* a is the pair (base node a, base node a + 4).
- Ply interface i (1-based, 1 .. n_plies - 1) lies between ply i and ply i + 1 at the thickness
  fraction alpha_i (``Laminate.interface_fractions``).
- Each cell holds, per interface, ``InterfaceState.NONE``, ``WEAK`` or ``STRONG``
  (``interface_state``, int8: the enum's values).
- An *extra node* is identified by (column's bottom base node, interface, set): set A is the
  interface surface of a weak refinement; set B the reserved copy activated by a strong one (the
  upper side of the crack). Extra nodes share the connectivity of their base nodes, so
  neighbouring cells refined at the same interface share them. They exist only once activated
  (unlike the LS-DYNA user element, whose extra nodes are integrated from the start).
- A refined cell splits into subelements, one per run of plies between active interfaces. Plies
  keep their integration points (Figure 2): a subelement spans plies [first, stop) and its nodes
  are: bottom = base nodes 0-3, or the extra nodes of the active interface below (set B if that
  interface is strong, else A); top = base nodes 4-7, or the set-A extra nodes of the active
  interface above.
- A strong interface carries a cohesive element: lower face = its set-A nodes, upper face = its
  set-B nodes.
The projection matrices P^sublam,i and P^coh,i of the paper are never formed: each subelement
and cohesive element holds 8 node indices ("which node is local node k"), that is all.

Node indices in the maps are *combined local* indices: base nodes 0 .. n_base - 1 (DOLFINx local
node index, owned then ghosts), extra nodes n_base + (local extra index, owned then ghosts).

Distribution (MPI). An extra node is owned by the rank that owns its column's bottom base node.
``ExtraNodes.activate`` is collective: ranks ask owners for the nodes their cells need, owners
create them (first request by the lowest original cell index wins, so results do not depend on
the partition), and a new ``dolfinx.common.IndexMap`` with ghosts is built. Owned local indices
are append-only, so state carries over by copying.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass, field

import numpy as np
from dolfinx import common, la
from mpi4py import MPI

from fenics_adaptive.settings.kinds import InterfaceState

SET_A, SET_B = 0, 1


def extra_key(
    global_bottom_node: np.ndarray | int, interface: int, node_set: int, n_interfaces: int
):
    """Global identity of an extra node (int64)."""
    return (int(global_bottom_node) * n_interfaces + (interface - 1)) * 2 + node_set


def extra_keys(
    global_bottom_nodes: np.ndarray, interfaces, node_sets, n_interfaces: int
) -> np.ndarray:
    """``extra_key`` of arrays (broadcast against each other), int64."""
    g = np.asarray(global_bottom_nodes, dtype=np.int64)
    return (g * n_interfaces + (np.asarray(interfaces, dtype=np.int64) - 1)) * 2 + node_sets


def key_arrays(keys: np.ndarray, n_interfaces: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``key_parts`` of an array of keys: (global bottom base nodes, interfaces, sets), int64."""
    keys = np.asarray(keys, dtype=np.int64)
    rest = keys // 2
    return rest // n_interfaces, rest % n_interfaces + 1, keys % 2


def key_parts(key: int, n_interfaces: int) -> tuple[int, int, int]:
    """(global bottom base node, interface, set) of an extra-node key."""
    node_set = int(key % 2)
    rest = int(key // 2)
    return rest // n_interfaces, rest % n_interfaces + 1, node_set


def sorted_lookup(
    table: tuple[np.ndarray, np.ndarray], queries: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """(found?, value) of each of ``queries`` (int64, any shape) in ``table`` = (sorted keys,
    their values); the value is meaningless where not found."""
    keys, values = table
    queries = np.asarray(queries, dtype=np.int64)
    if len(keys) == 0:
        return np.zeros(queries.shape, dtype=bool), np.zeros(queries.shape, dtype=np.int64)
    where = np.minimum(np.searchsorted(keys, queries), len(keys) - 1)
    return keys[where] == queries, values[where]


def lowest_tie_per_key(keys: np.ndarray, ties: np.ndarray) -> np.ndarray:
    """Indices of one entry per distinct key, the one with the lowest tie-break, in ascending
    key order."""
    order = np.lexsort((ties, keys))
    first_of_key = np.ones(len(order), dtype=bool)
    first_of_key[1:] = keys[order][1:] != keys[order][:-1]
    return order[first_of_key]


@dataclass
class ExtraNodes:
    """The active extra nodes of this rank (owned, then ghosts) and their distributed vectors.

    ``u``, ``v`` (displacement, velocity) and ``X`` (reference position) are DOLFINx vectors of
    block size 3 on ``index_map``; ``index`` maps a key to its local index."""

    comm: MPI.Comm
    n_interfaces: int
    base_map: common.IndexMap
    owned_keys: list[int] = field(default_factory=list)
    ghost_keys: list[int] = field(default_factory=list)
    ghost_owner: list[int] = field(default_factory=list)
    ghost_owner_index: list[int] = field(default_factory=list)  # local index on the owner
    index: dict[int, int] = field(default_factory=dict)
    index_map: common.IndexMap | None = None
    vectors: dict[str, la.Vector] = field(default_factory=dict)

    VECTOR_NAMES = ("u", "v", "X")

    def __post_init__(self) -> None:
        self._sorted: tuple[np.ndarray, np.ndarray] | None = None
        self._global_to_local = _global_to_local(self.base_map)
        globals_ = np.fromiter(self._global_to_local.keys(), dtype=np.int64)
        local = np.fromiter(self._global_to_local.values(), dtype=np.int64)
        order = np.argsort(globals_)
        self._base_sorted = (globals_[order], local[order])
        self._rebuild_index_map()
        self.vectors = {name: la.vector(self.index_map, bs=3) for name in self.VECTOR_NAMES}

    @property
    def n_owned(self) -> int:
        return len(self.owned_keys)

    @property
    def n_local(self) -> int:
        return len(self.owned_keys) + len(self.ghost_keys)

    def local_base_node(self, global_node: int) -> int:
        return self._global_to_local[global_node]

    def local_base_nodes(self, global_nodes: np.ndarray) -> np.ndarray:
        """Local indices (int64) of global base nodes of this rank (owned or ghosts)."""
        found, local = sorted_lookup(self._base_sorted, global_nodes)
        if not found.all():
            raise KeyError(int(np.asarray(global_nodes)[~found].flat[0]))
        return local.astype(np.int64)

    def locate(self, keys: np.ndarray) -> np.ndarray:
        """Local indices of active extra nodes given their keys (any shape); KeyError if one
        is not active here."""
        found, local = self._find(keys)
        if not found.all():
            raise KeyError(int(np.asarray(keys)[~found].flat[0]))
        return local

    def _find(self, keys: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(active here?, local index where active) of ``keys``, from a sorted copy of
        ``index`` made on first use after a change."""
        if self._sorted is None:
            known = np.fromiter(self.index.keys(), dtype=np.int64, count=len(self.index))
            local = np.fromiter(self.index.values(), dtype=np.int64, count=len(self.index))
            order = np.argsort(known)
            self._sorted = (known[order], local[order])
        return sorted_lookup(self._sorted, keys)

    def _base_owners(self, global_nodes: np.ndarray) -> np.ndarray:
        """Rank owning each of an array of global base nodes (this rank or a ghost's owner):
        the rank that owns the extra nodes of their columns."""
        found, local = sorted_lookup(self._base_sorted, global_nodes)
        if not found.all():
            raise KeyError("extra nodes requested on base nodes this rank does not hold")
        size = self.base_map.size_local
        owners = np.full(len(local), self.comm.rank, dtype=np.int64)
        ghost = local >= size
        owners[ghost] = self.base_map.owners[local[ghost] - size]
        return owners

    def activate(self, keys: np.ndarray, ties: np.ndarray, values: np.ndarray) -> np.ndarray:
        """Collective. Make the extra nodes ``keys`` (unique, int64) active with the initial
        ``values`` (n, 9): u, v, X of each, in mm and mm/s. Where ranks ask for the same node,
        the request with the lowest ``ties`` wins (the same on every rank); keys already active
        here are ignored (an active node keeps its state). Each node is created by the owner of
        its column's base node; the others get it as a ghost. Returns the local indices of this
        rank's newly owned nodes."""
        rank, size = self.comm.rank, self.comm.size
        width = 3 * len(self.VECTOR_NAMES)
        keys = np.asarray(keys, dtype=np.int64)
        order = np.argsort(keys)
        keys = keys[order]
        ties = np.asarray(ties, dtype=np.int64)[order]
        values = np.asarray(values, dtype=np.float64).reshape(len(keys), width)[order]
        fresh = ~self._find(keys)[0]
        keys, ties, values = keys[fresh], ties[fresh], values[fresh]
        owner = self._base_owners(keys // 2 // self.n_interfaces)
        outgoing = [(keys[owner == r], ties[owner == r], values[owner == r]) for r in range(size)]
        incoming = self.comm.alltoall(outgoing)

        # owners create what is asked of them: the lowest tie-break wins
        asked = np.concatenate([batch[0] for batch in incoming])
        asked_ties = np.concatenate([batch[1] for batch in incoming])
        asked_values = np.concatenate([batch[2] for batch in incoming]).reshape(-1, width)
        fresh = ~self._find(asked)[0]
        asked, asked_ties, asked_values = asked[fresh], asked_ties[fresh], asked_values[fresh]
        chosen = lowest_tie_per_key(asked, asked_ties)
        new_keys, new_values = asked[chosen], asked_values[chosen]  # keys ascending
        start = self.n_owned
        self.owned_keys.extend(new_keys.tolist())
        # tell each requester where its nodes live on the owner (known nodes are owned here)
        positions = []
        for batch in incoming:
            found, local = self._find(batch[0])
            positions.append(np.where(found, local, start + np.searchsorted(new_keys, batch[0])))
        answers = self.comm.alltoall(positions)
        new_ghosts = 0
        for r in range(size):
            if r != rank and len(outgoing[r][0]):
                self.ghost_keys.extend(outgoing[r][0].tolist())
                self.ghost_owner.extend([r] * len(outgoing[r][0]))
                self.ghost_owner_index.extend(answers[r].tolist())
                new_ghosts += len(outgoing[r][0])

        old_owned = start
        old_vectors = self.vectors
        old_ghosts = len(self.ghost_keys) - new_ghosts
        self._rebuild_index_map()
        self.vectors = {name: la.vector(self.index_map, bs=3) for name in self.VECTOR_NAMES}
        for name, vector in self.vectors.items():
            new = vector.array.reshape(-1, 3)
            old = old_vectors[name].array.reshape(-1, 3)
            new[:old_owned] = old[:old_owned]
            new[self.n_owned : self.n_owned + old_ghosts] = old[old_owned : old_owned + old_ghosts]
        created = np.arange(start, start + len(new_keys))
        for k, name in enumerate(self.VECTOR_NAMES):
            self.vectors[name].array.reshape(-1, 3)[created] = new_values[:, 3 * k : 3 * k + 3]
        for vector in self.vectors.values():
            vector.scatter_forward()
        return created

    def _rebuild_index_map(self) -> None:
        counts = self.comm.allgather(self.n_owned)
        offsets = np.concatenate([[0], np.cumsum(counts)])
        ghosts = np.array(
            [offsets[o] + p for o, p in zip(self.ghost_owner, self.ghost_owner_index, strict=True)],
            dtype=np.int64,
        )
        owners = np.array(self.ghost_owner, dtype=np.int32)
        self.index_map = common.IndexMap(self.comm, self.n_owned, ghosts, owners, 4719)
        self.index = {key: i for i, key in enumerate(self.owned_keys)}
        self.index.update({key: self.n_owned + j for j, key in enumerate(self.ghost_keys)})
        self._sorted = None


def _global_to_local(index_map: common.IndexMap) -> dict[int, int]:
    globals_ = index_map.local_to_global(
        np.arange(index_map.size_local + index_map.num_ghosts, dtype=np.int32)
    )
    return {int(g): i for i, g in enumerate(globals_)}


@dataclass(frozen=True)
class Subelement:
    """One subelement of a refined cell: plies [first, stop) (0-based). It is bounded below by
    interface ``first`` and above by interface ``stop`` (interface 0 standing for the cell's
    bottom face and n_plies for its top face)."""

    first: int
    stop: int

    @property
    def bottom(self) -> int:
        return self.first

    @property
    def top(self) -> int:
        return self.stop


def subelements(state_row: np.ndarray) -> list[Subelement]:
    """The subelements of a cell from its per-interface states (n_plies - 1,)."""
    n_plies = len(state_row) + 1
    active = [i for i in range(1, n_plies) if state_row[i - 1] != InterfaceState.NONE]
    bounds = [0, *active, n_plies]
    return [Subelement(lo, hi) for lo, hi in itertools.pairwise(bounds)]


@dataclass(frozen=True)
class CellColumns:
    """Base nodes of one cell's four columns: local and global indices, bottom and top."""

    bottom_local: np.ndarray  # (4,)
    top_local: np.ndarray  # (4,)
    bottom_global: np.ndarray  # (4,) int64


def interface_nodes(
    columns: CellColumns, interface: int, node_set: int, n_interfaces: int
) -> list[int]:
    """Keys of the four extra nodes of a cell at an interface (set A or B)."""
    return [int(extra_key(g, interface, node_set, n_interfaces)) for g in columns.bottom_global]


def subelement_nodes(
    state_row: np.ndarray,
    sub: Subelement,
    columns: CellColumns,
    n_plies: int,
    local_extra: dict[int, int],
    n_base: int,
) -> np.ndarray:
    """Combined local indices (8,) of a subelement's nodes, DOLFINx vertex order."""
    n_interfaces = n_plies - 1
    nodes = np.empty(8, dtype=np.int32)
    if sub.bottom == 0:
        nodes[:4] = columns.bottom_local
    else:
        node_set = SET_B if state_row[sub.bottom - 1] == InterfaceState.STRONG else SET_A
        keys = interface_nodes(columns, sub.bottom, node_set, n_interfaces)
        nodes[:4] = [n_base + local_extra[k] for k in keys]
    if sub.top == n_plies:
        nodes[4:] = columns.top_local
    else:
        keys = interface_nodes(columns, sub.top, SET_A, n_interfaces)
        nodes[4:] = [n_base + local_extra[k] for k in keys]
    return nodes


def cohesive_nodes(
    columns: CellColumns, interface: int, n_plies: int, local_extra: dict[int, int], n_base: int
) -> np.ndarray:
    """Combined local indices (8,) of the cohesive element of a strong interface: set A (lower
    face) then set B (upper face), face tensor order = the cell's column order."""
    n_interfaces = n_plies - 1
    lower = interface_nodes(columns, interface, SET_A, n_interfaces)
    upper = interface_nodes(columns, interface, SET_B, n_interfaces)
    return np.array([n_base + local_extra[k] for k in lower + upper], dtype=np.int32)


def subelement_table(states: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Every subelement of cells with interface states ``states`` (n, n_interfaces), as
    (row of ``states``, first ply, stop ply) arrays: cells in order, each bottom to top, as
    ``subelements`` lists them one cell at a time."""
    n, n_interfaces = states.shape
    bounds = np.ones((n, n_interfaces + 2), dtype=bool)
    bounds[:, 1:-1] = states != InterfaceState.NONE
    rows, plies = np.nonzero(bounds)
    same_cell = rows[:-1] == rows[1:]
    return rows[:-1][same_cell], plies[:-1][same_cell], plies[1:][same_cell]


def subelement_nodes_many(
    states: np.ndarray,
    first: np.ndarray,
    stop: np.ndarray,
    bottom_local: np.ndarray,
    top_local: np.ndarray,
    bottom_global: np.ndarray,
    locate,
    n_base: int,
) -> np.ndarray:
    """Combined local indices (m, 8) of m subelements at once: ``subelement_nodes`` for
    subelement plies first[e]:stop[e] of a cell with interface states ``states[e]`` and column
    nodes ``bottom_local[e]``, ``top_local[e]``, ``bottom_global[e]`` (each (m, 4));
    ``locate`` maps extra-node keys to local indices (``ExtraNodes.locate``)."""
    n_interfaces = states.shape[1]
    n_plies = n_interfaces + 1
    nodes = np.empty((len(first), 8), dtype=np.int32)
    on_base = first == 0
    nodes[on_base, :4] = bottom_local[on_base]
    inner = np.flatnonzero(~on_base)
    if len(inner):
        below = first[inner]
        strong = states[inner, below - 1] == InterfaceState.STRONG
        keys = extra_keys(
            bottom_global[inner],
            below[:, None],
            np.where(strong, SET_B, SET_A)[:, None],
            n_interfaces,
        )
        nodes[inner, :4] = n_base + locate(keys)
    on_base = stop == n_plies
    nodes[on_base, 4:] = top_local[on_base]
    inner = np.flatnonzero(~on_base)
    if len(inner):
        keys = extra_keys(bottom_global[inner], stop[inner][:, None], SET_A, n_interfaces)
        nodes[inner, 4:] = n_base + locate(keys)
    return nodes


def cohesive_nodes_many(
    interfaces: np.ndarray, bottom_global: np.ndarray, n_interfaces: int, locate, n_base: int
) -> np.ndarray:
    """``cohesive_nodes`` of m strong interfaces at once (cells' ``bottom_global`` (m, 4))."""
    lower = extra_keys(bottom_global, interfaces[:, None], SET_A, n_interfaces)
    upper = extra_keys(bottom_global, interfaces[:, None], SET_B, n_interfaces)
    return (n_base + locate(np.hstack([lower, upper]))).astype(np.int32)


def describe_cell(
    state_row: np.ndarray,
    columns: CellColumns,
    n_plies: int,
    local_extra: dict[int, int] | None = None,
    n_base: int | None = None,
) -> str:
    """Human-readable gather/scatter maps of one cell (the paper's projection matrices as index
    lists): which plies each subelement holds and which nodes are its local nodes 0-7."""
    n_interfaces = n_plies - 1
    lines = [
        "interface states: "
        + ", ".join(
            f"{i}: {InterfaceState(int(s)).label}" for i, s in enumerate(state_row, start=1)
        )
    ]

    def name(kind: str, where: int, node_set: int | None = None) -> list[str]:
        if kind == "bottom":
            return [f"base {int(n)}" for n in columns.bottom_local]
        if kind == "top":
            return [f"base {int(n)}" for n in columns.top_local]
        keys = interface_nodes(columns, where, node_set, n_interfaces)
        label = "AB"[node_set]
        if local_extra is None:
            return [f"extra i{where}{label}@{int(g)}" for g in columns.bottom_global]
        return [f"extra {n_base + local_extra[k]} (i{where}{label})" for k in keys]

    for s, sub in enumerate(subelements(state_row)):
        bottom_set = (
            SET_B if sub.bottom and state_row[sub.bottom - 1] == InterfaceState.STRONG else SET_A
        )
        bottom = name("bottom", 0) if sub.bottom == 0 else name("extra", sub.bottom, bottom_set)
        top = name("top", 0) if sub.top == n_plies else name("extra", sub.top, SET_A)
        plies = ", ".join(str(p + 1) for p in range(sub.first, sub.stop))
        lines.append(f"subelement {s + 1}: plies {plies}  (P^sublam,{s + 1})")
        for k, node in enumerate(bottom + top):
            lines.append(f"    local node {k} <- {node}")
    for i in range(1, n_plies):
        if state_row[i - 1] == InterfaceState.STRONG:
            lines.append(f"cohesive element at interface {i}  (P^coh,{i})")
            nodes = name("extra", i, SET_A) + name("extra", i, SET_B)
            for k, node in enumerate(nodes):
                lines.append(f"    local node {k} <- {node}")
    return "\n".join(lines)
