"""Clamps, prescribed motions and face loads (``settings.loads``), resolved to DOFs of a model.

Units: N, mm, s. A face is named by its group in the mesh (``fenics_adaptive.meshes.beam``: x0, x1,
top, x1_layer3, ...). Components are "x", "y", "z"."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import dolfinx
import numpy as np
import ufl
from dolfinx import fem
from mpi4py import MPI

from fenics_adaptive.adaptivity import enrichment as enr
from fenics_adaptive.errors import InputError, shared_errors
from fenics_adaptive.model.forms import LayeredModel
from fenics_adaptive.settings.loads import COMPONENTS, Amplitude, FaceLoad, PrescribedMotion


@dataclass
class ResolvedLoads:
    """The loading as arrays on the base DOFs of a model: prescribed DOFs with the index of the
    motion that drives each, and one nodal force vector per face load."""

    motions: list[PrescribedMotion]
    fixed: np.ndarray  # owned base DOFs under a prescribed motion (sorted, unique)
    fixed_motion: np.ndarray  # index into ``motions`` for each fixed DOF
    load_vectors: list[np.ndarray]  # one nodal force vector per FaceLoad (owned + ghosts), N
    load_amplitudes: list[Amplitude]
    _scratch: np.ndarray | None = None

    @property
    def constrained(self) -> np.ndarray:
        return self.fixed

    def external_force(self, t: float, out: np.ndarray) -> None:
        out.fill(0.0)
        if self._scratch is None or self._scratch.shape != out.shape:
            self._scratch = np.empty_like(out)
        for vector, amplitude in zip(self.load_vectors, self.load_amplitudes, strict=True):
            scale = amplitude(t)
            if scale != 0.0:
                np.multiply(vector, scale, out=self._scratch)
                out += self._scratch


def face_nodes(
    model: LayeredModel, face: str, x_range: tuple[float, float] | None = None
) -> np.ndarray:
    """Local nodes (owned and ghosts, sorted) on a face group. ``a&b`` names the nodes on both
    face a and face b (for example ``x1&top``: the top edge of the end x1); ``x_range`` keeps
    only those with x_min <= x <= x_max (a line of nodes across the width, or a pad)."""
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


def face_area(model: LayeredModel, face: str) -> float:
    ds = ufl.Measure("ds", domain=model.mesh, subdomain_data=model.beam.facet_tags)
    tags = model.beam.face_tags[face]
    area = fem.assemble_scalar(fem.form(1.0 * ds(tags)))
    return model.comm.allreduce(area, op=MPI.SUM)


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

    vectors = []
    ds = ufl.Measure("ds", domain=model.mesh, subdomain_data=model.beam.facet_tags)
    v = ufl.TestFunction(model.V)
    for load in loads:
        if "&" in load.face:
            raise InputError(
                load.key or "load", f"{load.face!r}: a load acts on one face, not on a&b"
            )
        area = face_area(model, load.face)
        traction = ufl.as_vector([f / area for f in load.force])
        vec = fem.assemble_vector(
            fem.form(ufl.dot(traction, v) * ds(model.beam.face_tags[load.face]))
        )
        vec.scatter_reverse(dolfinx.la.InsertMode.add)
        vec.scatter_forward()
        vectors.append(vec.array.copy())
    return ResolvedLoads(
        list(motions), fixed, fixed_motion, vectors, [load.amplitude for load in loads]
    )


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
    column_top: dict[int, int],
    n_interfaces: int,
) -> np.ndarray:
    """Collective: motion index (into ``motions``) holding each local extra DOF (owned and
    ghosts), -1 for none: a face motion holds an extra node when both base nodes of its column
    (``column_top``: top base node of each bottom one) are on that face; a symmetry interface
    holds u_z of its nodes. The first motion listed wins."""
    prescribed = np.full(3 * extra.n_local, -1, dtype=np.int64)
    if extra.index_map.size_global == 0:  # the same on every rank
        return prescribed
    n_base = base.V.dofmap.index_map.size_local + base.V.dofmap.index_map.num_ghosts
    parts = [enr.key_parts(k, n_interfaces) for k in extra.index]
    local = np.fromiter(extra.index.values(), dtype=np.int64)
    bottom = np.array([extra.local_base_node(g) for g, _, _ in parts], dtype=np.int64)
    top = np.array([column_top[b] for b in bottom], dtype=np.int64)
    interface = np.array([i for _, i, _ in parts], dtype=np.int64)
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
