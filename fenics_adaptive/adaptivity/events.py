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

import math
from dataclasses import dataclass, field

import numpy as np

from fenics_adaptive.adaptivity.equilibration import Equilibrated
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
    weak_reasons, strong_reasons: why each row of ``new_weak`` / ``new_strong`` refined: a
        ``Reason`` (the indicator that asked and its value).
    equilibrated: what the equilibration of the DOFs it freed did (``Equilibrated``: the same
        on every rank), None if it freed none or the stabilisation settings turn it off.
    """

    time: float
    cells: np.ndarray
    new_weak: np.ndarray = field(default_factory=lambda: np.zeros((0, 2), dtype=np.int64))
    new_strong: np.ndarray = field(default_factory=lambda: np.zeros((0, 2), dtype=np.int64))
    new_extra_nodes: int = 0
    energy_change: float = 0.0
    potential_change: float = 0.0
    weak_reasons: tuple[Reason, ...] = ()
    strong_reasons: tuple[Reason, ...] = ()
    equilibrated: Equilibrated | None = None


@dataclass(frozen=True)
class Reason:
    """Why a (cell, interface) refined.

    indicator: who asked: ``initial``, ``manual``, one of the [indicators] (``ply_failure``,
        ``interface_stress``, ``look_ahead``: the interface stress on its predicted index,
        ``matrix_damage``, ``strong_after``), ``spread`` or ``front``
        (neighbours added around cells that asked), or a Python indicator's name.
    value: what the indicator measured, compared with its threshold (a Hashin or initiation
        index, a predicted one, a matrix damage, the time in s since the interface became
        weak), NaN when it has no value.
    """

    indicator: str
    value: float = math.nan


UNKNOWN = Reason("unknown")

# why each request was made: (cell, interface, kind) -> Reason
Reasons = dict[tuple[int, int, int], Reason]


def note(reasons: Reasons | None, requests, indicator: str, values=None) -> None:
    """Record in ``reasons`` (when given) that ``indicator`` asked for ``requests`` ((cell,
    interface, kind) each), with ``values`` (one per request) or none. A request that an earlier
    indicator already asked for keeps that one's reason."""
    if reasons is None:
        return
    values = [math.nan] * len(requests) if values is None else values
    for request, value in zip(requests, values, strict=True):
        key = tuple(int(x) for x in request)
        if key not in reasons:
            reasons[key] = Reason(indicator, float(value))


def _reasons_of(pairs: np.ndarray, kinds: tuple[int, ...], reasons: Reasons) -> tuple:
    """The reason of each (cell, interface) row of ``pairs``: the first of ``kinds`` asked for."""
    out = []
    for cell, interface in pairs.tolist():
        found = (reasons.get((cell, interface, kind)) for kind in kinds)
        out.append(next((r for r in found if r is not None), UNKNOWN))
    return tuple(out)


def refine(structure, requests, t: float = 0.0, reasons: Reasons | None = None):
    """Collective: refine ``structure`` (``Structure.refine(requests, t)``; requests: (local
    cell, interface, WEAK or STRONG)) and say what changed as a ``RefinementEvent``, or
    ``None`` when no rank changed anything. t: s. ``reasons``: why each request was made (see
    ``note``), carried into the event. (A structure whose ``refine`` returns the event itself is
    passed through.)"""
    comm = structure.comm
    before = structure.interface_state.copy()
    energy_before = structure.refinement_energy
    extra_before = structure.extra.n_owned  # this rank's: summed only if anything changed
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
        new_extra_nodes=comm.allreduce(structure.extra.n_owned - extra_before),
        energy_change=structure.refinement_energy - energy_before,
        potential_change=structure.last_refinement_potential,
        # a strong request on an unrefined interface makes it weak on the way
        weak_reasons=_reasons_of(weak, (InterfaceState.WEAK, InterfaceState.STRONG), reasons or {}),
        strong_reasons=_reasons_of(strong, (InterfaceState.STRONG,), reasons or {}),
        equilibrated=structure.last_equilibrated,
    )
