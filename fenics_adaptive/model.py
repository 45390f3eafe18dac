"""The discrete model of a layered beam/plate: DOLFINx space, the solid-shell forms of each mesh
layer, lumped masses and the element-size-based stable time step.

Units: N, mm, s, tonne.

An ESL model has one mesh layer carrying the whole laminate; a layerwise (LW) model has one mesh
layer per sublaminate, each carrying its own plies. Both are the same object here.
"""

from __future__ import annotations

from dataclasses import dataclass

import dolfinx
import numpy as np
import ufl
from dolfinx import fem
from mpi4py import MPI

from fenics_adaptive import solid_shell
from fenics_adaptive.laminate import Laminate
from meshes.beam import BeamMesh

# FFCx kernels compiled for this CPU with reassociation allowed: lets the compiler vectorise the
# quadrature loops (about 5x faster force assembly here). Results change only at round-off.
JIT_OPTIONS = {
    "cffi_extra_compile_args": [
        "-O3",
        "-march=native",
        "-fno-math-errno",
        "-fno-trapping-math",
        "-fno-signed-zeros",
        "-fassociative-math",
        "-freciprocal-math",
    ]
}

# Local vertex lists of the six faces of a reference hexahedron (DOLFINx numbering).
HEX_FACES = np.array(
    [[0, 1, 3, 2], [4, 5, 7, 6], [0, 1, 5, 4], [2, 3, 7, 6], [0, 2, 6, 4], [1, 3, 7, 5]]
)


@dataclass
class LayeredModel:
    beam: BeamMesh
    layer_laminates: list[Laminate]  # laminate of mesh layer k (cell tag k + 1)
    points_per_ply: int
    V: fem.FunctionSpace
    u: fem.Function  # displacement, mm; the force form reads it
    force_ufl: ufl.Form  # f_int(u) . v, kept for linearisation (static solves, stiffness)
    force_form: fem.Form
    mass: np.ndarray  # lumped nodal mass per DOF (owned + ghosts), tonne

    @property
    def mesh(self) -> dolfinx.mesh.Mesh:
        return self.beam.mesh

    @property
    def comm(self) -> MPI.Comm:
        return self.beam.mesh.comm

    @property
    def n_owned_dofs(self) -> int:
        return self.V.dofmap.index_map.size_local * self.V.dofmap.index_map_bs

    def internal_force(self, out: dolfinx.la.Vector) -> None:
        """f_int(u) (N) into ``out``, a vector on the space's index map: owned entries complete,
        ghost entries hold this rank's partial sums."""
        out.array.fill(0.0)
        fem.assemble_vector(out.array, self.force_form)
        out.scatter_reverse(dolfinx.la.InsertMode.add)

    def total_mass(self) -> float:
        local = self.mass[: self.n_owned_dofs : 3].sum()
        return self.comm.allreduce(local, op=MPI.SUM)

    def stable_time_step(self) -> tuple[float, int]:
        """(min over cells of L_e / c, the cell attaining it), reduced over ranks. L_e = volume /
        largest face area; c = fastest dilatational wave speed of the cell's plies."""
        X = cell_vertex_coordinates(self.mesh)
        lengths = characteristic_lengths(X)
        speeds = np.zeros(len(X))
        for k, laminate in enumerate(self.layer_laminates):
            cells = self.beam.cell_tags.find(k + 1)
            cells = cells[cells < len(X)]
            speeds[cells] = max(p.material.dilatational_wave_speed() for p in laminate.plies)
        ratios = lengths / speeds
        cell = int(np.argmin(ratios))
        local = (float(ratios[cell]), cell)
        return self.comm.allreduce(local, op=MPI.MIN)


def build_model(
    beam: BeamMesh,
    layer_laminates: list[Laminate],
    points_per_ply: int = 1,
    selective: bool = True,
) -> LayeredModel:
    """``selective=False`` gives the plain fully integrated hexahedron (locks; for comparison)."""
    if len(layer_laminates) != beam.n_layers:
        raise ValueError(
            f"the mesh has {beam.n_layers} layers but {len(layer_laminates)} laminates were given"
        )
    for k, laminate in enumerate(layer_laminates):
        t_mesh = beam.layer_z[k + 1] - beam.layer_z[k]
        if abs(laminate.thickness - t_mesh) > 1e-9 * beam.thickness:
            raise ValueError(
                f"mesh layer {k} is {t_mesh} mm thick but its plies add up to {laminate.thickness}"
            )
        if laminate.n_plies * points_per_ply < 2:
            raise ValueError(
                f"mesh layer {k} has a single integration point through its thickness: its "
                "bending mode would have zero energy (use points_per_ply = 2)"
            )
    V = fem.functionspace(beam.mesh, ("Lagrange", 1, (3,)))
    u = fem.Function(V, name="displacement")
    v = ufl.TestFunction(V)
    force = 0
    mass = 0
    force_kernels = solid_shell.SeparateKernels(beam.mesh)
    mass_kernels = solid_shell.SeparateKernels(beam.mesh)
    n_owned = beam.mesh.topology.index_map(3).size_local
    for k, laminate in enumerate(layer_laminates):
        cells = beam.cell_tags.find(k + 1)
        cells = cells[cells < n_owned]
        groups = solid_shell.ply_groups(laminate, points_per_ply)
        force += solid_shell.internal_force_form(u, v, groups, force_kernels, cells, selective)
        mass += solid_shell.lumped_mass_form(v, groups, mass_kernels, cells)
    mass_vector = fem.assemble_vector(fem.form(mass))
    mass_vector.scatter_reverse(dolfinx.la.InsertMode.add)
    mass_vector.scatter_forward()
    return LayeredModel(
        beam=beam,
        layer_laminates=list(layer_laminates),
        points_per_ply=points_per_ply,
        V=V,
        u=u,
        force_ufl=force,
        force_form=fem.form(force, jit_options=JIT_OPTIONS),
        mass=mass_vector.array.copy(),
    )


def cell_vertex_coordinates(mesh: dolfinx.mesh.Mesh) -> np.ndarray:
    """(n_local_cells, 8, 3) vertex coordinates of the locally owned cells."""
    n_local = mesh.topology.index_map(3).size_local
    return mesh.geometry.x[mesh.geometry.dofmaps[0][:n_local]]


def characteristic_lengths(X: np.ndarray) -> np.ndarray:
    """Volume / largest face area of hexahedra with vertex coordinates X (n, 8, 3)."""
    faces = X[:, HEX_FACES, :]  # (n, 6, 4, 3), vertices in cyclic order
    diag1 = faces[:, :, 2] - faces[:, :, 0]
    diag2 = faces[:, :, 3] - faces[:, :, 1]
    areas = 0.5 * np.linalg.norm(np.cross(diag1, diag2), axis=2)
    return hexahedron_volumes(X) / areas.max(axis=1)


def hexahedron_volumes(X: np.ndarray) -> np.ndarray:
    """Exact volumes of trilinear hexahedra (2x2x2 Gauss on det J)."""
    g = solid_shell.GAUSS_2
    volume = np.zeros(len(X))
    for a in g:
        for b in g:
            for c in g:
                dN = reference_gradients(np.array([a, b, c]))  # (8, 3)
                J = np.einsum("nki,kj->nij", X, dN)  # (n, 3, 3): dx_i / dX_j
                volume += 0.125 * np.abs(np.linalg.det(J))
    return volume


def reference_gradients(point: np.ndarray) -> np.ndarray:
    """Gradients (8, 3) of the trilinear shape functions on [0, 1]^3 at ``point``, DOLFINx vertex
    order: vertex k sits at (k & 1, (k >> 1) & 1, (k >> 2) & 1)."""
    corners = np.array([[k & 1, (k >> 1) & 1, (k >> 2) & 1] for k in range(8)], dtype=float)
    # 1-D factors: corner coordinate 1 -> s, 0 -> 1 - s
    values = np.where(corners == 1, point, 1.0 - point)  # (8, 3)
    slopes = np.where(corners == 1, 1.0, -1.0)
    grads = np.empty((8, 3))
    grads[:, 0] = slopes[:, 0] * values[:, 1] * values[:, 2]
    grads[:, 1] = values[:, 0] * slopes[:, 1] * values[:, 2]
    grads[:, 2] = values[:, 0] * values[:, 1] * slopes[:, 2]
    return grads
