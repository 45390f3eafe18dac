"""The ESL solid-shell element: patch test, rigid-body motion, mass, and bending without shear
locking (static, against classical laminate beam theory).

Units: N, mm, s, tonne.
"""

import numpy as np
import pytest
from dolfinx import fem
from dolfinx.fem import petsc as fem_petsc
from fenics_adaptive.meshes import esl_mesh
from helpers import CROSS_PLY, esl_model, prototype_material
from petsc4py import PETSc

from fenics_adaptive.materials.laminate import VOIGT_PAIRS, Laminate, Ply
from fenics_adaptive.model import loading
from fenics_adaptive.model.forms import build_model
from fenics_adaptive.model.loading import face_dofs
from fenics_adaptive.settings.loads import Amplitude, FaceLoad, clamp
from fenics_adaptive.solver.static import solve_static, stiffness_form


def internal_force(model, u_nodes):
    model.u.x.array[:] = u_nodes
    f = fem.Function(model.V).x
    model.internal_force(f)
    return f.array


def linear_field(model, gradient, shift=(0.0, 0.0, 0.0)):
    x = model.V.tabulate_dof_coordinates()
    return (x @ np.asarray(gradient).T + np.asarray(shift)).ravel()


def skew_mesh(model, shear=0.35):
    """x += shear * y: every cell becomes the same parallelogram (a skewed patch)."""
    x = model.mesh.geometry.x
    x[:, 0] += shear * x[:, 1]
    model.reference_geometry_changed()


def distort_mesh(model, amount=0.25, seed=1):
    """Move each interior node column in-plane at random: general quadrilateral cells."""
    x = model.mesh.geometry.x
    rng = np.random.default_rng(seed)
    lo, hi = x.min(axis=0), x.max(axis=0)
    interior = np.all((x[:, :2] > lo[:2] + 1e-9) & (x[:, :2] < hi[:2] - 1e-9), axis=1)
    columns = {}
    for i in np.flatnonzero(interior):
        key = (round(x[i, 0], 9), round(x[i, 1], 9))
        columns.setdefault(key, rng.uniform(-amount, amount, 2))
        x[i, :2] += columns[key]
    model.reference_geometry_changed()


def patch_solution(model, gradient):
    """u = gradient . x prescribed on the lateral faces, the exact surface tractions sigma . n
    on top and bottom (one stiffness through the thickness, so sigma is uniform): solve, return
    the solution and the exact field."""
    exact = linear_field(model, gradient)
    C = model.layer_laminates[0].plies[0].stiffness()
    strain = 0.5 * (gradient + gradient.T)
    voigt = np.array([strain[i, j] * (1 if i == j else 2) for i, j in VOIGT_PAIRS])
    sigma_voigt = C @ voigt
    sigma = np.zeros((3, 3))
    for a, (i, j) in enumerate(VOIGT_PAIRS):
        sigma[i, j] = sigma[j, i] = sigma_voigt[a]
    area = model.beam.length * model.beam.width
    tractions = [
        FaceLoad(face, tuple(sign * area * sigma[:, 2]), Amplitude.constant())
        for face, sign in (("top", 1.0), ("bottom", -1.0))
    ]
    loads = loading.resolve(model, [], tractions)

    V = model.V
    g = fem.Function(V)
    lateral = np.concatenate(
        [
            face_dofs(model, face, comp, owned_only=False)
            for face in ("x0", "x1", "y0", "y1")
            for comp in "xyz"
        ]
    )
    g.x.array[lateral] = exact[lateral]
    bc = fem.dirichletbc(g, np.unique(lateral // 3).astype(np.int32))
    a = fem.form(stiffness_form(model))
    A = fem_petsc.assemble_matrix(a, bcs=[bc])
    A.assemble()
    rhs = fem.Function(V)  # keep it alive: its petsc_vec borrows its memory
    loads.external_force(0.0, rhs.x.array)
    b = rhs.x.petsc_vec
    fem_petsc.apply_lifting(b, [a], bcs=[[bc]])
    fem_petsc.set_bc(b, [bc])
    ksp = PETSc.KSP().create(model.comm)
    ksp.setOperators(A)
    ksp.setType("preonly")
    ksp.getPC().setType("lu")
    u = fem.Function(V)
    ksp.solve(b, u.x.petsc_vec)
    return u.x.array.copy(), exact


UNIFORM_STRAIN = np.array([[1.0, 0.3, 0.2], [-0.1, 0.5, 0.4], [0.25, -0.2, 0.7]]) * 1e-3
MEMBRANE_STRAIN = np.array([[1.0, 0.3, 0.0], [-0.1, 0.5, 0.0], [0.0, 0.0, 0.7]]) * 1e-3


@pytest.mark.parametrize("angle", [0.0, 30.0])
def test_patch_test_parallelogram_cells(angle):
    """Any uniform strain (all six components), on a skewed patch of parallelogram cells with
    interior nodes, is reproduced exactly: every node lands on the linear field. (Without the
    shear correction: a constant transverse shear then carries k G, as in any corrected shell.)"""
    model = esl_model([angle] * 4, 4.0, 3.0, 4, 3, shear_correction=False)
    skew_mesh(model)
    u, exact = patch_solution(model, UNIFORM_STRAIN)
    assert np.abs(u - exact).max() < 1e-12 * np.abs(exact).max()


def test_patch_test_distorted_cells_membrane_and_thickness():
    """On general (non-parallelogram) quadrilaterals the in-plane and thickness strains are still
    reproduced exactly (the selective transverse-shear rule is exact on parallelograms only)."""
    model = esl_model([30.0] * 4, 4.0, 3.0, 4, 3)
    distort_mesh(model)
    u, exact = patch_solution(model, MEMBRANE_STRAIN)
    assert np.abs(u - exact).max() < 1e-12 * np.abs(exact).max()


def test_rigid_body_motion_gives_zero_force():
    model = esl_model(CROSS_PLY, 6.0, 2.0, 3, 2)
    distort_mesh(model, amount=0.3)
    strain_force = np.abs(internal_force(model, linear_field(model, UNIFORM_STRAIN))).max()
    translation = linear_field(model, np.zeros((3, 3)), shift=(0.3, -0.2, 0.5))
    spin = np.array([[0.0, -0.4, 0.2], [0.4, 0.0, -0.1], [-0.2, 0.1, 0.0]]) * 1e-3
    rotation = linear_field(model, spin)
    assert np.abs(internal_force(model, translation)).max() < 1e-12 * strain_force
    assert np.abs(internal_force(model, rotation)).max() < 1e-12 * strain_force


def test_total_lumped_mass_equals_density_times_volume():
    light = prototype_material("light", rho=1.2e-9)
    heavy = prototype_material("heavy", rho=7.8e-9)
    laminate = Laminate((Ply(light, 0, 0.3), Ply(heavy, 45, 0.1), Ply(light, 90, 0.5)))
    from mpi4py import MPI

    beam = esl_mesh(MPI.COMM_WORLD, 12.0, 5.0, 6, 4, laminate.thickness)
    model = build_model(beam, [laminate])
    distort_mesh(model, amount=0.5)  # in-plane distortion keeps the area
    expected = 12.0 * 5.0 * (1.2e-9 * 0.8 + 7.8e-9 * 0.1)
    assert model.total_mass() == pytest.approx(expected, rel=1e-13)
    assert np.all(model.mass > 0)


def tip_deflection(model, force=-1.0):
    motions = clamp("x0")
    loads = loading.resolve(
        model, motions, [FaceLoad("x1", (0.0, 0.0, force), Amplitude.constant())]
    )
    u = solve_static(model, motions, loads, 0.0)
    return u[face_dofs(model, "x1", "z")].mean()


@pytest.mark.parametrize("angles", [[0] * 8, CROSS_PLY], ids=["[0]8", "[0/90]2s"])
@pytest.mark.parametrize("nx", [10, 40])
def test_cantilever_one_element_through_thickness_matches_beam_theory(angles, nx):
    """100 mm x 2 mm x 2 mm cantilever, tip load: with nx = 10 the cells are 10 x 2 x 2 mm
    (aspect ratio 5 in-plane and against the thickness). Beam theory: P L^3 / (3 EI), EI from
    classical laminate theory for a narrow beam, plus the shear deflection P L / (k G13 A)."""
    model = esl_model(angles, 100.0, 2.0, nx, 1)
    laminate = model.layer_laminates[0]
    EI = laminate.narrow_beam_bending_stiffness(2.0)
    bending = -(100.0**3) / (3 * EI)
    deflection = tip_deflection(model)
    assert deflection == pytest.approx(bending, rel=0.03)


def test_fully_integrated_hexahedron_locks():
    """The same cantilever without the selective shear rule is far too stiff: what the rule is
    for, and proof that the test above can fail."""
    model = esl_model([0] * 8, 100.0, 2.0, 10, 1, selective=False)
    EI = model.layer_laminates[0].narrow_beam_bending_stiffness(2.0)
    assert abs(tip_deflection(model)) < 0.6 * 100.0**3 / (3 * EI)
