"""The parts ``Structure`` is built from, each alone: the geometric helpers, the rule table, the
stabilisation, ply-damage and refinement states (their ``state()`` / ``restore()`` round trips),
the cohesive damage rows, the solver's blocks (lumped masses moved by a refinement); and the
comparison's element forces, which now take the structure's own rules.

Units: N, mm, s, tonne (stress MPa, energy mJ).
"""

from __future__ import annotations

import copy
import importlib.util
from pathlib import Path

import numpy as np
import pytest
from helpers import GLASS, prototype_material
from mpi4py import MPI

from fenics_adaptive.adaptivity.refinement import RefinementState
from fenics_adaptive.adaptivity.stabilisation import StabilisationState
from fenics_adaptive.element.geometry import quad_areas, slab_vertices, thickness_weight
from fenics_adaptive.element.rules import RuleTable
from fenics_adaptive.element.subelement import CORNERS, pack_rule, sublaminate_ply_zeta
from fenics_adaptive.element.timestep import characteristic_lengths, hexahedron_volumes
from fenics_adaptive.errors import InputError
from fenics_adaptive.materials import ply_damage as pd
from fenics_adaptive.materials.laminate import Laminate, Ply, ply_shear_factors
from fenics_adaptive.model.assembly import CohesiveSet, add_subelement_forces
from fenics_adaptive.model.ply_damage_state import PlyDamageState
from fenics_adaptive.settings.adaptivity import Interfaces, Stabilisation
from fenics_adaptive.settings.kinds import InterfaceState

CARBON = prototype_material("proto")
FAILURES = {
    "proto": pd.PlyFailure.from_mapping(
        "proto",
        {"XT": 2000.0, "XC": 1200.0, "YT": 50.0, "YC": 200.0, "S12": 80.0, "G2c": 0.2, "G6c": 1.0},
    ),
    "glass": pd.PlyFailure(
        "glass", XT=1100.0, XC=700.0, YT=40.0, YC=150.0, S12=70.0, S23=50.0, G2c=0.3, G6c=1.2
    ),
}
# three plies of different thickness and material: spans differ in rule and wave speed
LAMINATE = Laminate((Ply(CARBON, 0.0, 0.2), Ply(GLASS, 90.0, 0.3), Ply(CARBON, 45.0, 0.1)))


def box(lx: float, ly: float, lz: float) -> np.ndarray:
    """Vertices (1, 8, 3) of an axis-aligned box, DOLFINx tensor order."""
    return (CORNERS * np.array([lx, ly, lz]))[None]


# --- geometry ---------------------------------------------------------------------------------
def test_quad_area_of_known_quadrilaterals():
    rectangle = np.array([[0.0, 0.0, 0.0], [2.0, 0.0, 0.0], [0.0, 3.0, 0.0], [2.0, 3.0, 0.0]])
    # a parallelogram sheared by 1 mm along x and tilted out of the xy plane: base 2, height 3
    rotation = np.array([[1.0, 0.0, 0.0], [0.0, 0.6, -0.8], [0.0, 0.8, 0.6]])
    sheared = (rectangle + np.array([[0.0, 0, 0], [0, 0, 0], [1, 0, 0], [1, 0, 0]])) @ rotation.T
    areas = quad_areas(np.stack([rectangle, sheared]))
    np.testing.assert_allclose(areas, [6.0, 6.0], rtol=1e-14)
    # any leading shape: the six faces of a 1 x 2 x 3 box
    faces = box(1.0, 2.0, 3.0)[:, [[0, 1, 2, 3], [4, 5, 6, 7], [0, 1, 4, 5], [0, 2, 4, 6]]]
    np.testing.assert_allclose(quad_areas(faces), [[2.0, 2.0, 3.0, 6.0]], rtol=1e-14)
    # the stable-step length of the box: volume / largest face area
    assert characteristic_lengths(box(1.0, 2.0, 3.0))[0] == pytest.approx(6.0 / 6.0)


def test_volumes_and_lengths_of_distorted_hexahedra_by_two_paths():
    """The stable step's volumes and lengths (numba) on hexahedra far from boxes equal (a) the
    analytic volume of a frustum-like cell, a 2 x 1 bottom face under a 1 x 0.5 top face
    shifted sideways (a pyramid's frustum: h/3 (A + a + sqrt(A a))), and (b) on random
    distortions, 2x2x2 Gauss on det J built from ``reference_gradients`` and the faces'
    ``quad_areas``, to round-off."""
    from fenics_adaptive.element import solid_shell
    from fenics_adaptive.element.timestep import HEX_FACES, reference_gradients

    h = 0.7
    bottom = np.array([[0, 0, 0], [2, 0, 0], [0, 1, 0], [2, 1, 0]], dtype=float)
    top = 0.5 * bottom + np.array([0.3, 0.2, h])  # similar faces: a frustum of a pyramid
    frustum = np.vstack([bottom, top])[None]
    A, a = 2.0, 0.5
    expected = h / 3 * (A + a + np.sqrt(A * a))
    assert hexahedron_volumes(frustum)[0] == pytest.approx(expected, rel=1e-14)
    assert characteristic_lengths(frustum)[0] == pytest.approx(expected / A, rel=1e-14)

    rng = np.random.default_rng(11)
    X = box(1.5, 1.0, 0.4) + rng.uniform(-0.15, 0.15, (50, 8, 3))
    g = solid_shell.GAUSS_2
    volumes = np.zeros(len(X))
    for point in np.stack(np.meshgrid(g, g, g, indexing="ij"), axis=-1).reshape(-1, 3):
        J = np.einsum("nki,kj->nij", X, reference_gradients(point))
        volumes += 0.125 * np.abs(np.linalg.det(J))
    lengths = volumes / quad_areas(X[:, HEX_FACES, :]).max(axis=1)
    np.testing.assert_allclose(hexahedron_volumes(X), volumes, rtol=1e-13)
    np.testing.assert_allclose(characteristic_lengths(X), lengths, rtol=1e-13)


def test_slab_between_thickness_weights():
    fractions = LAMINATE.ply_fractions  # 0, 1/3, 5/6, 1
    assert thickness_weight(fractions, 1, 0, 3) == pytest.approx(1 / 3)
    assert thickness_weight(fractions, 2, 1, 3) == pytest.approx(0.75)  # (5/6 - 1/3) / (2/3)
    X = box(2.0, 1.0, 0.6)
    middle = slab_vertices(X[:, :4], X[:, 4:], np.array([1 / 3]), np.array([5 / 6]))
    np.testing.assert_allclose(middle[0, :4, 2], 0.2, rtol=1e-14)
    np.testing.assert_allclose(middle[0, 4:, 2], 0.5, rtol=1e-14)
    assert hexahedron_volumes(middle)[0] == pytest.approx(2.0 * 1.0 * 0.3, rel=1e-14)


# --- rule table -------------------------------------------------------------------------------
@pytest.mark.parametrize("points_per_ply", [1, 2])
def test_rule_table_gives_each_span_its_rule(points_per_ply):
    table = RuleTable(LAMINATE, points_per_ply)
    n = LAMINATE.n_plies
    shear_factors = {
        (a, b): ply_shear_factors(LAMINATE, a, b) for a in range(n) for b in range(a + 1, n + 1)
    }
    assert table.spans == [(a, b) for a in range(n) for b in range(a + 1, n + 1)]
    stiffness = np.array(LAMINATE.ply_stiffnesses())
    for first, stop in table.spans:
        rule = table.rules[table.index(first, stop)]
        # one ply: two points through it whatever points_per_ply, else points_per_ply per ply
        points = points_per_ply if stop - first > 1 else 2
        zeta = sublaminate_ply_zeta(LAMINATE.ply_fractions, first, stop)
        expected = pack_rule(
            zeta, stiffness[first:stop], points, shear_factors[first, stop], enhanced=True
        )
        for got, want in zip(rule, expected, strict=True):
            np.testing.assert_array_equal(got, want)
    # a one-ply subelement bends with energy: its normal-term points integrate (zeta - 1/2)^2
    rule = table.rules[table.index(1, 2)]
    normal = (rule.terms == 0) & (rule.position_of_point == rule.position_of_point[0])
    weights, zeta = rule.weights[normal], rule.zeta[normal]
    moment = np.sum(weights * (zeta - 0.5) ** 2) / np.sum(weights)
    assert moment == pytest.approx(1.0 / 12.0, rel=1e-12)
    # arrays of spans
    spans = np.array([[0, 3], [1, 2], [0, 1]])
    np.testing.assert_array_equal(table.rule_of(spans), [table.index(a, b) for a, b in spans])
    speeds = [p.material.dilatational_wave_speed() for p in LAMINATE.plies]
    np.testing.assert_allclose(table.wave_speed(spans), [max(speeds), speeds[1], speeds[0]])
    # the mass rule of a span: its weights times the densities give the span's mass per volume
    mass_rule = table.mass_rule(0, 3)
    density = np.array([p.material.rho for p in LAMINATE.plies])
    mean_density = np.sum(mass_rule.weights * mass_rule.density[mass_rule.ply_of_point])
    thicknesses = np.array([p.thickness for p in LAMINATE.plies])
    assert mean_density == pytest.approx(np.dot(density, thicknesses) / thicknesses.sum())
    with pytest.raises(ValueError, match="no ply span"):
        table.index(2, 2)


# --- stabilisation ----------------------------------------------------------------------------
def started_stabilisation() -> tuple[StabilisationState, np.ndarray, np.ndarray]:
    state = StabilisationState(Stabilisation(5.0e4, 2.0e-5, 1.0e-5), MPI.COMM_SELF)
    rng = np.random.default_rng(0)
    force, mass = rng.normal(size=(6, 3)), rng.uniform(1e-9, 2e-9, 6)
    state.request(np.array([3, 5]))
    state.request_pair(0, 1)
    state.request_pair(4, 2)
    state.start(
        1.0e-5,
        lambda cells: [np.array([0, 1, 2], np.int32), 3 * cells.astype(np.int32)],
        lambda: (force, mass, np.full(6, 0.1)),
    )
    return state, force, mass


def test_tie_forces_make_the_pairs_accelerate_together_and_round_trip():
    state, force, mass = started_stabilisation()
    assert not len(state.new_weak_cells) and not state.new_pairs  # requests consumed
    f_ext = np.zeros(18)
    state.add_tie_forces(1.0e-5, f_ext)
    f_ext = f_ext.reshape(-1, 3)
    acceleration = (f_ext - force) / mass[:, None]  # m a = f_ext - f_int
    np.testing.assert_allclose(acceleration[0], acceleration[1], rtol=1e-12)
    np.testing.assert_allclose(acceleration[4], acceleration[2], rtol=1e-12)
    windows = state.active_damping(1.0e-5)
    assert [(w.block, w.coefficient) for w in windows] == [(0, 5.0e4), (1, 5.0e4)]
    # open for damping_window from the refinement on
    assert [w.until for w in windows] == pytest.approx([3.0e-5, 3.0e-5], rel=1e-12)
    np.testing.assert_array_equal(windows[1].dofs, [9, 15])

    copy_ = StabilisationState(state.settings, MPI.COMM_SELF)
    copy_.restore(state.state())
    for t in (1.2e-5, 1.5e-5):  # the same forces while releasing: half of them at mid-window
        f_a, f_b = np.zeros(18), np.zeros(18)
        state.add_tie_forces(t, f_a)
        copy_.add_tie_forces(t, f_b)
        np.testing.assert_array_equal(f_a, f_b)
    np.testing.assert_allclose(f_b.reshape(-1, 3)[0], 0.5 * f_ext[0], rtol=1e-12)
    assert copy_.active_damping(2.9e-5)[1].until == windows[1].until
    assert not copy_.active_damping(3.1e-5)  # closed after its end
    copy_.add_tie_forces(2.0e-5, np.zeros(18))
    assert not copy_.ties  # released


# --- ply damage -------------------------------------------------------------------------------
def test_ply_damage_state_volumes_strength_and_round_trip():
    X = np.concatenate([box(1.0, 1.0, 0.6), box(1.0, 1.0, 0.6) + np.array([1.0, 0.0, 0.0])])
    cell_plies = np.array([[0, 3], [0, 3]])
    table = RuleTable(LAMINATE, 1)
    state = PlyDamageState(LAMINATE, FAILURES, table, X, cell_plies, MPI.COMM_SELF)
    # each ply's reference volume: its thickness over the unit square (the laminate is 0.6 thick)
    np.testing.assert_allclose(state.ply_volumes, [[0.2, 0.3, 0.1]] * 2, rtol=1e-12)
    # the crack band crosses the fibres: 0-degree ply across y, 90-degree across x
    np.testing.assert_allclose(state.band_width[:, :2], 1.0, rtol=1e-12)
    state.scale_matrix_strength(np.array([1]), [1], 0.5)
    C22 = GLASS.stiffness()[1, 1]
    assert state.damage[1, 1, pd.S_Y0] == pytest.approx((0.5 * 40.0) ** 2 / (2.0 * C22))
    assert state.damage[0, 1, pd.S_Y0] == 0.0
    state.damage[:, :, pd.S_DISSIPATED] = [[1.0, 2.0, 3.0], [0.0, 0.0, 10.0]]  # MPa = mJ/mm^3
    assert state.dissipated_energy() == pytest.approx(0.2 + 0.6 + 0.3 + 1.0)

    other = PlyDamageState(LAMINATE, FAILURES, table, X, cell_plies, MPI.COMM_SELF)
    kept = other.damage
    other.restore(state.state())
    assert other.damage is kept  # in place: the kernel's arguments stay valid
    np.testing.assert_array_equal(other.damage, state.damage)
    assert other.dissipated_energy() == state.dissipated_energy()


# --- refinement -------------------------------------------------------------------------------
def test_refinement_state_plans_books_and_replays():
    refinement = RefinementState(4, 2, Interfaces(refine=(1, 2), delaminate=(2,)))
    target = refinement.plan(
        [(0, 1, InterfaceState.WEAK), (1, 2, InterfaceState.STRONG)], MPI.COMM_SELF
    )
    assert not refinement.interface_state.any()  # a plan changes nothing yet
    np.testing.assert_array_equal(
        target[:2],
        [[InterfaceState.WEAK, InterfaceState.NONE], [InterfaceState.NONE, InterfaceState.STRONG]],
    )
    with pytest.raises(InputError, match="interface 1 is not allowed to delaminate"):
        refinement.plan([(0, 1, InterfaceState.STRONG)], MPI.COMM_SELF)
    changed = np.array([0, 1])
    # strong through weak: both cells weaken first, only cell 1 strengthens
    np.testing.assert_array_equal(refinement.to_weaken(changed, target, 1), [0])
    np.testing.assert_array_equal(refinement.to_weaken(changed, target, 2), [1])
    refinement.mark_weak(np.array([1]), 2)
    np.testing.assert_array_equal(refinement.to_strengthen(changed, target, 2), [1])
    refinement.mark_strong(np.array([1]), 2)
    assert refinement.damage_rows == {(1, 2): 0}
    np.testing.assert_array_equal(refinement.refined_cells(), [1])
    np.testing.assert_array_equal(refinement.unrefined_cells(), [0, 2, 3])
    refinement.record(2.0e-5, [(0, 1, InterfaceState.WEAK), (1, 2, InterfaceState.STRONG)])
    refinement.record(4.0e-5, [(3, 2, InterfaceState.WEAK)])
    refinement.book(0.25, -0.5)
    refinement.book(1.0, 0.125)
    assert refinement.energy == 0.875 and refinement.last_potential == 0.125

    replayed = []
    fresh = RefinementState(4, 2, refinement.interfaces)
    fresh.restore(refinement.state(), lambda requests, t: replayed.append((t, requests)))
    assert replayed == refinement.log
    assert fresh.energy == refinement.energy


def test_cohesive_rows_grow_undamaged_and_round_trip():
    cohesive = CohesiveSet.empty(np.zeros(8))
    cohesive.grow_rows(2)
    cohesive.damage[1] = 0.5
    cohesive.history[1, :, 0] = 0.01
    cohesive.grow_rows(3)
    np.testing.assert_array_equal(cohesive.damage, [[0.0] * 4, [0.5] * 4, [0.0] * 4])
    other = CohesiveSet.empty(np.zeros(8))
    other.grow_rows(3)
    other.restore(cohesive.state())
    np.testing.assert_array_equal(other.history, cohesive.history)
    np.testing.assert_array_equal(other.damage, cohesive.damage)


# --- the comparison's element forces use the structure's rules --------------------------------
ROOT = Path(__file__).parents[1]


@pytest.mark.skipif(MPI.COMM_WORLD.size > 1, reason="the comparison is serial")
def test_element_forces_of_one_ply_subelements_with_one_point_per_ply():
    """With points_per_ply = 1, a refined cell's one-ply subelements get two points through
    their thickness; the element forces of ``analysis.comparison`` must use them too (their
    own copy of the rules used one and missed this)."""
    from fenics_adaptive.analysis import comparison as cmp
    from fenics_adaptive.runner import build_structure

    spec = importlib.util.spec_from_file_location("esl_vs_lw_demo", ROOT / "demos" / "esl_vs_lw.py")
    demo = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(demo)
    settings = copy.deepcopy(demo.load_settings(ROOT / "demos" / "esl_vs_lw.toml"))
    settings["beam"].update(nx=4, ny=1, length=4.0, points_per_ply=1)
    config = demo.run_config(settings, settings["layups"]["[0/90]2s"], "adaptive")
    structure = build_structure(config)
    assert structure.base.points_per_ply == 1
    _, _, plies = structure.elements()
    assert (plies[:, 1] - plies[:, 0] == 1).all()  # every interface refined
    rng = np.random.default_rng(5)
    structure.base.u.x.array[:] = 1e-3 * rng.standard_normal(len(structure.base.u.x.array))
    extra = structure.extra.vectors["u"].array
    extra[:] = 1e-3 * rng.standard_normal(len(extra))
    structure.internal_force()
    expected = np.concatenate([structure.f_base.array, structure.f_extra.array]).reshape(-1, 3)
    total = cmp.element_forces(structure, np.ones(len(plies), dtype=bool))
    assert np.abs(total - expected).max() <= 1e-10 * np.abs(expected).max()


# --- the solver's blocks: lumped masses, prescribed DOFs, totals ------------------------------
def one_cell_space(thickness: float):
    """A vector P1 space on one 1 x 1 x ``thickness`` mm hexahedron (DOLFINx tensor order)."""
    from dolfinx import fem, mesh

    cube = mesh.create_box(
        MPI.COMM_SELF, [[0.0, 0.0, 0.0], [1.0, 1.0, thickness]], [1, 1, 1], mesh.CellType.hexahedron
    )
    return fem.functionspace(cube, ("Lagrange", 1, (3,)))


def test_blocks_move_mass_to_the_extra_nodes_of_a_refined_cell_and_keep_the_total():
    """A three-ply cell weakly refined at both interfaces, its masses moved by the blocks alone:
    the total mass stays the laminate's, and each interface plane carries half of the plies on
    either side (one-ply subelements of uniform density lump m/8 on each vertex)."""
    from dolfinx import common, la

    from fenics_adaptive.model.blocks import LumpedBlocks, subelement_mass_change
    from fenics_adaptive.model.border import BorderConstraints

    V = one_cell_space(LAMINATE.thickness)
    cell = V.dofmap.list[0].astype(np.int64)  # bottom four, then top four
    X_base = V.tabulate_dof_coordinates()
    table = RuleTable(LAMINATE, 2)
    ply_mass = np.array([p.material.rho * p.thickness for p in LAMINATE.plies])  # area 1 mm^2
    base_mass = np.zeros(3 * len(X_base))
    cell_masses = table.lumped_masses(X_base[cell][None], np.array([0]), np.array([3]))[0]
    for node, m in zip(cell, cell_masses, strict=True):
        base_mass[3 * node : 3 * node + 3] = m
    blocks = LumpedBlocks(
        V,
        base_mass,
        common.IndexMap(MPI.COMM_SELF, 0),
        np.zeros(0, np.int32),
        np.zeros(0, np.int32),
    )

    def fields(index_map):
        return la.vector(index_map, bs=3), la.vector(index_map, bs=3)

    base_fields = fields(V.dofmap.index_map)
    blocks.rebuild(
        BorderConstraints.empty(),
        np.zeros(0, np.int64),
        base_fields,
        fields(blocks.f_extra.index_map),
    )
    assert blocks.total_mass() == pytest.approx(ply_mass.sum(), rel=1e-13)

    # extra nodes 4 (i - 1) + k at interface i: combined local index n_base + that
    n_base = len(X_base)
    fractions = LAMINATE.ply_fractions

    def subelement_nodes(states, first, stop, cells):
        def face(level, half):
            if level == 0 or level == LAMINATE.n_plies:
                return cell[half]
            return n_base + 4 * (level - 1) + np.arange(4)

        return np.array(
            [
                np.concatenate([face(a, slice(0, 4)), face(b, slice(4, 8))])
                for a, b in zip(first, stop, strict=True)
            ]
        )

    def positions(nodes):
        out = X_base[np.minimum(nodes, n_base - 1)].copy()
        extra = nodes >= n_base
        level = (nodes[extra] - n_base) // 4 + 1
        out[extra] = X_base[cell[(nodes[extra] - n_base) % 4]]
        out[extra, 2] = fractions[level] * LAMINATE.thickness
        return out

    weak = np.full((1, 2), InterfaceState.WEAK)
    none = np.full((1, 2), InterfaceState.NONE)
    delta = subelement_mass_change(
        np.array([0]), none, weak, subelement_nodes, positions, table, n_base + 8
    )
    assert delta.sum() == pytest.approx(0.0, abs=1e-14 * ply_mass.sum())  # moved, not made
    blocks.resize_extra(common.IndexMap(MPI.COMM_SELF, 8))
    blocks.add_mass_change(delta)
    # interface 1's node 0 held in z by motion 0: the extra block's one prescribed DOF
    prescribed = np.full(24, -1, dtype=np.int64)
    prescribed[2] = 0
    extra_fields = fields(blocks.f_extra.index_map)
    blocks.rebuild(BorderConstraints.empty(), prescribed, base_fields, extra_fields)
    np.testing.assert_array_equal(blocks.extra_block.fixed, [2])
    np.testing.assert_array_equal(blocks.extra_block.fixed_motion, [0])
    assert blocks.total_mass() == pytest.approx(ply_mass.sum(), rel=1e-13)
    extra = blocks.extra_block.mass[::3]
    assert extra[:4].sum() == pytest.approx(0.5 * (ply_mass[0] + ply_mass[1]), rel=1e-12)
    assert extra[4:].sum() == pytest.approx(0.5 * (ply_mass[1] + ply_mass[2]), rel=1e-12)
    base = blocks.base_block.mass[::3]
    assert base[cell[:4]].sum() == pytest.approx(0.5 * ply_mass[0], rel=1e-12)
    assert base[cell[4:]].sum() == pytest.approx(0.5 * ply_mass[2], rel=1e-12)

    # a rigid translation at w (mm/s): momentum M w, kinetic energy M |w|^2 / 2
    w = np.array([3.0, -1.0, 2.0])
    for v in (base_fields[1], extra_fields[1]):
        v.array.reshape(-1, 3)[:] = w
    np.testing.assert_allclose(blocks.momentum(), ply_mass.sum() * w, rtol=1e-12)
    assert blocks.kinetic_energy() == pytest.approx(0.5 * ply_mass.sum() * w @ w, rel=1e-12)
    # more extra nodes: the owned ones keep their assembled masses, the new start empty
    kept = blocks.mass_extra.array.copy()
    blocks.resize_extra(common.IndexMap(MPI.COMM_SELF, 10))
    np.testing.assert_array_equal(blocks.mass_extra.array[:24], kept)
    assert not blocks.mass_extra.array[24:].any()


# --- the refined cells' elements --------------------------------------------------------------
def test_refined_cells_of_one_cell_open_only_at_its_strong_interface():
    """One three-ply cell, weak at interface 1 and strong at 2, its elements made by the part
    alone: three one-ply subelements and one cohesive element; opening the strong interface by
    a rigid lift of what lies above it stores K_n delta^2 A / 2 in the cohesive element only,
    and its two faces get equal and opposite forces K_n delta A."""
    from fenics_adaptive.model.refined_cells import RefinedCells
    from fenics_adaptive.settings.materials import CohesiveLaw

    law = CohesiveLaw(K_n=1e5, K_s=1e5, N=20.0, S=40.0, GIc=0.4, GIIc=1.0, law="bk", exponent=2.0)
    table = RuleTable(LAMINATE, 2)
    refined = RefinedCells(table, CohesiveSet.empty(law.as_array()))
    refined.cohesive.grow_rows(1)  # the damage row of (cell 0, interface 2)
    # combined nodes: 0-7 the cell, then interface 1 (8-11), interface 2 set A (12-15), set B
    faces = {0: np.arange(4), 1: 8 + np.arange(4), 2: 12 + np.arange(4), 3: 4 + np.arange(4)}

    def subelement_nodes(states, first, stop, cells):
        spans = zip(first, stop, strict=True)
        top = {**faces, 2: 16 + np.arange(4)}  # above the strong interface: set B
        return np.array(
            [np.concatenate([top[a] if a == 2 else faces[a], faces[b]]) for a, b in spans]
        )

    def cohesive_nodes(interfaces, cells):
        return np.array([np.concatenate([12 + np.arange(4), 16 + np.arange(4)])])

    states = np.array([[InterfaceState.WEAK, InterfaceState.STRONG]])
    refined.rebuild(np.array([0]), states, {(0, 2): 0}, subelement_nodes, cohesive_nodes)
    np.testing.assert_array_equal(refined.plies, [[0, 1], [1, 2], [2, 3]])
    np.testing.assert_array_equal(refined.cells, [0, 0, 0])
    np.testing.assert_allclose(refined.speeds, table.wave_speed(refined.plies))
    np.testing.assert_array_equal(refined.cohesive.interface, [2])
    nodes, cells, plies = refined.elements(
        np.zeros((0, 8)), np.zeros(0, np.int64), np.zeros((0, 2))
    )
    assert nodes.dtype == np.int32 and len(nodes) == 3
    np.testing.assert_array_equal(cells, refined.cells)
    np.testing.assert_array_equal(plies, refined.plies)

    X_base = box(1.0, 1.0, LAMINATE.thickness)[0]
    z = LAMINATE.ply_fractions * LAMINATE.thickness
    X_extra = np.vstack([np.column_stack([X_base[:4, :2], np.full(4, h)]) for h in z[[1, 2, 2]]])
    delta = 1.0e-5  # mm, below the onset opening N / K_n = 2e-4 mm
    u_base, u_extra = np.zeros((8, 3)), np.zeros((12, 3))
    u_base[4:, 2] = delta  # the top of the cell and set B lifted
    u_extra[8:, 2] = delta
    f_base, f_extra = np.zeros((8, 3)), np.zeros((12, 3))
    solid = add_subelement_forces(
        refined.subelements, X_base, X_extra, u_base, u_extra, f_base, f_extra, False
    )
    assert abs(solid) < 1e-20
    assert np.abs(f_base).max() < 1e-9 and np.abs(f_extra).max() < 1e-9
    cohesive = refined.add_cohesive_forces(X_base, X_extra, u_base, u_extra, f_base, f_extra)
    assert cohesive == pytest.approx(0.5 * law.K_n * delta**2, rel=1e-10)  # area 1 mm^2
    assert f_extra[8:, 2].sum() == pytest.approx(law.K_n * delta, rel=1e-10)
    assert f_extra[4:8, 2].sum() == pytest.approx(-law.K_n * delta, rel=1e-10)
    assert refined.cohesive.damage.max() == 0.0
