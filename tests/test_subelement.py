"""The numba solid-shell (sub)element kernels against the UFL forms of ``solid_shell`` and
against physics (rigid-body modes, constant stress, energy, mass).

Units: N, mm, s, tonne.

The UFL reference is ``solid_shell.internal_force_form`` / ``lumped_mass_form`` on a single-cell
DOLFINx mesh, compiled exactly as the model compiles them.
"""

from __future__ import annotations

import numpy as np
import pytest
from helpers import (
    BOX,
    SingleCell,
    distorted_hex,
    laminate_rule,
    random_laminate,
    relative_difference,
    subelement_vertices,
)

from fenics_adaptive.element import solid_shell
from fenics_adaptive.element import subelement as se
from fenics_adaptive.materials.laminate import Laminate

TOL = 1e-12


def random_displacement(rng: np.random.Generator, scale: float = 1e-2) -> np.ndarray:
    return rng.normal(scale=scale, size=(8, 3))


def kernel_force(X: np.ndarray, U: np.ndarray, rule: se.PackedRule) -> tuple[np.ndarray, float]:
    f = np.empty((8, 3))
    energy = se.solid_shell_force(X, U, *rule, f)
    return f, energy


# --- the packed rule --------------------------------------------------------------------------


def test_packed_rule_is_solid_shell_rule():
    laminate = random_laminate(np.random.default_rng(0), 4)
    for ppp in (1, 2, 3):
        rule = laminate_rule(laminate, ppp)
        # every term integrates the reference volume exactly once
        for code in range(4):
            assert rule.weights[rule.terms == code].sum() == pytest.approx(1.0, abs=1e-14)
        # ply by ply, term by term: solid_shell.ply_rules
        f = laminate.ply_fractions
        for k in range(laminate.n_plies):
            for code, term in enumerate(solid_shell.TERMS):
                p, w = solid_shell.ply_rules(f[k], f[k + 1], ppp)[term]
                mine = (rule.ply_of_point == k) & (rule.terms == code)
                # the same points and weights, in the rule's own order
                points = rule.coordinates()[mine]
                mine_order = np.lexsort(points.T[::-1])
                theirs_order = np.lexsort(p.T[::-1])
                np.testing.assert_array_equal(points[mine_order], p[theirs_order])
                np.testing.assert_array_equal(rule.weights[mine][mine_order], w[theirs_order])
        # line by line, bottom to top along each line (the order the kernel is fast in)
        assert np.all(np.diff(rule.position_of_point) >= 0)
        for q in range(len(rule.positions)):
            on_line = rule.position_of_point == q
            assert np.all(np.diff(rule.zeta[on_line]) > 0)
        assert len(rule.positions) == 9


def test_pack_rule_rejects_bad_input():
    laminate = random_laminate(np.random.default_rng(1), 5)
    C = np.array(laminate.ply_stiffnesses())
    f = laminate.ply_fractions
    with pytest.raises(ValueError, match="tile"):  # a subelement's plies, not renormalised
        se.pack_rule(np.column_stack([f[1:3], f[2:4]]), C[1:3], 1)
    with pytest.raises(ValueError, match="shape"):
        se.pack_rule(f, C[:3], 1)
    coupled = C.copy()
    coupled[0, 0, 3] = coupled[0, 3, 0] = 0.1 * C[0, 0, 0]
    with pytest.raises(ValueError, match="couples"):
        se.pack_rule(f, coupled, 1)
    with pytest.raises(ValueError, match="points_per_ply"):
        se.pack_rule(f, C, 0)
    with pytest.raises(ValueError, match="ply_density"):
        se.pack_mass_rule(f, np.ones(2))


# --- against UFL --------------------------------------------------------------------------------


@pytest.mark.parametrize("ppp", [1, 2])
def test_unrefined_element_matches_ufl(ppp):
    rng = np.random.default_rng(10 + ppp)
    laminate = random_laminate(rng, 5)
    rule = laminate_rule(laminate, ppp)
    worst = 0.0
    for _ in range(4):
        X = distorted_hex(rng, BOX * [1.0, 1.0, laminate.thickness])
        U = random_displacement(rng)
        f, _ = kernel_force(X, U, rule)
        f_ufl = SingleCell(X).force(laminate, ppp, U)
        worst = max(worst, relative_difference(f, f_ufl))
    assert worst < TOL, worst


def test_subelement_matches_ufl_of_sublaminate():
    """Plies 3..5 (1-based) of a 7-ply laminate, as a subelement of a distorted parent element:
    its vertices sit on the parent's vertical edges at the fractions of interfaces 2 and 5."""
    rng = np.random.default_rng(20)
    laminate = random_laminate(rng, 7)
    first, stop = 2, 5
    f = laminate.ply_fractions
    X_parent = distorted_hex(rng, BOX * [1.0, 1.0, laminate.thickness])
    X = subelement_vertices(X_parent, f, first, stop)
    sublaminate = Laminate(laminate.plies[first:stop])
    zeta = se.sublaminate_ply_zeta(f, first, stop)
    np.testing.assert_allclose(zeta[:, 0], sublaminate.ply_fractions[:-1], rtol=0, atol=1e-15)
    np.testing.assert_allclose(zeta[:, 1], sublaminate.ply_fractions[1:], rtol=0, atol=1e-15)
    C = np.array(laminate.ply_stiffnesses()[first:stop])
    cell = SingleCell(X)
    for ppp in (1, 2):
        rule = se.pack_rule(zeta, C, ppp)
        U = random_displacement(rng)
        f_kernel, _ = kernel_force(X, U, rule)
        f_ufl = cell.force(sublaminate, ppp, U)
        assert relative_difference(f_kernel, f_ufl) < TOL


# --- physics ------------------------------------------------------------------------------------


def test_rigid_body_motion_gives_no_force():
    rng = np.random.default_rng(40)
    laminate = random_laminate(rng, 5)
    for ppp in (1, 2):
        rule = laminate_rule(laminate, ppp)
        X = distorted_hex(rng, BOX * [1.0, 1.0, laminate.thickness])
        scale = 1e-2
        f_strain, e_strain = kernel_force(X, random_displacement(rng, scale), rule)
        translation = np.tile(rng.normal(scale=scale, size=3), (8, 1))
        W = rng.normal(scale=scale, size=(3, 3))
        rotation = (X - X.mean(axis=0)) @ (W - W.T).T  # u = w x (x - x_c), infinitesimal
        for U in (translation, rotation, translation + rotation):
            f, energy = kernel_force(X, U, rule)
            assert np.abs(f).max() < 1e-12 * np.abs(f_strain).max()
            assert abs(energy) < 1e-20 * e_strain


def _exact_constant_stress_force(X, laminate, H):
    """f_a = sum over plies of sigma_k . integral over ply k of grad N_a, sigma_k = C_k eps with
    the full 6x6 stiffness, by 3-point Gauss in every direction of every ply (exact on a
    parallelepiped) -- independent of the selective rule."""
    eps = np.array([H[0, 0], H[1, 1], H[2, 2], H[1, 2] + H[2, 1], H[0, 2] + H[2, 0]])
    eps = np.append(eps, H[0, 1] + H[1, 0])
    g, w = np.polynomial.legendre.leggauss(3)
    g, w = 0.5 * (g + 1.0), 0.5 * w
    f = np.zeros((8, 3))
    fractions = laminate.ply_fractions
    for k, C in enumerate(laminate.ply_stiffnesses()):
        s = C @ eps
        sigma = np.array([[s[0], s[5], s[4]], [s[5], s[1], s[3]], [s[4], s[3], s[2]]])
        lo, hi = fractions[k], fractions[k + 1]
        for a, wa in zip(g, w, strict=True):
            for b, wb in zip(g, w, strict=True):
                for c, wc in zip(g, w, strict=True):
                    p = np.array([a, b, lo + (hi - lo) * c])
                    factors = np.where(se.CORNERS == 1.0, p, 1.0 - p)
                    slopes = np.where(se.CORNERS == 1.0, 1.0, -1.0)
                    dN = np.empty((8, 3))
                    dN[:, 0] = slopes[:, 0] * factors[:, 1] * factors[:, 2]
                    dN[:, 1] = factors[:, 0] * slopes[:, 1] * factors[:, 2]
                    dN[:, 2] = factors[:, 0] * factors[:, 1] * slopes[:, 2]
                    J = X.T @ dN
                    dN_dx = dN @ np.linalg.inv(J)
                    f += wa * wb * wc * (hi - lo) * abs(np.linalg.det(J)) * dN_dx @ sigma
    energy = sum(
        0.5 * eps @ C @ eps * t.thickness / laminate.thickness
        for C, t in zip(laminate.ply_stiffnesses(), laminate.plies, strict=True)
    )
    return f, energy


def test_uniform_strain_gives_constant_stress_force():
    rng = np.random.default_rng(50)
    laminate = random_laminate(rng, 5)
    # a parallelepiped: a sheared, stretched box (constant Jacobian)
    A = np.eye(3) + rng.uniform(-0.2, 0.2, (3, 3))
    X = (se.CORNERS * BOX * [1.0, 1.0, laminate.thickness]) @ A.T + rng.normal(size=3)
    volume = abs(np.linalg.det(A)) * np.prod(BOX) * laminate.thickness
    H = rng.normal(scale=1e-3, size=(3, 3))  # u = H x + c: general, rotation part included
    U = X @ H.T + rng.normal(size=3)
    f_exact, energy_density = _exact_constant_stress_force(X, laminate, H)
    for ppp in (1, 2):
        f, energy = kernel_force(X, U, laminate_rule(laminate, ppp))
        assert relative_difference(f, f_exact) < TOL
        assert energy == pytest.approx(energy_density * volume, rel=TOL)
        assert np.abs(f.sum(axis=0)).max() < 1e-13 * np.abs(f).max()


def test_energy_is_half_u_dot_f_and_force_is_its_gradient():
    rng = np.random.default_rng(60)
    laminate = random_laminate(rng, 5)
    for ppp in (1, 2):
        rule = laminate_rule(laminate, ppp)
        X = distorted_hex(rng, BOX * [1.0, 1.0, laminate.thickness])
        U = random_displacement(rng)
        f, energy = kernel_force(X, U, rule)
        assert energy > 0.0
        assert energy == pytest.approx(0.5 * np.sum(U * f), rel=TOL)
        # the energy is quadratic in u: the central difference is its exact derivative
        dU = random_displacement(rng)
        h = 0.5
        _, e_plus = kernel_force(X, U + h * dU, rule)
        _, e_minus = kernel_force(X, U - h * dU, rule)
        assert (e_plus - e_minus) / (2 * h) == pytest.approx(np.sum(f * dU), rel=1e-10)


def test_batched_kernel_matches_single_element_kernel():
    rng = np.random.default_rng(70)
    laminate = random_laminate(rng, 6)
    C = np.array(laminate.ply_stiffnesses())
    f = laminate.ply_fractions
    rules = [
        laminate_rule(laminate, 1),  # ESL element
        se.pack_rule(se.sublaminate_ply_zeta(f, 0, 2), C[0:2], 2),  # lower subelement
        se.pack_rule(se.sublaminate_ply_zeta(f, 2, 6), C[2:6], 2),  # upper subelement
    ]
    packed = se.concatenate_rules(rules)
    rule_of_element = np.array([0, 1, 2, 0, 2, 1, 0], dtype=np.int64)
    ne = len(rule_of_element)
    X_all = np.array([distorted_hex(rng) for _ in range(ne)])
    U_all = np.array([random_displacement(rng) for _ in range(ne)])
    f_all = np.full((ne, 8, 3), np.nan)
    total = se.solid_shell_forces(X_all, U_all, rule_of_element, *packed, f_all, False)
    energies = []
    for e, r in enumerate(rule_of_element):
        f_single, energy = kernel_force(X_all[e], U_all[e], rules[r])
        np.testing.assert_allclose(f_all[e], f_single, rtol=0, atol=1e-14 * np.abs(f_single).max())
        energies.append(energy)
    assert total == pytest.approx(sum(energies), rel=1e-14)


# --- lumped mass --------------------------------------------------------------------------------


def _kernel_mass(X: np.ndarray, zeta: np.ndarray, rho: np.ndarray) -> np.ndarray:
    m = np.empty(8)
    se.solid_shell_lumped_mass(X, *se.pack_mass_rule(zeta, rho), m)
    return m


def test_lumped_mass_of_a_box_is_areal_mass_times_area():
    laminate = random_laminate(np.random.default_rng(80), 5)
    rho = np.array([p.material.rho for p in laminate.plies])
    X = se.CORNERS * BOX * [1.0, 1.0, laminate.thickness] + [3.0, -1.0, 2.0]
    m = _kernel_mass(X, laminate.ply_fractions, rho)
    area = BOX[0] * BOX[1]
    assert m.sum() == pytest.approx(laminate.areal_mass() * area, rel=1e-14)
    assert m.sum() == pytest.approx(
        sum(r * p.thickness for r, p in zip(rho, laminate.plies, strict=True)) * area
    )
    # a box: the four bottom corners carry equal masses, so do the four top ones
    np.testing.assert_allclose(m[:4], m[0], rtol=1e-14)
    np.testing.assert_allclose(m[4:], m[4], rtol=1e-14)


def test_lumped_mass_matches_ufl_and_is_invariant_under_refinement():
    rng = np.random.default_rng(90)
    laminate = random_laminate(rng, 5)
    rho = np.array([p.material.rho for p in laminate.plies])
    f = laminate.ply_fractions
    X = distorted_hex(rng, BOX * [1.0, 1.0, laminate.thickness])
    m = _kernel_mass(X, f, rho)
    m_ufl = SingleCell(X).lumped_mass(laminate)
    assert relative_difference(m, m_ufl) < TOL
    # refined at interfaces 2 and 4: three subelements, same total mass
    total = 0.0
    for first, stop in ((0, 2), (2, 4), (4, 5)):
        X_sub = subelement_vertices(X, f, first, stop)
        total += _kernel_mass(X_sub, se.sublaminate_ply_zeta(f, first, stop), rho[first:stop]).sum()
    assert total == pytest.approx(m.sum(), rel=1e-13)
