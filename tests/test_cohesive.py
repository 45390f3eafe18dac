"""Physics tests of the cohesive law and the 8-node cohesive element (single element, unit area).

Units: N, mm, s, tonne (penalty N/mm^3, strengths MPa, energies N/mm per unit area).

The upper face of one element with a unit-square reference face is moved by a prescribed uniform
displacement (lower face fixed); the work is accumulated with the trapezoidal rule using the force
the interface exerts against the motion, F = -f_coh on the upper nodes. Expected values are
written here from the textbook (beta) form of the law, independently of the kernel's form.
"""

import math

import numpy as np
import pytest
from helpers import energy_gradient

from fenics_adaptive.errors import InputError
from fenics_adaptive.materials.cohesive import (
    H_DISSIPATED,
    H_RELEASED,
    HISTORY,
    cohesive_element_force,
    cohesive_element_force_tracked,
    critical_energy,
    traction_separation_curve,
)
from fenics_adaptive.settings.materials import (
    LAW_BK,
    LAW_POWER,
    P_EXPONENT,
    P_GIC,
    P_GIIC,
    P_KN,
    P_KS,
    P_LAW,
    P_N,
    P_S,
    CohesiveLaw,
)

BASE = {
    "K_n": 1e5,
    "K_s": 1e5,
    "N": 20.0,
    "S": 40.0,
    "GIc": 0.4,
    "GIIc": 1.0,
    "law": "bk",
    "exponent": 1.5,
}
FACE = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [1.0, 1.0, 0.0]])
X_UNIT = np.vstack([FACE, FACE])
PHI = math.radians(30.0)  # direction of the shear opening in the plane (exercises d1 and d2)


def make_law(**changes) -> CohesiveLaw:
    return CohesiveLaw(**{**BASE, **changes})


def run(law, openings, X=X_UNIT, damage=None):
    """Move the upper face through ``openings`` (n, 3, global; lower face fixed). Returns the
    force per unit area on the upper face (n, 3), cumulative work per unit area (n,), stored energy
    per unit area (n,), the damage (n, 4) and the final damage array."""
    params = law.as_array()
    damage = np.zeros(4) if damage is None else damage
    u = np.zeros((8, 3))
    f = np.zeros((8, 3))
    n = len(openings)
    forces, work, stored, damages = np.zeros((n, 3)), np.zeros(n), np.zeros(n), np.zeros((n, 4))
    for j, opening in enumerate(openings):
        u[4:] = opening
        stored[j], area = cohesive_element_force(X, u, params, damage, f)
        forces[j] = -f[4:].sum(axis=0) / area
        stored[j] /= area
        damages[j] = damage
        if j:
            work[j] = work[j - 1] + 0.5 * (forces[j - 1] + forces[j]) @ (opening - openings[j - 1])
    return forces, work, stored, damages, damage


def direction(law, B):
    """Unit opening direction of constant mixity B = beta^2 K_s / (K_n + beta^2 K_s), and beta."""
    if B == 1.0:
        return np.array([math.cos(PHI), math.sin(PHI), 0.0]), math.inf
    beta = math.sqrt(B * law.K_n / ((1.0 - B) * law.K_s))
    e = np.array([beta * math.cos(PHI), beta * math.sin(PHI), 1.0])
    return e / np.linalg.norm(e), beta


def analytic(law, beta):
    """(d0, dF, K_m) of a proportional path, LS-DYNA *MAT_138 formulas in terms of beta."""
    dI0, dII0 = law.N / law.K_n, law.S / law.K_s
    if math.isinf(beta):
        d0 = dII0
        return d0, 2.0 * law.GIIc / (law.K_s * d0), law.K_s
    b2 = beta * beta
    d0 = dI0 * dII0 * math.sqrt((1.0 + b2) / (dII0**2 + b2 * dI0**2))
    K_m = (law.K_n + b2 * law.K_s) / (1.0 + b2)
    if law.law == "bk":
        B = b2 * law.K_s / (law.K_n + b2 * law.K_s)
        dF = 2.0 / (K_m * d0) * (law.GIc + (law.GIIc - law.GIc) * B**law.exponent)
    else:
        a = law.exponent
        bracket = (law.K_n / law.GIc) ** a + (law.K_s * b2 / law.GIIc) ** a
        dF = 2.0 * (1.0 + b2) / d0 * bracket ** (-1.0 / a)
    return d0, dF, K_m


def analytic_traction(law, openings, d0, dF):
    """Bilinear traction (global = local frame for the flat element) along a proportional path."""
    dm = np.linalg.norm(openings * [1.0, 1.0, 0.0] + np.maximum(openings * [0, 0, 1.0], 0), axis=1)
    factor = np.ones_like(dm)
    soft = dm > d0
    factor[soft] = np.clip(d0 * (dF - dm[soft]) / (dm[soft] * (dF - d0)), 0.0, None)
    return openings * [law.K_s, law.K_s, law.K_n] * factor[:, None]


def proportional_path(e, d0, dF, n_elastic=200, n_soft=2000, n_after=50):
    """Openings along e: to the onset, to full separation, a little beyond (onset and final
    opening are sample points, so the trapezoidal work is exact on the bilinear curve)."""
    dm = np.concatenate(
        [
            np.linspace(0.0, d0, n_elastic + 1),
            np.linspace(d0, dF, n_soft + 1)[1:],
            np.linspace(dF, 1.05 * dF, n_after + 1)[1:],
        ]
    )
    return dm[:, None] * e


BK_CASES = [
    ("mode I", {}, 0.0),
    ("mode II", {}, 1.0),
    ("B=0.25", {}, 0.25),
    ("B=0.5", {}, 0.5),
    ("B=0.75", {}, 0.75),
    ("B=0.5 K_n!=K_s", {"K_n": 2e5, "K_s": 5e4}, 0.5),
]


@pytest.mark.parametrize(("name", "changes", "B"), BK_CASES, ids=[c[0] for c in BK_CASES])
def test_bk_energy_peak_and_curve(name, changes, B):
    law = make_law(**changes)
    e, beta = direction(law, B)
    d0, dF, K_m = analytic(law, beta)
    openings = proportional_path(e, d0, dF)
    forces, work, stored, damages, _ = run(law, openings)

    # dissipated energy at full separation
    expected = law.GIc + (law.GIIc - law.GIc) * B**law.exponent
    assert critical_energy(law, B) == pytest.approx(expected, rel=1e-12)
    assert 0.5 * K_m * d0 * dF == pytest.approx(expected, rel=1e-12)
    assert stored[-1] == 0.0
    assert np.all(damages[-1] == 1.0)
    dissipated = work[-1] - stored[-1]
    print(
        f"{name}: dissipated {dissipated:.9g} N/mm, expected {expected:.9g}, "
        f"rel err {dissipated / expected - 1:.2e}"
    )
    assert dissipated == pytest.approx(expected, rel=1e-2)
    # dissipation never negative, never decreasing
    D = work - stored
    assert np.all(np.diff(D) >= -1e-12 * expected)

    # peak traction = onset traction, on the quadratic criterion
    t_onset = np.array([law.K_s * d0 * e[0], law.K_s * d0 * e[1], law.K_n * d0 * e[2]])
    peak = np.linalg.norm(t_onset)
    j = np.argmax(np.linalg.norm(forces, axis=1))
    np.testing.assert_allclose(forces[j], t_onset, rtol=0, atol=1e-9 * peak)
    t_shear = math.hypot(forces[j, 0], forces[j, 1])
    assert (forces[j, 2] / law.N) ** 2 + (t_shear / law.S) ** 2 == pytest.approx(1.0, rel=1e-9)
    if B == 0.0:
        assert forces[j, 2] == pytest.approx(law.N, rel=1e-9)
    if B == 1.0:
        assert t_shear == pytest.approx(law.S, rel=1e-9)

    # the whole traction-separation curve
    error = np.abs(forces - analytic_traction(law, openings, d0, dF)).max() / peak
    assert error < 1e-6


def test_power_law_energy():
    law = make_law(law="power", exponent=2.0)
    B = 0.5
    e, beta = direction(law, B)
    d0, dF, K_m = analytic(law, beta)
    expected = (((1 - B) / law.GIc) ** 2 + (B / law.GIIc) ** 2) ** -0.5
    assert critical_energy(law, B) == pytest.approx(expected, rel=1e-12)
    assert 0.5 * K_m * d0 * dF == pytest.approx(expected, rel=1e-12)
    openings = proportional_path(e, d0, dF)
    forces, work, stored, _, _ = run(law, openings)
    print(
        f"power B=0.5: dissipated {work[-1]:.9g} N/mm, expected {expected:.9g}, "
        f"rel err {work[-1] / expected - 1:.2e}"
    )
    assert work[-1] - stored[-1] == pytest.approx(expected, rel=1e-2)
    peak = law.K_n * d0
    assert np.abs(forces - analytic_traction(law, openings, d0, dF)).max() / peak < 1e-6


@pytest.mark.parametrize("B", [0.0, 0.5])
def test_unload_reload_along_secant(B):
    law = make_law()
    e, beta = direction(law, B)
    d0, dF, K_m = analytic(law, beta)
    Gc = critical_energy(law, B)
    d_max = d0 + 0.4 * (dF - d0)
    # onset is a sample point, so the trapezoidal work is exact on the bilinear curve
    load = np.concatenate([np.linspace(0.0, d0, 101), np.linspace(d0, d_max, 1001)[1:]])
    load = load[:, None] * e
    unload = np.linspace(d_max, 0.0, 201)[:, None] * e
    reload = np.linspace(0.0, d_max, 201)[:, None] * e
    to_end = np.linspace(d_max, 1.05 * dF, 2001)[:, None] * e
    openings = np.vstack([load, unload[1:], reload[1:], to_end[1:]])
    forces, work, stored, damages, _ = run(law, openings)

    n1 = len(load)
    cycle = slice(n1 - 1, n1 - 1 + 2 * (len(unload) - 1) + 1)  # unload + reload
    d_expected = dF * (d_max - d0) / (d_max * (dF - d0))
    assert damages[n1 - 1] == pytest.approx(np.full(4, d_expected), rel=1e-12)
    # damage frozen and tractions on the damaged secant during the cycle
    assert np.all(damages[cycle] == damages[n1 - 1])
    secant = (1.0 - d_expected) * openings[cycle] * [law.K_s, law.K_s, law.K_n]
    peak = K_m * d0
    assert np.abs(forces[cycle] - secant).max() < 1e-9 * peak
    # no new dissipation while unloading/reloading; the dissipation so far is the
    # triangle between the loading curve and the secant: Gc (d_max - d0)/(dF - d0)
    D = work - stored
    assert np.ptp(D[cycle]) < 1e-9 * Gc
    assert D[n1 - 1] == pytest.approx(Gc * (d_max - d0) / (dF - d0), rel=1e-9)
    assert work[n1 - 1 + len(unload) - 1] == pytest.approx(D[n1 - 1], rel=1e-9)  # at zero
    # and the total is still Gc
    assert work[-1] == pytest.approx(Gc, rel=1e-2)


def test_compression_is_penalty_only():
    law = make_law()
    d0 = law.N / law.K_n
    ez = np.array([0.0, 0.0, 1.0])
    push = np.concatenate([np.linspace(0.0, -10 * d0, 201), np.linspace(-10 * d0, 0.0, 201)[1:]])

    # fresh interface
    openings = push[:, None] * ez
    forces, work, stored, damages, _ = run(law, openings)
    np.testing.assert_allclose(forces[:, 2], law.K_n * push, rtol=1e-12, atol=0)
    assert np.abs(forces[:, :2]).max() < 1e-12 * law.N
    assert np.all(damages == 0.0)
    np.testing.assert_allclose(stored, 0.5 * law.K_n * push**2, rtol=1e-12)
    np.testing.assert_allclose(work, stored, atol=1e-12 * law.GIc)

    # after partial mode-I damage: load, unload, then push together and release
    dF = 2.0 * law.GIc / law.N
    d_max = d0 + 0.5 * (dF - d0)
    opening = np.concatenate([np.linspace(0, d_max, 1001), np.linspace(d_max, 0, 201)[1:]])
    _, _, _, damages1, damage = run(law, opening[:, None] * ez)
    assert 0.4 < damage[0] < 1.0
    forces, work2, stored, damages, _ = run(law, openings, damage=damage.copy())
    np.testing.assert_allclose(forces[:, 2], law.K_n * push, rtol=1e-12, atol=0)
    assert np.all(damages == damages1[-1])
    assert abs(work2[-1]) < 1e-12 * law.GIc  # closed compression cycle: no dissipation
    np.testing.assert_allclose(work2, stored, atol=1e-12 * law.GIc)


def rotation(axis, angle_deg):
    axis = np.asarray(axis, float) / np.linalg.norm(axis)
    K = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    a = math.radians(angle_deg)
    return np.eye(3) + math.sin(a) * K + (1 - math.cos(a)) * K @ K


@pytest.mark.parametrize("axis", [(1.0, 0.0, 0.0), (1.0, 1.0, 0.0)])
def test_rigid_rotation(axis):
    law = make_law()
    params = law.as_array()
    d0 = law.N / law.K_n
    R = rotation(axis, 90.0)
    f = np.zeros((8, 3))
    for opening in (0.0, 0.5 * d0, 3.0 * d0):
        jump = np.zeros((8, 3))
        jump[4:, 2] = opening
        damage_ref = np.zeros(4)
        energy_ref, _ = cohesive_element_force(X_UNIT, jump, params, damage_ref, f)
        f_ref = f.copy()
        # (a) flat reference, current configuration rotated: x = R (X + jump)
        u_a = (X_UNIT + jump) @ R.T - X_UNIT
        # (b) rotated reference, rotated displacement
        X_b, u_b = X_UNIT @ R.T, jump @ R.T
        for X, u in ((X_UNIT, u_a), (X_b, u_b)):
            damage = np.zeros(4)
            energy, area = cohesive_element_force(X, u, params, damage, f)
            assert area == pytest.approx(1.0, rel=1e-12)
            if opening == 0.0:
                assert np.abs(f).max() < 1e-12
                assert energy == 0.0
            else:
                # pure mode I, rotated: the same traction turned with the element
                np.testing.assert_allclose(f, f_ref @ R.T, rtol=0, atol=1e-9 * law.N)
                np.testing.assert_allclose(damage, damage_ref, rtol=1e-9, atol=1e-15)
                assert energy == pytest.approx(energy_ref, rel=1e-9)
                normal = R @ [0.0, 0.0, 1.0]
                # upper face pulled back along the (rotated) normal, lower face pushed along it
                assert f[4:] @ normal == pytest.approx(f_ref[4:, 2], rel=1e-9)
                assert np.all(f[4:] @ normal < 0.0)
        if opening > 0.0:
            assert np.all(f_ref[:4, 2] > 0.0)  # sign convention: lower nodes pulled up


def test_force_is_energy_gradient():
    """With K_n = K_s the elastic energy 1/2 K |jump|^2 does not depend on the frame, so
    f_coh = -dW/du exactly: checks shape functions, Gauss rule, area and scatter on a distorted,
    non-planar element moved far from its reference (rotated, stretched mid-surface)."""
    law = make_law()
    params = law.as_array()
    rng = np.random.default_rng(1)
    face = FACE * [2.0, 1.5, 0.0] + rng.uniform(-0.3, 0.3, (4, 3))
    X = np.vstack([face, face])
    mid = rng.uniform(-0.2, 0.2, (4, 3)) + face @ rotation((0.3, 1.0, 0.2), 40.0).T - face
    half_jump = rng.uniform(-3e-5, 3e-5, (4, 3))
    u = np.vstack([mid - half_jump, mid + half_jump])

    def energy(u):
        damage = np.zeros(4)
        W, _ = cohesive_element_force(X, u, params, damage, np.zeros((8, 3)))
        assert np.all(damage == 0.0)
        return W

    f = np.zeros((8, 3))
    cohesive_element_force(X, u, params, np.zeros(4), f)
    h = 1e-8
    grad = energy_gradient(energy, u, h)
    np.testing.assert_allclose(f, -grad, rtol=0, atol=1e-6 * np.abs(f).max())
    np.testing.assert_allclose(f.sum(axis=0), 0.0, atol=1e-12 * np.abs(f).max())


@pytest.mark.slow
def test_curve_helper_matches_element():
    law = make_law(K_n=2e5, K_s=5e4)
    e, beta = direction(law, 0.5)
    d0, dF, _ = analytic(law, beta)
    openings = proportional_path(e, d0, dF, 20, 100, 5)
    tractions, damages, stored = traction_separation_curve(law, openings)
    forces, _, stored_el, damages_el, _ = run(law, openings)
    np.testing.assert_allclose(tractions, forces, rtol=1e-12, atol=1e-12 * law.N)
    np.testing.assert_allclose(damages, damages_el[:, 0], rtol=1e-12)
    np.testing.assert_allclose(stored, stored_el, rtol=1e-10, atol=1e-18)


def test_as_array_slots():
    law = make_law(K_n=1.1e5, K_s=0.9e5, law="power", exponent=1.2)
    p = law.as_array()
    assert p.dtype == np.float64
    assert (p[P_KN], p[P_KS], p[P_N], p[P_S]) == (1.1e5, 0.9e5, 20.0, 40.0)
    assert (p[P_GIC], p[P_GIIC], p[P_LAW], p[P_EXPONENT]) == (0.4, 1.0, LAW_POWER, 1.2)
    assert make_law().as_array()[P_LAW] == LAW_BK


@pytest.mark.parametrize(
    ("changes", "key", "words"),
    [
        ({"GIc": -1.0}, "cohesive.GIc", "> 0"),
        ({"K_n": 0.0}, "cohesive.K_n", "> 0"),
        ({"K_s": math.inf}, "cohesive.K_s", "finite"),
        ({"N": math.nan}, "cohesive.N", "finite"),
        ({"S": "40"}, "cohesive.S", "number"),
        ({"GIIc": True}, "cohesive.GIIc", "number"),
        ({"exponent": 0.0}, "cohesive.exponent", "> 0"),
        ({"law": "linear"}, "cohesive.law", "bk, power"),
        ({"GIc": 0.001}, "cohesive.GIc", "softening impossible"),  # N^2/(2 K_n) = 0.002
        ({"GIIc": 0.008}, "cohesive.GIIc", "softening impossible"),  # S^2/(2 K_s) = 0.008
    ],
)
def test_invalid_parameters(changes, key, words):
    with pytest.raises(InputError) as info:
        make_law(**changes)
    assert info.value.key == key
    assert words in str(info.value)


def test_from_mapping():
    assert CohesiveLaw.from_mapping(BASE) == make_law()
    with pytest.raises(InputError) as info:
        CohesiveLaw.from_mapping({**BASE, "eta": 1.5})
    assert info.value.key == "cohesive.eta"
    assert "unknown" in str(info.value)
    missing = dict(BASE)
    del missing["GIIc"]
    with pytest.raises(InputError) as info:
        CohesiveLaw.from_mapping(missing)
    assert info.value.key == "cohesive.GIIc"
    assert "missing" in str(info.value)
    with pytest.raises(InputError) as info:
        CohesiveLaw.from_mapping({**BASE, "GIc": -0.4})
    assert info.value.key == "cohesive.GIc"


def _turned_element(rng):
    """A distorted, non-planar element's reference X (8, 3) and a motion u (8, 3) that turns and
    stretches its mid-surface far from the reference, without a jump yet."""
    face = FACE * [2.0, 1.5, 0.0] + rng.uniform(-0.3, 0.3, (4, 3))
    mid = rng.uniform(-0.2, 0.2, (4, 3)) + face @ rotation((0.3, 1.0, 0.2), 70.0).T - face
    return np.vstack([face, face]), np.vstack([mid, mid])


@pytest.mark.parametrize("damage", [0.95, 1.0])
def test_force_is_energy_gradient_of_a_damaged_interface_in_compression(damage):
    """Damaged (or broken) and partly closed, with K_n != K_s, the energy depends on how the
    jump splits into normal and tangential parts, hence on the frame, which turns with the
    mid-surface: f_coh = -dW/du holds only with the frame's turning in the force. Without it
    the interface would give or take energy on a closed path (next test)."""
    law = make_law(K_s=0.6e5)
    params = law.as_array()
    rng = np.random.default_rng(7)
    X, u = _turned_element(rng)
    jump = rng.uniform(-2e-4, 2e-4, (4, 3))  # mixed signs: points open and closed
    u[:4] -= 0.5 * jump
    u[4:] += 0.5 * jump
    state = np.full(4, damage)

    def energy(v):
        d = state.copy()
        W, _ = cohesive_element_force(X, v, params, d, np.zeros((8, 3)))
        assert np.array_equal(d, state)  # the openings stay below what would damage it more
        return W

    f = np.zeros((8, 3))
    cohesive_element_force(X, u, params, state.copy(), f)
    h = 1e-9
    grad = energy_gradient(energy, u, h)
    np.testing.assert_allclose(f, -grad, rtol=0, atol=1e-6 * np.abs(f).max())


def test_a_broken_interface_turned_around_a_closed_path_does_no_work():
    """A fully damaged interface pressed closed (its only force the contact penalty K_n d3 n)
    whose faces turn by 60 degrees, change their jump, turn back and restore it: the work of
    its forces around the closed path is zero (to the trapezoidal rule's O(h^2)), as for any
    force that is the gradient of an energy. A penalty along a normal that turns without its
    share of the frame's change did a tenth of the largest stored energy per cycle."""
    law = make_law(K_s=0.6e5)
    params = law.as_array()
    J0 = np.array([1.0e-4, 0.5e-4, -2.0e-4])  # mm, global: closed at the start
    J1 = np.array([0.0, -1.5e-4, 0.5e-4])

    def motion(theta, s):
        mid = X_UNIT[:4] @ rotation((1.0, 0.3, 0.0), theta).T - X_UNIT[:4]
        jump = J0 + s * J1
        return np.vstack([mid - 0.5 * jump, mid + 0.5 * jump])

    n = 2000
    legs = [
        [(60.0 * k / n, 0.0) for k in range(n + 1)],
        [(60.0, k / n) for k in range(n + 1)],
        [(60.0 * (1 - k / n), 1.0) for k in range(n + 1)],
        [(0.0, 1 - k / n) for k in range(n + 1)],
    ]
    damage = np.ones(4)
    work = 0.0
    stored = []
    f_old = u_old = None
    for leg in legs:
        for theta, s in leg:
            u = motion(theta, s)
            f = np.zeros((8, 3))
            energy, _ = cohesive_element_force(X_UNIT, u, params, damage, f)
            stored.append(energy)
            if f_old is not None:
                work += 0.5 * np.sum((f_old + f) * (u - u_old))
            f_old, u_old = f, u
    assert max(stored) > 0.0 and stored[-1] == pytest.approx(stored[0], rel=1e-12)
    assert abs(work) < 1e-6 * max(stored)  # measured 2e-8


def smooth_step(x, start, stop):
    t = min(max((x - start) / (stop - start), 0.0), 1.0)
    return 1.0 - t * t * (3.0 - 2.0 * t)


@pytest.mark.parametrize(("slid", "pressed"), [(0.3, 0.05), (0.7, 0.05), (0.9, 0.15), (0.2, 0.18)])
def test_a_broken_interface_lets_go_of_faces_slid_by_its_size_or_pressed_through(slid, pressed):
    """A broken interface pressed closed keeps its full contact penalty while its faces slid
    by less than half its size (1 mm here) and passed less than a tenth of it into each
    other; it lets go smoothly up to a slip of its size and a depth of a fifth of it
    (``pressed_share``), and carries nothing beyond. An intact interface keeps all of it."""
    law = make_law(K_s=0.6e5)
    params = law.as_array()
    direction = np.array([math.cos(PHI), math.sin(PHI), 0.0])

    def state(slip, depth):
        u = np.zeros((8, 3))
        u[4:] = slip * direction + [0.0, 0.0, -depth]
        return u

    f = np.zeros((8, 3))
    stored, _ = cohesive_element_force(X_UNIT, state(slid, pressed), params, np.ones(4), f)
    share = smooth_step(slid, 0.5, 1.0) * smooth_step(pressed, 0.1, 0.2)
    assert stored == pytest.approx(share * 0.5 * law.K_n * pressed**2, rel=1e-9)
    # the penalty's force only, pressing the faces apart: no pull, no push along the slip
    np.testing.assert_allclose(
        f[4:].sum(axis=0), [0.0, 0.0, share * law.K_n * pressed], atol=1e-12 * law.K_n
    )
    for far in (state(1.01, pressed), state(slid, 0.21)):
        assert cohesive_element_force(X_UNIT, far, params, np.ones(4), f)[0] == 0.0
        assert np.abs(f).max() == 0.0
        intact, _ = cohesive_element_force(X_UNIT, far, params, np.zeros(4), f)
        assert intact > 0.5 * law.K_n * far[4, 2] ** 2 - 1e-12  # all of it, and shear


def test_what_a_broken_interface_lets_go_of_is_gone_and_dissipated():
    """The faces of a broken interface pressed 0.08 mm deep slide 1.2 times its size and back:
    the contact lets go as they slide past half its size and does not come back when they
    return (the smallest share it has had); the work done on the interface equals what it
    holds plus what it dissipated (the penalty's energy let go), to 1e-4 of that energy."""
    law = make_law()
    params = law.as_array()
    damage, history = np.ones(4), np.zeros((4, HISTORY))
    direction = np.array([math.cos(PHI), math.sin(PHI), 0.0])
    slips = np.concatenate([np.linspace(0.0, 1.2, 3001), np.linspace(1.2, 0.0, 3001)[1:]])
    work, f_old, u_old, stored = 0.0, None, None, []
    for slip in slips:
        u = np.zeros((8, 3))
        u[4:] = slip * direction + [0.0, 0.0, -0.08]
        f = np.zeros((8, 3))
        energy, _ = cohesive_element_force_tracked(X_UNIT, u, params, damage, history, f)
        stored.append(energy)
        if f_old is not None:
            work -= 0.5 * np.sum((f_old + f) * (u - u_old))  # done on the interface
        f_old, u_old = f, u
    assert stored[0] == pytest.approx(0.5 * law.K_n * 0.08**2, rel=1e-12)
    assert stored[-1] == 0.0 and np.all(history[:, H_RELEASED] == 1.0)
    dissipated = history[:, H_DISSIPATED].sum()
    assert dissipated == pytest.approx(stored[0], rel=1e-12)  # it let go of all it held
    assert work + stored[0] == pytest.approx(stored[-1] + dissipated, rel=1e-4)


def test_a_collapsed_mid_surface_gives_nan_not_an_exception():
    """Faces moved so that their mid-surface collapses to a point have no normal: the kernel
    returns NaN forces (which a run's not-finite guard reports, naming the time and place)
    instead of raising from inside the compiled loop."""
    law = make_law()
    u = np.zeros((8, 3))
    u[:4] = -X_UNIT[:4]  # lower face to the origin, upper face too: mid-surface a point
    u[4:] = -X_UNIT[4:]
    f = np.zeros((8, 3))
    cohesive_element_force(X_UNIT, u, law.as_array(), np.ones(4), f)
    assert np.isnan(f).any()
