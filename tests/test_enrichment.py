"""The AFEM enrichment: subelement layout (paper Figure 2), extra-node positions (Eq. 1), and
what weak and strong refinement must conserve (mass, momentum, the displacement field)."""

import tomllib
from pathlib import Path

import numpy as np
import pytest

from fenics_adaptive.adaptivity import enrichment as enr
from fenics_adaptive.model.diagnostics import cell_maps
from fenics_adaptive.settings.config import parse_config
from fenics_adaptive.settings.kinds import InterfaceState
from fenics_adaptive.settings.solver import SolverSettings
from fenics_adaptive.simulation import build_structure
from fenics_adaptive.solver import explicit

DATA = Path(__file__).parent / "data"


def figure2_columns():
    return enr.CellColumns(
        bottom_local=np.array([0, 1, 2, 3]),
        top_local=np.array([4, 5, 6, 7]),
        bottom_global=np.array([10, 11, 12, 13]),
    )


def test_figure_2_seven_plies_refined_at_interfaces_2_and_4():
    """Paper Figure 2: plies 1-2 in the bottom subelement, 3-4 in the second, 5-7 on top."""
    state = np.array([0, 1, 0, 2, 0, 0], dtype=np.int8)
    subs = enr.subelements(state)
    assert [(s.first, s.stop) for s in subs] == [(0, 2), (2, 4), (4, 7)]
    text = enr.describe_cell(state, figure2_columns(), 7)
    assert "subelement 1: plies 1, 2" in text
    assert "subelement 2: plies 3, 4" in text
    assert "subelement 3: plies 5, 6, 7" in text
    # the third subelement sits on the upper copy (set B) of the strong interface 4
    third = text.split("subelement 3")[1]
    assert "i4B" in third.split("cohesive")[0]
    assert "cohesive element at interface 4" in text


def tcb(kind: str = "adaptive", **interfaces) -> dict:
    """The TCB test config; its refinements leave the new nodes where they are placed (these
    tests check the placement: the equilibration that moves them after it is
    ``tests/test_equilibration.py``'s)."""
    data = tomllib.loads((DATA / f"tcb_{kind}.toml").read_text())
    data["interfaces"].update(interfaces)
    if kind == "adaptive":
        data["stabilisation"] = {"equilibrate": False}
    return data


def structure_of(data):
    return build_structure(parse_config(data))


def test_extra_node_positions_follow_eq_1():
    structure = structure_of(tcb(initial="strong"))
    alpha = structure.laminate.interface_fractions
    n_if = structure.interface_state.shape[1]
    X = structure.extra.vectors["X"].array.reshape(-1, 3)
    checked = 0
    for key, local in structure.extra.index.items():
        g, interface, _ = enr.key_parts(key, n_if)
        bottom = structure.extra.local_base_node(g)
        top = structure.columns.top_of[bottom]
        expected = structure.X_base[bottom] + alpha[interface - 1] * (
            structure.X_base[top] - structure.X_base[bottom]
        )
        assert np.allclose(X[local], expected, atol=1e-14)
        checked += 1
    assert checked == structure.extra.n_local > 0
    # shared by neighbours: 21 columns x (interface 4: A; 2 and 6: A and B) x 2 rows of nodes
    assert structure.extra.n_owned == 21 * 2 * 5


def set_linear_state(structure, rng):
    """u and v linear in x (any smooth field would do): nodal values from coordinates."""
    A = rng.normal(size=(3, 3)) * 1e-3
    B = rng.normal(size=(3, 3))
    for block, X in ((structure.base_block, structure.X_base),):
        block.u.array.reshape(-1, 3)[:] = X @ A.T
        block.v.array.reshape(-1, 3)[:] = X @ B.T
    return A, B


@pytest.mark.parametrize("shear_correction", [False, True])
def test_weak_then_strong_refinement_conserves_mass_momentum_and_the_field(shear_correction):
    """The field, mass and momentum stay. The strain energy stays without the shear
    correction; with it (the default) the subelements carry their own spans' factors, and the
    change is the refinement's booked potential energy (docs/afem/04 computes it by hand)."""
    data = tcb(initial="none")
    data["model"]["shear_correction"] = shear_correction
    structure = structure_of(data)
    rng = np.random.default_rng(3)
    A, B = set_linear_state(structure, rng)
    mass, momentum = structure.total_mass(), structure.momentum()
    structure.internal_force()
    energy = structure.internal_forces.energies()[0]
    cells = np.arange(5, 12)
    assert structure.refine([(c, i, InterfaceState.WEAK) for c in cells for i in (2, 4, 6)])
    # extra nodes start on the element's own (here linear) displacement and velocity fields
    X_extra = structure.extra.vectors["X"].array.reshape(-1, 3)
    assert np.allclose(structure.extra.vectors["u"].array.reshape(-1, 3), X_extra @ A.T)
    assert np.allclose(structure.extra.vectors["v"].array.reshape(-1, 3), X_extra @ B.T)
    assert structure.total_mass() == pytest.approx(mass, rel=1e-14)
    assert np.allclose(structure.momentum(), momentum, rtol=1e-13, atol=0)
    structure.internal_force()
    weak = structure.internal_forces.energies()[0]
    if shear_correction:
        assert abs(weak - energy) > 1e-4 * energy
    assert weak - energy == pytest.approx(
        structure.last_refinement_potential, rel=1e-9, abs=1e-12 * energy
    )
    energy = weak

    assert structure.refine([(c, i, InterfaceState.STRONG) for c in cells for i in (2, 6)])
    assert structure.total_mass() == pytest.approx(mass, rel=1e-14)
    assert np.allclose(structure.momentum(), momentum, rtol=1e-13, atol=0)
    structure.internal_force()
    solid, cohesive = structure.internal_forces.energies()
    assert solid == pytest.approx(energy, rel=1e-12)
    assert cohesive == 0.0  # a just-duplicated interface is closed
    assert len(structure.cohesive) == 2 * len(cells)


def bent_structure(angles=(0, 90, 45, -45, 0, 90, 30, 0)):
    """A TCB (by default of an unsymmetric layup) without the shear correction, in a smooth
    field of bending, stretching and twisting (quadratic in x, y, z)."""
    data = tcb(initial="none")
    data["model"]["shear_correction"] = False
    data["laminate"]["angles"] = list(angles)
    structure = structure_of(data)
    X = structure.X_base
    x, y, z = X[:, 0], X[:, 1], X[:, 2] - X[:, 2].mean()
    u = structure.base_block.u.array.reshape(-1, 3)
    u[:, 0] = 1e-3 * (-z * x + 0.3 * x + 0.2 * y * z)
    u[:, 1] = 1e-3 * (0.4 * z * x - 0.1 * y)
    u[:, 2] = 1e-3 * (0.5 * x**2 - 0.2 * x * y + 0.05 * z * x)
    return structure


@pytest.mark.parametrize("interfaces", [(2,), (6,), (2, 4, 6)])
def test_weak_refinement_keeps_the_enhanced_thickness_strain(interfaces, monkeypatch):
    """Bending makes the ESL cell's enhanced thickness strain nonzero. New nodes placed on
    that field (compatible plus enhanced, ``solid_shell.enhanced_displacement``) give
    subelements that hold the cell's strain exactly: with every cell refined (no border
    constraint) and no shear correction, the strain energy is unchanged to round-off. On the
    straight line alone, the energy jumps by several tenths of a per cent."""

    def jump(straight_line):
        if straight_line:
            monkeypatch.setattr(
                "fenics_adaptive.model.structure.enhanced_displacement",
                lambda X, alpha, zeta: np.zeros((len(X), 4, 3)),
            )
        structure = bent_structure()
        structure.internal_force()
        before = structure.internal_forces.energies()[0]
        cells = np.arange(structure.base.n_owned_cells)
        structure.refine([(c, i, InterfaceState.WEAK) for c in cells for i in interfaces])
        structure.internal_force()
        return structure.internal_forces.energies()[0] / before - 1.0

    kept = jump(False)
    assert -1e-4 < kept <= 1e-13
    assert jump(True) > 50 * abs(kept)


@pytest.mark.parametrize("cells", [range(20), range(5, 12), [7]])
def test_one_material_split_keeps_the_strain_energy_to_round_off(cells):
    """Plies of one material: the subelements' own enhanced strains have nothing to add to the
    cell's, so refining cells of the bent TCB at an off-centre interface leaves the strain
    energy unchanged to round-off: every cell, a region, one cell. On a region's border the
    extra nodes follow their unrefined neighbour's straight line with the offset they were
    placed at (``border.record_offsets``); without it a region grown one strip at a time (a
    delamination front) jumped by a whole cell's enhanced strain energy at every step."""
    structure = bent_structure(angles=[0] * 8)
    structure.internal_force()
    before = structure.internal_forces.energies()[0]
    structure.refine([(c, 2, InterfaceState.WEAK) for c in cells])
    structure.internal_force()
    assert structure.internal_forces.energies()[0] == pytest.approx(before, rel=1e-12)


def test_refined_cell_masses_are_the_subelement_masses():
    structure = structure_of(tcb(initial="none"))
    m_base = structure.mass_base.array.copy()
    total = structure.total_mass()
    structure.refine([(0, 4, InterfaceState.WEAK)])
    # assembled: cell 0's four extra nodes hold the plies around interface 4 of that cell, half
    # of the cell's mass; the base nodes lost exactly that
    n_owned = 3 * structure.extra.n_owned
    extra_mass = structure.mass_extra.array[:n_owned:3].sum()
    cell_mass = structure.laminate.areal_mass() * 0.5 * 0.5
    assert extra_mass == pytest.approx(0.5 * cell_mass, rel=1e-13)
    assert m_base[::3].sum() - structure.mass_base.array[::3].sum() == pytest.approx(
        0.5 * cell_mass, rel=1e-12
    )
    # what the solver divides by: the two border nodes (columns shared with the unrefined cell
    # 1) follow their base nodes in x and y (u_z is held by the symmetry of interface 4) and
    # handed those masses to them; the two nodes at the beam's end keep theirs
    assert len(structure.border.dofs) == 2 * 2
    assert np.all(structure.border.weights == 0.5)  # interface 4 is the mid-plane
    assert structure.extra_block.mass[::3].sum() == pytest.approx(0.5 * cell_mass / 2, rel=1e-12)
    assert structure.total_mass() == pytest.approx(total, rel=1e-14)


def test_refinement_outside_the_allowed_interfaces_is_refused():
    structure = structure_of(tcb(initial="none"))
    with pytest.raises(Exception, match="interface 3"):
        structure.refine([(0, 3, InterfaceState.WEAK)])
    with pytest.raises(Exception, match="delaminate"):
        structure.refine([(0, 4, InterfaceState.STRONG)])


@pytest.mark.slow
def test_stable_step_drops_with_thin_subelements_and_cohesive_springs():
    """Refining at interface 1 leaves a subelement one ply (0.256 mm) thick: L_e / c halves
    about; a stiff cohesive penalty lowers it further. The run stays stable at the new step."""
    data = tcb(initial="none", refine=[1, 4], delaminate=[2, 6])
    data["solver"].pop("time_step")
    data["model"]["points_per_ply"] = 2
    structure = structure_of(data)
    before, _ = structure.stable_time_step()
    structure.refine([(c, 1, InterfaceState.WEAK) for c in range(structure.base.n_owned_cells)])
    after, where = structure.stable_time_step()
    thin = 0.256 / structure.laminate.plies[0].material.dilatational_wave_speed()
    assert "subelement" in where
    assert after == pytest.approx(thin, rel=0.02)
    assert after < 0.6 * before

    data["cohesive"]["K_n"] = data["cohesive"]["K_s"] = 1e7
    structure = structure_of(data)
    structure.refine([(c, 2, InterfaceState.STRONG) for c in range(structure.base.n_owned_cells)])
    limit, where = structure.stable_time_step()
    assert "cohesive" in where
    config = parse_config(data)
    settings = SolverSettings(end_time=2000 * 0.9 * limit, output_interval=1e-6)
    stats = explicit.run(structure, settings, config.probe)
    assert stats.time_step == pytest.approx(0.9 * limit)
    assert all(np.isfinite(r.kinetic_energy) for r in stats.history)
    assert max(abs(r.energy_balance) for r in stats.history) < 1e-6 * max(
        r.external_work for r in stats.history
    )


def test_cell_maps_of_a_refined_cell_name_its_nodes():
    structure = structure_of(tcb(initial="none"))
    structure.refine([(0, 4, InterfaceState.WEAK), (0, 2, InterfaceState.STRONG)])
    text = cell_maps(structure, 0)
    assert text.count("subelement") == 3
    assert "subelement 1: plies 1, 2" in text and "subelement 3: plies 5, 6, 7, 8" in text
    assert "cohesive element at interface 2" in text
    # every node a subelement names is a real local node with the coordinates Eq. (1) gives
    n_base = structure.n_base
    for line in text.splitlines():
        if "<- extra" in line:
            node = int(line.split("<- extra ")[1].split()[0])
            assert n_base <= node < n_base + structure.extra.n_local


def test_one_ply_subelements_have_no_zero_energy_modes():
    """Refining every interface of a [0]8 beam with one point per ply leaves one-ply
    subelements; with one point through their thickness they would bend at zero energy. The
    stiffness of the clamped, fully refined beam has no zero eigenvalue."""
    from fenics_adaptive.analysis.comparison import probe_stiffness

    data = tcb(initial="none")
    data["mesh"].update(nx=4, length=2.0)
    data["interfaces"] = {"refine": [1, 2, 3, 4, 5, 6, 7]}
    data.pop("cohesive")
    structure = structure_of(data)
    cells = range(structure.base.n_owned_cells)
    structure.refine([(c, i, InterfaceState.WEAK) for c in cells for i in range(1, 8)])
    K, _ = probe_stiffness(structure)
    fixed = np.concatenate(
        [structure.base_block.fixed, structure.extra_block.fixed + 3 * structure.n_base]
    )
    free = np.setdiff1d(np.arange(K.n), fixed)
    dense = np.zeros((K.n, K.n))
    np.add.at(dense, (K.rows, K.cols), K.values)
    eigenvalues = np.linalg.eigvalsh(0.5 * (dense + dense.T)[np.ix_(free, free)])
    assert eigenvalues.min() > 1e-8 * eigenvalues.max()


def test_vectorised_maps_equal_the_cell_by_cell_maps():
    """The structure builds its subelement and cohesive node lists for all refined cells at
    once (``enrichment.subelement_table`` / ``subelement_nodes_many``); the per-cell functions
    the docs use are an independent path to the same lists."""
    structure = structure_of(tcb(initial="none"))
    rng = np.random.default_rng(7)
    n_cells = structure.base.n_owned_cells
    # random mixed refinement in three rounds: weak and strong, in any order of interfaces
    for _ in range(3):
        cells = rng.choice(n_cells, size=n_cells // 3, replace=False)
        requests = [
            (int(c), int(i), int(rng.choice([InterfaceState.WEAK, InterfaceState.STRONG])))
            for c in cells
            for i in rng.choice([2, 4, 6], size=rng.integers(1, 4), replace=False)
            if i != 4
        ] + [(int(c), 4, InterfaceState.WEAK) for c in cells[::2]]
        structure.refine(requests)

    n_plies = structure.laminate.n_plies
    nodes, cells_of, plies, cohesive = [], [], [], []
    for cell in range(n_cells):
        row = structure.interface_state[cell]
        columns = enr.CellColumns(
            structure.bottom_local[cell], structure.top_local[cell], structure.bottom_global[cell]
        )
        for sub in enr.subelements(row):
            nodes.append(
                enr.subelement_nodes(
                    row, sub, columns, n_plies, structure.extra.index, structure.n_base
                )
            )
            cells_of.append(cell)
            plies.append((sub.first, sub.stop))
        for interface in np.flatnonzero(row == InterfaceState.STRONG) + 1:
            cohesive.append(
                enr.cohesive_nodes(
                    columns, int(interface), n_plies, structure.extra.index, structure.n_base
                )
            )
    refined = (structure.interface_state != InterfaceState.NONE).any(axis=1)
    assert refined.sum() > n_cells // 2
    assert (structure.interface_state == InterfaceState.STRONG).any() and len(cohesive) > 0
    keep = refined[np.array(cells_of)]
    np.testing.assert_array_equal(structure.subelements.nodes, np.array(nodes)[keep])
    np.testing.assert_array_equal(structure.subelement_cells, np.array(cells_of)[keep])
    np.testing.assert_array_equal(structure.subelement_plies, np.array(plies)[keep])
    np.testing.assert_array_equal(structure.cohesive.nodes, np.array(cohesive))
