"""Equilibration: a refinement's new degrees of freedom put where the refined cells are in
equilibrium with what held them before.

Units: N, mm, s, tonne.

Why. A refinement places its new extra nodes on the straight line of the element they split
(``Structure._activate_weak``): the ESL field, linear through the sublaminate. That field is
not in equilibrium ply by ply. The ESL element spreads its transverse shear evenly through the
thickness (with the laminate's shear correction); the subelements of plies of different
stiffness need a zig-zag to carry one shear flow, and a strong interface's new cohesive
element carries nothing until its faces have moved apart by traction / penalty. Left where
they are placed, the new nodes carry out-of-balance forces up to 2.5 x the load on a bent
cantilever (``[0/90/90/0]``, tip pushed 2.5 mm), which the explicit solver turns into kinetic
energy within a few steps; the ringing reaches the interfaces' strengths, and the beam that the
layerwise model bends intact delaminated end to end.

What. The moving DOFs F are the free extra DOFs (neither on the border of a refined region nor
prescribed) of the refined cells, every DOF the refinement freed elsewhere (a border node the
region has grown over, a set-B node whose interface is now strong all around), and the base
DOFs of the refined cells; of these, those that no motion prescribes and no contact presses
(a contact's stiffness is not in the tangent). With every other DOF held, F solves the
linearised balance

    K_FF du_F = f_target,F - f_int,F(u)

once or a few times (``ITERATIONS``), with targets that leave the acceleration of every DOF
of F as it was (``_kept_force``; the held DOFs around take the change of the forces their
moved neighbours put on them): a DOF that was free (extra or base) keeps the internal force it
had, changed by the face loads a refined side face moves onto the new nodes and by the
inertia of the mass the new nodes take off it, f + (f_ext,now - f_ext,before) + (m_before -
m_now) a (whatever else acts on it, contact or a tie, stays as it was); a freed one carries
its load less m a, a the acceleration of the material point it stands for (a set-B node's
set-A partner's, else its column's: the base nodes below and above interpolated at its
interface, as its motion is placed), m the mass the solver divides by. The base DOFs move
because the refined cells are not the ESL cell: held at the ESL's positions, a cantilever's
refined cells carried 156 N at its tip where the ESL carried 140 N, and under finite
kinematics, next to a pushed end whose layerwise interfaces were already softening, the held
base forced the new interfaces open and the beam delaminated end to end
(``tests/test_equilibration.py``). Not in the targets or the tangent: forces that depend on
the positions from outside (a user's springs), and the work the loads do over the jump
(the energy booked is the change of kinetic and strain energy).
K_FF is the tangent of the elements around F: the solid elements' (unrefined cells and
subelements: the small-strain kernel probed with unit displacements, or central differences
of the finite-strain one about u) and the cohesive elements' (central differences of the law
about the current opening, ``cohesive.cohesive_tangents``), with the border DOFs that follow a
moving master carried along (T^T K T). Velocities stay as placed (they keep the momentum).
The strain energy this changes is the refinement's potential change, booked with it
(``RefinementState.book``).

The system is gathered to rank 0 and solved there by LU (a refinement moves a few thousand
DOFs at a time): the same matrix whatever the partition, up to the order of its sums, so that
runs on any number of ranks agree to round-off. A singular tangent (a sublaminate held by
nothing) leaves the DOFs where they are (``Equilibrated.steps`` 0). The probing evaluations
of the internal force leave the damage as it was (``Structure.probing``): the damage belongs
to the balanced state the solver evaluates next. The tangent is that of undamaged plies, kept
through the steps (a modified Newton iteration): where plies are damaged or the kinematics
finite the remainder shrinks by a factor per step rather than vanishing at once.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
from dolfinx import la
from mpi4py import MPI
from petsc4py import PETSc

from fenics_adaptive.adaptivity import enrichment as enr
from fenics_adaptive.materials.cohesive import cohesive_tangents
from fenics_adaptive.model.mass_scaling import distinct_elements, element_stiffness
from fenics_adaptive.settings.materials import P_KN, P_KS, P_N, P_S

if TYPE_CHECKING:
    from fenics_adaptive.model.structure import Structure

# modified-Newton steps at most (the tangent of the first kept: small strain, undamaged plies, is
# exact for most refinements, and a second step mops up the finite-strain or damaged rest)
ITERATIONS = 3
# stop once the largest out-of-balance force is this share of the first one: what is left
# rings that much less (each step costs an evaluation of the internal force)
TOLERANCE = 1e-3
# central-difference step of the cohesive tangent, a share of the law's smaller onset opening
COHESIVE_PROBE = 1e-4
# elements whose tangents are formed at once (24 x 24 each)
CHUNK = 2048


@dataclass(frozen=True)
class Equilibrated:
    """What one equilibration did: ``dofs`` the DOFs it moved (all ranks), ``imbalance`` and
    ``remaining`` the largest out-of-balance force on them (N) before and after, ``steps`` the
    Newton steps taken, ``moved`` the largest correction of a displacement (mm)."""

    dofs: int
    imbalance: float
    remaining: float
    steps: int
    moved: float

    @property
    def settled(self) -> bool:
        """Whether it got down to ``TOLERANCE`` of the first imbalance (not: the balanced
        state lies past an interface's onset, whose softening the tangent does not know, or
        the plies are damaged or strained far: what is left rings)."""
        return self.remaining <= TOLERANCE * self.imbalance


def free_extra_dofs(structure: Structure) -> tuple[np.ndarray, np.ndarray]:
    """This rank's free extra DOFs, owned and ghosts (neither on the border of a refined region
    nor prescribed): (codes 3 key + component, the same on every rank and before and after a
    refinement; flat local DOF indices of the extra block)."""
    extra = structure.extra
    keys = np.array(extra.owned_keys + extra.ghost_keys, dtype=np.int64)
    free = np.ones(3 * len(keys), dtype=bool)
    free[structure.border.dofs - 3 * structure.n_base] = False
    free[structure.extra_prescribed >= 0] = False
    codes = (3 * keys[:, None] + np.arange(3)).ravel()
    dofs = np.flatnonzero(free)
    return codes[dofs], dofs


@dataclass(frozen=True)
class BeforeRefinement:
    """What the equilibration keeps of the state a refinement starts from (``of``, with the
    internal forces evaluated there): the free extra DOFs (codes, ``free_extra_dofs``), and of
    the owned extra and base DOFs the internal force and the face loads (N) and the lumped
    masses (tonne: a refinement moves some onto its new nodes). A refinement appends its new
    extra nodes after the owned ones a rank had: an owned extra DOF keeps its index."""

    free_extra: np.ndarray
    extra_force: np.ndarray
    base_force: np.ndarray
    extra_load: np.ndarray
    base_load: np.ndarray
    extra_mass: np.ndarray
    base_mass: np.ndarray

    @classmethod
    def of(cls, structure: Structure, t: float) -> BeforeRefinement:
        """At time t (s), the internal forces evaluated."""
        n_base, n_extra = len(structure.base_block.mass), 3 * structure.extra.n_owned
        base_load, extra_load = face_loads(structure, t)
        return cls(
            free_extra_dofs(structure)[0],
            structure.f_extra.array[:n_extra].copy(),
            structure.f_base.array[:n_base].copy(),
            extra_load,
            base_load,
            structure.extra_block.mass.copy(),
            structure.base_block.mass.copy(),
        )


def face_loads(structure: Structure, t: float) -> tuple[np.ndarray, np.ndarray]:
    """The face loads (N) at time t (s) on the owned base and extra DOFs."""
    base = np.zeros(len(structure.base.u.x.array))
    extra = np.zeros(3 * structure.extra.n_owned)
    structure.loads.external_force(t, base, extra)
    return base[: len(structure.base_block.mass)], extra


@dataclass(frozen=True)
class _Moving:
    """The DOFs one equilibration moves on this rank (local flat indices, owned and ghosts,
    owned first in each block): ``extra`` and ``base``, their global ids in one numbering
    (extra DOFs first), and how many of each are owned."""

    extra: np.ndarray
    base: np.ndarray
    ids: np.ndarray
    owned_extra: int
    owned_base: int

    @property
    def owned_ids(self) -> np.ndarray:
        n_extra = len(self.extra)
        return np.concatenate(
            [self.ids[: self.owned_extra], self.ids[n_extra : n_extra + self.owned_base]]
        )


def equilibrate(
    structure: Structure,
    before: BeforeRefinement,
    cells: np.ndarray,
    t: float,
    accelerations: tuple[np.ndarray, np.ndarray] | None = None,
    contact: list[np.ndarray] | None = None,
) -> Equilibrated | None:
    """Collective: put in balance at time t (s) the nodes of the refined ``cells`` (owned,
    local): their free extra DOFs, every DOF freed since ``before`` (``BeforeRefinement``)
    and their base DOFs that no motion prescribes and no contact presses (``contact``: the
    contact contributors' forces per block, owned DOFs, N, or None); every other DOF held
    (module docstring). ``accelerations``: the base and extra blocks' (owned DOFs, mm/s^2)
    as the solver had them at t (None: at rest). Returns what it did, None where no rank moves
    any DOF; otherwise the internal forces (and ``internal_forces.energies()``) are left
    evaluated at the final state, the damage as it was."""
    comm = structure.comm
    codes, free = free_extra_dofs(structure)
    freed = ~np.isin(codes, before.free_extra)
    moving = np.zeros(3 * structure.extra.n_local, dtype=bool)
    moving[free[freed]] = True
    moving[free[_in_cells(structure, cells, free)]] = True
    moving = _shared(structure.extra.index_map, moving)
    if contact is not None:  # (the forces of the extra nodes before the refinement)
        moving &= ~_owners_flags(structure.extra.index_map, contact[1] != 0.0)
    base = _moving_base(structure, cells, contact)
    extra = np.flatnonzero(moving)
    dofs = _Moving(
        extra,
        base,
        _global_ids(structure, extra, base),
        int(np.count_nonzero(extra < 3 * structure.extra.n_owned)),
        int(np.count_nonzero(base < len(structure.base_block.mass))),
    )
    total = comm.allreduce(dofs.owned_extra + dofs.owned_base, op=MPI.SUM)
    if not total:
        return None
    was_free = np.zeros(3 * structure.extra.n_local, dtype=bool)
    was_free[free[~freed]] = True
    owned_extra = extra[: dofs.owned_extra]
    base_load, extra_load = face_loads(structure, t)  # (of the refined structure)
    target = np.concatenate(
        [
            _targets(
                structure, owned_extra, was_free[owned_extra], before, accelerations, extra_load
            ),
            _base_targets(structure, base[: dofs.owned_base], before, accelerations, base_load),
        ]
    )
    first = remaining = target - _internal_force(structure, dofs, t)
    size = comm.allreduce(float(np.abs(first).max(initial=0.0)), op=MPI.MAX)
    if size == 0.0:  # nothing out of balance (a structure at rest): nothing to solve
        return Equilibrated(total, 0.0, 0.0, 0, 0.0)
    # the global id of each moving DOF at its combined flat index (base DOFs first), -1 else
    slot = np.full(3 * (structure.n_base + structure.extra.n_local), -1, dtype=np.int64)
    slot[3 * structure.n_base + extra] = dofs.ids[: len(extra)]
    slot[base] = dofs.ids[len(extra) :]
    rows, columns, values = _tangent(structure, _dof_map(structure, slot))
    factor = _Factor(comm, rows, columns, values, dofs.owned_ids)
    u_extra, u_base = structure.extra.vectors["u"].array, structure.base.u.x.array
    largest, moved, steps = size, 0.0, 0
    try:
        while steps < ITERATIONS and largest > TOLERANCE * size:
            correction = factor.solve(remaining, dofs.ids)
            if correction is None:  # (a singular tangent: the DOFs stay where they are)
                break
            u_extra[extra] += correction[: len(extra)]
            u_base[base] += correction[len(extra) :]
            structure.follow_border()  # border DOFs whose masters moved go with them
            change = float(np.abs(correction).max(initial=0.0))
            moved = max(moved, comm.allreduce(change, op=MPI.MAX))
            steps += 1
            remaining = target - _internal_force(structure, dofs, t)
            largest = comm.allreduce(float(np.abs(remaining).max(initial=0.0)), op=MPI.MAX)
    finally:
        factor.free()
    return Equilibrated(total, size, largest, steps, moved)


def _moving_base(
    structure: Structure, cells: np.ndarray, contact: list[np.ndarray] | None
) -> np.ndarray:
    """Collective: the local base DOFs (flat, owned first) of the refined ``cells`` (owned)
    that move: neither prescribed nor pressed by a contact (``contact``, as ``equilibrate``
    takes it), the same on every rank that holds them."""
    index_map = structure.base.V.dofmap.index_map
    nodes = np.concatenate([structure.bottom_local[cells], structure.top_local[cells]], axis=1)
    flags = np.zeros(3 * structure.n_base, dtype=bool)
    flags[(3 * nodes.ravel()[:, None] + np.arange(3)).ravel()] = True
    flags = _shared(index_map, flags)
    held = np.zeros(len(structure.base_block.mass), dtype=bool)
    held[structure.base_block.fixed] = True
    if contact is not None:
        held |= contact[0] != 0.0
    return np.flatnonzero(flags & ~_owners_flags(index_map, held))


def _owners_flags(index_map, owned: np.ndarray) -> np.ndarray:
    """Collective: per local DOF (flat, owned and ghosts, of ``index_map``'s nodes) the flag
    its owner set in ``owned`` (the first owned DOFs; those beyond its length unset)."""
    vector = la.vector(index_map, bs=3)
    vector.array[: len(owned)] = owned
    vector.scatter_forward()
    return vector.array > 0.5


def _global_ids(structure: Structure, extra: np.ndarray, base: np.ndarray) -> np.ndarray:
    """One global numbering of the moving DOFs ``extra`` and ``base`` (local flat indices of
    their blocks): 3 node + component, the base nodes after every extra node."""
    extra_nodes = structure.extra.index_map.local_to_global((extra // 3).astype(np.int32))
    base_map = structure.base.V.dofmap.index_map
    base_nodes = base_map.local_to_global((base // 3).astype(np.int32))
    n_extra = structure.extra.index_map.size_global
    return np.concatenate(
        [
            3 * extra_nodes.astype(np.int64) + extra % 3,
            3 * (n_extra + base_nodes.astype(np.int64)) + base % 3,
        ]
    )


def _in_cells(structure: Structure, cells: np.ndarray, dofs: np.ndarray) -> np.ndarray:
    """(len(dofs),) bool: which local extra DOFs ``dofs`` (flat) belong to a node of the
    subelements of the owned ``cells`` (the only elements with extra nodes)."""
    nodes = structure.subelements.nodes[np.isin(structure.subelement_cells, cells)]
    touched = nodes.ravel().astype(np.int64) - structure.n_base
    inside = np.zeros(structure.extra.n_local, dtype=bool)
    inside[touched[touched >= 0]] = True
    return inside[dofs // 3]


def _shared(index_map, flags: np.ndarray) -> np.ndarray:
    """Collective: per-DOF ``flags`` (local DOFs of ``index_map``'s nodes, flat) set wherever
    any rank set them."""
    vector = la.vector(index_map, bs=3)
    vector.array[:] = flags
    vector.scatter_reverse(la.InsertMode.add)
    vector.scatter_forward()
    return vector.array > 0.5


def _targets(
    structure: Structure,
    owned: np.ndarray,
    was_free: np.ndarray,
    before: BeforeRefinement,
    accelerations: tuple[np.ndarray, np.ndarray] | None,
    extra_load: np.ndarray,
) -> np.ndarray:
    """Collective: the internal force (N) each owned moving DOF ``owned`` (flat) is to carry,
    so that the refinement changes no acceleration. One that ``was_free`` keeps the one it had
    (``before``; whatever else acts on it, contact or a tie, stays as it was). A freed one
    carries its load less m a, a the acceleration of the material point it stands for: for a
    set-B node whose set-A partner was free, the partner's (``accelerations``, the blocks'
    owned DOFs, mm/s^2, before the refinement); else its column's, the base nodes below and
    above interpolated at its interface's thickness fraction (as a new node's motion is
    placed); none at rest (``accelerations`` None). m: the mass the solver divides by.
    ``extra_load``: the face loads (N) on the owned extra DOFs now (``face_loads``)."""
    comm = structure.comm
    target = extra_load[owned]
    if comm.allreduce(accelerations is not None, op=MPI.LOR):
        base = la.vector(structure.base.V.dofmap.index_map, bs=3)
        if accelerations is not None:
            n_owned_base = len(structure.base_block.mass)
            base.array[:n_owned_base] = accelerations[0][:n_owned_base]
        base.scatter_forward()  # (the top node of a column may be a ghost)
        on_base = base.array.reshape(-1, 3)
        n_interfaces = structure.refinement.n_interfaces
        keys = np.array(structure.extra.owned_keys, dtype=np.int64)[owned // 3]
        global_bottom, interface, node_set = enr.key_arrays(keys, n_interfaces)
        bottom = structure.extra.local_base_nodes(global_bottom)
        top = structure.columns.top_of[bottom]
        share = structure.laminate.ply_fractions[interface]
        component = owned % 3
        a = (1.0 - share) * on_base[bottom, component] + share * on_base[top, component]
        if accelerations is not None:
            # a new set-B node moves with its partner (set A: the key below it)
            partner = 3 * (keys - 1) + component
            with_partner = (node_set == enr.SET_B) & np.isin(partner, before.free_extra)
            if with_partner.any():
                local = 3 * structure.extra.locate(keys[with_partner] - 1) + component[with_partner]
                old = accelerations[1]
                known = local < len(old)
                a[np.flatnonzero(with_partner)[known]] = old[local[known]]
        target -= structure.extra_block.mass[owned] * a
    kept = owned[was_free]  # (indices the refinement did not change: ``BeforeRefinement``)
    target[was_free] = _kept_force(
        before.extra_force[kept],
        extra_load[kept] - before.extra_load[kept],
        before.extra_mass[kept] - structure.extra_block.mass[kept],
        accelerations[1][kept] if accelerations is not None else None,
    )
    return target


def _kept_force(
    force: np.ndarray, load_change: np.ndarray, mass_lost: np.ndarray, a: np.ndarray | None
) -> np.ndarray:
    """The internal force (N) that leaves a DOF the acceleration ``a`` (mm/s^2; None: at rest)
    it had with internal force ``force``: m a = f_ext + f_other - f_int before and after, so
    f_int changes by the change of its load (``load_change``, N) and by the inertia of the
    mass it lost (``mass_lost``, tonne). What else acts on it (contact, a tie, a spring) is
    taken as it was."""
    target = force + load_change
    if a is not None:
        target += mass_lost * a
    return target


def _base_targets(
    structure: Structure,
    owned: np.ndarray,
    before: BeforeRefinement,
    accelerations: tuple[np.ndarray, np.ndarray] | None,
    base_load: np.ndarray,
) -> np.ndarray:
    """The internal force (N) each owned moving base DOF ``owned`` (flat) is to carry so that
    its acceleration stays as it was (``_kept_force``: the loads a refined side face moves onto
    the new nodes, ``base_load`` now against ``before``, and the mass the new nodes take off
    it)."""
    return _kept_force(
        before.base_force[owned],
        base_load[owned] - before.base_load[owned],
        before.base_mass[owned] - structure.base_block.mass[owned],
        accelerations[0][owned] if accelerations is not None else None,
    )


def _internal_force(structure: Structure, dofs: _Moving, t: float) -> np.ndarray:
    """Collective: f_int (N) at the owned moving DOFs ``dofs`` (extra, then base) at time t
    (s), the damage left as it was."""
    with structure.probing():
        structure.internal_force(t)
    return np.concatenate(
        [
            structure.f_extra.array[dofs.extra[: dofs.owned_extra]],
            structure.f_base.array[dofs.base[: dofs.owned_base]],
        ]
    )


def _dof_map(structure: Structure, slot: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """How each combined flat DOF moves with the moving ones (``slot``: the global id of
    each, -1 else): (ids (n, 2), weights (n, 2)). A moving DOF is itself; a border DOF
    follows its two masters (T in K_FF = T^T K T), those of them moving; the rest are
    held (id -1)."""
    ids = np.full((len(slot), 2), -1, dtype=np.int64)
    weights = np.zeros((len(slot), 2))
    ids[:, 0] = slot
    weights[:, 0] = slot >= 0
    border = structure.border
    masters = slot[border.masters]
    ids[border.dofs] = masters
    weights[border.dofs] = np.where(masters >= 0, border.weights, 0.0)
    return ids, weights


def _tangent(
    structure: Structure, dof_map: tuple[np.ndarray, np.ndarray]
) -> tuple[np.ndarray, ...]:
    """This rank's share of K_FF as triplets (row id, column id, N/mm), not summed by entry: its
    solid (unrefined cells and subelements) and cohesive elements that move with a moving DOF
    (``dof_map``, ``_dof_map``)."""
    moves = (dof_map[0].reshape(-1, 6) >= 0).any(axis=1)  # per combined node
    parts = []
    nodes, cells, plies = structure.elements()
    solid = np.flatnonzero(moves[nodes].any(axis=1))
    rules = structure.element_rules(plies[solid])
    for start in range(0, len(solid), CHUNK):
        chosen = solid[start : start + CHUNK]
        element_nodes = nodes[chosen].astype(np.int64)
        K = _solid_tangents(structure, element_nodes, cells[chosen], rules[start : start + CHUNK])
        parts.append(_triplets(dof_map, element_nodes, K))
    cohesive = structure.cohesive
    params = cohesive.params
    joined = np.zeros(0, dtype=np.int64)  # (a law without penalties carries nothing)
    if len(cohesive) and params[P_KN] > 0.0 and params[P_KS] > 0.0:
        joined = np.flatnonzero(moves[cohesive.nodes].any(axis=1))
        onset = min(params[P_N] / params[P_KN], params[P_S] / params[P_KS])
        # a small share of the onset opening (the law is linear below it), and never more than
        # a millionth of the laminate's thickness (a law without onset: the static check's)
        cap = 1e-6 * structure.laminate.thickness
        step = min(COHESIVE_PROBE * onset, cap) if onset > 0.0 else cap
    for start in range(0, len(joined), CHUNK):
        chosen = joined[start : start + CHUNK]
        element_nodes = cohesive.nodes[chosen].astype(np.int64)
        X = np.ascontiguousarray(structure.gather(element_nodes, "X"))
        u = np.ascontiguousarray(structure.gather(element_nodes, "u"))
        damage = np.ascontiguousarray(cohesive.damage[cohesive.damage_row[chosen]])
        K = np.empty((len(chosen), 24, 24))
        cohesive_tangents(X, u, params, damage, step, K)
        parts.append(_triplets(dof_map, element_nodes, K))
    if not parts:
        return np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros(0)
    return tuple(np.concatenate(p) for p in zip(*parts, strict=True))


def _solid_tangents(
    structure: Structure, nodes: np.ndarray, cells: np.ndarray, rules: np.ndarray
) -> np.ndarray:
    """(n, 24, 24) N/mm tangents of solid (sub)elements ``nodes`` (n, 8) of owned ``cells`` in
    the global frame: small strain, the kernel's stiffness; finite strain, central differences
    about the current displacements (both with undamaged plies)."""
    frames = structure.base.element_frames(cells)

    def in_frames(name: str) -> np.ndarray:  # the kernels take each element in its frame
        x = structure.gather(nodes, name)
        return np.ascontiguousarray(np.einsum("eij,eaj->eai", frames, x) if len(frames) else x)

    packed = structure.rule_table.packed
    X = in_frames("X")
    if structure.base.finite:
        K = element_stiffness(X, rules, packed, in_frames("u"))
    else:  # each distinct shape once (a structured mesh has a few), the same on every rank
        shapes, first, same = distinct_elements(X, rules, structure.laminate.thickness)
        K = element_stiffness(shapes, rules[first], packed)[same]
    if len(frames):  # K_global = T^T K_local T, T = blockdiag(F, ..., F)
        n = len(K)
        K = K.reshape(n, 8, 3, 8, 3)
        K = np.einsum("eki,eakbl,elj->eaibj", frames, K, frames).reshape(n, 24, 24)
    return K


def _triplets(
    dof_map: tuple[np.ndarray, np.ndarray], nodes: np.ndarray, K: np.ndarray
) -> tuple[np.ndarray, ...]:
    """T^T K T of element matrices ``K`` (n, 24, 24) of elements ``nodes`` (n, 8) between the
    moving DOFs (``_dof_map``), as (row id, column id, value), not yet summed by entry (one
    sort for all, in ``_tangent``)."""
    flat = (3 * nodes[:, :, None] + np.arange(3)).reshape(-1, 24)
    ids, weights = dof_map[0][flat], dof_map[1][flat]  # (n, 24, 2)
    # a second master only where a border DOF follows two (most elements have none)
    masters = range(2) if (ids[:, :, 1] >= 0).any() else range(1)
    rows, columns, values = [], [], []
    for p in masters:
        for q in masters:
            row = np.broadcast_to(ids[:, :, p, None], K.shape)
            column = np.broadcast_to(ids[:, None, :, q], K.shape)
            keep = (row >= 0) & (column >= 0)
            scaled = K * weights[:, :, p, None] * weights[:, None, :, q]
            rows.append(row[keep])
            columns.append(column[keep])
            values.append(scaled[keep])
    return np.concatenate(rows), np.concatenate(columns), np.concatenate(values)


def _summed(rows: np.ndarray, columns: np.ndarray, values: np.ndarray) -> tuple[np.ndarray, ...]:
    """Triplets with repeated (row, column) summed, ordered by row then column."""
    if len(rows) == 0:
        return rows, columns, values
    width = int(columns.max()) + 1
    unique, which = np.unique(rows * width + columns, return_inverse=True)
    summed = np.bincount(which.ravel(), weights=values, minlength=len(unique))
    return unique // width, unique % width, summed


class _Factor:
    """K_FF gathered from every rank and factorised on rank 0 (LU); ``solve`` sends each
    rank the corrections of its DOFs, or None to all where rank 0 found the tangent
    singular."""

    def __init__(self, comm: MPI.Comm, rows, columns, values, owned_ids: np.ndarray):
        """``rows``, ``columns``, ``values``: this rank's share of K_FF (global DOF ids, N/mm);
        ``owned_ids``: the ids of its owned moving DOFs, in the order of the residuals
        ``solve`` will be given."""
        self.comm = comm
        if comm.size > 1:  # each rank's share summed before it travels (smaller messages)
            rows, columns, values = _summed(rows, columns, values)
        gathered = comm.gather((rows, columns, values, owned_ids), root=0)
        self.ksp = self.A = None
        ids = None
        if comm.rank == 0:
            rows, columns, values, self.residual_ids = (
                np.concatenate(part) for part in zip(*gathered, strict=True)
            )
            ids = np.sort(self.residual_ids)
            n = len(ids)
            place = np.zeros(int(ids[-1]) + 1 if n else 0, dtype=PETSc.IntType)
            place[ids] = np.arange(n)  # each id's row (ids are global DOF numbers: few)
            r, c = place[rows], place[columns]
            # PETSc sums the repeated entries (the elements' shares) as it assembles
            self.A = PETSc.Mat().create(comm=PETSc.COMM_SELF)
            self.A.setSizes((n, n))
            self.A.setType(PETSc.Mat.Type.SEQAIJ)
            self.A.setPreallocationCOO(r, c)
            self.A.setValuesCOO(np.ascontiguousarray(values, dtype=PETSc.ScalarType))
            self.A.assemble()
            self.ksp = PETSc.KSP().create(PETSc.COMM_SELF)
            self.ksp.setOperators(self.A)
            self.ksp.setType("preonly")
            self.ksp.getPC().setType("lu")
        self.ids = comm.bcast(ids, root=0)

    def solve(self, residual: np.ndarray, ids: np.ndarray) -> np.ndarray | None:
        """Collective: the corrections (mm) at this rank's moving DOFs ``ids`` (owned and
        ghosts) for the out-of-balance forces ``residual`` (N) at its owned ones (in the order
        of the ``owned_ids`` it gave); None on every rank if the solve failed (a zero pivot:
        a sublaminate held by nothing) or gave a value that is not finite."""
        gathered = self.comm.gather(residual, root=0)
        solution = None
        if self.comm.rank == 0:
            b = np.zeros(len(self.ids))
            b[np.searchsorted(self.ids, self.residual_ids)] = np.concatenate(gathered)
            rhs = PETSc.Vec().createWithArray(b, comm=PETSc.COMM_SELF)
            x = rhs.duplicate()
            try:
                self.ksp.solve(rhs, x)
                if self.ksp.getConvergedReason() > 0 and np.isfinite(x.getArray()).all():
                    solution = x.getArray().copy()
            except PETSc.Error:
                solution = None
            finally:
                rhs.destroy()
                x.destroy()
        solution = self.comm.bcast(solution, root=0)
        if solution is None:
            return None
        return solution[np.searchsorted(self.ids, ids)]

    def free(self) -> None:
        """Release the factorisation (rank 0's)."""
        if self.ksp is not None:
            self.ksp.destroy()
            self.A.destroy()
