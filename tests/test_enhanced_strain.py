"""The enhanced assumed thickness strain (``element.solid_shell`` module docstring): the numba
kernels and the UFL forms condense the same four parameters per element, to round-off; the
condensed parameters make the energy stationary; constant stress is untouched (patch test);
and the spurious thickness stress of bending (Poisson thickness locking) is gone.

Units: N, mm, s, tonne (stresses MPa).
"""

from __future__ import annotations

import numpy as np
import pytest
from dolfinx import fem
from helpers import (
    CARBON,
    CROSS_PLY,
    PROTOTYPE_PLY,
    EnhancedCell,
    distorted_hex,
    esl_model,
    random_laminate,
    relative_difference,
    subelement_vertices,
)

from fenics_adaptive.adaptivity.indicators import ply_stresses
from fenics_adaptive.analysis.comparison import solve_linear_static
from fenics_adaptive.element import subelement as se
from fenics_adaptive.element.subelement import sublaminate_ply_zeta
from fenics_adaptive.materials.laminate import Laminate, Ply
from fenics_adaptive.model import loading
from fenics_adaptive.model.forms import CondensedThicknessStrain, cell_vertex_coordinates
from fenics_adaptive.settings.config import parse_config
from fenics_adaptive.settings.loads import Amplitude, FaceLoad, clamp
from fenics_adaptive.simulation import build_structure
from fenics_adaptive.solver.static import solve_static


def kernel_force(X, U, rule, finite: bool) -> tuple[np.ndarray, float]:
    f = np.empty((8, 3))
    energy = se.solid_shell_force(X, U, *rule, f, finite)
    return f, energy


# each kinematics and each number of points per ply once (every UFL form compiled costs
# 10-20 s on a fresh machine; the kernel's two branches do not depend on each other)
@pytest.mark.parametrize(("kinematics", "ppp"), [("small", 1), ("finite", 2)])
def test_kernel_equals_condensed_ufl_form(kinematics, ppp):
    """A distorted hexahedron of a random 4-ply laminate and one of its subelements (plies 1:3)
    under a random displacement: the numba kernel's force and energy equal the UFL form's with
    the parameters condensed by UFL assembly, to round-off; the condensed parameters make the
    UFL energy stationary; the enhanced strain changes the force by percents (it is there)."""
    rng = np.random.default_rng(11 + ppp)
    laminate = random_laminate(rng, 4)
    parent = distorted_hex(rng)
    stiffness = np.array(laminate.ply_stiffnesses())
    for first, stop in ((0, 4), (1, 3)):
        X = subelement_vertices(parent, laminate.ply_fractions, first, stop)
        sub = Laminate(laminate.plies[first:stop])
        U = rng.normal(scale=1e-2, size=(8, 3))
        cell = EnhancedCell(X, sub, ppp, kinematics)
        f_ufl, energy_ufl = cell.force(U)
        zeta = sublaminate_ply_zeta(laminate.ply_fractions, first, stop)
        rule = se.pack_rule(zeta, stiffness[first:stop], ppp, enhanced=True)
        f, energy = kernel_force(X, U, rule, kinematics == "finite")
        assert relative_difference(f, f_ufl) < 1e-12
        assert energy == pytest.approx(energy_ufl, rel=1e-12)
        scale = np.abs(f_ufl).max() * np.abs(U).max()
        assert np.abs(cell.parameter_residual()).max() < 1e-12 * scale
        plain_rule = se.pack_rule(zeta, stiffness[first:stop], ppp)
        plain, plain_energy = kernel_force(X, U, plain_rule, kinematics == "finite")
        assert relative_difference(plain, f) > 1e-3
        assert energy < plain_energy  # the condensed parameters minimise the energy


def test_enhanced_strain_leaves_constant_stress_alone():
    """Patch test of the enhancement alone, on a distorted hexahedron: under a uniform stress
    (a uniform strain of plies of one material and angle, unequal in thickness) the condensed
    parameters are zero, so the force is the compatible element's (the 1 / |det J| scaling
    makes the modes orthogonal to constant stress). A uniform strain of a laminate of
    different plies is not a constant stress: there the parameters are not zero. The
    hexahedron's vertical edges are parallel: where they are not, the edge-sampled thickness
    strain (``element.assumed_strain``) is not uniform under a uniform strain."""
    rng = np.random.default_rng(5)
    laminate = Laminate(tuple(Ply(CARBON, 30.0, t) for t in (0.2, 0.5, 0.3)))
    X = distorted_hex(rng, amount=0.2)
    X[4:] = X[:4] + (X[4:] - X[:4]).mean(axis=0)  # parallel vertical edges
    strain = rng.normal(scale=1e-3, size=(3, 3))
    U = X @ strain.T
    stiffness = np.array(laminate.ply_stiffnesses())
    for ppp in (1, 2):
        plain = kernel_force(X, U, se.pack_rule(laminate.ply_fractions, stiffness, ppp), False)
        rule = se.pack_rule(laminate.ply_fractions, stiffness, ppp, enhanced=True)
        enhanced = kernel_force(X, U, rule, False)
        assert relative_difference(enhanced[0], plain[0]) < 1e-12
        assert enhanced[1] == pytest.approx(plain[1], rel=1e-12)


@pytest.mark.parametrize(
    "angles", [[0] * 8, CROSS_PLY, [0, 90, 0]], ids=["[0]8", "[0/90]2s", "[0/90/0]"]
)
def test_no_spurious_thickness_stress_in_bending(angles):
    """A tip-loaded ESL cantilever (S = 12.5, one cell through the thickness): in the cells
    around mid-span the plies' mean thickness stress stays below 1 % of the largest ply bending
    stress (beam theory: zero); with the compatible thickness strain alone it is the Poisson
    share of the bending stress (2.5 % for [0]8, tens of percent in 90-degree plies)."""
    ratios = {}
    for enhanced in (True, False):
        model = esl_model(angles, 25.0, 2.0, 25, 1, enhanced_strain=enhanced, points_per_ply=2)
        motions = clamp("x0")
        loads = loading.resolve(
            model, motions, [FaceLoad("x1", (0.0, 0.0, -1.0), Amplitude.constant())]
        )
        u = solve_static(model, motions, loads, 0.0)
        laminate = model.layer_laminates[0]
        stiffness = np.array(laminate.ply_stiffnesses())
        rule = se.pack_rule(laminate.ply_fractions, stiffness, 2, enhanced=enhanced)
        X_all = cell_vertex_coordinates(model.mesh)
        dofs = model.V.dofmap.list[: len(X_all)]
        x = X_all.mean(axis=1)[:, 0]
        worst_zz, worst_xx = 0.0, 0.0
        for cell in np.flatnonzero(np.abs(x - 12.5) < 3.0):
            strains = se.ply_mean_strains(X_all[cell], u.reshape(-1, 3)[dofs[cell]], rule)
            stresses = np.einsum("kab,kb->ka", stiffness, strains)
            worst_zz = max(worst_zz, np.abs(stresses[:, 2]).max())
            worst_xx = max(worst_xx, np.abs(stresses[:, 0]).max())
        ratios[enhanced] = worst_zz / worst_xx
    assert ratios[True] < 0.01, ratios
    assert ratios[False] > max(0.02, 5 * ratios[True]), ratios


def test_indicator_ply_stresses_carry_the_enhanced_strain():
    """The refinement indicators' ply stresses (``indicators.ply_stresses``, at each ply's
    centre) add the element's condensed enhanced strain: in a bent ESL [0/90]2s cantilever the
    thickness stress around mid-span stays below 1 % of the peak bending stress, where the
    compatible strain alone gives the Poisson share (the same parameters as the force kernel:
    ``subelement.enhanced_parameter_maps``)."""
    worst = {}
    for enhanced in (True, False):
        data = {
            "model": {"kind": "esl", "points_per_ply": 2, "enhanced_strain": enhanced},
            "mesh": {"length": 25.0, "width": 2.0, "nx": 25, "ny": 2},
            "materials": {"ply": PROTOTYPE_PLY},
            "laminate": {"material": "ply", "ply_thickness": 0.25, "angles": CROSS_PLY},
            "clamp": [{"face": "x0"}],
            "load": [{"face": "x1", "force": [0.0, 0.0, -1.0], "curve": [[0.0, 1.0]]}],
            "solver": {"end_time": 1e-6},
            "output": {"interval": 1e-6, "displacement_face": "x1", "reaction_face": "x0",
                       "component": "z"},
        }  # fmt: skip
        structure = build_structure(parse_config(data))
        solve_linear_static(structure)
        stresses = ply_stresses(structure)
        x = structure.X_base[structure.bottom_local].mean(axis=1)[:, 0]
        middle = np.abs(x - 12.5) < 3.0
        worst[enhanced] = (
            np.abs(stresses[middle, :, 2]).max() / np.abs(stresses[middle, :, 0]).max()
        )
    assert worst[True] < 0.01, worst
    assert worst[False] > max(0.02, 5 * worst[True]), worst


@pytest.mark.parametrize("angles", [CROSS_PLY, [0.0, 45.0, 90.0]], ids=["[0/90]2s", "[0/45/90]"])
def test_small_strain_linear_maps_equal_the_assembled_condensation(angles):
    """With small strain the model takes each cell's parameters from a precomputed linear map
    of its nodal displacements (numba, ``subelement.enhanced_parameter_maps``); the UFL
    assembly of their residual (the finite-strain path) gives the same parameters, to
    round-off, on distorted cells, and so the same force."""
    model = esl_model(angles, 6.0, 3.0, 6, 3)
    rng = np.random.default_rng(2)
    x = model.mesh.geometry.x
    # in-plane distortion, thickness intact (the vertical edges tilt: the thickness strain is
    # sampled on them, element.assumed_strain)
    x[:, :2] += rng.uniform(-0.1, 0.1, (len(x), 2))
    model.reference_geometry_changed()
    model.u.x.array[:] = rng.normal(scale=1e-2, size=model.u.x.array.shape)
    fast = model.enhanced
    assert fast.linear_maps is not None
    f_fast = np.zeros_like(model.u.x.array)
    model.add_internal_force(f_fast)
    cells = fast.cells
    assembled = CondensedThicknessStrain(
        model.energy_ufl, fast.field, model.u, model.V, cells, bent=model.bent
    )
    assembled.condense()
    scale = np.abs(assembled.alpha).max()
    assert scale > 0.0
    np.testing.assert_allclose(fast.alpha, assembled.alpha, rtol=0, atol=1e-12 * scale)
    f_assembled = fem.assemble_vector(model.force_form).array  # the field as assembled now
    np.testing.assert_allclose(f_fast, f_assembled, rtol=0, atol=1e-11 * np.abs(f_fast).max())
