"""What a refinement changed, as the solver is told it: one event per refinement that changed
something on some rank.

Units: N, mm, s, tonne (energies in mJ = N mm).

``refine`` (below: ``Structure.refine`` and what it changed) returns a ``RefinementEvent`` (or
``None`` when no rank changed anything; the same answer on every rank, since refinement is
collective). The solver reacts to it in one
place: new work arrays for the grown blocks, the stable step chosen again, the stabilisation of
the new refinement started, the potential energy change booked as internal work. Observers get
the same event.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from fenics_adaptive.settings.kinds import InterfaceState


@dataclass(frozen=True)
class RefinementEvent:
    """One refinement, seen from this rank.

    time: s, when it happened (between two steps).
    cells: this rank's owned cells whose interface state changed (local indices).
    new_weak: this rank's (cell, interface) pairs that became weak, shape (n, 2).
    new_strong: this rank's (cell, interface) pairs that became strong, shape (n, 2).
    new_extra_nodes: extra nodes added, over all ranks.
    energy_change: mJ, mechanical energy (kinetic + strain + stored cohesive) the refinement
        added, over all ranks (lumped masses move, so the kinetic energy changes).
    potential_change: mJ, its strain + stored cohesive part, over all ranks (the solver books it
        as internal work, so that the dissipated energy does not jump).
    """

    time: float
    cells: np.ndarray
    new_weak: np.ndarray = field(default_factory=lambda: np.zeros((0, 2), dtype=np.int64))
    new_strong: np.ndarray = field(default_factory=lambda: np.zeros((0, 2), dtype=np.int64))
    new_extra_nodes: int = 0
    energy_change: float = 0.0
    potential_change: float = 0.0


def refine(structure, requests, t: float = 0.0) -> RefinementEvent | None:
    """Collective: refine ``structure`` (``Structure.refine(requests, t)``; requests: (local
    cell, interface, WEAK or STRONG)) and say what changed as a ``RefinementEvent``, or
    ``None`` when no rank changed anything. t: s. (A structure whose ``refine`` returns the
    event itself is passed through.)"""
    comm = structure.comm
    before = structure.interface_state.copy()
    energy_before = structure.refinement_energy
    extra_before = comm.allreduce(structure.extra.n_owned)
    changed = structure.refine(requests, t)
    if isinstance(changed, RefinementEvent) or not changed:
        return changed or None
    after = structure.interface_state
    weak = np.argwhere((before == InterfaceState.NONE) & (after >= InterfaceState.WEAK))
    strong = np.argwhere((before != InterfaceState.STRONG) & (after == InterfaceState.STRONG))
    weak[:, 1] += 1  # interfaces count from 1
    strong[:, 1] += 1
    return RefinementEvent(
        time=t,
        cells=np.flatnonzero((after != before).any(axis=1)),
        new_weak=weak.astype(np.int64),
        new_strong=strong.astype(np.int64),
        new_extra_nodes=comm.allreduce(structure.extra.n_owned) - extra_before,
        energy_change=structure.refinement_energy - energy_before,
        potential_change=structure.last_refinement_potential,
    )
