"""The discrete model of a layered beam/plate: DOLFINx space, the solid-shell forms of each mesh
layer, lumped masses and the element-size-based stable time step.

Units: N, mm, s, tonne.

An ESL model has one mesh layer carrying the whole laminate; a layerwise (LW) model has one mesh
layer per sublaminate, each carrying its own plies. Both are the same object here.

``kinematics`` ("small" or "finite", see ``solid_shell``) selects the strain measure of the UFL
forms; the adaptive model's numba subelements read the same attribute, so the two paths always
use the same kinematics.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import dolfinx
import numpy as np
import ufl
from dolfinx import fem
from mpi4py import MPI
from numba import njit

from fenics_adaptive.element import solid_shell
from fenics_adaptive.element.timestep import characteristic_lengths
from fenics_adaptive.materials.laminate import Laminate, shear_correction_factors
from fenics_adaptive.meshes.beam import BeamMesh
from fenics_adaptive.settings.kinds import Kinematics

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


@dataclass
class LayeredModel:
    """The base discretisation. Its UFL forms integrate the cells listed in ``ufl_cells`` (per
    mesh layer; all owned cells at first): an adaptive model takes refined cells out of them and
    computes those with the numba subelement kernel instead."""

    beam: BeamMesh
    layer_laminates: list[Laminate]  # laminate of mesh layer k (cell tag k + 1)
    points_per_ply: int
    selective: bool
    V: fem.FunctionSpace
    u: fem.Function  # displacement, mm; the forms read it
    mass: np.ndarray  # lumped nodal mass per DOF (owned + ghosts), tonne
    ufl_cells: list[np.ndarray] = field(default_factory=list)
    force_ufl: ufl.Form | None = None  # f_int(u) . v, kept for linearisation (static, stiffness)
    force_form: fem.Form | None = None
    energy_form: fem.Form | None = None
    kinematics: str = "small"  # "small" | "finite" (solid_shell.KINEMATICS)
    # transverse shear correction of each layer's elements (laminate.shear_correction_factors)
    shear_correction: bool = False

    @property
    def finite(self) -> bool:
        """Total Lagrangian (Green-Lagrange strain) rather than small-strain kinematics."""
        return self.kinematics == Kinematics.FINITE

    @property
    def mesh(self) -> dolfinx.mesh.Mesh:
        return self.beam.mesh

    @property
    def comm(self) -> MPI.Comm:
        return self.beam.mesh.comm

    @property
    def n_owned_dofs(self) -> int:
        return self.V.dofmap.index_map.size_local * self.V.dofmap.index_map_bs

    @property
    def n_owned_cells(self) -> int:
        return self.mesh.topology.index_map(3).size_local

    def layer_cells(self, layer: int) -> np.ndarray:
        cells = self.beam.cell_tags.find(layer + 1)
        return cells[cells < self.n_owned_cells].astype(np.int32)

    def set_ufl_cells(self, cells_per_layer: list[np.ndarray]) -> None:
        """Integrate the UFL forms over these owned cells of each layer (compiled kernels are
        cached, so this is cheap)."""
        self.ufl_cells = [np.asarray(c, dtype=np.int32) for c in cells_per_layer]
        v = ufl.TestFunction(self.V)
        kernels = solid_shell.SeparateKernels(self.mesh)
        energy = 0
        factors = self.shear_factors()
        for laminate, cells, k in zip(self.layer_laminates, self.ufl_cells, factors, strict=True):
            groups = solid_shell.ply_groups(laminate, self.points_per_ply, k)
            energy += solid_shell.strain_energy_form(
                self.u, groups, kernels, cells, self.selective, self.kinematics
            )
        self.force_ufl = ufl.derivative(energy, self.u, v)
        self.force_form = fem.form(self.force_ufl, jit_options=JIT_OPTIONS)
        self.energy_form = fem.form(energy, jit_options=JIT_OPTIONS)
        self.packed = PackedDisplacement([self.force_form, self.energy_form], self.u, self.V)

    @property
    def laminate(self) -> Laminate:
        """The whole laminate, all layers' plies bottom to top."""
        return Laminate(tuple(p for layer in self.layer_laminates for p in layer.plies))

    def shear_factors(self) -> list[tuple[float, float]]:
        """(k_xz, k_yz) of each layer's elements: the whole laminate's shear distribution over
        the layer's plies, or (1, 1) without ``shear_correction``."""
        laminate, first, out = self.laminate, 0, []
        for layer in self.layer_laminates:
            stop = first + layer.n_plies
            out.append(
                shear_correction_factors(laminate, first, stop)
                if self.shear_correction
                else (1.0, 1.0)
            )
            first = stop
        return out

    def set_kinematics(self, kinematics: str) -> None:
        """Switch the strain measure ("small" or "finite") and rebuild the forms over the same
        cells (for a model built without it, e.g. by an older caller)."""
        if kinematics not in solid_shell.KINEMATICS:
            raise ValueError(
                f"kinematics must be one of {', '.join(solid_shell.KINEMATICS)} "
                f"(got {kinematics!r})"
            )
        self.kinematics = kinematics
        self.set_ufl_cells(self.ufl_cells)

    def update_coefficients(self) -> None:
        """The per-step pre-pass of the forms: pack what their kernels read that depends on
        the displacement (``PackedDisplacement``). A per-cell element parameter computed from
        u before the assembly (an enhanced-strain multiplier, say) is computed and packed here,
        so that the force and the energy both see it."""
        self.packed.update()

    def assemble_internal_force(self, out: np.ndarray) -> None:
        """Add this rank's share of f_int(u) (N) over the UFL cells into ``out`` (owned + ghost
        entries, no scatter), from the coefficients of the last ``update_coefficients``."""
        fem.assemble_vector(
            out, self.force_form, constants=self.packed.constants[0], coeffs=self.packed.coeffs[0]
        )

    def add_internal_force(self, out: np.ndarray) -> None:
        """Add this rank's share of f_int(u) (N) over the UFL cells into ``out`` (owned + ghost
        entries, no scatter)."""
        self.update_coefficients()
        self.assemble_internal_force(out)

    def internal_force(self, out: dolfinx.la.Vector) -> None:
        """f_int(u) (N) into ``out``, a vector on the space's index map: owned entries complete,
        ghost entries hold this rank's partial sums."""
        out.array.fill(0.0)
        self.add_internal_force(out.array)
        out.scatter_reverse(dolfinx.la.InsertMode.add)

    def local_strain_energy(self) -> float:
        """Strain energy (mJ) of this rank's UFL cells."""
        self.update_coefficients()
        return fem.assemble_scalar(
            self.energy_form, constants=self.packed.constants[1], coeffs=self.packed.coeffs[1]
        )

    def strain_energy(self) -> float:
        """Strain energy (mJ) of the UFL cells, summed over ranks."""
        return self.comm.allreduce(self.local_strain_energy(), op=MPI.SUM)

    def total_mass(self) -> float:
        local = self.mass[: self.n_owned_dofs : 3].sum()
        return self.comm.allreduce(local, op=MPI.SUM)

    def cell_wave_speeds(self) -> np.ndarray:
        """Fastest dilatational wave speed (mm/s) of the plies of each owned cell."""
        speeds = np.zeros(self.n_owned_cells)
        for k, laminate in enumerate(self.layer_laminates):
            speeds[self.layer_cells(k)] = max(
                p.material.dilatational_wave_speed() for p in laminate.plies
            )
        return speeds

    def stable_time_step(self) -> tuple[float, int]:
        """(min over cells of L_e / c, the cell attaining it), reduced over ranks. L_e = volume /
        largest face area; c = fastest dilatational wave speed of the cell's plies."""
        ratios = characteristic_lengths(cell_vertex_coordinates(self.mesh))
        ratios /= self.cell_wave_speeds()
        if len(ratios) == 0:  # a rank without cells still joins the reduction
            return self.comm.allreduce((np.inf, -1), op=MPI.MIN)
        cell = int(np.argmin(ratios))
        return self.comm.allreduce((float(ratios[cell]), cell), op=MPI.MIN)


def build_model(
    beam: BeamMesh,
    layer_laminates: list[Laminate],
    points_per_ply: int = 1,
    selective: bool = True,
    kinematics: str = "small",
    shear_correction: bool = False,
) -> LayeredModel:
    """``selective=False`` gives the plain fully integrated hexahedron (locks; for comparison).
    ``kinematics``: "small" (linear strain) or "finite" (total Lagrangian, Green-Lagrange).
    ``shear_correction``: the laminate's transverse shear correction on each layer's elements
    (``materials.laminate.shear_correction_factors``); off, the constant shear strain of the
    element carries the plies' full shear moduli."""
    if kinematics not in solid_shell.KINEMATICS:
        raise ValueError(
            f"kinematics must be one of {', '.join(solid_shell.KINEMATICS)} (got {kinematics!r})"
        )
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
    model = LayeredModel(
        beam=beam,
        layer_laminates=list(layer_laminates),
        points_per_ply=points_per_ply,
        selective=selective,
        V=V,
        u=fem.Function(V, name="displacement"),
        mass=np.zeros(0),
        kinematics=kinematics,
        shear_correction=shear_correction,
    )
    cells = [model.layer_cells(k) for k in range(len(layer_laminates))]
    model.set_ufl_cells(cells)

    v = ufl.TestFunction(V)
    kernels = solid_shell.SeparateKernels(beam.mesh)
    mass = 0
    for laminate, layer_cells in zip(layer_laminates, cells, strict=True):
        groups = solid_shell.ply_groups(laminate, points_per_ply)
        mass += solid_shell.lumped_mass_form(v, groups, kernels, layer_cells)
    mass_vector = fem.assemble_vector(fem.form(mass))
    mass_vector.scatter_reverse(dolfinx.la.InsertMode.add)
    mass_vector.scatter_forward()
    model.mass = mass_vector.array.copy()
    return model


def cell_vertex_coordinates(mesh: dolfinx.mesh.Mesh) -> np.ndarray:
    """(n_local_cells, 8, 3) vertex coordinates of the locally owned cells."""
    n_local = mesh.topology.index_map(3).size_local
    return mesh.geometry.x[mesh.geometry.dofmaps[0][:n_local]]


@njit(cache=True)
def _gather_cell_values(u, cell_dofs, out):
    """out[r, 3 a + c] = u[3 cell_dofs[r, a] + c]: the displacement as FFCx kernels read it."""
    for r in range(cell_dofs.shape[0]):
        for a in range(cell_dofs.shape[1]):
            for c in range(3):
                out[r, 3 * a + c] = u[3 * cell_dofs[r, a] + c]


class PackedDisplacement:
    """The constants and the packed displacement of the model's forms (force, energy), kept
    between steps.

    DOLFINx packs every coefficient of every integral on each assembly call. The forms have
    several integrals over the same cells (one kernel per custom quadrature rule, see
    ``solid_shell.SeparateKernels``), each with its own copy of u, and their constants (the ply
    stiffnesses) never change. Here the constants are packed once, and u once per call of
    ``update`` into one array per set of cells, shared by every integral of every form over
    those cells. ``constants[i]`` and ``coeffs[i]`` are what ``forms[i]``'s assembly takes.

    The layout is DOLFINx's for a blocked P1 space: per cell, the 8 nodes in dofmap order, 3
    components each. ``tests/test_model.py`` checks it against ``fem.pack_coefficients``; this
    class does not call that at set-up, because it packs every integral at once (100 MiB for a
    40 000-cell ESL plate, 400 MiB for its layerwise model) and the freed memory stays with
    the process."""

    def __init__(self, forms: list[fem.Form], u: fem.Function, V: fem.FunctionSpace):
        if V.dofmap.index_map_bs != 3 or V.dofmap.list.shape[1] != 8:
            raise ValueError("PackedDisplacement: expected a 3-component P1 space on hexahedra")
        self.u = u.x.array
        dofmap = V.dofmap.list
        cell = fem.IntegralType.cell
        groups: dict[bytes, tuple[np.ndarray, np.ndarray]] = {}
        self.constants: list[np.ndarray] = []
        self.coeffs: list[dict] = []
        for form in forms:
            cpp = form._cpp_object
            if len(cpp.coefficients) != 1 or not np.shares_memory(
                cpp.coefficients[0].x.array, u.x.array
            ):
                raise ValueError("PackedDisplacement: a form must have u as its only coefficient")
            if set(cpp.integral_types) != {cell}:
                raise ValueError("PackedDisplacement: expected cell integrals only")
            coeffs = {}
            for i in range(cpp.num_integrals(cell, 0)):  # the keys DOLFINx's packing uses
                cells = np.asarray(cpp.domains(cell, i))
                signature = cells.tobytes()
                if signature not in groups:
                    cell_dofs = np.ascontiguousarray(dofmap[cells], dtype=np.int64)
                    groups[signature] = (cell_dofs, np.empty((len(cells), 24)))
                coeffs[(cell, i)] = groups[signature][1]
            self.constants.append(fem.pack_constants(form))
            self.coeffs.append(coeffs)
        self.groups = list(groups.values())
        self.update()

    def update(self) -> None:
        for cell_dofs, packed in self.groups:
            _gather_cell_values(self.u, cell_dofs, packed)
