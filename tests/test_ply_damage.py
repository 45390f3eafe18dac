"""Physics tests of the ply damage model (Hashin indices, crack-band matrix damage) and of the
damage-aware solid-shell (sub)element kernels.

Units: N, mm, s, tonne (stress MPa, fracture energy N/mm, energy mJ).

Material points are driven in the ply's material frame with one strain component prescribed and
the other normal stresses held at zero (uniaxial stress), iterating on the damage of the step;
the onset energy is taken from the step's elastic predictor, where an explicit step finds it.
Work is integrated with the trapezoidal rule; the dissipated energy is work minus the secant
strain energy. Expected values come from the textbook crack band model (bilinear curve, area
G_c / l_c), not from the kernel's formulas.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from helpers import GLASS, energy_gradient, prototype_material

from fenics_adaptive.element import subelement as se
from fenics_adaptive.errors import InputError
from fenics_adaptive.materials import ply_damage as pd
from fenics_adaptive.materials.laminate import Laminate, Ply
from fenics_adaptive.settings import materials as sm

MATERIAL = prototype_material("proto")
FAILURE_TABLE = {"XT": 2000.0, "XC": 1200.0, "YT": 50.0, "YC": 200.0, "S12": 80.0}
FAILURE = sm.PlyFailure.from_mapping("proto", {**FAILURE_TABLE, "G2c": 0.2, "G6c": 1.0})
GLASS_FAILURE = sm.PlyFailure(
    "glass", XT=1100.0, XC=700.0, YT=40.0, YC=150.0, S12=70.0, S23=50.0, G2c=0.3, G6c=1.2
)
FAILURES = {"proto": FAILURE, "glass": GLASS_FAILURE}
NORMAL = (0, 1, 2)


# --- parameters --------------------------------------------------------------------------------


def test_failure_parameters_are_validated():
    table = {**FAILURE_TABLE, "G2c": 0.2, "G6c": 1.0}
    failure = sm.PlyFailure.from_mapping("proto", table)
    params = failure.as_array()
    assert params[sm.F_XT] == 2000.0 and params[sm.F_YC] == 200.0 and params[sm.F_G6C] == 1.0
    # default transverse shear strength: YC / (2 tan 53 deg)
    assert params[sm.F_S23] == pytest.approx(200.0 / (2.0 * math.tan(math.radians(53.0))))
    assert sm.PlyFailure.from_mapping("proto", {**table, "S23": 60.0}).as_array()[sm.F_S23] == 60
    cases = [
        ({**table, "Xt": 1.0}, "materials.proto.failure.Xt: unknown key"),
        ({k: v for k, v in table.items() if k != "G6c"}, "materials.proto.failure.G6c: missing"),
        ({**table, "YT": -1.0}, "materials.proto.failure.YT: must be a finite number > 0"),
        ({**table, "G2c": True}, "materials.proto.failure.G2c: must be a number"),
        ({**table, "S12": math.inf}, "materials.proto.failure.S12: must be a finite number"),
        ({**table, "S23": 20.0}, "materials.proto.failure.S23: the transverse shear strength"),
        ({**table, "YC": 60.0}, r"materials.proto.failure.S23: .*default YC / \(2 tan 53"),
    ]
    for values, message in cases:
        with pytest.raises(InputError, match=message):
            sm.PlyFailure.from_mapping("proto", values)
    with pytest.raises(InputError, match=r"materials\.glass\.failure: missing"):
        pd.pack_ply_damage([Ply(GLASS, 0.0, 0.2)], {"proto": FAILURE})


def test_band_width_limit_is_the_snap_back_limit():
    limit = pd.max_band_width(MATERIAL, FAILURE)
    mode_i = 2.0 * MATERIAL.E2 * FAILURE.G2c / FAILURE.YT**2
    shear = 2.0 * MATERIAL.G12 * FAILURE.G6c / FAILURE.S12**2
    assert limit == min(mode_i, shear)
    pd.check_band_width(MATERIAL, FAILURE, 0.99 * limit)
    with pytest.raises(InputError, match=r"materials.proto.failure.G2c: .* 2 E2 G2c / YT\^2"):
        pd.check_band_width(MATERIAL, FAILURE, 1.01 * mode_i)
    with pytest.raises(InputError, match=r"materials.proto.failure.G6c: .*snap-back"):
        pd.check_band_width(MATERIAL, sm.PlyFailure(**{**FAILURE.__dict__, "G2c": 1.0}), shear)
    # a cell across the crack: a |sin t| + b |cos t| for an a x b rectangle
    X = se.CORNERS * [2.0, 0.5, 0.3]
    assert pd.crack_band_width(X, 0.0) == pytest.approx(0.5)
    assert pd.crack_band_width(X, 90.0) == pytest.approx(2.0)
    assert pd.crack_band_width(X, -30.0) == pytest.approx(2.0 * 0.5 + 0.5 * math.sqrt(3) / 2)


# --- failure indices ----------------------------------------------------------------------------


def hashin_F(f: sm.PlyFailure, s: np.ndarray) -> tuple[float, float, float, float]:
    """Hashin's (1980) four criteria as written in the paper (value 1 at failure)."""
    s11, s22, s33, s23, s13, s12 = s
    S23 = f.transverse_shear_strength
    shear = (s12**2 + s13**2) / f.S12**2
    ft = (s11 / f.XT) ** 2 + shear if s11 >= 0 else 0.0
    fc = (s11 / f.XC) ** 2 if s11 < 0 else 0.0
    sn = s22 + s33
    rest = (s23**2 - s22 * s33) / S23**2 + shear
    mt = (sn / f.YT) ** 2 + rest if sn >= 0 else 0.0
    mc = ((f.YC / (2 * S23)) ** 2 - 1) * sn / f.YC + (sn / (2 * S23)) ** 2 + rest if sn < 0 else 0
    return ft, fc, mt, mc


def test_indices_are_load_factors_of_hashin_criteria():
    f = FAILURE
    cases = {
        (0.8 * f.XT, 0, 0, 0, 0, 0): (0.8, 0, 0, 0),
        (-0.5 * f.XC, 0, 0, 0, 0, 0): (0, 0.5, 0, 0),
        (0, f.YT, 0, 0, 0, 0): (0, 0, 1, 0),
        (0, -f.YC, 0, 0, 0, 0): (0, 0, 0, 1),
        (0, 0, 0, 0, 0, 0.5 * f.S12): (0.5, 0, 0.5, 0),  # Hashin's fibre mode sees s12 too
    }
    for stress, expected in cases.items():
        np.testing.assert_allclose(pd.failure_indices(f, np.array(stress)), expected, atol=1e-12)
    rng = np.random.default_rng(0)
    for _ in range(200):
        s = rng.normal(size=6) * [f.XT, f.YT, f.YT, f.S12, f.S12, f.S12]
        indices = np.array(pd.failure_indices(f, s))
        for k in range(4):
            if indices[k] == 0.0:
                assert hashin_F(f, s)[k] <= 0.0
                continue
            # degree one in the load, and exactly Hashin's criterion = 1 at stress / index
            assert pd.failure_indices(f, 3.0 * s)[k] == pytest.approx(3.0 * indices[k])
            assert hashin_F(f, s / indices[k])[k] == pytest.approx(1.0, rel=1e-12)


# --- material point ----------------------------------------------------------------------------


def uniaxial(component, values, band_width, state=None, material=MATERIAL, failure=FAILURE):
    """Drive material-frame strain ``component`` through ``values`` with the other normal
    stresses zero (and the other shear strains zero). Returns strains (n, 6), stresses (n, 6),
    work (n,), secant energy (n,) per unit volume, the damage (n,) and the final state."""
    state = pd.new_state() if state is None else state
    free = [i for i in NORMAL if i != component] if component in NORMAL else []
    C0 = material.stiffness()
    n = len(values)
    strains, stresses = np.zeros((n, 6)), np.zeros((n, 6))
    work, energy, damage = np.zeros(n), np.zeros(n), np.zeros(n)
    for j, value in enumerate(values):
        d = state[pd.S_D]
        for _ in range(200):
            eps = np.zeros(6)
            eps[component] = value
            for crack_open in (True, False):
                C = pd.damaged_material_stiffness(material, d, crack_open)
                if free:
                    eps[free] = -np.linalg.solve(C[np.ix_(free, free)], C[free, component] * value)
                if (C0 @ eps)[1] > 0.0 or not crack_open:
                    break
            trial = state.copy()
            sigma, psi = pd.material_point_update(material, failure, eps, band_width, trial)
            # onset is found on the elastic predictor (as an explicit step finds it): keep it
            state[pd.S_Y0] = trial[pd.S_Y0]
            if abs(trial[pd.S_D] - d) <= 1e-14:
                break
            d = trial[pd.S_D]
        else:
            raise AssertionError("the damage of the step did not converge")
        state[:] = trial
        strains[j], stresses[j], energy[j], damage[j] = eps, sigma, psi, state[pd.S_D]
        if j:
            work[j] = work[j - 1] + 0.5 * (stresses[j] + stresses[j - 1]) @ (eps - strains[j - 1])
    return strains, stresses, work, energy, damage, state


@pytest.mark.slow
@pytest.mark.parametrize(
    ("component", "strength", "modulus", "G"),
    [(1, "YT", "E2", "G2c"), (5, "S12", "G12", "G6c")],
    ids=["transverse_tension", "in_plane_shear"],
)
@pytest.mark.parametrize("band_width", [1.2, 0.05])
def test_crack_band_dissipates_fracture_energy_per_area(
    component, strength, modulus, G, band_width
):
    peak = getattr(FAILURE, strength)
    E = getattr(MATERIAL, modulus)
    Gc = getattr(FAILURE, G)
    assert band_width < pd.max_band_width(MATERIAL, FAILURE)
    # the law softens towards Gc / (1 - RESIDUAL) so that, with the residual stiffness kept,
    # exactly Gc is dissipated per crack area
    e0, ef = peak / E, 2.0 * Gc / ((1.0 - pd.RESIDUAL) * peak * band_width)
    values = np.linspace(0.0, 1.25 * ef, 2001)
    eps, sig, work, energy, damage, state = uniaxial(component, values, band_width)
    e, s = eps[:, component], sig[:, component]
    # uniaxial: the other stresses vanish
    others = [i for i in range(6) if i != component]
    assert np.abs(sig[:, others]).max() < 1e-9 * peak
    # elastic up to the peak, then the bilinear law's damage with the residual stiffness
    assert s.max() == pytest.approx(peak, rel=2e-3)
    elastic = e <= e0
    np.testing.assert_allclose(s[elastic], E * e[elastic], rtol=1e-12)
    softening = (e > e0 * 1.01) & (e < ef)
    # the straight softening line of the textbook bilinear curve, plus what the residual
    # stiffness carries (RESIDUAL E e at most)
    textbook = peak * (ef - e[softening]) / (ef - e0)
    excess = s[softening] - textbook
    assert excess.min() > -0.01 * peak
    assert np.all(excess <= 1.5 * pd.RESIDUAL * E * e[softening] + 0.01 * peak)
    assert np.all(np.diff(damage) >= 0.0)
    assert state[pd.S_D] == 1.0
    cracked = e >= ef  # only the residual stiffness is left
    assert np.all(s[cracked] >= 0.0)
    assert np.all(s[cracked] <= 1.5 * pd.RESIDUAL * E * e[cracked])
    # energy per unit crack area: dissipated per volume times the band width
    dissipated = work[-1] - energy[-1]
    assert dissipated * band_width == pytest.approx(Gc, rel=1e-2)
    assert dissipated * band_width == pytest.approx(Gc, rel=1e-4)  # trapezoidal rule error only


@pytest.mark.slow
def test_unloading_follows_the_secant_and_reloading_dissipates_nothing():
    band_width = 0.5
    ef = 2.0 * FAILURE.G2c / (FAILURE.YT * band_width)
    top = 0.6 * ef
    unload = np.linspace(top, 0.0, 301)[1:]  # to zero
    reload = np.linspace(0.0, 0.999 * top, 301)[1:]  # back to just below the previous maximum
    path = np.concatenate([np.linspace(0.0, top, 301), unload, reload])
    eps, sig, work, energy, damage, _ = uniaxial(1, path, band_width)
    d = damage[300]
    assert 0.2 < d < 0.9
    np.testing.assert_array_equal(damage[300:], d)
    secant = sig[300, 1] / eps[300, 1]
    assert secant < 0.5 * MATERIAL.E2
    np.testing.assert_allclose(sig[300:, 1], secant * eps[300:, 1], rtol=0, atol=1e-10)
    dissipated = work - energy
    assert dissipated[300] > 0.0
    np.testing.assert_allclose(dissipated[300:], dissipated[300], rtol=1e-9)


@pytest.mark.slow
def test_transverse_compression_does_not_damage_and_a_closed_crack_carries_it():
    eps, sig, _, _, damage, state = uniaxial(1, np.linspace(0, -1.5 * FAILURE.YC / 1e4, 101), 0.5)
    assert np.all(damage == 0.0) and state[pd.S_Y0] == 0.0
    np.testing.assert_allclose(sig[:, 1], MATERIAL.E2 * eps[:, 1], rtol=1e-12)
    assert state[pd.S_MC] == pytest.approx(1.5, rel=1e-9) and state[pd.S_MT] == 0.0
    # crack the ply in tension, then compress it: the full transverse stiffness comes back
    ef = 2.0 * FAILURE.G2c / (FAILURE.YT * 0.5)
    path = np.concatenate([np.linspace(0, 1.1 * ef, 201), np.linspace(1.1 * ef, -0.01, 201)])
    eps, sig, _, _, damage, _ = uniaxial(1, path, 0.5)
    assert damage[-1] == 1.0
    compressed = eps[:, 1] < 0
    np.testing.assert_allclose(sig[compressed, 1], MATERIAL.E2 * eps[compressed, 1], rtol=1e-12)


def test_fibre_loading_leaves_the_matrix_intact():
    for sign, index in ((1.0, pd.S_FT), (-1.0, pd.S_FC)):
        strength = FAILURE.XT if sign > 0 else FAILURE.XC
        values = sign * np.linspace(0, 1.5 * strength / MATERIAL.E1, 51)
        eps, sig, _, _, damage, state = uniaxial(0, values, 0.5)
        assert np.all(damage == 0.0) and state[pd.S_Y0] == 0.0
        np.testing.assert_allclose(sig[:, 0], MATERIAL.E1 * eps[:, 0], rtol=1e-12)
        assert state[index] == pytest.approx(1.5, rel=1e-9)
        assert max(state[pd.S_MT], state[pd.S_MC]) < 1e-9


def fully_removed(crack_open: bool) -> np.ndarray:
    """The stiffness with all that matrix damage can remove removed: without the residual."""
    return pd.damaged_material_stiffness(MATERIAL, 1.0 / (1.0 - pd.RESIDUAL), crack_open)


def test_damaged_stiffness_is_positive_definite_and_keeps_the_fibres():
    C0 = MATERIAL.stiffness()
    for crack_open in (True, False):
        for d in (0.0, 0.3, 0.9, 1.0):
            C = pd.damaged_material_stiffness(MATERIAL, d, crack_open)
            np.testing.assert_allclose(C, C.T, rtol=0, atol=1e-14 * C0.max())
            assert np.linalg.eigvalsh(C).min() > 0.0  # the residual keeps d = 1 definite too
        # what the residual keeps: RESIDUAL of what damage removes
        residual = pd.damaged_material_stiffness(MATERIAL, 1.0, crack_open) - fully_removed(
            crack_open
        )
        np.testing.assert_allclose(
            residual, pd.RESIDUAL * (C0 - fully_removed(crack_open)), atol=1e-12 * C0.max()
        )
        C1 = fully_removed(crack_open)
        assert np.linalg.eigvalsh(C1).min() > -1e-9 * C0.max()
        # cracked: no shear on the crack faces, the fibres and the 13 shear untouched
        rng = np.random.default_rng(1)
        eps = rng.normal(size=6)
        sigma = C1 @ eps
        assert abs(sigma[3]) < 1e-12 and abs(sigma[5]) < 1e-12
        assert C1[4, 4] == C0[4, 4]
        if crack_open:
            assert abs(sigma[1]) < 1e-9 * np.abs(C0 @ eps).max()
            # the uniaxial fibre modulus is still E1
            E1 = C1[0, 0] - C1[0, 2] ** 2 / C1[2, 2]  # sigma_22 = 0 anyway, sigma_33 = 0
            assert E1 == pytest.approx(MATERIAL.E1, rel=1e-9)
        else:
            np.testing.assert_array_equal(C1[:3, :3], C0[:3, :3])
    # compliance form: only S22, S44, S66 change (d here: the effective, residual-scaled damage)
    d = 0.4
    S = np.linalg.inv(pd.damaged_material_stiffness(MATERIAL, d / (1.0 - pd.RESIDUAL), True))
    S0 = MATERIAL.compliance()
    expected = S0.copy()
    expected[1, 1] += d / ((1 - d) * C0[1, 1])
    expected[3, 3] /= 1 - d
    expected[5, 5] /= 1 - d
    np.testing.assert_allclose(S, expected, rtol=1e-10, atol=1e-14 * np.abs(S0).max())


# --- element kernels ---------------------------------------------------------------------------


def random_laminate(rng: np.random.Generator, n_plies: int) -> Laminate:
    angles = rng.uniform(-90.0, 90.0, n_plies)
    angles[1] = 90.0
    materials = [MATERIAL if k % 2 == 0 else GLASS for k in range(n_plies)]
    return Laminate(
        tuple(
            Ply(m, float(a), float(t))
            for m, a, t in zip(materials, angles, rng.uniform(0.1, 0.4, n_plies), strict=True)
        )
    )


def distorted_hex(rng: np.random.Generator, size: np.ndarray, amount: float = 0.12):
    return se.CORNERS * size + rng.uniform(-amount, amount, (8, 3)) * size


def test_packed_damage_is_consistent_with_the_ply_stiffness():
    rng = np.random.default_rng(2)
    laminate = random_laminate(rng, 5)
    packed = pd.pack_ply_damage(laminate.plies, FAILURES)
    for k, ply in enumerate(laminate.plies):
        T = pd.strain_rotation(ply.angle)
        C0 = ply.material.stiffness()
        np.testing.assert_allclose(T.T @ C0 @ T, ply.stiffness(), atol=1e-9 * C0.max())
        np.testing.assert_allclose(packed.strain_to_stress[k], C0 @ T, atol=1e-9 * C0.max())
        # the shell-frame secant stiffness is the rotated material-frame one
        for crack_open in (True, False):
            C = pd.degraded_shell_stiffness(
                np.array(laminate.ply_stiffnesses()), packed, k, 0.7, crack_open
            )
            C_mat = pd.damaged_material_stiffness(ply.material, 0.7, crack_open)
            np.testing.assert_allclose(C, T.T @ C_mat @ T, atol=1e-9 * C0.max())
            se.solid_shell.check_monoclinic(C)


@pytest.mark.slow
def test_ply_mean_strain_of_a_uniform_strain_is_that_strain():
    rng = np.random.default_rng(3)
    laminate = random_laminate(rng, 4)
    A = np.eye(3) + rng.uniform(-0.2, 0.2, (3, 3))
    X = (se.CORNERS * [1.5, 1.0, laminate.thickness]) @ A.T
    H = rng.normal(scale=1e-3, size=(3, 3))
    U = X @ H.T + rng.normal(size=3)
    E = H + H.T
    expected = [E[0, 0] / 2, E[1, 1] / 2, E[2, 2] / 2, E[1, 2], E[0, 2], E[0, 1]]
    for ppp in (1, 2):
        rule = se.pack_rule(laminate.ply_fractions, np.array(laminate.ply_stiffnesses()), ppp)
        strains = se.ply_mean_strains(X, U, rule)
        np.testing.assert_allclose(strains, np.tile(expected, (4, 1)), rtol=0, atol=1e-15)


def damaged_force(X, U, rule, packed, band_width, state):
    f = np.full((8, 3), np.nan)
    energy = se.solid_shell_force_damaged(X, U, *rule, *packed, band_width, state, f)
    return f, energy


def elastic_force(X, U, rule, stiffness=None):
    f = np.full((8, 3), np.nan)
    if stiffness is not None:
        rule = rule._replace(stiffness=np.ascontiguousarray(stiffness))
    energy = se.solid_shell_force(X, U, *rule, f)
    return f, energy


@pytest.mark.slow
@pytest.mark.parametrize("enhanced", [False, True])
def test_undamaged_kernel_is_the_elastic_kernel(enhanced):
    """With no damage the damaged kernel (its own strain pass and, with the enhanced thickness
    strain, its own condensation) gives the elastic kernel's force and energy."""
    rng = np.random.default_rng(4)
    laminate = random_laminate(rng, 5)
    packed = pd.pack_ply_damage(laminate.plies, FAILURES)
    C = np.array(laminate.ply_stiffnesses())
    for ppp in (1, 2):
        rule = se.pack_rule(laminate.ply_fractions, C, ppp, enhanced=enhanced)
        X = distorted_hex(rng, np.array([2.0, 1.5, laminate.thickness]))
        U = rng.normal(scale=1e-4, size=(8, 3))
        state = pd.new_state(5)
        f, energy = damaged_force(X, U, rule, packed, np.full(5, 0.5), state)
        f_el, energy_el = elastic_force(X, U, rule)
        assert np.all(state[:, pd.S_D] == 0.0) and state[:, pd.S_FT].max() > 0.0
        assert np.abs(f - f_el).max() <= 1e-13 * np.abs(f_el).max()
        assert energy == pytest.approx(energy_el, rel=1e-13)


@pytest.mark.parametrize("enhanced", [False, True])
def test_damaged_kernel_uses_each_plys_degraded_stiffness(enhanced):
    """Preset damage below what the strain would add. Under a uniform strain every point of a
    ply has the same transverse stress, so the force is the elastic kernel's with each ply's
    secant stiffness, open or closed as the sign of that stress says. Under any displacement
    the crack opens point by point, the material stays elastic between damage increments: the
    force is the gradient of the returned secant energy (the per-ply switch it replaces was
    not, and pumped energy into ringing cracked plies). With the enhanced thickness strain the
    gradient property also checks its condensation with open cracks (Newton on the open
    points: the energy is stationary in the parameters only if it converged)."""
    rng = np.random.default_rng(5)
    laminate = random_laminate(rng, 5)
    packed = pd.pack_ply_damage(laminate.plies, FAILURES)
    C = np.array(laminate.ply_stiffnesses())
    rule = se.pack_rule(laminate.ply_fractions, C, 2, enhanced=enhanced)
    X = distorted_hex(rng, np.array([2.0, 1.5, laminate.thickness]))
    preset = pd.new_state(5)
    preset[:, pd.S_D] = [0.3, 0.0, 0.95, 1.0, 0.6]
    preset[:, pd.S_Y0] = 1.0  # far above the energy of these strains: no growth

    def run(U):
        state = preset.copy()
        f, energy = damaged_force(X, U, rule, packed, np.full(5, 0.5), state)
        np.testing.assert_array_equal(state[:, : pd.S_FT], preset[:, : pd.S_FT])
        return f, energy

    # uniform strain, x stretched and y shortened: one sign per ply, open where the fibres
    # run across x (ply 2 is at 90 degrees), closed where they run along it
    H = np.diag([3e-4, -3e-4, 0.0]) + rng.normal(scale=2e-5, size=(3, 3))
    U = X @ H.T
    f, energy = run(U)
    strains = se.ply_mean_strains(X, U, rule)
    opens = [(packed.strain_to_stress[k] @ strains[k])[1] > 0 for k in range(5)]
    assert any(opens) and not all(opens)
    degraded = [
        pd.degraded_shell_stiffness(C, packed, k, preset[k, pd.S_D], opens[k]) for k in range(5)
    ]
    f_el, energy_el = elastic_force(X, U, rule, np.array(degraded))
    assert np.abs(f - f_el).max() <= 1e-12 * np.abs(f_el).max()
    assert energy == pytest.approx(energy_el, rel=1e-12)
    f_undamaged, _ = elastic_force(X, U, rule)
    assert np.abs(f - f_undamaged).max() > 1e-2 * np.abs(f_undamaged).max()

    # any displacement: f = dE/du (central differences), E = 1/2 u . f
    U = rng.normal(scale=2e-4, size=(8, 3))
    f, energy = run(U)
    assert energy == pytest.approx(0.5 * np.sum(f * U), rel=1e-12)
    h = 1e-9
    numeric = energy_gradient(lambda V: run(V)[1], U, h)
    assert np.abs(numeric - f).max() < 1e-5 * np.abs(f).max()


def test_batched_kernel_shares_one_state_per_cell_and_laminate_ply():
    """Cell 0 unrefined (ESL), cell 1 refined at interface 2 (two subelements), cell 2 an LW
    cell holding plies 3..4 only: combined-local nodes with extra nodes, results equal to the
    single-element kernel on the matching slices of the state."""
    rng = np.random.default_rng(6)
    laminate = random_laminate(rng, 5)
    C = np.array(laminate.ply_stiffnesses())
    frac = laminate.ply_fractions
    spans = [(0, 5), (0, 2), (2, 5), (3, 5)]
    rules = [se.pack_rule(se.sublaminate_ply_zeta(frac, a, b), C[a:b], 1) for a, b in spans]
    packed = [pd.pack_ply_damage(laminate.plies[a:b], FAILURES) for a, b in spans]
    all_rules = se.concatenate_rules(rules)
    all_packed = pd.concatenate_ply_damage(packed)
    rule_of_element = np.array([0, 1, 2, 3], dtype=np.int64)
    state_row = np.array([0, 1, 1, 2], dtype=np.int64)
    first_ply = np.array([0, 0, 2, 3], dtype=np.int64)
    n_base, n_extra = 30, 10
    nodes = rng.permutation(n_base + n_extra)[:32].reshape(4, 8).astype(np.int32)
    X_base, X_extra = np.zeros((n_base, 3)), np.zeros((n_extra, 3))
    for e in range(4):
        X = distorted_hex(rng, np.array([1.0, 1.2, 0.6])) + 3.0 * e
        for a, node in enumerate(nodes[e]):
            if node < n_base:
                X_base[node] = X[a]
            else:
                X_extra[node - n_base] = X[a]
    u_base = rng.normal(scale=3e-3, size=(n_base, 3))
    u_extra = rng.normal(scale=3e-3, size=(n_extra, 3))
    band_width = rng.uniform(0.2, 0.6, (3, 5, 2))
    state = pd.new_state(3, 5)
    state[:, :, pd.S_D] = rng.uniform(0, 0.5, (3, 5))
    state[:, :, pd.S_Y0] = rng.uniform(1e-3, 1e-2, (3, 5))
    expected_state = state.copy()
    f_base, f_extra = np.zeros((n_base, 3)), np.zeros((n_extra, 3))
    energy = se.add_damaged_subelement_forces(
        nodes,
        rule_of_element,
        state_row,
        first_ply,
        *all_rules,
        *all_packed,
        band_width,
        state,
        X_base,
        X_extra,
        u_base,
        u_extra,
        f_base,
        f_extra,
        True,
        False,
        False,
        0.0,
        np.zeros(1, dtype=np.int64),
        np.zeros((0, 3, 3)),
    )
    g_base, g_extra = np.zeros((n_base, 3)), np.zeros((n_extra, 3))
    total = 0.0
    for e in range(4):
        X = np.array([X_base[i] if i < n_base else X_extra[i - n_base] for i in nodes[e]])
        U = np.array([u_base[i] if i < n_base else u_extra[i - n_base] for i in nodes[e]])
        a, b = spans[rule_of_element[e]]
        r = state_row[e]
        f, en = damaged_force(X, U, rules[e], packed[e], band_width[r, a:b], expected_state[r, a:b])
        total += en
        for k, i in enumerate(nodes[e]):
            (g_base[i] if i < n_base else g_extra[i - n_base])[:] += f[k]
    np.testing.assert_array_equal(state, expected_state)
    assert (state[:, :, pd.S_D] > 0.5).any()  # the strain did damage some plies
    scale = np.abs(g_base).max()
    assert np.abs(f_base - g_base).max() <= 1e-13 * scale
    assert np.abs(f_extra - g_extra).max() <= 1e-13 * scale
    assert energy == pytest.approx(total, rel=1e-13)


# --- one cross-ply cell pulled across the fibres of its 0-degree ply -----------------------------


def pull_cross_ply_cell(width_y: float, steps: int = 1500):
    """A 1 x width_y x 0.5 mm cell of [90, 0] (bottom to top, 0.25 mm each) stretched along y
    (u_y = e_y y prescribed) with free lateral contraction (u_x = e_x x, u_z = e_z z chosen so
    that the x and z resultants vanish), until both plies have cracked. Returns the dissipated
    energy and the damage history (steps, 2)."""
    laminate = Laminate.from_angles(MATERIAL, [90.0, 0.0], 0.25)
    C = np.array(laminate.ply_stiffnesses())
    rule = se.pack_rule(laminate.ply_fractions, C, 1)
    packed = pd.pack_ply_damage(laminate.plies, FAILURES)
    X = se.CORNERS * [1.0, width_y, 0.5]
    band_width = np.array([pd.crack_band_width(X, ply.angle) for ply in laminate.plies])
    np.testing.assert_allclose(band_width, [1.0, width_y])  # 90: across x; 0: across y
    for b in band_width:
        pd.check_band_width(MATERIAL, FAILURE, b)

    def resultants(stiffness, strain):
        f, _ = elastic_force(X, X * strain, rule, stiffness)
        return np.array([f[:, 0] @ X[:, 0], f[:, 2] @ X[:, 2]])

    state = pd.new_state(2)
    work, u_old, f_old = 0.0, np.zeros((8, 3)), np.zeros((8, 3))
    history = []
    e_y = 0.0
    for _ in range(steps):
        e_y += 4e-5
        d = state[:, pd.S_D].copy()
        for _ in range(100):
            stiffness = np.array(
                [pd.degraded_shell_stiffness(C, packed, k, d[k], True) for k in (0, 1)]
            )
            r0 = resultants(stiffness, [0.0, e_y, 0.0])
            K = np.column_stack([resultants(stiffness, s) for s in ([1, 0, 0], [0, 0, 1])])
            e_x, e_z = np.linalg.solve(K, -r0)
            u = X * [e_x, e_y, e_z]
            trial = state.copy()
            f, energy = damaged_force(X, u, rule, packed, band_width, trial)
            state[:, pd.S_Y0] = trial[:, pd.S_Y0]  # onset on the elastic predictor
            if np.abs(trial[:, pd.S_D] - d).max() <= 1e-14:
                break
            d = trial[:, pd.S_D].copy()
        else:
            raise AssertionError("the damage of the step did not converge")
        state = trial
        work += 0.5 * np.sum((f + f_old) * (u - u_old))
        u_old, f_old = u, f
        history.append(state[:, pd.S_D].copy())
        if state[:, pd.S_D].min() == 1.0 and len(history) > 20 and history[-20].min() == 1.0:
            break
    return work - energy, np.array(history), state


@pytest.mark.slow
@pytest.mark.parametrize("width_y", [1.0, 0.25])
def test_cracks_of_a_cross_ply_cell_dissipate_G2c_per_crack_area(width_y):
    dissipated, history, state = pull_cross_ply_cell(width_y)
    assert history[-1].min() == 1.0, "pull further: a ply has not cracked through"
    # the 0-degree ply (fibres along x, top) is loaded across its fibres and cracks first,
    # while the 90-degree ply (fibres along y) still carries its load undamaged
    first = np.argmax(history[:, 1] > 0.0)
    assert history[first, 0] == 0.0
    # its fibres then carry the pull: the fibre tension index of the 90-degree ply grows
    assert state[0, pd.S_FT] > state[1, pd.S_FT]
    # crack areas: the 0-degree ply's crack runs along x (thickness x 1 mm), the 90-degree
    # ply's along y (thickness x width_y)
    area = 0.25 * 1.0 + 0.25 * width_y
    assert dissipated / area == pytest.approx(FAILURE.G2c, rel=1e-2)


def test_nominal_ply_stresses_are_the_damaged_secant_stiffness_times_the_strain():
    """The output's vectorised ply stress equals C(d) T eps built from the damaged material
    stiffness, with the crack open under transverse tension and closed under compression."""
    material = prototype_material("m", rho=1e-9)
    plies = [Ply(material, angle, 0.25) for angle in (0.0, 30.0, 90.0)]
    rng = np.random.default_rng(7)
    strains = 1e-3 * rng.standard_normal((50, 3, 6))
    damage = rng.uniform(0.0, 1.0, (50, 3))
    stresses = pd.nominal_ply_stresses(strains, plies, damage)
    for c in range(50):
        for k, ply in enumerate(plies):
            eps = pd.strain_rotation(ply.angle) @ strains[c, k]
            crack_open = (material.stiffness() @ eps)[1] > 0.0
            C = pd.damaged_material_stiffness(material, damage[c, k], crack_open)
            np.testing.assert_allclose(stresses[c, k], C @ eps, rtol=1e-12, atol=1e-9)


@pytest.mark.parametrize("shear_factors", [(1.0, 1.0), (0.6, 0.85)])
def test_what_the_law_dissipates_is_what_the_element_releases_with_shear_correction(
    shear_factors,
):
    """An element of four random plies, its transverse shear corrected (the factors scale its
    shear terms' weights) or not, strained through the thickness in compression and
    transverse shear until its plies crack: the damage law's summed dissipation equals the
    work done on the element (trapezoidal) minus its strain energy, to 1e-3. The law takes
    the transverse shear energy the element holds, with the correction (without it the law
    booked 1 / k times the element's release in that mode: 28 % too much on an impacted
    plate)."""
    laminate = random_laminate(np.random.default_rng(3), 4)
    packed = pd.pack_ply_damage(laminate.plies, FAILURES)
    rule = se.pack_rule(
        laminate.ply_fractions, np.array(laminate.ply_stiffnesses()), 2, shear_factors
    )
    X = se.CORNERS * [1.0, 1.0, laminate.thickness]
    volumes = np.diff(laminate.ply_fractions) * laminate.thickness
    H = np.array([[0.0, 0.0, 0.3], [0.0, 0.0, 0.5], [0.0, 0.0, -0.4]])
    state = pd.new_state(1, 4)[0]
    f, f_old, u_old = np.zeros((8, 3)), np.zeros((8, 3)), np.zeros((8, 3))
    work = energy = 0.0
    for k in np.linspace(0.0, 0.1, 501)[1:]:
        u = X @ (k * H).T
        energy = se.solid_shell_force_damaged(X, u, *rule, *packed, np.full(4, 0.5), state, f)
        work += 0.5 * np.sum((f + f_old) * (u - u_old))
        f_old, u_old = f.copy(), u
    assert state[:, pd.S_D].max() > 0.5
    dissipated = state[:, pd.S_DISSIPATED] @ volumes
    assert dissipated == pytest.approx(work - energy, rel=1e-3)


def test_a_ply_cracked_in_bending_dissipates_G2c_per_crack_area():
    """A 1 x 1 x 0.5 mm cell of [90, 0] (bottom to top) bent about its own mid-plane, the
    90-degree ply in tension, until that ply has cracked through: the work done on the cell
    (trapezoidal) less its strain energy is G2c times the crack's area (the ply's thickness
    times the width), and the law books the same. The ply's strain rises linearly from the
    mid-plane to the bottom face, so the element releases 4/3 of what the ply's mean strain
    holds: a law driven by the mean strain booked 3/4 of the release and let the crack
    dissipate 4/3 G2c."""
    laminate = Laminate.from_angles(MATERIAL, [90.0, 0.0], 0.25)
    rule = se.pack_rule(laminate.ply_fractions, np.array(laminate.ply_stiffnesses()), 2)
    packed = pd.pack_ply_damage(laminate.plies, FAILURES)
    X = se.CORNERS * [1.0, 1.0, 0.5]
    band_width = np.array([pd.crack_band_width(X, ply.angle) for ply in laminate.plies])
    state = pd.new_state(2)
    f, f_old, u_old = np.zeros((8, 3)), np.zeros((8, 3)), np.zeros((8, 3))
    work = energy = 0.0
    for kappa in np.linspace(0.0, 0.12, 1201)[1:]:  # 1/mm, the bottom face in tension
        u = np.zeros((8, 3))
        u[:, 0] = -kappa * X[:, 0] * (X[:, 2] - 0.25)
        u[:, 2] = 0.5 * kappa * X[:, 0] ** 2
        energy = se.solid_shell_force_damaged(X, u, *rule, *packed, band_width, state, f)
        work += 0.5 * np.sum((f + f_old) * (u - u_old))
        f_old, u_old = f.copy(), u
    assert state[0, pd.S_D] == 1.0 and state[1, pd.S_D] == 0.0
    area = 0.25 * 1.0
    assert (work - energy) / area == pytest.approx(FAILURE.G2c, rel=1e-2)
    booked = state[:, pd.S_DISSIPATED] @ (np.diff(laminate.ply_fractions) * 0.5)
    assert booked == pytest.approx(work - energy, rel=1e-3)
