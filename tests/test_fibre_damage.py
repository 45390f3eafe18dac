"""Fibre failure and erosion (issue 18 items 2 and 3): the crack-band fibre damage of
``materials.ply_damage`` through the damage-aware element kernel, and the removal of elements
whose fibres have all broken.

Material: IM7/8552 (Camanho, Maimi and Davila 2007; the fibre fracture energies Gft = 81.5
N/mm and Gfc = 106.3 N/mm of Maimi, Camanho, Mayugo and Davila 2007, Part II).

Expected values come from the crack band model, not from the kernel: a cube of side h pulled
(pushed) along the fibres to full fibre failure dissipates G h^2, G per unit area of the crack
across it, whatever h; the dissipation is measured twice, from the law's own increments and as
the work of the element's forces (trapezoidal) minus its remaining strain energy.
Units: N, mm, s, tonne (MPa, N/mm, mJ).
"""

from __future__ import annotations

import numpy as np
import pytest
from mpi4py import MPI

from fenics_adaptive.element import subelement as se
from fenics_adaptive.element.rules import RuleTable
from fenics_adaptive.errors import InputError
from fenics_adaptive.materials import ply_damage as pd
from fenics_adaptive.materials.laminate import Laminate, PlyMaterial
from fenics_adaptive.model.ply_damage_state import PlyDamageState
from fenics_adaptive.settings.materials import PlyFailure

IM7 = PlyMaterial("im7", E1=171420.0, E2=9080.0, G12=5290.0, nu12=0.32, nu23=0.5, rho=1.59e-9)
IM7_FAILURE = PlyFailure(
    "im7", XT=2326.2, XC=1200.1, YT=62.3, YC=199.8, S12=92.3, G2c=0.277, G6c=0.788,
    Gft=81.5, Gfc=106.3,
)  # fmt: skip
FAILURES = {"im7": IM7_FAILURE}


def unidirectional_cube(size: float, n_plies: int = 2):
    """A cube of side ``size`` (mm) of 0-degree plies: (X, packed rule, packed damage)."""
    laminate = Laminate.from_angles(IM7, [0.0] * n_plies, size / n_plies)
    rule = se.pack_rule(laminate.ply_fractions, np.array(laminate.ply_stiffnesses()), 2)
    packed = pd.pack_ply_damage(laminate.plies, FAILURES)
    return se.CORNERS * size, rule, packed


def uniaxial_stress_motion(X: np.ndarray, fibre_strain: float) -> np.ndarray:
    """Displacement (8, 3) of the homogeneous strain of uniaxial fibre stress: eps11 =
    ``fibre_strain``, the lateral strains of the ply's Poisson ratios (the whole-ply degradation
    keeps the stress uniaxial as the fibres fail)."""
    strain = fibre_strain * np.array([1.0, -IM7.nu12, -IM7.nu12])
    return X * strain


def element_step(
    X, u, rule, packed, bands, state, f, corotational, erode, min_volume_ratio, eroded
):
    """One damage-updating call of the batched damaged kernel on the single element X (8, 3)
    moved by u: its force into f (8, 3), its energy (mJ) returned; the other arguments as
    ``subelement.add_damaged_subelement_forces`` takes them (one cell row, base nodes only)."""
    none = np.zeros((0, 3))
    return se.add_damaged_subelement_forces(
        np.arange(8, dtype=np.int32)[None],
        np.zeros(1, np.int64),
        np.zeros(1, np.int64),
        np.zeros(1, np.int64),
        *se.concatenate_rules([rule]),
        *packed,
        bands,
        state,
        X,
        none,
        u,
        none,
        f,
        none,
        True,
        corotational,
        erode,
        min_volume_ratio,
        eroded,
        np.zeros((0, 3, 3)),
    )


def pull_to_failure(size: float, sign: float, steps: int = 3000, erode: bool = False):
    """Strain the cube along its fibres (sign +1: tension, -1: compression) to 1.3 times the
    strain where the bilinear law's fibre stress would vanish. Returns (dissipated by the law,
    its fibre share, eroded, work - strain energy, the stress history (MPa), strains, state)."""
    X, rule, packed = unidirectional_cube(size)
    G, strength = (
        (IM7_FAILURE.Gft, IM7_FAILURE.XT) if sign > 0 else (IM7_FAILURE.Gfc, IM7_FAILURE.XC)
    )
    final = 2.0 * G / (strength * size)
    n = len(rule.stiffness)
    state = pd.new_state(1, n)
    bands = np.array([pd.crack_band_widths(X, 0.0)] * n)[None]
    volume = size**3
    work, energy = 0.0, 0.0
    u_old, f_old = np.zeros((8, 3)), np.zeros((8, 3))
    stresses, strains = [], []
    eroded = np.zeros(1, dtype=np.int64)
    for eps in sign * np.linspace(0.0, 1.3 * final, steps + 1)[1:]:
        u = uniaxial_stress_motion(X, eps)
        f = np.zeros((8, 3))
        energy = element_step(X, u, rule, packed, bands, state, f, False, erode, 0.0, eroded)
        work += 0.5 * np.sum((f + f_old) * (u - u_old))
        u_old, f_old = u, f
        stresses.append(f[X[:, 0] > 0.5 * size, 0].sum() / size**2)
        strains.append(eps)
    ply_volume = volume / n
    dissipated = state[0, :, pd.S_DISSIPATED].sum() * ply_volume
    fibre = state[0, :, pd.S_FIBRE_DISSIPATED].sum() * ply_volume
    assert eroded[0] == (1 if erode and state[0, :, pd.S_DF].min() == 1.0 else 0)
    eroded = state[0, :, pd.S_ERODED].sum() * ply_volume
    return dissipated, fibre, eroded, work - energy, np.array(stresses), np.array(strains), state


@pytest.mark.parametrize("sign", [1.0, -1.0], ids=["tension", "compression"])
@pytest.mark.parametrize("size", [0.5, 1.0, 2.0])
def test_fibre_dissipation_per_crack_area_is_the_fibre_fracture_energy(size, sign):
    dissipated, fibre, _, lost, stress, strain, state = pull_to_failure(size, sign)
    G = IM7_FAILURE.Gft if sign > 0 else IM7_FAILURE.Gfc
    area = size * size
    assert np.all(state[0, :, pd.S_DF] == 1.0)
    assert np.all(state[0, :, pd.S_D] == 0.0)  # uniaxial fibre stress: no matrix crack
    assert fibre == dissipated  # all of it the fibres'
    assert fibre / area == pytest.approx(G, rel=1e-4)  # the issue asks 1 %: 2e-6 measured
    assert lost / area == pytest.approx(G, rel=1e-4)  # the work not stored: the same energy
    # the peak: the fibre strength at XT / E1 (the bilinear law's)
    strength = IM7_FAILURE.XT if sign > 0 else IM7_FAILURE.XC
    peak = np.argmax(sign * stress)
    assert sign * stress[peak] == pytest.approx(strength, rel=2e-3)
    step = abs(strain[1] - strain[0])
    assert abs(sign * strain[peak] - strength / IM7.E1) <= step


def test_the_fibres_do_not_break_in_in_plane_shear():
    """Shear at the in-plane strength cracks the matrix (Hashin's fibre tension index, which
    holds the shear, reaches 1 as well) but breaks no fibre: fibre damage initiates on the fibre
    stress alone."""
    state = np.zeros(pd.N_STATE)
    for gamma in np.linspace(0.0, 3.0 * IM7_FAILURE.S12 / IM7.G12, 300)[1:]:
        pd.material_point_update(IM7, IM7_FAILURE, np.array([0, 0, 0, 0, 0, gamma]), 0.5, state)
    assert state[pd.S_D] > 0.5 and state[pd.S_FT] >= 1.0
    assert state[pd.S_DF] == 0.0 and state[pd.S_FIBRE_DISSIPATED] == 0.0


def test_matrix_damage_alone_without_fibre_energies():
    """Without Gft and Gfc the fibres never break (fibre failure an index), as before."""
    failure = PlyFailure(
        "im7", XT=2326.2, XC=1200.1, YT=62.3, YC=199.8, S12=92.3, G2c=0.277, G6c=0.788
    )
    state = np.zeros(pd.N_STATE)
    for eps in np.linspace(0.0, 0.05, 200)[1:]:
        pd.material_point_update(IM7, failure, np.array([eps, 0, 0, 0, 0, 0]), 0.5, state)
    assert state[pd.S_FT] > 1.0 and state[pd.S_DF] == 0.0


def test_a_cell_too_long_for_the_fibre_energy_is_refused():
    """Snap-back: the band along the fibres must stay below 2 E1 G / X^2 (5.2 mm in tension for
    IM7/8552): a 6 mm cell is refused naming Gft, a 4 mm one is not; a weak Gfc is named. The
    band of a 90-degree ply's fibre crack is the cell's width."""
    limit = 2.0 * IM7.E1 * IM7_FAILURE.Gft / IM7_FAILURE.XT**2
    assert 5.0 < limit < 5.3

    def state_for(angles, length: float, failures=FAILURES) -> PlyDamageState:
        laminate = Laminate.from_angles(IM7, angles, 0.5)
        X = (se.CORNERS * [length, 0.5, 1.0])[None]
        n = len(angles)
        return PlyDamageState(
            laminate, failures, RuleTable(laminate, 2), X, np.array([[0, n]]), MPI.COMM_SELF
        )

    state_for([0.0, 0.0], 4.0)
    with pytest.raises(InputError, match=r"im7.failure.Gft: a cell is 6 mm along the fibres"):
        state_for([0.0, 0.0], 6.0)
    weak = PlyFailure(**{**IM7_FAILURE.__dict__, "Gfc": 5.0})  # limit 1.19 mm
    with pytest.raises(InputError, match=r"failure.Gfc: .*2 E1 Gfc / XC\^2"):
        state_for([0.0, 0.0], 2.0, {"im7": weak})
    assert state_for([0.0, 90.0], 0.8).band_width[0].tolist() == [[0.5, 0.8], [0.8, 0.5]]


def test_fibre_damage_needs_both_energies():
    with pytest.raises(InputError, match=r"failure\.Gfc: missing"):
        PlyFailure.from_mapping(
            "im7",
            {"XT": 2326.2, "XC": 1200.1, "YT": 62.3, "YC": 199.8, "S12": 92.3,
             "G2c": 0.277, "G6c": 0.788, "Gft": 81.5},
        )  # fmt: skip


def test_an_eroded_element_carries_nothing_and_books_its_energy():
    """With erosion the element leaves once its fibres have all failed: its force is exactly
    zero from then on, and the strain energy it held then (the RESIDUAL share) is booked, so
    that the work done on it equals what it dissipated plus what erosion took (to 1e-4: the
    trapezoidal work of the step that drops the force misses half that step's increment)."""
    size = 1.0
    dissipated, _, eroded, lost, stress, _, state = pull_to_failure(size, 1.0, erode=True)
    assert np.all(state[0, :, pd.S_DF] == 1.0)
    gone = np.flatnonzero(stress == 0.0)
    assert len(gone) > 100 and np.all(stress[gone[0] :] == 0.0)  # once gone, gone
    assert eroded > 0.0
    # the eroded element's energy is no longer in the kernel's: the work not stored is the
    # dissipated plus the eroded energy
    assert lost == pytest.approx(dissipated + eroded, rel=1e-4)
    kept, *_ = pull_to_failure(size, 1.0, erode=False)
    assert dissipated == pytest.approx(kept, rel=1e-12)  # erosion changes nothing before it


@pytest.mark.parametrize("sign", [1.0, -1.0], ids=["tension", "compression"])
def test_a_rigidly_turned_element_breaks_its_fibres_alike(sign):
    """Objectivity under finite kinematics (co-rotated kernel): the cube pulled along its
    fibres and the same motion turned rigidly by 90 degrees about two axes break the same
    fibres and dissipate the same energy (1e-10)."""
    X, rule, packed = unidirectional_cube(1.0)
    Q = np.array([[0.0, -1.0, 0.0], [0.0, 0.0, -1.0], [1.0, 0.0, 0.0]])
    results = []
    for turn in (np.eye(3), Q):
        state = pd.new_state(1, 2)[0]
        f = np.zeros((8, 3))
        for eps in sign * np.linspace(0.0, 0.5, 400)[1:]:
            u = (X + uniaxial_stress_motion(X, eps)) @ turn.T - X
            se.solid_shell_force_damaged(
                X, u, *rule, *packed, np.ones((2, 2)), state, f, corotational=True
            )
        results.append((state.copy(), f @ turn))
    (state, f), (turned, g) = results
    assert state[:, pd.S_DF].min() > 0.5
    np.testing.assert_allclose(turned[:, pd.S_DF], state[:, pd.S_DF], rtol=0, atol=1e-12)
    dissipated = state[:, pd.S_FIBRE_DISSIPATED]
    np.testing.assert_allclose(
        turned[:, pd.S_FIBRE_DISSIPATED], dissipated, rtol=0, atol=1e-10 * dissipated.max()
    )
    np.testing.assert_allclose(g, f, rtol=0, atol=1e-9 * np.abs(f).max())


def test_a_fast_sphere_perforates_a_plate_that_erodes(tmp_path):
    """tests/data/perforation.toml: a 1 g sphere at 100 m/s (5 J) into a 1 mm [0/90]s plate,
    finite kinematics, ply damage with broken fibres and erosion. Erosion removes the broken
    and the crushed elements (without it the run has stopped on an inverted element, or not:
    the run after the fibres soften is chaotic, round-off decides), the sphere goes on 2.8 mm
    deep, the energy balance from the work stays closed to 1e-3 of the impact
    energy through it, and the one from the states (the damage laws' own dissipation) to
    10 %: fibres and matrix soften within a few steps at this rate, where the laws'
    consistent increments are exact only for proportional steps (quasi-static fibre failure
    closes it, the tests above). Most of the energy the plies take is the fibres'."""
    import tomllib
    from pathlib import Path

    from fenics_adaptive.io.output import read_history
    from fenics_adaptive.runner import execute
    from fenics_adaptive.settings.config import parse_config

    data = tomllib.loads((Path(__file__).parent / "data" / "perforation.toml").read_text())
    summary, structure = execute(
        parse_config(data), tmp_path / "eroding", MPI.COMM_WORLD, False, log=None
    )
    h = read_history(tmp_path / "eroding" / "history.csv")
    energy = 0.5 * 1.0e-6 * 1.0e5**2  # mJ
    assert np.ptp(h["energy_balance"]) < 1e-3 * energy
    assert h["eroded_energy"][-1] > 0.0
    assert h["fibre_dissipation"][-1] > 0.8 * h["ply_dissipation"][-1]
    assert np.abs(h["state_energy_balance"]).max() < 0.1 * max(h["impact_work"])
    assert h["impactor_displacement"][-1] < -2.0  # mm: past the 1 mm plate's thickness
    damage = structure.damage_state
    eroded_cells = np.count_nonzero(damage[:, :, pd.S_DF].min(axis=1) == 1.0)  # (unrefined)
    assert eroded_cells >= 4
    assert summary["eroded_elements_at_end"] == eroded_cells


def test_contact_lets_go_of_the_nodes_erosion_has_freed(tmp_path):
    """The sphere's contact with the top face of tests/data/perforation.toml: with the four
    cells around the plate's centre eroded, their shared centre node leaves the contact (no
    element holds it), their other nodes stay (their neighbours still do); a node pressed
    into the sphere then gets no force."""
    import tomllib
    from pathlib import Path

    from fenics_adaptive.model.contact import Contact
    from fenics_adaptive.settings.config import parse_config
    from fenics_adaptive.simulation import build_structure

    data = tomllib.loads((Path(__file__).parent / "data" / "perforation.toml").read_text())
    config = parse_config(data)
    structure = build_structure(config, MPI.COMM_WORLD)
    contact = Contact.on(config.impactor, structure)
    X = structure.X_base[contact.nodes]
    centre = np.flatnonzero(np.all(np.isclose(X, [5.0, 5.0, 1.0]), axis=1))
    cells = np.flatnonzero(
        np.all(np.abs(structure.cell_vertices().mean(axis=1)[:, :2] - 5.0) < 0.5, axis=1)
    )
    assert len(centre) == 1 and len(cells) == 4
    structure.damage_state[cells, :, pd.S_DF] = 1.0
    contact.release()
    assert np.flatnonzero(~contact.active).tolist() == centre.tolist()
    # push every face node 0.1 mm into the sphere: the freed one is left alone
    structure.base.u.x.array[:] = 0.0
    u = structure.base.u.x.array.reshape(-1, 3)
    u[contact.nodes, 2] = contact.centre[2] - contact.body.radius - 1.0 + 0.1
    f = np.zeros(structure.base.u.x.array.shape)
    contact.add_force(0.0, f, np.zeros(0))
    pushed = f.reshape(-1, 3)[contact.nodes, 2]
    assert pushed[centre[0]] == 0.0 and np.count_nonzero(pushed) > 0


def _uniaxial_fibre_path(stresses: np.ndarray, state: np.ndarray) -> np.ndarray:
    """Drive one IM7 point through uniaxial fibre stresses (MPa, the undamaged strain of each
    along the path: eps = S0 s e1); returns the fibre stress it carries at each."""
    S0 = np.linalg.inv(IM7.stiffness())
    carried = []
    for s in stresses:
        sigma, _ = pd.material_point_update(IM7, IM7_FAILURE, S0[:, 0] * s, 0.5, state)
        carried.append(sigma[0])
    return np.array(carried)


@pytest.mark.parametrize("first", ["compression", "tension"])
def test_each_fibre_mode_starts_at_its_own_strength(first):
    """A ply just past its strength in one mode (the fibres start to break there), unloaded,
    then loaded the other way breaks at that mode's strength (within 1 %), not at the first
    mode's: tension and kink-band compression each have their own onset."""
    XT, XC = IM7_FAILURE.XT, IM7_FAILURE.XC
    sign = -1.0 if first == "compression" else 1.0
    strength, other = (XC, XT) if first == "compression" else (XT, XC)
    state = np.zeros(pd.N_STATE)
    up = np.linspace(0.0, 1.002 * strength, 400)
    _uniaxial_fibre_path(sign * np.concatenate([up, up[::-1]]), state)
    started = state[pd.S_DF]
    assert 0.0 < started < 0.01
    carried = _uniaxial_fibre_path(-sign * np.linspace(0.0, 1.5 * other, 1500), state)
    peak = other * (1.0 - (1.0 - pd.RESIDUAL) * started)  # the fibres the first mode left
    assert np.abs(carried).max() == pytest.approx(peak, rel=1e-2)


def test_matrix_and_fibres_breaking_in_one_step_book_what_the_ply_loses():
    """One point strained proportionally in fibre compression with in-plane shear, in steps
    coarse enough that matrix and fibre damage grow in the same updates: the damage laws'
    summed dissipation is the work done on the point (trapezoidal) minus its strain energy,
    to 1e-3 (6e-4: the fibres' increments see the matrix stiffness change between steps;
    booking their release at the matrix damage of before the update made it 1.9e-3)."""
    direction = np.array([-1.0, 0.0, 0.0, 0.0, 0.0, 2.5])  # material frame, engineering shear
    state = np.zeros(pd.N_STATE)
    work, energy, sigma_old, eps_old = 0.0, 0.0, np.zeros(6), np.zeros(6)
    both = 0
    for s in np.linspace(0.0, 0.12, 121)[1:]:
        d_before = state[[pd.S_D, pd.S_DF]].copy()
        eps = s * direction
        sigma, energy = pd.material_point_update(IM7, IM7_FAILURE, eps, 0.5, state)
        work += 0.5 * (sigma + sigma_old) @ (eps - eps_old)
        sigma_old, eps_old = sigma, eps
        both += bool(np.all(state[[pd.S_D, pd.S_DF]] > d_before))
    assert both >= 3 and state[pd.S_DF] > 0.5
    assert state[pd.S_DISSIPATED] == pytest.approx(work - energy, rel=1e-3)


def test_a_volume_ratio_without_erosion_is_refused():
    import tomllib
    from pathlib import Path

    from fenics_adaptive.settings.config import parse_config

    data = tomllib.loads((Path(__file__).parent / "data" / "perforation.toml").read_text())
    data["model"].update(erosion=False, erosion_volume_ratio=0.3)
    with pytest.raises(InputError, match=r"model\.erosion_volume_ratio: needs model\.erosion"):
        parse_config(data)


def test_an_element_turned_inside_out_books_the_energy_it_held():
    """Under finite kinematics an element whose motion's fit turns inside out has no frame to
    compute its energy in: it is eroded with the energy its plies held at their last update
    (``subelement._book_last_energy``), here all of the strain energy of a cube stretched
    along its fibres to half their strength, then mirrored through its mid-plane."""
    X, rule, packed = unidirectional_cube(1.0)
    n = len(rule.stiffness)
    state = pd.new_state(1, n)
    bands = np.array([pd.crack_band_widths(X, 0.0)] * n)[None]
    eroded = np.zeros(1, dtype=np.int64)

    def step(u):
        return element_step(
            X, u, rule, packed, bands, state, np.zeros((8, 3)), True, True, 0.2, eroded
        )

    held = step(uniaxial_stress_motion(X, 0.5 * IM7_FAILURE.XT / IM7.E1))
    assert held > 0.0 and eroded[0] == 0
    mirrored = X * [1.0, 1.0, -1.0] - X
    assert step(mirrored) == 0.0
    assert eroded[0] == 1 and np.all(state[0, :, pd.S_DF] == 1.0)
    booked = state[0, :, pd.S_ERODED].sum() / n  # per unit volume of the unit cube's plies
    assert booked == pytest.approx(held, rel=1e-9)
