"""Gather, compute, scatter: numba loops over subelements and cohesive elements.

Units: N, mm, s, tonne.

Node indices are *combined local* indices: i < n_base is base node i (DOLFINx local node, owned
then ghosts), i >= n_base is extra node i - n_base (see ``enrichment``). Each element gathers
its 8 nodes' reference coordinates and displacements (the paper's P x), calls the element
kernel, and adds its force into the nodal force arrays (P^T f). Forces land on ghost entries
too; the caller's reverse scatter sums them on the owners.

Kinematics: ``add_subelement_forces(..., finite=True)`` evaluates the subelements with the total
Lagrangian (Green-Lagrange) kernel, as the UFL forms of a model built with kinematics =
"finite". The cohesive element needs no switch: its local frame always follows the current
mid-surface (``cohesive``), so it is objective under large rotations as it is.

Sign: ``add_subelement_forces`` adds f^sublam; ``add_cohesive_forces`` subtracts f^coh (paper
Eq. 3: f = f^lam - f^coh, with f^coh the force the tractions apply to the nodes), so both build
the internal force f_int of m a = f_ext - f_int.
"""

from __future__ import annotations

import contextlib
from dataclasses import dataclass, field

import numpy as np
from numba import njit

from fenics_adaptive.element import batched
from fenics_adaptive.element.subelement import (
    PackedRules,
    gather_nodes,
    scatter_add_nodes,
)
from fenics_adaptive.materials.cohesive import H_DISSIPATED, HISTORY, cohesive_element_force_tracked
from fenics_adaptive.settings.materials import P_N, P_S

# elements per kernel call of the interior part of the internal forces: about a millisecond of
# work between two ``progress`` calls (0.5 us per ESL cell, a few us per refined cell's
# subelement; ``internal_forces``)
INTERIOR_CHUNK = 2048


def chunk_bounds(n: int, size: int = INTERIOR_CHUNK) -> list[tuple[int, int]]:
    """[start, stop) of the consecutive chunks of ``size`` of n elements (at least one, maybe
    empty)."""
    return [(start, min(start + size, n)) for start in range(0, max(n, 1), size)]


# MPa: a strength no traction reaches (finite: the onset opening N/K stays a number)
UNREACHABLE_STRENGTH = 1e100


# the frames of elements in the global frame: none (the kernels then rotate nothing)
NO_FRAMES = np.zeros((0, 3, 3))


@dataclass
class SubelementSet:
    """Layered solid-shell (sub)elements computed by numba: nodes (n, 8) combined local
    indices; each uses rule ``rule_of_element`` of ``rules``. ``interior`` (n,) bool: the
    elements the solver computes while the halo exchange is under way (``NodeArrays.interior``;
    None: all). ``order``: the order the batched kernel takes them in, the interior elements
    first, each part grouped by rule (``batched.lane_order``); ``interior_order`` and
    ``boundary_order`` are its two parts. ``frames`` (n, 3, 3): each element's frame on a curved
    shell (its cell's, ``element.geometry.cell_frames``); (0, 3, 3), the default: the global
    frame."""

    nodes: np.ndarray
    rule_of_element: np.ndarray
    rules: PackedRules
    interior: np.ndarray | None = None
    frames: np.ndarray = field(default_factory=lambda: NO_FRAMES)
    order: np.ndarray = field(init=False, repr=False)
    interior_order: np.ndarray = field(init=False, repr=False)
    boundary_order: np.ndarray = field(init=False, repr=False)

    def __post_init__(self) -> None:
        # one type per kernel argument whatever the caller built: an int64 node table (the
        # analysis tools', tests') compiled the batched kernel a second time (3 s here)
        self.nodes = np.ascontiguousarray(self.nodes, dtype=np.int32).reshape(-1, 8)
        self.rule_of_element = np.ascontiguousarray(self.rule_of_element, dtype=np.int64)
        rule = self.rule_of_element
        inner = np.arange(len(rule)) if self.interior is None else np.flatnonzero(self.interior)
        outer = np.flatnonzero(~self.interior) if self.interior is not None else inner[:0]
        self.order = np.concatenate(
            [part[batched.lane_order(rule[part])] for part in (inner, outer)]
        ).astype(np.int64)
        self.interior_order = self.order[: len(inner)]
        self.boundary_order = self.order[len(inner) :]

    @classmethod
    def empty(cls, rules: PackedRules) -> SubelementSet:
        return cls(np.zeros((0, 8), np.int32), np.zeros(0, np.int64), rules)

    def __len__(self) -> int:
        return len(self.nodes)


@dataclass
class CohesiveSet:
    """8-node cohesive elements: nodes (n, 8) combined local indices (lower face, upper face);
    element e keeps its damage history in ``damage[damage_row[e]]`` (4 points), which persists
    when the set is rebuilt."""

    nodes: np.ndarray
    damage_row: np.ndarray
    damage: np.ndarray  # (rows, 4)
    params: np.ndarray  # CohesiveLaw.as_array()
    interface: np.ndarray  # (n,) ply interface (1-based) of each element
    # (rows, 4, cohesive.HISTORY) per point: last local opening, dissipated energy (mJ) and
    # released contact share; persists with ``damage``
    history: np.ndarray | None = None
    # (rows,) the rows of an insert film ([[delamination]]): failed from t = 0, not grown
    insert: np.ndarray | None = None

    def __post_init__(self) -> None:
        # one type per kernel argument (see ``SubelementSet``): the layerwise model's pairs
        # came as int64, the refined cells' as int32, and each compiled the kernel anew
        self.nodes = np.ascontiguousarray(self.nodes, dtype=np.int32).reshape(-1, 8)
        self.damage_row = np.ascontiguousarray(self.damage_row, dtype=np.int64)
        if self.history is None:
            self.history = np.zeros((len(self.damage), 4, HISTORY))
        if self.insert is None:
            self.insert = np.zeros(len(self.damage), dtype=bool)

    @classmethod
    def empty(cls, params: np.ndarray) -> CohesiveSet:
        return cls(
            np.zeros((0, 8), np.int32),
            np.zeros(0, np.int64),
            np.zeros((0, 4)),
            params,
            np.zeros(0, np.int32),
        )

    def dissipated_energy(self) -> float:
        """Energy (mJ) the damage of this rank's cohesive points has dissipated so far."""
        return float(self.history[:, :, H_DISSIPATED].sum())

    def failed(self) -> np.ndarray:
        """Elements whose four points are fully damaged (the delaminated area)."""
        return self.damage[self.damage_row].min(axis=1) >= 1.0

    def inserted(self) -> np.ndarray:
        """Elements of an insert film (delaminated from t = 0, not grown)."""
        return self.insert[self.damage_row]

    def delaminate(self, elements: np.ndarray) -> None:
        """Make ``elements`` an insert film: their four points fully damaged, no energy
        dissipated (the film was never bonded)."""
        rows = self.damage_row[elements]
        self.damage[rows] = 1.0
        self.insert[rows] = True

    def grow_rows(self, n_rows: int) -> None:
        """Damage and history rows for ``n_rows`` (>= the present number) elements; the new rows
        undamaged."""
        grown = np.zeros((n_rows, 4))
        grown[: len(self.damage)] = self.damage
        self.damage = grown
        history = np.zeros((n_rows, *self.history.shape[1:]))
        history[: len(self.history)] = self.history
        self.history = history
        insert = np.zeros(n_rows, dtype=bool)
        insert[: len(self.insert)] = self.insert
        self.insert = insert

    @contextlib.contextmanager
    def linear_elastic(self):
        """Inside the block the law has no damage onset (its strengths out of reach): an
        intact element is a linear spring layer of the penalty stiffnesses, a failed one keeps
        only its compression branch. For static solutions; the damage, history and parameters
        are put back as they were when the block ends."""
        params, state = self.params.copy(), {k: v.copy() for k, v in self.state().items()}
        self.params[P_N] = self.params[P_S] = UNREACHABLE_STRENGTH
        try:
            yield
        finally:
            self.params[:] = params
            self.restore(state)

    def state(self) -> dict[str, np.ndarray]:
        """The history-dependent arrays: {"damage": (rows, 4), "history": (rows, 4, HISTORY),
        "insert": (rows,)}."""
        return {"damage": self.damage, "history": self.history, "insert": self.insert}

    def restore(self, state: dict[str, np.ndarray]) -> None:
        """Put back the damage, history and insert rows of ``state`` (as ``state`` gives them)
        into the rows the set holds (a checkpoint written before inserts existed has none;
        one written before the history's last column, ``cohesive.H_RELEASED``, zeros there)."""
        self.damage[:] = state["damage"]
        history = state["history"]
        # a checkpoint written before the contact's release was tracked: none let go then
        self.history[..., : history.shape[-1]] = history
        self.history[..., history.shape[-1] :] = 0.0
        self.insert[:] = state.get("insert", False)

    def __len__(self) -> int:
        return len(self.nodes)


def add_subelement_forces(
    subelements: SubelementSet,
    X_base: np.ndarray,
    X_extra: np.ndarray,
    u_base: np.ndarray,
    u_extra: np.ndarray,
    f_base: np.ndarray,
    f_extra: np.ndarray,
    finite: bool = False,
    order: np.ndarray | None = None,
) -> float:
    """f += sum_i P_i^T f^sublam_i; returns the strain energy (mJ). Arrays (n, 3). ``finite``:
    total Lagrangian kinematics (Green-Lagrange strain), else small strain. ``order``: the
    elements to compute, in the kernel's order (``subelements.interior_order`` or
    ``boundary_order``); None: all (``subelements.order``)."""
    order = subelements.order if order is None else order
    if len(order) == 0:
        return 0.0
    return batched.add_subelement_forces(
        subelements.nodes,
        order,
        subelements.rule_of_element,
        *subelements.rules,
        X_base,
        X_extra,
        u_base,
        u_extra,
        f_base,
        f_extra,
        bool(finite),
        subelements.frames,
    )


def add_cohesive_forces(
    cohesive: CohesiveSet,
    X_base: np.ndarray,
    X_extra: np.ndarray,
    u_base: np.ndarray,
    u_extra: np.ndarray,
    f_base: np.ndarray,
    f_extra: np.ndarray,
) -> float:
    """f -= sum_i P_i^T f^coh_i, updating the damage history and the dissipated energy
    (``CohesiveSet.history``); returns the stored (recoverable) cohesive energy (mJ). Arrays
    (n, 3)."""
    if len(cohesive) == 0:
        return 0.0
    return _add_cohesive_forces(
        cohesive.nodes,
        cohesive.damage_row,
        cohesive.damage,
        cohesive.history,
        cohesive.params,
        X_base,
        X_extra,
        u_base,
        u_extra,
        f_base,
        f_extra,
    )


@njit(cache=True)
def _add_cohesive_forces(
    element_nodes,
    damage_row,
    damage,
    history,
    params,
    X_base,
    X_extra,
    u_base,
    u_extra,
    f_base,
    f_extra,
):
    n_base = X_base.shape[0]
    X = np.empty((8, 3))
    u = np.empty((8, 3))
    f = np.empty((8, 3))
    stored = 0.0
    for e in range(element_nodes.shape[0]):
        nodes = element_nodes[e]
        gather_nodes(nodes, n_base, X_base, X_extra, X)
        gather_nodes(nodes, n_base, u_base, u_extra, u)
        row = damage_row[e]
        energy, _ = cohesive_element_force_tracked(X, u, params, damage[row], history[row], f)
        stored += energy
        scatter_add_nodes(nodes, n_base, f, -1.0, f_base, f_extra)
    return stored
