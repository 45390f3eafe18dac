"""The laminate's transverse shear correction (``materials.laminate.shear_correction_factors``):
the classical values where they are known, its bounds on any laminate and span, the same factor
on the UFL form and the numba rule, and what it is for: a cantilever's shear deflection right at
every slenderness."""

import numpy as np
import pytest
from helpers import tip_loaded_cantilever_error

from fenics_adaptive.element import solid_shell
from fenics_adaptive.element.rules import RuleTable
from fenics_adaptive.materials.laminate import Laminate, PlyMaterial, shear_correction_factors

PLY = PlyMaterial("ply", E1=1.0e5, E2=1.0e4, G12=5.0e3, nu12=0.25, nu23=0.25, rho=1.6e-9, G23=4e3)
ISOTROPIC = PlyMaterial("iso", E1=7.0e4, E2=7.0e4, G12=7.0e4 / 2.6, nu12=0.3, nu23=0.3, rho=2.7e-9)


@pytest.mark.parametrize("n", [1, 2, 3, 8])
@pytest.mark.parametrize("material", [PLY, ISOTROPIC])
def test_a_homogeneous_section_gets_five_sixths(n, material):
    laminate = Laminate.from_angles(material, [0.0] * n, 0.3)
    np.testing.assert_allclose(shear_correction_factors(laminate), 5 / 6, rtol=1e-12)
    if n % 2 == 0:  # each half of a symmetric section carries half the shear force
        np.testing.assert_allclose(shear_correction_factors(laminate, 0, n // 2), 5 / 6)


def test_the_factor_is_the_exact_shear_compliance_of_a_two_material_section():
    """A sandwich of stiff skins on a soft core, against the closed form of its shear flow:
    g(z) from equilibrium, k = 1 / (int G dz int g^2 / G dz), integrated here on a fine grid."""
    skin = PlyMaterial("skin", E1=7.0e4, E2=7.0e4, G12=2.7e4, nu12=0.3, nu23=0.3, rho=1e-9)
    core = PlyMaterial("core", E1=1.0e3, E2=1.0e3, G12=50.0, nu12=0.3, nu23=0.3, rho=1e-10)
    laminate = Laminate(
        tuple(
            Laminate.from_angles(m, [0.0], t).plies[0]
            for m, t in ((skin, 0.5), (core, 4.0), (skin, 0.5))
        )
    )
    z = np.linspace(0.0, 5.0, 200001)
    in_core = (z > 0.5) & (z < 4.5)
    E = np.where(in_core, reduced_modulus(core), reduced_modulus(skin))  # plane-stress Q11
    z_n = 2.5
    D = np.trapezoid(E * (z - z_n) ** 2, z)
    moment = E * (z_n - z)
    g = np.concatenate([[0.0], np.cumsum(0.5 * np.diff(z) * (moment[1:] + moment[:-1]))]) / D
    assert np.trapezoid(g, z) == pytest.approx(1.0, rel=1e-6)
    k = shear_correction_factors(laminate)
    # xz takes G13 = G12, yz G23 (here E / (2 (1 + nu23)) of each material)
    for computed, shear in zip(k, ("G12", "shear_modulus_23"), strict=True):
        values = [getattr(m, shear) for m in (core, skin)]
        G = np.where(in_core, *values)
        exact = 1.0 / (np.trapezoid(G, z) * np.trapezoid(g**2 / G, z))
        # (the grid integrates across the jumps in E and G to about 3e-5)
        assert computed == pytest.approx(exact, rel=1e-4)
    k_xz = k[0]
    assert k_xz < 0.2  # a soft core carries nearly all the shear: far from 5/6


def reduced_modulus(material: PlyMaterial) -> float:
    from fenics_adaptive.materials.laminate import reduced_plane_stress_stiffness

    return reduced_plane_stress_stiffness(material.stiffness())[0, 0]


def test_every_span_of_every_laminate_gets_a_factor_in_0_1_tending_to_1_when_thin():
    rng = np.random.default_rng(5)
    for _ in range(20):
        n = int(rng.integers(2, 9))
        laminate = Laminate.from_angles(PLY, rng.choice([0.0, 45.0, -45.0, 90.0], n), 0.2)
        for first in range(n):
            for stop in range(first + 1, n + 1):
                k = np.array(shear_correction_factors(laminate, first, stop))
                assert np.all((k > 0.0) & (k <= 1.0 + 1e-12)), (first, stop, k)
    thick = Laminate.from_angles(PLY, [0.0] * 41, 0.1)
    assert min(shear_correction_factors(thick, 20, 21)) > 0.999  # the mid-plane ply


def test_the_ufl_form_and_the_numba_rule_carry_the_same_factors():
    laminate = Laminate.from_angles(PLY, [0.0, 45.0, 90.0, -45.0], 0.25)
    table, plain = RuleTable(laminate, 2), RuleTable(laminate, 2, shear_correction=False)
    for first, stop in table.spans:
        # spans of several plies carry the span's factors, a one-ply element the ply's moduli
        k_xz, k_yz = shear_correction_factors(laminate, first, stop) if stop - first > 1 else (1, 1)
        rule, reference = table.rule(first, stop), plain.rule(first, stop)
        ratio = rule.weights / reference.weights
        codes = {t: solid_shell.TERMS.index(t) for t in solid_shell.TERMS}
        expected = {"normal": 1.0, "shear_xz": k_xz, "shear_yz": k_yz,
                    "shear_cross": np.sqrt(k_xz * k_yz)}  # fmt: skip
        for term, value in expected.items():
            np.testing.assert_allclose(ratio[rule.terms == codes[term]], value, rtol=1e-13)
    groups = solid_shell.ply_groups(laminate, 2, shear_correction_factors(laminate))
    plain_groups = solid_shell.ply_groups(laminate, 2)
    k_xz, _ = shear_correction_factors(laminate)
    for group, reference in zip(groups, plain_groups, strict=True):
        np.testing.assert_allclose(
            group.rules["shear_xz"][1], k_xz * reference.rules["shear_xz"][1], rtol=1e-13
        )
        np.testing.assert_array_equal(group.rules["normal"][1], reference.rules["normal"][1])


def cantilever_error(angles: list[float], slenderness: float, correction: bool) -> float:
    """ESL (2 points per ply) tip deflection of a cantilever under a top-face load against
    laminate beam theory with the exact shear compliance (relative)."""
    model = {"points_per_ply": 2, "shear_correction": correction}
    return tip_loaded_cantilever_error(PLY, angles, slenderness, model)[0]


@pytest.mark.slow
@pytest.mark.parametrize("angles", [[0.0] * 8, [0.0, 90.0, 0.0]], ids=["[0]8", "[0/90/0]"])
def test_with_the_correction_a_short_cantilever_bends_as_a_slender_one(angles):
    """From S = L/h = 50 (bending only) to S = 5 (a third of the deflection is shear) the ESL's
    error against beam theory with the exact shear compliance changes by 0.2 % at most with
    the correction, by 3-5 % without (the element's constant shear strain is too stiff)."""
    corrected = [cantilever_error(angles, s, True) for s in (5.0, 50.0)]
    plain = [cantilever_error(angles, s, False) for s in (5.0, 50.0)]
    assert abs(corrected[0] - corrected[1]) < 0.002, corrected
    assert plain[1] - plain[0] > 0.03, plain
    # with the enhanced thickness strain nothing else remains (measured 0.07 % at most; 0.5-1.2 %
    # of Poisson stiffening without it)
    assert max(map(abs, corrected)) < 0.002
