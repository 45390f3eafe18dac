"""A run's state on another partition: restart on another number of ranks, re-balancing.

A checkpoint holds each rank's arrays in that rank's local order (``io.checkpoint``). To
continue on another partition, each array also says how its rows are indexed, by a *layout*:

- ``Rows(keys, owned)``: row i belongs to the entity with the stable key ``keys[i]`` (the same
  on any partition: ``node_keys``, ``extra_node_keys``, ``cell_keys`` and what is built from
  them); ``owned[i]``: this rank's row is the one to read (a ghost's copy is not);
- ``PARTIAL``: a rank's share of a sum (a work, an energy): the shares of the old ranks are
  added up, old rank r's going to new rank r mod size, so that the totals are kept and the
  same partition gets its own shares back;
- anything else is the same on every rank (``REPLICATED``) and taken from old rank 0.

The new partition's objects give the layouts of their own rows, and ``StoredState.rows``
fills each row from the old rank that owned that key. A refinement log (local cells) is
handed over separately (``refinement_requests``).

Units: none (keys and arrays as their owners store them).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from fenics_adaptive.adaptivity import enrichment as enr

PARTIAL = "partial"
REPLICATED = "replicated"

# how a checkpoint stores a layout next to the array ``name``
KEYS, OWNED = "@keys", "@owned"
PARTIAL_NAMES = "@partial"


@dataclass(frozen=True)
class Rows:
    """The rows of a state array along ``axis``: ``keys`` (n,) int64 stable keys, ``owned``
    (n,) bool (None: all owned). ``fill``: the value of a row whose key no old rank holds
    (None: such a row is an error)."""

    keys: np.ndarray
    owned: np.ndarray | None = None
    axis: int = 0
    fill: float | bool | None = None


Layout = Rows | str


class NotMovable(Exception):
    """The state cannot be moved to another partition now (the message says why)."""


def contributor_layouts(contributors, structure) -> dict[str, Layout]:
    """The layouts of the force contributors' states (``Contributor.state``), by
    ``<name>_<key>``: each contributor's ``layout(structure)``; one without a state has none.
    Raises ``NotMovable`` for one with a state and no ``layout``."""
    out: dict[str, Layout] = {}
    for contributor in contributors:
        if not contributor.state():
            continue
        layout = getattr(contributor, "layout", None)
        if layout is None:
            raise NotMovable(f"the force contributor {contributor.name!r} has no layout")
        out.update({f"{contributor.name}_{k}": v for k, v in layout(structure).items()})
    return out


def node_keys(base) -> np.ndarray:
    """(owned + ghost base nodes,) int64: each local base node's index in the mesh as it was
    generated (``geometry.input_global_indices``), the same on any partition. ``base``: the
    structure's ``LayeredModel``."""
    index_map = base.V.dofmap.index_map
    n_base = index_map.size_local + index_map.num_ghosts
    geometry = base.mesh.geometry
    original = np.asarray(geometry.input_global_indices, dtype=np.int64)
    # a P1 space's node k of a cell sits at the cell's geometry node k (both in vertex order)
    dofs = np.asarray(base.V.dofmap.list).ravel()
    nodes = np.asarray(geometry.dofmaps[0]).ravel()
    out = np.full(n_base, -1, dtype=np.int64)
    out[dofs] = original[nodes]
    return out


def extra_node_keys(structure) -> np.ndarray:
    """(owned + ghost extra nodes,) int64: ``enrichment.extra_key`` of each local extra node
    with its column's bottom base node numbered by ``node_keys`` instead of DOLFINx's global
    numbering (which depends on the partition)."""
    extra = structure.extra
    keys = np.array(extra.owned_keys + extra.ghost_keys, dtype=np.int64)
    if len(keys) == 0:
        return keys
    bottom, interface, node_set = enr.key_arrays(keys, extra.n_interfaces)
    stable_bottom = structure.node_keys[extra.local_base_nodes(bottom)]
    return enr.extra_keys(stable_bottom, interface, node_set, extra.n_interfaces)


def dof_keys(node_key: np.ndarray) -> np.ndarray:
    """(3 n,) the stable keys of the x, y, z DOFs of nodes with stable keys ``node_key``."""
    return (3 * np.asarray(node_key, dtype=np.int64)[:, None] + np.arange(3)).ravel()


def annotate(arrays: dict[str, np.ndarray], layouts: dict[str, Layout]) -> dict:
    """``arrays`` with their ``layouts`` as a checkpoint stores them: ``<name>@keys`` and
    ``<name>@owned`` of each ``Rows`` array, the names of the ``PARTIAL`` ones in
    ``@partial``. A layout of an array the state does not hold now (a look-ahead's snapshots
    before its first evaluation) is left out."""
    out = dict(arrays)
    partial = []
    for name, layout in layouts.items():
        if name not in arrays:
            continue
        if isinstance(layout, Rows):
            keys = np.asarray(layout.keys, dtype=np.int64)
            shape = np.shape(arrays[name])
            if 0 in shape[: layout.axis]:
                continue  # nothing stored (a look-ahead with no snapshot yet): as it is
            if keys.shape != (np.shape(arrays[name])[layout.axis],):
                raise ValueError(f"{name}: {len(keys)} keys for {np.shape(arrays[name])}")
            owned = np.ones(len(keys), bool) if layout.owned is None else layout.owned
            out[name + KEYS], out[name + OWNED] = keys, np.asarray(owned, dtype=bool)
        elif layout == PARTIAL:
            partial.append(name)
    out[PARTIAL_NAMES] = np.array(partial, dtype=str)
    return out


class StoredState:
    """Every old rank's arrays of a checkpoint (``files[r]``: old rank r's), read on a new
    partition of ``size`` ranks."""

    def __init__(self, files: list[dict[str, np.ndarray]], rank: int, size: int):
        self.files, self.rank, self.size = files, rank, size
        self.partial = set(files[0].get(PARTIAL_NAMES, np.zeros(0, str)).tolist())
        self._tables: dict[str, tuple[np.ndarray, np.ndarray, np.ndarray]] = {}

    def names(self, prefix: str) -> list[str]:
        """The arrays whose names start with ``prefix`` (layouts left out)."""
        return [n for n in self.files[0] if n.startswith(prefix) and "@" not in n]

    def keyed(self, name: str) -> bool:
        return name + KEYS in self.files[0]

    def value(self, name: str, layout: Layout | None = None) -> np.ndarray:
        """This rank's ``name``: its rows by ``layout`` for a keyed array, its share of a
        partial sum, else old rank 0's."""
        if self.keyed(name):
            if not isinstance(layout, Rows):
                raise KeyError(f"{name}: stored by rows, but this run has no rows for it")
            return self.rows(name, layout)
        if name in self.partial:
            shares = [f[name] for r, f in enumerate(self.files) if r % self.size == self.rank]
            return np.sum(shares, axis=0) if shares else np.zeros_like(self.files[0][name])
        return self.files[0][name]

    def rows(self, name: str, layout: Rows) -> np.ndarray:
        """(rows of ``layout``, ...) of ``name``: each row from the old rank that owned its
        key. Raises KeyError for a key no old rank owned (unless ``layout.fill``)."""
        keys, values, order = self._table(name, layout.axis)
        wanted = np.asarray(layout.keys, dtype=np.int64)
        where = np.minimum(np.searchsorted(keys, wanted), max(len(keys) - 1, 0))
        found = keys[where] == wanted if len(keys) else np.zeros(len(wanted), dtype=bool)
        if not found.all() and layout.fill is None:
            raise KeyError(f"{name}: {int((~found).sum())} row(s) of this partition not stored")
        shape = (len(wanted), *values.shape[1:])
        out = np.full(shape, layout.fill if layout.fill is not None else 0, dtype=values.dtype)
        out[found] = values[order[where[found]]]
        return np.moveaxis(out, 0, layout.axis)

    def _table(self, name: str, axis: int):
        """(sorted keys, their rows stacked along axis 0, the order that sorts them) of the
        owned rows of every old rank."""
        if name not in self._tables:
            keys, values = [], []
            for f in self.files:
                owned = f[name + OWNED]
                keys.append(f[name + KEYS][owned])
                values.append(np.moveaxis(f[name], axis, 0)[owned])
            keys = np.concatenate(keys)
            order = np.argsort(keys, kind="stable")
            if np.any(np.diff(keys[order]) == 0):
                raise ValueError(f"{name}: a row owned by two ranks")
            self._tables[name] = (keys[order], np.concatenate(values), order)
        return self._tables[name]
