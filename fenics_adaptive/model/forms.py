"""The discrete model of a layered beam/plate: DOLFINx space, the solid-shell forms of each mesh
layer, lumped masses and the element-size-based stable time step.

Units: N, mm, s, tonne.

An ESL model has one mesh layer carrying the whole laminate; a layerwise (LW) model has one mesh
layer per sublaminate, each carrying its own plies. Both are the same object here.

``kinematics`` ("small" or "finite", see ``solid_shell``) selects the strain measure of the UFL
forms; the adaptive model's numba subelements read the same attribute, so the two paths always
use the same kinematics. Likewise ``enhanced_strain``, the enhanced assumed thickness strain
(``solid_shell`` module docstring), condensed before each assembly (``CondensedThicknessStrain``).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import dolfinx
import numpy as np
import ufl
from dolfinx import fem
from dolfinx.fem.forms import CompiledForm
from mpi4py import MPI
from numba import njit

from fenics_adaptive.element import solid_shell
from fenics_adaptive.element.assumed_strain import cells_with_bent_directors
from fenics_adaptive.element.subelement import (
    concatenate_rules,
    enhanced_parameter_maps,
    pack_rule,
)
from fenics_adaptive.element.timestep import characteristic_lengths
from fenics_adaptive.materials.laminate import Laminate, ply_shear_factors
from fenics_adaptive.meshes.beam import BeamMesh
from fenics_adaptive.meshes.shell import ShellMesh
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
class CompiledForms:
    """The model's force and energy forms compiled without their cells: ``subdomains`` is the
    (id, cells) list the UFL measures share, ``layer_of_subdomain`` the (id, mesh layer) of
    each, ``field`` the enhanced thickness strain's coefficient (or None), ``key`` the
    formulation they were compiled for (``LayeredModel._form_key``)."""

    key: tuple
    force: CompiledForm
    energy: CompiledForm
    subdomains: list[tuple[int, np.ndarray]]
    layer_of_subdomain: list[tuple[int, int]]
    field: fem.Function | None
    frame: fem.Function | None = None  # the cells' frames on a curved shell (DG0, 3 x 3)
    bent: fem.Function | None = None  # 1 on the cells whose directors bend (DG0)


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
    # transverse shear correction of each layer's elements, ply by ply
    # (laminate.ply_shear_factors)
    shear_correction: bool = True
    # the enhanced assumed thickness strain (no Poisson thickness locking), condensed per cell
    enhanced_strain: bool = True
    enhanced: CondensedThicknessStrain | None = None
    # each layer's plies pre-integrated through the thickness where the rule takes them
    # (solid_shell.thickness_rule), else points_per_ply Gauss points in each ply
    preintegrate: bool = True
    _enhanced_maps: np.ndarray | None = None  # enhanced_parameter_maps, once computed
    _compiled: CompiledForms | None = None  # the forms' kernels, once per formulation
    _cell_time_steps: np.ndarray | None = None  # cell_time_steps, once computed
    _cells_pending: bool = False  # set_ufl_cells(defer=True) recorded cells the forms lack
    _frames: np.ndarray | None = None  # cell_frames, once computed
    _face_nodes: dict = field(default_factory=dict)  # loading.face_nodes, by face and range

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

    def set_ufl_cells(self, cells_per_layer: list[np.ndarray], defer: bool = False) -> None:
        """Integrate the UFL forms over these owned cells of each layer. The forms are built
        and compiled once per formulation (``_form_key``); a new set of cells only hands the
        compiled kernels new integration cells (a refinement event used to spend 60 ms here
        re-deriving and looking up the same kernels). ``defer``: record the cells only; the
        forms take them when next used (``forms_ready``): a structure refines far more often
        than it solves statically, and its steps do not assemble these forms."""
        self.ufl_cells = [np.asarray(c, dtype=np.int32) for c in cells_per_layer]
        self._cells_pending = defer
        if not defer:
            self._hand_cells_to_forms()

    def forms_ready(self) -> None:
        """Hand the forms the cells a deferred ``set_ufl_cells`` recorded; call before using
        ``force_ufl``, ``energy_ufl``, ``force_form``, ``energy_form`` or ``enhanced``
        directly (this class's own methods do)."""
        if self._cells_pending:
            self._cells_pending = False
            self._hand_cells_to_forms()

    def _hand_cells_to_forms(self) -> None:
        """The compiled forms (compiled first if the formulation changed) over ``ufl_cells``."""
        if self._compiled is None or self._compiled.key != self._form_key():
            self._compiled = self._compile_forms()
        compiled = self._compiled
        # the UFL forms' measures share this list: force_ufl and energy_ufl follow it too
        for k, (subdomain_id, layer) in enumerate(compiled.layer_of_subdomain):
            compiled.subdomains[k] = (subdomain_id, self.ufl_cells[layer])
        subdomains = {fem.IntegralType.cell: list(compiled.subdomains)}
        coefficients = {self.u: self.u}
        for extra in (compiled.field, compiled.frame, compiled.bent):
            if extra is not None:
                coefficients[extra] = extra
        self.force_form, self.energy_form = (
            fem.create_form(form, spaces, self.mesh, subdomains, coefficients, {})
            for form, spaces in ((compiled.force, [self.V]), (compiled.energy, []))
        )
        field = compiled.field
        self.packed = PackedDisplacement(
            [self.force_form, self.energy_form],
            self.u,
            self.V,
            field,
            compiled.frame,
            compiled.bent,
        )
        self.enhanced = None
        if field is not None:
            cells = np.concatenate(self.ufl_cells) if self.ufl_cells else np.zeros(0, np.int32)
            maps = None if self.finite else self.enhanced_parameter_maps()[cells]
            self.enhanced = CondensedThicknessStrain(
                self.energy_ufl, field, self.u, self.V, cells, maps, compiled.frame, compiled.bent
            )

    def _form_key(self) -> tuple:
        """What the compiled forms depend on besides the cells."""
        return (
            tuple(self.layer_laminates),
            self.points_per_ply,
            self.selective,
            self.kinematics,
            self.shear_correction,
            self.enhanced_strain,
            self.preintegrate,
        )

    def _compile_forms(self) -> CompiledForms:
        """The energy and force forms of the layers over the cells ``ufl_cells`` holds now, and
        their compiled kernels; each integral's subdomain id remembers its layer."""
        v = ufl.TestFunction(self.V)
        kernels = solid_shell.SeparateKernels(self.mesh)
        field = None
        if self.enhanced_strain:
            field = fem.Function(fem.functionspace(self.mesh, ("DG", 1)), name="enhanced_zz")
        frame = self.frame_function()
        bent = self.bent_function()
        energy = 0
        layer_of_subdomain = []
        factors = self.shear_factors()
        for layer, (laminate, cells, k) in enumerate(
            zip(self.layer_laminates, self.ufl_cells, factors, strict=True)
        ):
            groups = solid_shell.energy_groups(laminate, self.points_per_ply, k, self.preintegrate)
            first = len(kernels.subdomains)
            energy += solid_shell.strain_energy_form(
                self.u, groups, kernels, cells, self.selective, self.kinematics, field, frame, bent
            )
            layer_of_subdomain += [(i, layer) for i, _ in kernels.subdomains[first:]]
        self.energy_ufl = energy
        self.force_ufl = ufl.derivative(energy, self.u, v)
        return CompiledForms(
            key=self._form_key(),
            force=fem.compile_form(self.comm, self.force_ufl, jit_options=JIT_OPTIONS),
            energy=fem.compile_form(self.comm, energy, jit_options=JIT_OPTIONS),
            subdomains=kernels.subdomains,
            layer_of_subdomain=layer_of_subdomain,
            field=field,
            frame=frame,
            bent=bent,
        )

    @property
    def curved(self) -> bool:
        """Whether the cells carry frames of their own (a shell mesh, ``meshes.shell``): the
        strain is then taken in each cell's frame (``cell_frames``); on the flat meshes of
        ``meshes.beam`` the frame is global (x, y, z) and nothing is rotated."""
        return isinstance(self.beam, ShellMesh)

    def cell_frames(self) -> np.ndarray | None:
        """(n_cells, 3, 3) frame of every local cell (owned, then ghosts), rows the material 1-,
        2- and 3- (normal) directions (``meshes.shell.ShellMesh.cell_frames``), from the
        reference geometry (computed once); None on a flat mesh (the global frame)."""
        if not self.curved:
            return None
        if self._frames is None:
            mesh = self.mesh
            self._frames = self.beam.cell_frames(mesh.geometry.x[mesh.geometry.dofmaps[0]])
        return self._frames

    def element_frames(self, cells: np.ndarray) -> np.ndarray:
        """(n, 3, 3) frames of (sub)elements of the local ``cells`` for the numba kernels: their
        cells' (``cell_frames``), or (0, 3, 3) on a flat mesh (nothing to rotate)."""
        frames = self.cell_frames()
        if frames is None:
            return np.zeros((0, 3, 3))
        return np.ascontiguousarray(frames[np.asarray(cells, dtype=np.int64)])

    @property
    def frame(self) -> fem.Function | None:
        """The cells' frames the compiled forms read (``frame_function``), or None."""
        self.forms_ready()
        return self._compiled.frame

    @property
    def bent(self) -> fem.Function | None:
        """The compiled forms' marker of the cells whose directors bend (``bent_function``), or
        None."""
        self.forms_ready()
        return self._compiled.bent

    def frame_function(self) -> fem.Function | None:
        """The cells' frames as the UFL forms read them: a DG0 3 x 3 function (None on a flat
        mesh)."""
        frames = self.cell_frames()
        if frames is None:
            return None
        space = fem.functionspace(self.mesh, ("DG", 0, (3, 3)))
        frame = fem.Function(space, name="frame")
        dofs = space.dofmap.list[: len(frames), 0]
        frame.x.array.reshape(-1, 9)[dofs] = frames.reshape(-1, 9)
        return frame

    def bent_function(self) -> fem.Function | None:
        """The UFL forms' marker of the cells whose directors bend (a DG0 function, 1 there and
        0 elsewhere; ``element.assumed_strain``), or None where no cell of any rank has them
        (the meshes' flat cells: the forms then leave the correction out, and compile as
        before)."""
        X = self.mesh.geometry.x[self.mesh.geometry.dofmaps[0]]  # every local cell
        bent = cells_with_bent_directors(X)
        if not self.comm.allreduce(bool(bent.any()), op=MPI.LOR):
            return None
        space = fem.functionspace(self.mesh, ("DG", 0))
        marker = fem.Function(space, name="bent_directors")
        marker.x.array[space.dofmap.list[: len(bent), 0]] = bent.astype(np.float64)
        return marker

    def reference_geometry_changed(self) -> None:
        """Call after moving the mesh's reference nodes (``mesh.geometry.x``): the small-strain
        enhanced parameter maps are computed from it once (``enhanced_parameter_maps``) and
        are rebuilt here, with the forms, as are the cells' time steps. The package itself never
        moves them."""
        self._enhanced_maps = None
        self._cell_time_steps = None
        self._frames = None
        # the forms' frames and marker of bent cells are the old geometry's
        self._compiled = None
        self.set_ufl_cells(self.ufl_cells)

    def enhanced_parameter_maps(self) -> np.ndarray:
        """(n_owned_cells, 4, 8, 3) small-strain maps from each cell's nodal displacements (its
        vertex order) to its four enhanced thickness strain parameters
        (``subelement.enhanced_parameter_maps``), computed once per model from the reference
        geometry and the stiffness (``reference_geometry_changed`` after moving the mesh)."""
        if self._enhanced_maps is None:
            maps = np.zeros((self.n_owned_cells, 4, 8, 3))
            X = cell_vertex_coordinates(self.mesh)
            frames = self.cell_frames()
            for k, laminate in enumerate(self.layer_laminates):
                rule = pack_rule(
                    laminate.ply_fractions,
                    np.array(laminate.ply_stiffnesses()),
                    self.points_per_ply,
                    enhanced=True,
                    preintegrate=self.preintegrate,
                )
                if not np.array_equal(rule.positions[:4], solid_shell.ENHANCED_LINES):
                    raise RuntimeError("the rule's first four lines are not the enhanced lines")
                cells = self.layer_cells(k)
                layer_maps = np.zeros((len(cells), 4, 8, 3))
                X_cells = X[cells]
                if frames is not None:  # in the cells' frames: x' = R x
                    X_cells = np.einsum("cij,caj->cai", frames[cells], X_cells)
                enhanced_parameter_maps(
                    np.ascontiguousarray(X_cells),
                    np.zeros(len(cells), dtype=np.int64),
                    *concatenate_rules([rule]),
                    layer_maps,
                )
                if frames is not None:  # alpha = m' . (R u) = (R^T m') . u
                    layer_maps = np.einsum("ckaj,cji->ckai", layer_maps, frames[cells])
                maps[cells] = layer_maps
            self._enhanced_maps = maps
        return self._enhanced_maps

    @property
    def laminate(self) -> Laminate:
        """The whole laminate, all layers' plies bottom to top."""
        return Laminate(tuple(p for layer in self.layer_laminates for p in layer.plies))

    def shear_factors(self) -> list[np.ndarray]:
        """(n_plies, 2) each ply's (m_xz, m_yz) of each layer's elements: the whole laminate's
        shear distribution over the layer's plies (``materials.laminate.ply_shear_factors``:
        1 for a one-ply layer or without ``shear_correction``)."""
        laminate, first, out = self.laminate, 0, []
        for layer in self.layer_laminates:
            stop = first + layer.n_plies
            out.append(ply_shear_factors(laminate, first, stop, self.shear_correction))
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
        """The pre-pass of the forms before an assembly: pack what their kernels read that
        depends on the displacement (``PackedDisplacement``), and condense the enhanced
        thickness strain of every UFL cell from it, so that the force and the energy both see
        it."""
        self.forms_ready()
        self.packed.update()
        if self.enhanced is not None:
            self.enhanced.condense()
            self.packed.set_field()

    def assemble_internal_force(self, out: np.ndarray) -> None:
        """Add this rank's share of f_int(u) (N) over the UFL cells into ``out`` (owned + ghost
        entries, no scatter), from the coefficients of the last ``update_coefficients``."""
        self.forms_ready()
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

    def cell_time_steps(self) -> np.ndarray:
        """(n_owned_cells,) L_e / c (s) of each cell: L_e = volume / largest face area, c the
        fastest dilatational wave speed of its plies. Computed once from the reference geometry
        (``reference_geometry_changed`` after moving the mesh); do not modify."""
        if self._cell_time_steps is None:
            ratios = characteristic_lengths(cell_vertex_coordinates(self.mesh))
            self._cell_time_steps = ratios / self.cell_wave_speeds()
        return self._cell_time_steps

    def stable_time_step(self) -> tuple[float, int]:
        """(min over cells of L_e / c, the cell attaining it), reduced over ranks
        (``cell_time_steps``)."""
        ratios = self.cell_time_steps()
        if len(ratios) == 0:  # a rank without cells still joins the reduction
            return self.comm.allreduce((np.inf, -1), op=MPI.MIN)
        cell = int(np.argmin(ratios))
        return self.comm.allreduce((float(ratios[cell]), cell), op=MPI.MIN)


def build_model(
    beam: BeamMesh,
    layer_laminates: list[Laminate],
    points_per_ply: int = 2,
    selective: bool = True,
    kinematics: str = "small",
    shear_correction: bool = True,
    enhanced_strain: bool = True,
    preintegrate: bool = True,
) -> LayeredModel:
    """``selective=False`` gives the plain fully integrated hexahedron (locks; for comparison).
    ``kinematics``: "small" (linear strain) or "finite" (total Lagrangian, Green-Lagrange).
    ``shear_correction``: the laminate's transverse shear correction on each layer's elements
    of several plies, ply by ply (``materials.laminate.ply_shear_factors``); off, the constant
    shear strain of the element carries the plies' full shear moduli. ``enhanced_strain``: the
    enhanced assumed thickness strain (``solid_shell`` module docstring); off, the element has
    Poisson thickness locking in bending (kept for comparison). ``preintegrate``: each layer's
    plies pre-integrated onto three points through the thickness where
    ``solid_shell.thickness_rule`` takes that rule (exact in bending, cheaper than a point per
    ply); off, or where it is not
    positive definite, ``points_per_ply`` Gauss points in each ply."""
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
        if laminate.n_plies * points_per_ply < 2:  # one ply: Gauss points whatever the rule
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
        enhanced_strain=enhanced_strain,
        preintegrate=preintegrate,
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


@njit(cache=True)
def _gather_field(field, field_dofs, out, offset):
    """out[r, offset + j] = field[field_dofs[r, j]]: a per-cell field as FFCx kernels read it."""
    for r in range(field_dofs.shape[0]):
        for j in range(field_dofs.shape[1]):
            out[r, offset + j] = field[field_dofs[r, j]]


class PackedDisplacement:
    """The constants and the packed coefficients of the model's forms (force, energy), kept
    between steps: the displacement u and, with the enhanced thickness strain, its per-cell
    ``field`` (a scalar DG Q1 function), and on a curved shell the cells' ``frame`` (a DG0
    3 x 3 function) and the marker of its ``bent`` cells (DG0), which never change: packed
    once.

    DOLFINx packs every coefficient of every integral on each assembly call. The forms have
    several integrals over the same cells (one kernel per custom quadrature rule, see
    ``solid_shell.SeparateKernels``), each with its own copy of u, and their constants (the ply
    stiffnesses) never change. Here the constants are packed once, and u once per call of
    ``update`` (the field once per ``set_field``) into one array per set of cells, shared by
    every integral of every form over those cells. ``constants[i]`` and ``coeffs[i]`` are what
    ``forms[i]``'s assembly takes.

    The layout is DOLFINx's: per cell, the coefficients in the form's order, each in its cell
    dofmap order, block-unrolled (u: the 8 nodes, 3 components each; the field: its 8 cell
    values; the frame: its 9 entries; the bent cells' marker: 1). ``tests/test_model.py``
    checks it against ``fem.pack_coefficients``; this class does not call that at set-up,
    because it packs every integral at once (100 MiB for a 40 000-cell ESL plate, 400 MiB for
    its layerwise model) and the freed memory stays with the process."""

    def __init__(
        self,
        forms: list[fem.Form],
        u: fem.Function,
        V: fem.FunctionSpace,
        field: fem.Function | None = None,
        frame: fem.Function | None = None,
        bent: fem.Function | None = None,
    ):
        if V.dofmap.index_map_bs != 3 or V.dofmap.list.shape[1] != 8:
            raise ValueError("PackedDisplacement: expected a 3-component P1 space on hexahedra")
        self.u = u.x.array
        self.field = None if field is None else field.x.array
        known = [u, field, frame, bent]
        cell = fem.IntegralType.cell
        # per set of cells and layout: u's cell dofs, the packed array, the field's unrolled
        # cell dofs and offset (or None)
        groups: dict[tuple, tuple[np.ndarray, np.ndarray, tuple | None]] = {}
        self.constants: list[np.ndarray] = []
        self.coeffs: list[dict] = []
        for form in forms:
            cpp = form._cpp_object
            order = []
            for c in cpp.coefficients:
                match = [  # the same function (a rank without nodes has empty arrays)
                    i
                    for i, f in enumerate(known)
                    if f is not None
                    and (c is f._cpp_object or np.shares_memory(c.x.array, f.x.array))
                ]
                if not match:
                    raise ValueError("PackedDisplacement: a form reads an unknown coefficient")
                order.append(match[0])
            if order[0] != 0 or len(order) != len(set(order)):
                raise ValueError("PackedDisplacement: u must be a form's first coefficient")
            widths = [24] + [_unrolled_width(known[k]) for k in order[1:]]
            offsets = np.concatenate([[0], np.cumsum(widths)]).astype(int)
            if set(cpp.integral_types) != {cell}:
                raise ValueError("PackedDisplacement: expected cell integrals only")
            coeffs = {}
            for i in range(cpp.num_integrals(cell, 0)):  # the keys DOLFINx's packing uses
                cells = np.asarray(cpp.domains(cell, i))
                signature = (cells.tobytes(), tuple(order))
                if signature not in groups:
                    cell_dofs = np.ascontiguousarray(V.dofmap.list[cells], dtype=np.int64)
                    packed = np.zeros((len(cells), offsets[-1]))
                    field_slot = None
                    for position, k in enumerate(order[1:], start=1):
                        dofs = _unrolled_dofs(known[k], cells)
                        if k == 1:
                            field_slot = (dofs, int(offsets[position]))
                        else:  # the frame or the bent cells' marker: fixed, packed once
                            _gather_field(known[k].x.array, dofs, packed, int(offsets[position]))
                    groups[signature] = (cell_dofs, packed, field_slot)
                coeffs[(cell, i)] = groups[signature][1]
            self.constants.append(fem.pack_constants(form))
            self.coeffs.append(coeffs)
        self.groups = list(groups.values())
        self.update()

    def update(self) -> None:
        """Pack the current displacement."""
        for cell_dofs, packed, _ in self.groups:
            _gather_cell_values(self.u, cell_dofs, packed)

    def set_field(self) -> None:
        """Pack the field's current values (in the forms that read it)."""
        for _, packed, field_slot in self.groups:
            if field_slot is not None:
                _gather_field(self.field, field_slot[0], packed, field_slot[1])


def _unrolled_width(function: fem.Function) -> int:
    """Values per cell of a coefficient as FFCx reads it (dofs per cell x block size)."""
    dofmap = function.function_space.dofmap
    return dofmap.list.shape[1] * dofmap.index_map_bs


def _unrolled_dofs(function: fem.Function, cells: np.ndarray) -> np.ndarray:
    """(len(cells), width) the entries of ``function.x.array`` each cell reads, in order."""
    dofmap = function.function_space.dofmap
    bs = dofmap.index_map_bs
    blocks = dofmap.list[cells].astype(np.int64)
    return np.ascontiguousarray(
        (bs * blocks[:, :, None] + np.arange(bs)[None, None, :]).reshape(
            len(cells), blocks.shape[1] * bs
        )
    )


@njit(cache=True)
def _condense_lines(residual, cell_dofs, T, h, alpha):
    """alpha[r] = -(T^T residual[cell_dofs[r]]) / h[r] (``CondensedThicknessStrain``)."""
    for r in range(cell_dofs.shape[0]):
        for k in range(T.shape[1]):
            s = 0.0
            for j in range(T.shape[0]):
                s += T[j, k] * residual[cell_dofs[r, j]]
            alpha[r, k] = -s / h[r, k]


@njit(cache=True)
def _linear_parameters(u, node_of_vertex, maps, alpha):
    """alpha[r, k] = sum maps[r, k, a, i] u[3 node_of_vertex[r, a] + i]."""
    for r in range(maps.shape[0]):
        for k in range(maps.shape[1]):
            s = 0.0
            for a in range(8):
                node = 3 * node_of_vertex[r, a]
                for i in range(3):
                    s += maps[r, k, a, i] * u[node + i]
            alpha[r, k] = s


@njit(cache=True)
def _field_values(alpha, T, cell_dofs, field):
    """field[cell_dofs[r]] = T alpha[r]: the field alpha g of each cell at its 8 nodes."""
    for r in range(cell_dofs.shape[0]):
        for j in range(T.shape[0]):
            s = 0.0
            for k in range(T.shape[1]):
                s += T[j, k] * alpha[r, k]
            field[cell_dofs[r, j]] = s


class CondensedThicknessStrain:
    """The enhanced thickness strain of the UFL cells, condensed cell by cell (``solid_shell``
    module docstring: four parameters alpha per cell, one per line of the normal term's points).

    The forms read it as ``field``, a scalar DG Q1 function equal to alpha(xi, eta) g(zeta) in
    each cell (``solid_shell.enhanced_nodal_map`` T: its 8 cell values are T alpha). The
    residual of the four parameters is T^T of the energy's derivative with respect to the
    field, and their stiffness h (diagonal: each parameter lives on its own line of points) is
    T^T of the derivative's derivative in the direction T (1, 1, 1, 1). ``condense`` assembles
    the derivative at field = 0 from the packed displacement (one vector assembly over the
    normal terms' points) and sets alpha = -r / h: exact in one step, the residual being linear
    in alpha (St. Venant-Kirchhoff plies, small or finite strain). With small strain r is
    linear in u too: given ``linear_maps`` (n, 4, 8, 3) (``LayeredModel
    .enhanced_parameter_maps``), alpha is their product with the cells' displacements, 96
    multiply-adds per cell instead of an assembly (``tests/test_enhanced_strain.py`` holds the
    two equal)."""

    def __init__(
        self,
        energy: ufl.Form,
        field: fem.Function,
        u: fem.Function,
        V: fem.FunctionSpace,
        cells: np.ndarray,
        linear_maps: np.ndarray | None = None,
        frame: fem.Function | None = None,
        bent: fem.Function | None = None,
    ):
        A = field.function_space
        self.field = field
        self._field_array = field.x.array  # taken once: each .array costs 2 us
        self.u = u.x.array
        self.cells = np.asarray(cells, dtype=np.int64)
        self.T = solid_shell.enhanced_nodal_map(A.element.interpolation_points)
        self.cell_dofs = np.ascontiguousarray(A.dofmap.list[self.cells], dtype=np.int64)
        self.alpha = np.zeros((len(self.cells), self.T.shape[1]))
        self.linear_maps = None
        if linear_maps is not None:
            self.linear_maps = np.ascontiguousarray(linear_maps)
            self.node_of_vertex = np.ascontiguousarray(V.dofmap.list[self.cells], dtype=np.int64)
            return
        residual = ufl.derivative(energy, field, ufl.TestFunction(A))
        self.residual_form = fem.form(
            ufl.replace(residual, {field: ufl.zero()}), jit_options=JIT_OPTIONS
        )
        direction = fem.Function(A)
        direction.x.array[self.cell_dofs] = self.T.sum(axis=1)
        hessian = fem.assemble_vector(
            fem.form(ufl.derivative(residual, field, direction), jit_options=JIT_OPTIONS)
        )
        self.h = hessian.array[self.cell_dofs] @ self.T  # (n, 4)
        self.residual = np.zeros(A.dofmap.index_map.size_local + A.dofmap.index_map.num_ghosts)
        self.packed = PackedDisplacement([self.residual_form], u, V, frame=frame, bent=bent)

    def condense(self) -> None:
        """alpha of every cell from the current displacement, and the field's values from it."""
        if self.linear_maps is not None:
            _linear_parameters(self.u, self.node_of_vertex, self.linear_maps, self.alpha)
        else:
            self.packed.update()
            self.residual.fill(0.0)
            fem.assemble_vector(
                self.residual,
                self.residual_form,
                constants=self.packed.constants[0],
                coeffs=self.packed.coeffs[0],
            )
            _condense_lines(self.residual, self.cell_dofs, self.T, self.h, self.alpha)
        _field_values(self.alpha, self.T, self.cell_dofs, self._field_array)
