"""Clamps, prescribed motions and face loads (``settings.loads``), resolved to DOFs of a model.

Units: N, mm, s. A face is named by its group in the mesh (``fenics_adaptive.meshes.beam``: x0, x1,
top, x1_layer3, ...). Components are "x", "y", "z".

A face load acts on the facets of its face whose centroid lies in its region: a uniform traction
(total force / area of those facets), or a pressure against the outward normal, shaped along x
by its distribution. It is given to the nodes as the integral of the traction times each
node's shape function over the facets (work-equivalent, ``quad_traction_integrals``): on the
unrefined mesh, and moved by ``ResolvedLoads.refine`` onto the faces of the subelements of
refined cells, whose extra nodes on the face then carry their share (the same integrals, so
the two never disagree). Only side faces change: a refined cell's bottom and top subelements
keep its base nodes on the bottom and top faces. An extra node on the border of a refined
region (bound to masters, ``model.border``) hands its share to its masters with the
constraint's weights, as it does its internal force, so the nodal loads stay work-equivalent on
the constrained field too."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np
from dolfinx import common, fem, la
from mpi4py import MPI

from fenics_adaptive.adaptivity import enrichment as enr
from fenics_adaptive.element.geometry import (
    HEX_FACETS,
    HEX_SIDE_FACETS,
    quad_areas,
    quad_traction_integrals,
)
from fenics_adaptive.errors import InputError, shared_errors
from fenics_adaptive.model.border import BorderConstraints, transfer_forces
from fenics_adaptive.model.forms import LayeredModel
from fenics_adaptive.settings.loads import COMPONENTS, Amplitude, FaceLoad, PrescribedMotion


@dataclass
class ResolvedLoads:
    """The loading as arrays on the DOFs of a model: prescribed DOFs with the index of the
    motion that drives each, and one nodal force vector per face load on the base DOFs and one
    on the extra DOFs (the extra nodes of refined cells on a loaded side face, ``refine``)."""

    motions: list[PrescribedMotion]
    fixed: np.ndarray  # owned base DOFs under a prescribed motion (sorted, unique)
    fixed_motion: np.ndarray  # index into ``motions`` for each fixed DOF
    load_vectors: list[np.ndarray]  # one nodal force vector per FaceLoad (owned + ghosts), N
    load_amplitudes: list[Amplitude]
    # per load: its traction at amplitude 1 and the (owned cell, local facet) pairs of the
    # facets it acts on (refinement moves the share of the side facets among them)
    tractions: list[FaceTraction] = field(default_factory=list)
    facets: list[np.ndarray] = field(default_factory=list)
    # per load: the base vector as assembled on the unrefined mesh, and the extra nodes' share
    # (local extra DOFs, owned + ghosts, N) of the current refinement (``refine``)
    assembled: list[np.ndarray] = field(default_factory=list)
    extra_vectors: list[np.ndarray] = field(default_factory=list)
    # some rank's extra nodes carry load (the same on every rank)
    has_extra: bool = False
    # per load on the bottom or top face: the mean traction (n_owned_cells, 2, 3) N/mm^2 it
    # puts on each owned cell's bottom (0) and top (1) face at amplitude 1
    cell_tractions: list[np.ndarray] = field(default_factory=list)
    # per load: this rank's sum (3,) N of the extra vector's owned entries
    extra_resultants: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    _scratch: np.ndarray | None = None
    _scratch_extra: np.ndarray | None = None

    @property
    def constrained(self) -> np.ndarray:
        return self.fixed

    def cell_face_tractions(self, t: float, n_cells: int) -> np.ndarray:
        """(n_cells, 2, 3) N/mm^2 = MPa: the mean traction the loads put on the bottom (0) and
        top (1) face of each of the ``n_cells`` owned cells at time t (s)."""
        total = np.zeros((n_cells, 2, 3))
        for tractions, amplitude in zip(self.cell_tractions, self.load_amplitudes, strict=True):
            if len(tractions):
                total += amplitude(t) * tractions
        return total

    def external_force(
        self, t: float, out: np.ndarray, out_extra: np.ndarray | None = None
    ) -> None:
        """The loads at time t (s) into ``out`` (base DOFs, owned + ghosts, N) and ``out_extra``
        (the first len(out_extra) local extra DOFs: the owned ones, or all). Raises ValueError
        without ``out_extra`` when the loads reach extra nodes (on any rank): a caller that
        knows only the base DOFs would lose that share of the load."""
        if self.has_extra and out_extra is None:
            raise ValueError(
                "the face loads act on extra nodes of refined cells too: pass out_extra "
                "(the extra DOFs' external force) to ResolvedLoads.external_force"
            )
        self._scratch = _add_scaled(self.load_vectors, self.load_amplitudes, t, out, self._scratch)
        if out_extra is not None:
            # every extra vector has the extra nodes' layout of the last refinement (no loads:
            # no vectors, nothing to check)
            n = len(out_extra)
            if self.extra_vectors and n > len(self.extra_vectors[0]):
                raise ValueError(
                    f"out_extra has {n} DOFs, more than the {len(self.extra_vectors[0])} local "
                    "extra DOFs the loads were refined for (ResolvedLoads.refine after every "
                    "refinement)"
                )
            self._scratch_extra = _add_scaled(
                self.extra_vectors, self.load_amplitudes, t, out_extra, self._scratch_extra
            )

    def extra_resultant(self, t: float) -> np.ndarray:
        """(3,) N: this rank's sum of the loads on its owned extra DOFs at time t (s)."""
        out = np.zeros(3)
        for resultant, amplitude in zip(self.extra_resultants, self.load_amplitudes, strict=True):
            out += amplitude(t) * resultant
        return out

    def extra_force(self, t: float, n: int) -> np.ndarray:
        """(n // 3, 3) N: the loads on the first ``n`` local extra DOFs at time t (s)
        (allocates: for refinement time, not for the time loop)."""
        out = np.zeros(n)
        for vector, amplitude in zip(self.extra_vectors, self.load_amplitudes, strict=True):
            out += amplitude(t) * vector[:n]
        return out.reshape(-1, 3)

    def refine(
        self,
        cell_nodes: np.ndarray,
        subelement_nodes: np.ndarray,
        subelement_cells: np.ndarray,
        positions: Callable[[np.ndarray], np.ndarray],
        border: BorderConstraints,
        base_map: common.IndexMap,
        extra_map: common.IndexMap,
    ) -> None:
        """Collective: put each load's share on a side face of a refined cell onto the faces of
        its subelements (Gauss integrals of their shape functions, work-equivalent), after a
        refinement. ``cell_nodes`` (n_owned_cells, 8): base nodes of the owned cells;
        ``subelement_nodes`` (m, 8): combined local nodes (i < n_base: base node i, else extra
        node i - n_base) of the subelements of the refined cells, ``subelement_cells`` (m,)
        their owned cells; ``positions(nodes)``: reference positions (mm) of combined nodes;
        ``border``: the extra nodes' border constraints, whose share goes to their masters
        with the constraint's weights (as their internal forces do); ``base_map`` /
        ``extra_map``: the index maps of the base and extra nodes.

        Recomputed from the unrefined mesh's vectors each time: top and bottom faces keep
        their base nodes (a refined cell's outer subelements have them), side faces lose the
        whole cell face's share and gain the subelement faces'."""
        n_base = base_map.size_local + base_map.num_ghosts
        n_extra = extra_map.size_local + extra_map.num_ghosts
        refined = np.zeros(len(cell_nodes), dtype=bool)
        refined[subelement_cells] = True
        order = np.argsort(subelement_cells, kind="stable")
        sorted_cells = subelement_cells[order]
        self.load_vectors, self.extra_vectors = [], []
        resultants = []
        for traction, facets, assembled in zip(
            self.tractions, self.facets, self.assembled, strict=True
        ):
            facets = facets[refined[facets[:, 0]] & np.isin(facets[:, 1], HEX_SIDE_FACETS)]
            cells, local = facets[:, 0], facets[:, 1]
            whole = cell_nodes[cells[:, None], HEX_FACETS[local]]  # (k, 4) base nodes
            # the subelements of each facet's cell, the facet's vertices of each
            start = np.searchsorted(sorted_cells, cells, side="left")
            count = np.searchsorted(sorted_cells, cells, side="right") - start
            facet_of = np.repeat(np.arange(len(cells)), count)
            offsets = np.arange(len(facet_of)) - np.repeat(np.cumsum(count) - count, count)
            subs = order[np.repeat(start, count) + offsets]
            parts = subelement_nodes[subs[:, None], HEX_FACETS[local[facet_of]]]  # (j, 4)
            nodes = np.concatenate([whole, parts])
            X = positions(nodes)
            # out of the body: from the cell's centre to the facet's (a part shares its facet's)
            outward = positions(whole).mean(axis=1) - positions(cell_nodes[cells]).mean(axis=1)
            shares = quad_traction_integrals(
                X, np.concatenate([outward, outward[facet_of]]), traction
            )
            shares[: len(whole)] *= -1.0
            combined = np.zeros((n_base + n_extra, 3))
            np.add.at(combined, nodes.ravel(), shares.reshape(-1, 3))
            delta_base = la.vector(base_map, bs=3)
            delta_extra = la.vector(extra_map, bs=3)
            delta_base.array[:] = combined[:n_base].ravel()
            delta_extra.array[:] = combined[n_base:].ravel()
            if len(border):
                transfer_forces(
                    border.dofs,
                    border.masters,
                    border.weights,
                    3 * n_base,
                    delta_base.array,
                    delta_extra.array,
                )
            for vector in (delta_base, delta_extra):
                vector.scatter_reverse(la.InsertMode.add)
                vector.scatter_forward()
            self.load_vectors.append(assembled + delta_base.array)
            self.extra_vectors.append(delta_extra.array.copy())
            owned = delta_extra.array[: 3 * extra_map.size_local].reshape(-1, 3)
            resultants.append(owned.sum(axis=0))
        self.extra_resultants = np.array(resultants).reshape(-1, 3)
        local = any(np.any(vector != 0.0) for vector in self.extra_vectors)
        self.has_extra = bool(extra_map.comm.allreduce(local, op=MPI.LOR))


def _add_scaled(
    vectors: Sequence[np.ndarray],
    amplitudes: Sequence[Amplitude],
    t: float,
    out: np.ndarray,
    scratch: np.ndarray | None,
) -> np.ndarray:
    """out = sum of amplitude(t) x vector (the first len(out) entries of each), through
    ``scratch`` (made anew only when the shape changes: no allocation per step); returns the
    scratch array."""
    n = len(out)
    out.fill(0.0)
    if scratch is None or scratch.shape != out.shape:
        scratch = np.empty_like(out)
    for vector, amplitude in zip(vectors, amplitudes, strict=True):
        scale = amplitude(t)
        if scale != 0.0:
            np.multiply(vector if len(vector) == n else vector[:n], scale, out=scratch)
            out += scratch
    return scratch


def on_top_or_bottom(face: str) -> bool:
    """Whether a face group (``a&b`` as in ``face_nodes``) lies on the top or bottom face:
    ``top``, ``bottom`` or an edge of theirs such as ``x0&top``."""
    return bool({"top", "bottom"} & set(face.split("&")))


def face_nodes(
    model: LayeredModel, face: str, x_range: tuple[float, float] | None = None
) -> np.ndarray:
    """Local nodes (owned and ghosts, sorted) on a face group. ``a&b`` names the nodes on both
    face a and face b (for example ``x1&top``: the top edge of the end x1); ``x_range`` keeps
    only those with x_min <= x <= x_max (a line of nodes across the width, or a pad). Found
    once per model and face (the base mesh never changes: a refinement asks again for each
    motion); a copy is returned."""
    key = (face, None if x_range is None else tuple(x_range))
    if key not in model._face_nodes:
        model._face_nodes[key] = _located_face_nodes(model, face, x_range)
    return model._face_nodes[key].copy()


def _located_face_nodes(
    model: LayeredModel, face: str, x_range: tuple[float, float] | None
) -> np.ndarray:
    """``face_nodes`` found from the mesh's facet groups."""
    names = face.split("&")
    nodes = None
    for name in names:
        beam = model.beam
        facets = beam.facets(name)
        fdim = beam.mesh.topology.dim - 1
        beam.mesh.topology.create_connectivity(fdim, beam.mesh.topology.dim)
        on_face = fem.locate_dofs_topological(model.V, fdim, facets)
        nodes = on_face if nodes is None else np.intersect1d(nodes, on_face)
    if x_range is not None:
        x = model.V.tabulate_dof_coordinates()[nodes, 0]
        tol = 1e-6 * model.beam.length
        nodes = nodes[(x >= x_range[0] - tol) & (x <= x_range[1] + tol)]
    return np.sort(nodes).astype(np.int32)


def face_dofs(
    model: LayeredModel,
    face: str,
    component: str,
    owned_only: bool = True,
    x_range: tuple[float, float] | None = None,
) -> np.ndarray:
    """DOFs (block-unrolled, sorted) of one component on a face group (``face_nodes``): this
    rank's owned ones, or with ``owned_only=False`` also its ghosts."""
    dofs = 3 * face_nodes(model, face, x_range) + COMPONENTS[component]
    if owned_only:
        dofs = dofs[dofs < model.n_owned_dofs]
    return dofs.astype(np.int32)


def resolve(
    model: LayeredModel, motions: Sequence[PrescribedMotion], loads: Sequence[FaceLoad]
) -> ResolvedLoads:
    """The motions and loads on this rank's DOFs. Collective (``face_nodes``, the face areas
    and the load vectors). Raises InputError on every rank for a motion's face without nodes and
    for two faces that prescribe a shared DOF differently (found on the ranks holding it)."""
    owner: dict[int, int] = {}
    for k, motion in enumerate(motions):
        dofs = face_dofs(model, motion.face, motion.component, x_range=motion.x_range)
        if model.comm.allreduce(len(dofs), op=MPI.SUM) == 0:
            where = f" at x in {motion.x_range} mm" if motion.x_range is not None else ""
            raise InputError(
                motion.key or "clamp", f"face {motion.face!r}{where} has no nodes to prescribe"
            )
        # a conflict lies on the ranks that hold the shared DOF: every rank learns of it here,
        # before the next motion's collective face lookup
        with shared_errors(model.comm):
            for dof in dofs:
                previous = owner.setdefault(int(dof), k)
                if previous != k and motions[previous] != motion:
                    # the same DOF prescribed twice is fine only if both hold it at zero
                    if not (_is_zero(motions[previous]) and _is_zero(motion)):
                        other = motions[previous]
                        raise InputError(
                            motion.key or other.key or "prescribed",
                            f"{motion.face!r} ({motion.key or 'a symmetry interface'}) and "
                            f"{other.face!r} ({other.key or 'a symmetry interface'}) both "
                            f"prescribe component {motion.component} of the nodes they share, "
                            "differently",
                        )
    fixed = np.array(sorted(owner), dtype=np.int32)
    fixed_motion = np.array([owner[int(d)] for d in fixed], dtype=np.int32)

    vectors, tractions, facet_lists, cell_tractions = [], [], [], []
    cell_nodes = model.V.dofmap.list[: model.n_owned_cells]
    X_nodes = model.V.tabulate_dof_coordinates()
    index_map = model.V.dofmap.index_map
    for load in loads:
        if "&" in load.face:
            raise InputError(
                load.key or "load", f"{load.face!r}: a load acts on one face, not on a&b"
            )
        # the (owned cell, local facet) pairs on the face with their centroid in the region
        cells, local, X = face_facets(model, load.face)
        centre = X.mean(axis=1)
        inside = load.region.holds(centre[:, 0], centre[:, 1])
        cells, local, X, centre = cells[inside], local[inside], X[inside], centre[inside]
        area = model.comm.allreduce(float(quad_areas(X).sum()), op=MPI.SUM)
        if area == 0.0:
            raise InputError(
                load.key or "load",
                f"no facet of face {load.face!r} has its centroid in the load's region "
                f"{load.region}",
            )
        traction = FaceTraction.of(load, area)
        outward = centre - X_nodes[cell_nodes[cells]].mean(axis=1)
        shares = quad_traction_integrals(X, outward, traction)  # (k, 4, 3)
        vector = la.vector(index_map, bs=3)
        nodal = vector.array.reshape(-1, 3)
        np.add.at(
            nodal, cell_nodes[cells[:, None], HEX_FACETS[local]].ravel(), shares.reshape(-1, 3)
        )
        vector.scatter_reverse(la.InsertMode.add)
        vector.scatter_forward()
        vectors.append(vector.array.copy())
        tractions.append(traction)
        facet_lists.append(np.column_stack([cells, local]).astype(np.int64))
        cell_tractions.append(
            _cell_face_tractions(load.face, cells, shares, X, model.n_owned_cells)
        )
    return ResolvedLoads(
        list(motions),
        fixed,
        fixed_motion,
        vectors,
        [load.amplitude for load in loads],
        tractions,
        facet_lists,
        [vector.copy() for vector in vectors],
        [np.zeros(0) for _ in loads],
        extra_resultants=np.zeros((len(loads), 3)),
        cell_tractions=cell_tractions,
    )


def face_facets(model: LayeredModel, face: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The facets of a face group on this rank's owned cells: (cells (k,), their local facet
    (k,), DOLFINx reference numbering, and its vertices X (k, 4, 3) mm in tensor order)."""
    tdim = model.mesh.topology.dim
    model.mesh.topology.create_connectivity(tdim, tdim - 1)
    cell_facets = model.mesh.topology.connectivity(tdim, tdim - 1).array.reshape(
        -1, len(HEX_FACETS)
    )[: model.n_owned_cells]
    cells, local = np.nonzero(np.isin(cell_facets, model.beam.facets(face)))
    nodes = model.V.dofmap.list[: model.n_owned_cells][cells[:, None], HEX_FACETS[local]]
    return cells, local, model.V.tabulate_dof_coordinates()[nodes]


@dataclass(frozen=True)
class FaceTraction:
    """The traction (N/mm^2) of a face load at amplitude 1, as ``quad_traction_integrals``
    takes it: uniform ``vector`` (a total force over the loaded area), or the load's pressure
    times its distribution's factor at x, against the outward normal."""

    load: FaceLoad
    vector: np.ndarray | None = None

    @classmethod
    def of(cls, load: FaceLoad, area: float) -> FaceTraction:
        """The traction of ``load`` acting on ``area`` mm^2 (over all ranks)."""
        if load.pressure is not None:
            return cls(load)
        return cls(load, np.asarray(load.force, dtype=np.float64) / area)

    def __call__(self, points: np.ndarray, normals: np.ndarray) -> np.ndarray:
        if self.vector is not None:
            return np.broadcast_to(self.vector, points.shape)
        return -self.load.pressure * self.load.factor(points[:, 0])[:, None] * normals


def _cell_face_tractions(
    face: str, cells: np.ndarray, shares: np.ndarray, X: np.ndarray, n_cells: int
) -> np.ndarray:
    """(n_cells, 2, 3) mean traction (N/mm^2) of a load on the bottom (0) or top (1) face of
    the owned cells ``cells`` (its nodal shares (k, 4, 3) N over the facets X (k, 4, 3)); empty
    for a load on another face."""
    if face not in ("bottom", "top"):
        return np.zeros((0, 2, 3))
    out = np.zeros((n_cells, 2, 3))
    out[cells, int(face == "top")] = shares.sum(axis=1) / quad_areas(X)[:, None]
    return out


def _motion_key(motion: PrescribedMotion) -> str:
    """The config table a motion comes from, for messages: a clamp holds every component at
    zero, the rest are [[prescribed]] entries (or a symmetry condition, also zero)."""
    return "clamp" if _is_zero(motion) else "prescribed"


def _is_zero(motion: PrescribedMotion) -> bool:
    return motion.value == 0.0 or all(v == 0.0 for v in motion.amplitude.values)


def extra_node_prescriptions(
    motions: Sequence[PrescribedMotion],
    base: LayeredModel,
    extra: enr.ExtraNodes,
    top_of: np.ndarray,
    n_interfaces: int,
) -> np.ndarray:
    """Collective: motion index (into ``motions``) holding each local extra DOF (owned and
    ghosts), -1 for none: a face motion holds an extra node when both base nodes of its column
    (``top_of``: the top base node of each local bottom one, ``CellColumnTable.top_of``) are
    on that face; a symmetry interface
    holds u_z of its nodes. The first motion listed wins."""
    prescribed = np.full(3 * extra.n_local, -1, dtype=np.int64)
    if extra.index_map.size_global == 0:  # the same on every rank
        return prescribed
    n_base = base.V.dofmap.index_map.size_local + base.V.dofmap.index_map.num_ghosts
    keys = np.fromiter(extra.index.keys(), dtype=np.int64, count=len(extra.index))
    local = np.fromiter(extra.index.values(), dtype=np.int64, count=len(extra.index))
    bottom_global, interface, _ = enr.key_arrays(keys, n_interfaces)
    bottom = extra.local_base_nodes(bottom_global)
    top = top_of[bottom]
    for m, motion in enumerate(motions):
        if motion.face.startswith("interface"):
            on = interface == int(motion.face.removeprefix("interface"))
        else:  # face_nodes is collective: every rank, also one without extra nodes
            mask = np.zeros(n_base, dtype=bool)
            mask[face_nodes(base, motion.face, motion.x_range)] = True
            on = mask[bottom] & mask[top]
        dofs = 3 * local[on] + COMPONENTS[motion.component]
        dofs = dofs[prescribed[dofs] < 0]
        prescribed[dofs] = m
    return prescribed
