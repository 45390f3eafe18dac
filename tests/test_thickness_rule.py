"""The pre-integrated through-thickness rule (``solid_shell.thickness_rule``), the default.

Three points carry the laminate's stiffness moments of order 0, 1 and 2 through the thickness
(its A, B and D), so that on cells with parallel top and bottom faces (where the small strain,
enhanced thickness strain included, is affine along each vertical line) the element energy and
force are exact for any number of plies, at the cost of three points per line instead of one
or two per ply (issue 14: one point per ply was 1-11 % off in bending). Checked here:

- the points reproduce the moments of random laminates and spans; one material gets its own
  stiffness at each point;
- on flat cells (skewed in-plane, any displacement) the kernel's force and energy with the
  pre-integrated rule equal those with 2 and 3 Gauss points per ply (both exact) to 1e-12, for
  whole laminates and subelements, with the enhanced thickness strain and shear correction;
- on distorted cells the numba kernel and the condensed UFL form integrate the same rule:
  equal to 1e-12, small and finite kinematics;
- the rule falls back to Gauss points per ply where a point's stiffness would not be positive
  definite (a sandwich with a soft core, a [0/90] pair), for one ply, and for ply damage; the
  element energy stays positive on distorted cells;
- with the defaults and the shear correction, tip-loaded ESL cantilevers of four layups at
  S = L/h = 5 and 50 bend as laminate beam theory with the laminate's exact shear compliance
  within 1 % and 0.2 % (measured 0.50 % and 0.08 % at most), and no integration warning is
  printed; one point per ply, 0.9-8.8 % too flexible, warns.

Units: N, mm, s, tonne (stress MPa).
"""

from __future__ import annotations

import numpy as np
import pytest
from helpers import (
    BOX,
    CARBON,
    GLASS,
    EnhancedCell,
    distorted_hex,
    random_laminate,
    relative_difference,
    subelement_vertices,
    tip_loaded_cantilever_error,
)
from mpi4py import MPI

from fenics_adaptive.element import solid_shell
from fenics_adaptive.element import subelement as se
from fenics_adaptive.element.rules import RuleTable, bending_stiffness_error, integration_warnings
from fenics_adaptive.materials.laminate import Laminate, Ply, shear_correction_factors
from fenics_adaptive.settings.config import parse_config
from fenics_adaptive.simulation import build_structure

QUASI_ISOTROPIC = [0.0, 45.0, -45.0, 90.0, 90.0, -45.0, 45.0, 0.0]


def bounds_of(laminate: Laminate) -> np.ndarray:
    f = laminate.ply_fractions
    return np.column_stack([f[:-1], f[1:]])


def kernel_force(X, U, rule, finite: bool = False) -> tuple[np.ndarray, float]:
    f = np.empty((8, 3))
    energy = se.solid_shell_force(X, U, *rule, f, finite)
    return f, energy


def flat_cell(rng: np.random.Generator, thickness: float) -> np.ndarray:
    """A prism with a skewed quadrilateral base whose top face is the bottom face moved by one
    vector (a sheared column): J does not depend on zeta."""
    bottom = np.array([[0.0, 0.0, 0.0], [2.0, 0.0, 0.0], [0.0, 1.5, 0.0], [2.0, 1.5, 0.0]])
    bottom[:, :2] += rng.uniform(-0.3, 0.3, (4, 2))
    lift = np.array([rng.uniform(-0.2, 0.2), rng.uniform(-0.2, 0.2), thickness])
    return np.vstack([bottom, bottom + lift])


def test_the_three_points_carry_the_laminates_moments():
    rng = np.random.default_rng(3)
    for n in range(1, 9):
        laminate = random_laminate(rng, n) if n >= 2 else Laminate.from_angles(CARBON, [30.0], 1)
        bounds = bounds_of(laminate)
        C = np.array(laminate.ply_stiffnesses())
        zeta, weights, S = solid_shell.preintegrated_stiffness(bounds, C)
        for j in range(3):
            exact = sum(
                C[k] * (bounds[k, 1] ** (j + 1) - bounds[k, 0] ** (j + 1)) / (j + 1)
                for k in range(n)
            )
            ruled = np.einsum("p,pab->ab", weights * zeta**j, S)
            np.testing.assert_allclose(ruled, exact, rtol=0, atol=1e-12 * np.abs(C).max())
    one_material = Laminate.from_angles(GLASS, [20.0] * 5, 0.2)
    _, _, S = solid_shell.preintegrated_stiffness(
        bounds_of(one_material), np.array(one_material.ply_stiffnesses())
    )
    for S_p in S:
        np.testing.assert_allclose(S_p, one_material.plies[0].stiffness(), rtol=1e-12, atol=1e-9)


@pytest.mark.parametrize("angles", [QUASI_ISOTROPIC, [0.0, 90.0, 0.0], [0.0, 90.0, 90.0, 0.0]])
def test_on_flat_cells_the_preintegrated_rule_is_exact(angles):
    """Force and energy equal those of 2 and 3 Gauss points per ply (exact for the affine
    strain of a flat cell) to 1e-12: the whole laminate and two of its subelements."""
    rng = np.random.default_rng(11)
    laminate = Laminate(
        tuple(Ply(CARBON if k % 2 else GLASS, a, 0.25) for k, a in enumerate(angles))
    )
    C = np.array(laminate.ply_stiffnesses())
    f = laminate.ply_fractions
    X_parent = flat_cell(rng, laminate.thickness)
    n = laminate.n_plies
    for first, stop in {(0, n), (0, 2), (1, n)}:
        X = subelement_vertices(X_parent, f, first, stop)
        zeta = se.sublaminate_ply_zeta(f, first, stop)
        factors = shear_correction_factors(laminate, first, stop)
        rule = se.pack_rule(zeta, C[first:stop], 2, factors, enhanced=True, preintegrate=True)
        assert rule.stiffness.shape[0] == 3, "the three pre-integrated points"
        for _ in range(3):
            U = rng.normal(scale=1e-2, size=(8, 3))
            force, energy = kernel_force(X, U, rule)
            for ppp in (2, 3):
                gauss = se.pack_rule(zeta, C[first:stop], ppp, factors, enhanced=True)
                force_gauss, energy_gauss = kernel_force(X, U, gauss)
                assert relative_difference(force, force_gauss) < 1e-12
                assert energy == pytest.approx(energy_gauss, rel=1e-12)


@pytest.mark.parametrize("kinematics", ["small", "finite"])
def test_the_kernel_and_the_ufl_form_integrate_the_same_rule(kinematics):
    """A distorted hexahedron (faces not parallel: the rule is a quadrature there, not exact)
    of a random 5-ply laminate: the numba kernel and the condensed UFL form agree to 1e-12."""
    rng = np.random.default_rng(17)
    laminate = random_laminate(rng, 5)
    C = np.array(laminate.ply_stiffnesses())
    rule = se.pack_rule(laminate.ply_fractions, C, 2, enhanced=True, preintegrate=True)
    assert rule.stiffness.shape[0] == 3
    X = distorted_hex(rng, BOX * [1.0, 1.0, laminate.thickness])
    cell = EnhancedCell(X, laminate, 2, kinematics, preintegrate=True)
    for scale in (1e-3, 5e-2):
        U = rng.normal(scale=scale, size=(8, 3))
        force, energy = kernel_force(X, U, rule, kinematics == "finite")
        force_ufl, energy_ufl = cell.force(U)
        assert relative_difference(force, force_ufl) < 1e-12
        assert energy == pytest.approx(energy_ufl, rel=1e-12)


def test_the_rule_falls_back_to_points_per_ply_where_a_point_would_not_be_positive_definite():
    skin = Ply(CARBON, 0.0, 0.5)
    core = Ply(Laminate.from_angles(GLASS, [0.0], 1).plies[0].material, 0.0, 5.0)
    soft = type(GLASS)("foam", E1=100.0, E2=100.0, G12=40.0, nu12=0.25, nu23=0.25, rho=1e-10)
    cases = {
        "sandwich": (Laminate((skin, Ply(soft, 0.0, 5.0), skin)), False),
        "[0/90]": (Laminate.from_angles(CARBON, [0.0, 90.0], 0.25), False),
        "one ply": (Laminate.from_angles(CARBON, [0.0], 0.25), False),
        "[0/90/0]": (Laminate.from_angles(CARBON, [0.0, 90.0, 0.0], 0.25), True),
        "glass core": (Laminate((skin, core, skin)), True),
    }
    for name, (laminate, preintegrated) in cases.items():
        C = np.array(laminate.ply_stiffnesses())
        rule = solid_shell.thickness_rule(bounds_of(laminate), C, 2, preintegrate=True)
        assert rule.preintegrated == preintegrated, name
        if not preintegrated:  # two Gauss points in each ply, each with its ply's stiffness
            assert len(rule.zeta) == 2 * laminate.n_plies
            np.testing.assert_array_equal(rule.stiffness, C)
        assert bending_stiffness_error(laminate, 2, preintegrate=True) == pytest.approx(
            0, abs=1e-12
        )
    # ply damage integrates ply by ply: the structure's table is not pre-integrated
    table = RuleTable(cases["[0/90/0]"][0], 2, preintegrate=True)
    assert table.rule(0, 3).stiffness.shape[0] == 3  # pre-integrated
    assert len(np.unique(table.rule(0, 2).zeta)) == 4  # [0/90]: two Gauss points in each ply


def test_preintegrated_elements_have_positive_energy_on_distorted_cells():
    rng = np.random.default_rng(23)
    for _ in range(5):
        laminate = random_laminate(rng, int(rng.integers(3, 9)))
        rule = se.pack_rule(
            laminate.ply_fractions, np.array(laminate.ply_stiffnesses()), 2, preintegrate=True
        )
        X = distorted_hex(rng, BOX * [1.0, 1.0, laminate.thickness], amount=0.2)
        for _ in range(20):
            _, energy = kernel_force(X, rng.normal(scale=1e-2, size=(8, 3)), rule)
            assert energy > 0.0


def cantilever(angles: list[float], slenderness: float, model: dict | None = None):
    """(ESL tip deflection / laminate beam theory - 1, config) of a tip-loaded carbon
    cantilever, [model] defaults with the shear correction, but ``model``."""
    return tip_loaded_cantilever_error(
        CARBON, angles, slenderness, {"shear_correction": True, **(model or {})}
    )


@pytest.mark.skipif(MPI.COMM_WORLD.size > 1, reason="the static comparison is serial")
@pytest.mark.parametrize(
    "angles",
    [[0.0] * 8, [0.0, 90.0, 0.0, 90.0, 90.0, 0.0, 90.0, 0.0], QUASI_ISOTROPIC, [0.0, 90.0, 0.0]],
    ids=["[0]8", "[0/90]2s", "[0/45/-45/90]s", "[0/90/0]"],
)
def test_default_integration_bends_esl_cantilevers_as_laminate_beam_theory(angles):
    """Issue 14's targets: within 1 % at S >= 10 and 2 % at S = 5. Measured (this carbon ply,
    E1/E2 = 14): -0.50 % for [0/45/-45/90]s at S = 5, 0.08 % at most at S = 50. One point per
    ply, the former default, is 0.9-8.8 % too flexible at S = 50."""
    for slenderness, tolerance in ((5.0, 0.01), (50.0, 0.002)):
        error, config = cantilever(angles, slenderness)
        assert abs(error) < tolerance, (slenderness, error)
        warnings = integration_warnings([config.laminate], config.points_per_ply, True)
        assert warnings == []
    one_point, config = cantilever(
        angles, 50.0, {"thickness_integration": "plies", "points_per_ply": 1}
    )
    assert one_point - error > 0.008, (one_point, error)
    (warning,) = integration_warnings([config.laminate], 1, config.preintegrate)
    assert "points_per_ply = 1 integrates the bending stiffness" in warning


def test_ply_damage_takes_points_ply_by_ply():
    data = {
        "model": {"kind": "esl", "ply_damage": True},
        "mesh": {"length": 2.0, "width": 0.5, "nx": 4, "ny": 1},
        "materials": {"carbon": {"E1": CARBON.E1, "E2": CARBON.E2, "G12": CARBON.G12,
                                 "nu12": CARBON.nu12, "nu23": CARBON.nu23, "rho": CARBON.rho,
                                 "failure": {"XT": 2000.0, "XC": 1200.0, "YT": 50.0,
                                             "YC": 200.0, "S12": 80.0, "G2c": 0.3,
                                             "G6c": 0.8}}},
        "laminate": {"material": "carbon", "ply_thickness": 0.25, "angles": QUASI_ISOTROPIC},
        "clamp": [{"face": "x0"}],
        "solver": {"end_time": 1e-6},
        "output": {"interval": 1e-6, "displacement_face": "x1", "reaction_face": "x0",
                   "component": "z"},
    }  # fmt: skip
    config = parse_config(data)
    assert not config.preintegrate
    structure = build_structure(config)
    assert not structure.rule_table.preintegrate
    rule = structure.rule_table.rule(0, 8)
    assert rule.stiffness.shape[0] == 8 and len(np.unique(rule.zeta)) == 16
