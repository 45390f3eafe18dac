"""Refinement indicators: which cells refine, at which interfaces, weak or strong (paper,
"Adaptivity").

Units: N, mm, s, tonne (stresses MPa).

- ``ply_failure`` (weak): a ply's Hashin index (``ply_damage.hashin_indices``: exposure
  factors, 1 = failure, fibre or matrix) reaches a fraction of 1 in a cell: the refinable
  interfaces nearest below and above that ply refine weakly, for a better through-thickness
  field around it (the paper: the bottom 0/90 interface refines when the lowermost ply fails).
- ``interface_stress`` (strong): the cohesive initiation criterion
  sqrt((<sigma_zz>/N)^2 + (tau/S)^2), evaluated at an interface with the out-of-plane stresses
  of ``interlaminar.interlaminar_stresses``, reaches a fraction of 1 (equilibrium recovery
  taken onto the face tractions and the cell's own resultants; that module says how), or,
  with ``look_ahead``, the index predicted for the time a refinement takes to act
  (``IndexHistory``).
- ``matrix_damage`` (strong): matrix damage has started in a ply next to a delaminable
  interface (matrix-crack-induced delamination).
- manual: at a time or a probe displacement, in an x range (the paper's TCB); see ``Manual``.
Refinement spreads to ``spread`` rings of neighbouring cells (cells sharing a node) and is never
undone. The ply fields the indicators read are ``ply_fields``'; their names are re-exported
here, as are the interlaminar estimate's.
"""

from __future__ import annotations

import math

import numpy as np
from dolfinx import la
from numba import njit

from fenics_adaptive.adaptivity.events import Reasons, note
from fenics_adaptive.adaptivity.interlaminar import (
    face_geometry,
    face_tractions,
    initiation_index,
    interface_initiation,
    interlaminar_stresses,
    recovered_interface_stresses,
)
from fenics_adaptive.adaptivity.ply_fields import (
    ElementData,
    element_data,
    ply_failure_indices,
    ply_shear_scale,
    ply_strains,
    ply_stresses,
    to_material_frame,
)
from fenics_adaptive.materials.cohesive import cohesive_zone_length
from fenics_adaptive.materials.ply_damage import S_D
from fenics_adaptive.parallel.reductions import summed
from fenics_adaptive.settings.adaptivity import IndicatorSettings
from fenics_adaptive.settings.kinds import InterfaceState

__all__ = [
    "SNAPSHOTS_PER_LEAD",
    "ElementData",
    "IndexHistory",
    "default_interval",
    "element_data",
    "face_tractions",
    "front_distances",
    "front_requests",
    "indicator_requests",
    "initiation_index",
    "interface_initiation",
    "interlaminar_stresses",
    "ply_failure_indices",
    "ply_shear_scale",
    "ply_strains",
    "ply_stresses",
    "recovered_interface_stresses",
    "spread",
    "sublaminate_thicknesses",
    "to_material_frame",
]


# ---------------------------------------------------------------------------- decisions
def indicator_requests(
    structure,
    settings: IndicatorSettings,
    strengths: tuple[float, float],
    t: float = 0.0,
    reasons: Reasons | None = None,
    face_force: np.ndarray | None = None,
    history: IndexHistory | None = None,
):
    """The refinements the indicators ask for on this rank's cells at time t: (cell,
    interface, kind). ``strengths``: the cohesive law's normal and shear strengths (MPa).
    ``reasons``: when given, each request's indicator and value are noted in it (``note``).
    ``face_force``: the supports' and contact forces on the base DOFs (N, owned), for the
    interlaminar estimate (``interlaminar_stresses``). ``history``: when given, the interface
    stress indicator also refines where the index predicted one lead time ahead
    (``IndexHistory.predict``, which keeps the index) reaches its threshold: noted as
    ``look_ahead`` with the predicted index where the present one has not.
    Collective (the stress recovery averages over neighbouring cells on all ranks)."""
    requests = []
    state = structure.interface_state
    if settings.strong_after is not None:
        for interface in structure.interfaces.delaminate:
            due = (state[:, interface - 1] == InterfaceState.WEAK) & (
                structure.weak_since[:, interface - 1] + settings.strong_after <= t
            )
            asked = [(int(c), interface, InterfaceState.STRONG) for c in np.flatnonzero(due)]
            waited = t - structure.weak_since[[c for c, _, _ in asked], interface - 1]
            note(reasons, asked, "strong_after", waited)
            requests += asked
    if settings.ply_failure is not None:
        index = ply_failure_indices(structure)
        weak = sorted(set(structure.interfaces.refine) | set(structure.interfaces.delaminate))
        for ply in range(index.shape[1]):
            cells = np.flatnonzero(index[:, ply] >= settings.ply_failure)
            # the refinable interfaces nearest below (<= ply) and above (>= ply + 1) the ply
            below = [i for i in weak if i <= ply]
            above = [i for i in weak if i >= ply + 1]
            for interface in ([below[-1]] if below else []) + ([above[0]] if above else []):
                todo = cells[state[cells, interface - 1] == InterfaceState.NONE]
                asked = [(int(c), interface, InterfaceState.WEAK) for c in todo]
                note(reasons, asked, "ply_failure", index[todo, ply])
                requests += asked
    if settings.matrix_damage:
        damage = structure.damage_state[:, :, S_D]
        for interface in structure.interfaces.delaminate:
            cracked = (damage[:, interface - 1] > 0.0) | (damage[:, interface] > 0.0)
            todo = np.flatnonzero(cracked & (state[:, interface - 1] < InterfaceState.STRONG))
            asked = [(int(c), interface, InterfaceState.STRONG) for c in todo]
            worst = np.maximum(damage[todo, interface - 1], damage[todo, interface])
            note(reasons, asked, "matrix_damage", worst)
            requests += asked
    if settings.interface_stress is not None:
        at = structure.interfaces.delaminate  # (the estimate at these boundaries alone)
        estimate = interlaminar_stresses(structure, t, face_force, boundaries=at)
        index = initiation_index(estimate, *strengths)
        predicted = history.predict(t, index) if history is not None else index
        for j, interface in enumerate(sorted(set(at))):
            unbroken = state[:, interface - 1] < InterfaceState.STRONG
            now = index[:, j] >= settings.interface_stress
            ahead = (predicted[:, j] >= settings.interface_stress) & ~now
            for flagged, name, value in (
                (now, "interface_stress", index[:, j]),
                (ahead, "look_ahead", predicted[:, j]),  # (by the prediction alone)
            ):
                todo = np.flatnonzero(flagged & unbroken)
                asked = [(int(c), interface, InterfaceState.STRONG) for c in todo]
                note(reasons, asked, name, value[todo])
                requests += asked
    return requests


# the look-ahead keeps its past indices at least lead / this apart (``IndexHistory``): a bound
# on their number (a long release window with a short interval would keep thousands)
SNAPSHOTS_PER_LEAD = 32


class IndexHistory:
    """The interface-stress initiation index (``initiation_index``, (owned cells, delaminable
    interfaces)) at the past indicator evaluations, for the look-ahead rule (``[indicators]
    look_ahead``): a cell refines strongly when its index *predicted* one lead time ahead
    reaches the threshold,

        predicted(t) = I(t) + max(0, I(t) - I(t - lead)),

    the rise of the last lead time continued over the next. The lead is the time a decision
    takes to act: the interval between evaluations (a cell that crosses just after one waits for
    the next) plus the stabilisation's release window (the new crack's tie force fades over
    it). A fixed margin below 1 covers a slow rise and misses a fast one (docs/indicators.md:
    at 0.9 alone, the plate impact's interface 4 refined late and burst 6-10 us after the
    layerwise one, at a higher force); with the prediction the margin below 1 is left to cover
    the estimate's own lag behind the stress it stands for. Without a window the prediction is
    the index one interval ahead, nearly the present one. I(t - lead) is interpolated linearly
    in time between the snapshots around it, the present one included; before the first
    snapshot the first is taken (a run from rest: predicted = 2 I - I(0) while t < lead, a
    prediction over t, not over a whole lead). An oscillation of amplitude A, or a jump of the
    estimate (a neighbour's refinement changes the column averages it is recovered from), can
    raise the prediction by up to 2 A, or the jump, for one lead: on the demos every cell it
    flagged was flagged without it too, a little later.

    Kept: the snapshots within the last lead time and one older, at least lead /
    ``SNAPSHOTS_PER_LEAD`` apart (a later one replaces the last where they would be closer).
    Per owned cell: local to the rank; ``state()`` goes into each rank's checkpoint.

    ``lead``: s. ``times`` (s) and ``snapshots`` ((cells, interfaces) each): a ``state()``'s,
    to go on from."""

    def __init__(self, lead: float, times=(), snapshots=()):
        if not (math.isfinite(lead) and lead >= 0.0):
            raise ValueError(f"IndexHistory: the lead time must be >= 0 s, not {lead!r}")
        self.lead = lead
        self.times: list[float] = [float(x) for x in times]
        self.snapshots: list[np.ndarray] = [np.array(x, dtype=float) for x in snapshots]

    def past(self, t: float) -> np.ndarray | None:
        """The index at time ``t`` (s), interpolated between the snapshots around it (the
        first before them, the last after them); None without snapshots."""
        times = self.times
        if not times:
            return None
        if t <= times[0]:
            return self.snapshots[0]
        if t >= times[-1]:
            return self.snapshots[-1]
        k = int(np.searchsorted(times, t, side="right"))  # times[k - 1] < t <= times[k]
        w = (t - times[k - 1]) / (times[k] - times[k - 1])
        return (1.0 - w) * self.snapshots[k - 1] + w * self.snapshots[k]

    def predict(self, t: float, index: np.ndarray) -> np.ndarray:
        """The index predicted at t + lead from ``index``, the one at t (s), which is kept as
        the snapshot at t (replacing any at t or later: a run restored to an earlier time)."""
        index = np.asarray(index, dtype=float)
        times, snapshots = self.times, self.snapshots
        while times and times[-1] >= t:
            times.pop()
            snapshots.pop()
        if len(times) >= 2 and t - times[-2] < self.lead / SNAPSHOTS_PER_LEAD:
            times.pop()
            snapshots.pop()
        times.append(float(t))
        snapshots.append(index.copy())
        # (with the present snapshot in: evaluations further apart than the lead interpolate
        # between the last one and now, not continue the whole gap's rise over one lead)
        predicted = index + np.maximum(0.0, index - self.past(t - self.lead))
        while len(times) >= 2 and times[1] <= t - self.lead:  # what no later call reads
            del times[0], snapshots[0]
        return predicted

    def state(self) -> dict[str, np.ndarray]:
        """The snapshots' times (s) and the snapshots (n, cells, interfaces)."""
        shape = self.snapshots[0].shape if self.snapshots else (0, 0)
        return {
            "times": np.array(self.times, dtype=float),
            "snapshots": np.array(self.snapshots, dtype=float).reshape(len(self.times), *shape),
        }


def sublaminate_thicknesses(laminate, delaminate: tuple[int, ...]) -> np.ndarray:
    """(n_plies - 1,) mm: at each ply interface, the thinner of the two sublaminates it
    separates once every interface in ``delaminate`` (1-based) has split: the plies up to the
    next delaminable interface (or face) below and above."""
    t = np.array([p.thickness for p in laminate.plies])
    z = np.concatenate([[0.0], np.cumsum(t)])
    bounds = np.array(sorted({0, len(t), *delaminate}))
    out = np.zeros(len(t) - 1)
    for interface in range(1, len(t)):
        below = bounds[bounds < interface].max()
        above = bounds[bounds > interface].min()
        out[interface - 1] = min(z[interface] - z[below], z[above] - z[interface])
    return out


def front_distances(structure, law, distance: float | None = None) -> np.ndarray:
    """(n_plies - 1,) mm: how far around a started delamination each interface refines
    strongly (``front_requests``); 0 where the interface may not delaminate. ``distance``: the
    user's, or None for each interface's own: the length of its process zone when fully grown
    (``cohesive.cohesive_zone_length`` of ``law``, with the larger transverse modulus of the
    two plies it joins) plus two thicknesses of the thinner sublaminate it separates. The zone
    then develops inside the refined region, and ahead of it the band where the peel and shear
    stresses of the bonded part decay (over a few thicknesses of the more compliant, thinner
    arm: a beam on an elastic foundation, a film on a substrate) is refined as well, so that the
    border constraint, which holds the interface to the unrefined neighbour's kinematics, acts
    on neither."""
    return laminate_front_distances(
        structure.laminate, structure.interfaces.delaminate, law, distance
    )


def laminate_front_distances(
    laminate, delaminate, law, distance: float | None = None
) -> np.ndarray:
    """``front_distances`` of a ``laminate`` whose interfaces ``delaminate`` (1-based) may
    delaminate, before any structure is built (the partition's weights:
    ``parallel.balance.film_cost``)."""
    plies = laminate.plies
    out = np.zeros(len(plies) - 1)
    delaminate = tuple(delaminate)
    if distance is not None:
        out[[i - 1 for i in delaminate]] = distance
        return out
    sublaminate = sublaminate_thicknesses(laminate, delaminate)
    for i in delaminate:
        modulus = max(plies[i - 1].material.E2, plies[i].material.E2)
        out[i - 1] = cohesive_zone_length(law, modulus) + 2.0 * sublaminate[i - 1]
    return out


def default_interval(structure) -> float:
    """Time (s) between indicator evaluations when the config gives none: the time a shear
    wave, sqrt(G12 / rho) of the slowest ply, takes to cross the narrowest band that
    ``front_distances`` keeps refined ahead of a process zone (two thicknesses of the thinner
    sublaminate at an interface that may refine). No delamination front runs faster than that
    wave, so between two evaluations a front cannot cross the band."""
    plies = structure.laminate.plies
    interfaces = sorted(set(structure.interfaces.refine) | set(structure.interfaces.delaminate))
    if interfaces:
        thick = sublaminate_thicknesses(structure.laminate, tuple(interfaces))
        band = 2.0 * min(thick[i - 1] for i in interfaces)
    else:
        band = 2.0 * structure.laminate.thickness
    speed = min(math.sqrt(p.material.G12 / p.material.rho) for p in plies)
    return band / speed


@njit(cache=True)
def _nearest_within(points, sources, reach, out):
    """out[k]: distance from points[k] to the nearest of ``sources`` (sorted by x), inf if none
    lies within ``reach``: only the sources whose x lies within reach are measured."""
    n = sources.shape[0]
    for k in range(points.shape[0]):
        x = points[k, 0]
        lo, hi = 0, n
        while lo < hi:  # first source with x >= x - reach
            mid = (lo + hi) // 2
            if sources[mid, 0] < x - reach:
                lo = mid + 1
            else:
                hi = mid
        best = np.inf
        j = lo
        while j < n and sources[j, 0] <= x + reach:
            d = np.sqrt(
                (sources[j, 0] - x) ** 2
                + (sources[j, 1] - points[k, 1]) ** 2
                + (sources[j, 2] - points[k, 2]) ** 2
            )
            if d < best:
                best = d
            j += 1
        out[k] = best if best <= reach else np.inf


def front_requests(
    structure,
    distances: np.ndarray,
    reasons: Reasons | None = None,
    known: np.ndarray | None = None,
) -> tuple[list[tuple[int, int, int]], np.ndarray]:
    """Collective: strong refinements that keep every started delamination inside the refined
    region: at each interface i, the cells whose centroid lies within ``distances[i - 1]``
    (mm, ``front_distances``) of the centroid of a cell whose cohesive element there has
    damage > 0 (on any rank), and at least the cells that share a node with such a cell
    (where the cells are larger than the distance: else no cell would be kept ahead of the
    front, and the border constraint of the refined region would hold its process zone),
    not yet strong there. Noted in ``reasons``, when given, as ``front`` with the distance
    (mm) to the nearest such cell (NaN for a touching cell beyond the distance).

    ``known``: the started (cell, interface) pairs, as keys ``cell * n_plies + interface``
    (sorted, this rank's), whose surroundings an earlier call asked for and that were all
    refined since: only the others are searched around (refinement is never undone and the
    centroids do not move, so the cells around a known one are strong already). Returns the
    requests and the keys known after this call (give them to the next one once the requests
    are refined)."""
    state = structure.interface_state
    centroids = face_geometry(structure).centroids
    cells, interfaces, rows = element_data(structure).cohesive_rows.T
    damaged = structure.cohesive.damage[rows].max(axis=1) > 0.0
    # (the few damaged elements first: the set operations then run on them, not on all)
    candidates = np.flatnonzero((distances[interfaces - 1] > 0.0) & damaged)
    cells, interfaces = cells[candidates], interfaces[candidates]
    n = state.shape[1] + 1
    keys = cells * n + interfaces
    known = np.zeros(0, np.int64) if known is None else known
    hit = ~np.isin(keys, known, assume_unique=True)
    if hit.any():
        known = np.union1d(known, keys[hit]).astype(np.int64)
    started = {int(i): cells[hit & (interfaces == i)] for i in np.unique(interfaces[hit])}
    # every rank takes part, whatever it holds: the interfaces in order, one gather each
    everywhere = structure.comm.allgather(sorted(started))
    if not any(everywhere):  # nothing started anywhere since the last call
        return [], known
    requests = []
    for interface in sorted(set().union(*everywhere)):
        local = centroids[started.get(interface, np.zeros(0, np.int64))].reshape(-1, 3)
        sources = np.vstack(structure.comm.allgather(local))
        sources = np.ascontiguousarray(sources[np.argsort(sources[:, 0], kind="stable")])
        nearest = np.empty(len(centroids))
        _nearest_within(centroids, sources, distances[interface - 1], nearest)
        todo = np.flatnonzero(
            np.isfinite(nearest) & (state[:, interface - 1] < InterfaceState.STRONG)
        )
        asked = [(int(c), interface, InterfaceState.STRONG) for c in todo]
        note(reasons, asked, "front", nearest[todo])
        requests += asked
    # the cells touching a started delamination (one ring, collective on every rank)
    damaged = np.concatenate([np.zeros(0, np.int64), *started.values()]).astype(np.int64)
    at = np.concatenate(
        [np.zeros(0, np.int64), *(np.full(len(c), i) for i, c in started.items())]
    ).astype(np.int64)
    strong = np.full(len(damaged), int(InterfaceState.STRONG), dtype=np.int64)
    cells, interfaces, _ = spread_arrays(structure, damaged, at, strong, 1)
    already = np.array([c * n + i for c, i, _ in requests], dtype=np.int64)
    new = (state[cells, interfaces - 1] < InterfaceState.STRONG) & ~np.isin(
        cells * n + interfaces, already
    )
    touching = [
        (c, i, int(InterfaceState.STRONG))
        for c, i in zip(cells[new].tolist(), interfaces[new].tolist(), strict=True)
    ]
    note(reasons, touching, "front")  # (no distance: a neighbour, however far its centroid)
    return requests + touching, known


# ---------------------------------------------------------------------------- spreading
def spread(structure, requests: list[tuple[int, int, int]], rings: int) -> list:
    """Add the cells sharing a node with a requested cell (``rings`` times), with the same
    interface and kind. Collective (neighbours may live on other ranks)."""
    asked = np.asarray(requests, dtype=np.int64).reshape(-1, 3)
    cells, interfaces, kinds = spread_arrays(structure, *asked.T, rings)
    return list(zip(cells.tolist(), interfaces.tolist(), kinds.tolist(), strict=True))


def spread_arrays(
    structure, cells: np.ndarray, interfaces: np.ndarray, kinds: np.ndarray, rings: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``spread`` on arrays: the (cells, interfaces, kinds) (int64) that share a node with the
    given ones, ``rings`` times (the given ones included), by cell, then kind, then interface.
    Collective."""
    n_interfaces = structure.interface_state.shape[1]
    nodes = structure.cell_nodes
    # (contiguous copies: the kernels' argument types stay the same, the caller's arrays
    # are not handed back; the kernels do not check bounds, so the values are checked here)
    cells, interfaces, kinds = (
        np.array(a, dtype=np.int64, order="C").reshape(-1) for a in (cells, interfaces, kinds)
    )
    if not (len(cells) == len(interfaces) == len(kinds)):
        raise ValueError("spread: one interface and one kind per cell")
    for what, values, low, high in (
        ("cell", cells, 0, len(nodes) - 1),
        ("interface", interfaces, 1, n_interfaces),
        ("kind", kinds, int(InterfaceState.WEAK), int(InterfaceState.STRONG)),
    ):
        if len(values) and (values.min() < low or values.max() > high):
            raise ValueError(f"spread: a {what} outside {low} .. {high}")
    for _ in range(rings):
        if not summed(structure.comm, [len(cells)])[0]:
            break
        marks = face_geometry(structure).sums_vector(structure, 2 * n_interfaces)
        table = marks.array.reshape(-1, 2 * n_interfaces)
        _mark_nodes(nodes, cells, (kinds - 1) * n_interfaces + interfaces - 1, table)
        marks.scatter_reverse(la.InsertMode.add)  # (a ghost's marks reach its owner, and back)
        marks.scatter_forward()
        cells, marked = _marked_cells(nodes, table)
        kinds, interfaces = np.divmod(marked, n_interfaces)
        kinds += 1
        interfaces += 1
    return cells, interfaces, kinds


@njit(cache=True)
def _mark_nodes(nodes, cells, columns, table):
    """table[node, columns[k]] = 1 for every node of every cell ``cells[k]``."""
    for k in range(cells.shape[0]):
        for a in range(nodes.shape[1]):
            table[nodes[cells[k], a], columns[k]] = 1.0


@njit(cache=True)
def _marked_cells(nodes, table):
    """(cells, columns): every (cell, column of ``table``) for which a node of the cell is
    marked there, by cell, then column."""
    marked = np.zeros(table.shape[0], dtype=np.bool_)
    for node in range(table.shape[0]):
        for j in range(table.shape[1]):
            if table[node, j] > 0.0:
                marked[node] = True
                break
    hit = np.zeros(table.shape[1], dtype=np.bool_)
    count = 0
    for step in range(2):  # count, then fill
        if step == 1:
            cells = np.empty(count, dtype=np.int64)
            columns = np.empty(count, dtype=np.int64)
            count = 0
        for c in range(nodes.shape[0]):
            near = False
            for a in range(nodes.shape[1]):
                near = near or marked[nodes[c, a]]
            if not near:
                continue
            hit[:] = False
            for a in range(nodes.shape[1]):
                node = nodes[c, a]
                if marked[node]:
                    for j in range(table.shape[1]):
                        if table[node, j] > 0.0:
                            hit[j] = True
            for j in range(table.shape[1]):
                if hit[j]:
                    if step == 1:
                        cells[count] = c
                        columns[count] = j
                    count += 1
    return cells, columns
