"""One rule table: the analysis tools integrate every (sub)element as the structure does.

``comparison.element_forces`` (behind ``comparison.interface_tractions``) recomputes element
forces outside the structure's force loop. With integration rules or kinematics of its own it
drifts from ``Structure.internal_force``: the copy it once had packed one-ply subelements with
``points_per_ply`` points where the structure's ``RuleTable`` gives them two (with one point per
ply: element forces 15 % off, the interface shear of a refined [0/90/0] 8 % off at mid-span
though its displacements equal LW's), and it used small strain on finite-kinematics structures
(issue 14). Checked here:

- all elements' forces, less the cohesive forces, moved by the border constraints as the
  structure moves them, are the structure's internal force to 1e-10 (relative to its largest
  entry): for a chain of refinement states (none, one cell, adjacent cells, weak and strong
  mixed, every cell at every interface) x points_per_ply 1 and 2, small and finite kinematics
  (finite: a state turned through 60 degrees, where small strain is far off), layerwise models
  of one- and several-ply layers with and without cohesive elements;
- a [0/90/0] cantilever refined at both interfaces from the start (one or two points per ply;
  its one-ply subelements have two either way) has LW's static solution and LW's interface
  tractions to 1e-8;
- what the tools cannot reproduce is refused with a clear error: element forces with ply
  damage, a probed stiffness (linear static solution) with finite kinematics.

Small meshes (3 x 2 cells of four plies, a 6-cell beam of three): a few seconds warm.
Units: N, mm, s, tonne (stress MPa).
"""

from __future__ import annotations

import copy
import math

import numpy as np
import pytest
from fenics_adaptive.meshes.beam import layered_mesh
from helpers import COHESIVE_LAW, PROTOTYPE_PLY, prototype_material
from mpi4py import MPI

from fenics_adaptive.analysis import comparison as cmp
from fenics_adaptive.materials.laminate import Laminate
from fenics_adaptive.model.assembly import SubelementSet, add_cohesive_forces, add_subelement_forces
from fenics_adaptive.model.border import transfer_forces
from fenics_adaptive.model.forms import build_model
from fenics_adaptive.model.loading import resolve
from fenics_adaptive.model.structure import Structure
from fenics_adaptive.settings.config import parse_config
from fenics_adaptive.settings.kinds import InterfaceState
from fenics_adaptive.simulation import build_structure

pytestmark = pytest.mark.skipif(MPI.COMM_WORLD.size > 1, reason="the comparison is serial")

WEAK, STRONG = InterfaceState.WEAK, InterfaceState.STRONG
# a general small strain (1e-3) for the states below
STRAIN = np.array([[1.0, 0.3, 0.2], [0.3, -0.5, 0.4], [0.2, 0.4, 0.7]]) * 1e-3


def strip(kind: str = "adaptive", points_per_ply: int = 1, kinematics: str = "small") -> dict:
    """A 6 x 3 mm strip of four unequal-angle 0.25 mm plies in 3 x 2 cells, clamped at x = 0;
    adaptive: interfaces 1 and 3 may refine, 2 may delaminate (cohesive)."""
    data = {
        "model": {"kind": kind, "points_per_ply": points_per_ply, "kinematics": kinematics},
        "mesh": {"length": 6.0, "width": 3.0, "nx": 3, "ny": 2},
        "materials": {"prototype": dict(PROTOTYPE_PLY)},
        "laminate": {"material": "prototype", "ply_thickness": 0.25, "angles": [0, 45, 90, -30]},
        "interfaces": {"refine": [1, 3], "delaminate": [2]},
        "cohesive": dict(COHESIVE_LAW),
        "clamp": [{"face": "x0"}],
        "solver": {"end_time": 1.0e-6},
        "output": {
            "interval": 1.0e-6,
            "displacement_face": "x1",
            "reaction_face": "x0",
            "component": "z",
        },
    }
    if kind == "layerwise":
        data["interfaces"] = {}
        data.pop("cohesive")
    return data


def rotation(axis, angle_deg: float) -> np.ndarray:
    axis = np.asarray(axis, float) / np.linalg.norm(axis)
    K = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    a = math.radians(angle_deg)
    return np.eye(3) + math.sin(a) * K + (1 - math.cos(a)) * K @ K


def deform(structure: Structure, R: np.ndarray, noise: float = 2e-5, seed: int = 3) -> None:
    """u on every base and extra node: a small strain and a little noise (mm; the default opens
    the interfaces up to about 5e-5 mm, below the cohesive onset), the whole then turned
    rigidly by R; the border's constrained extra nodes put back on their masters."""
    rng = np.random.default_rng(seed)
    for X, u in (
        (structure.X_base, structure.base.u.x.array.reshape(-1, 3)),
        (
            structure.extra.vectors["X"].array.reshape(-1, 3),
            structure.extra.vectors["u"].array.reshape(-1, 3),
        ),
    ):
        x = X + X @ STRAIN.T + rng.normal(scale=noise, size=X.shape)
        u[:] = x @ R.T - X
    structure.follow_border()


def internal_force(structure: Structure) -> np.ndarray:
    """The structure's own f_int (n_base + n_extra, 3), N."""
    structure.internal_force()
    return np.concatenate([structure.f_base.array, structure.f_extra.array]).reshape(-1, 3)


def force_of_the_analysis_tools(structure: Structure) -> np.ndarray:
    """The same force from ``comparison.element_forces`` of all elements, less the cohesive
    elements' forces, the border's constrained DOFs handed to their masters (serial: no
    reverse scatter to do)."""
    nodes, _, _ = structure.elements()
    f = cmp.element_forces(structure, np.ones(len(nodes), dtype=bool))
    f_base, f_extra = f[: structure.n_base], f[structure.n_base :]
    X_extra = structure.extra.vectors["X"].array.reshape(-1, 3)
    u_base = structure.base.u.x.array.reshape(-1, 3)
    u_extra = structure.extra.vectors["u"].array.reshape(-1, 3)
    add_cohesive_forces(
        structure.cohesive, structure.X_base, X_extra, u_base, u_extra, f_base, f_extra
    )
    border = structure.border
    if len(border):
        transfer_forces(
            border.dofs,
            border.masters,
            border.weights,
            3 * structure.n_base,
            f_base.reshape(-1),
            f_extra.reshape(-1),
        )
    return f


def assert_forces_agree(structure: Structure, what: str) -> float:
    """The analysis tools' force equals the structure's to 1e-10; returns the largest entry (N)."""
    expected = internal_force(structure)
    scale = np.abs(expected).max()
    difference = np.abs(force_of_the_analysis_tools(structure) - expected).max()
    assert difference <= 1e-10 * scale, f"{what}: {difference / scale:.3e} of the largest force"
    assert np.all(structure.cohesive.damage == 0.0), what  # the cohesive elements stayed elastic
    return scale


def assert_form_agrees(structure: Structure, what: str) -> None:
    """The structure's solids (every cell through the batched kernel, the rule table's rules)
    against the base model's UFL form over the same cells (a structure none of whose cells is
    refined), force and strain energy to 1e-10: the two independent paths a static solve and a
    step take."""
    solid = next(c for c in structure.internal_forces.contributors if c.name == "solid")
    f_base = np.zeros_like(structure.base.u.x.array)
    f_extra = np.zeros_like(structure.extra.vectors["u"].array)
    solid.add_force(0.0, f_base, f_extra)
    f_form = np.zeros_like(f_base)
    structure.base.add_internal_force(f_form)
    scale = np.abs(f_form).max()
    difference = np.abs(f_base - f_form).max()
    assert difference <= 1e-10 * scale, f"{what}: {difference / scale:.3e} of the largest force"
    energy = structure.base.local_strain_energy()
    assert solid.energy() == pytest.approx(energy, rel=1e-10), what


def refinement_chain(structure: Structure):
    """(name, requests) of refinement states, each adding to the one before: none; one cell;
    it and its neighbour along x; weak and strong mixed over three cells; every cell at every
    interface (one subelement per ply everywhere, a cohesive element in each cell)."""
    centre = structure.cell_vertices().mean(axis=1)
    order = np.lexsort((centre[:, 0], centre[:, 1]))  # row y = 0.75 first, along x
    a, b, c = (int(k) for k in order[:3])  # three adjacent cells along x
    yield "none", []
    yield "one cell", [(a, 1, WEAK)]
    yield "adjacent cells", [(a, 3, WEAK), (b, 1, WEAK)]
    yield "mixed", [(a, 2, STRONG), (b, 2, STRONG), (c, 3, WEAK)]
    every = range(structure.base.n_owned_cells)
    yield "all cells", [(k, i, s) for k in every for i, s in ((1, WEAK), (2, STRONG), (3, WEAK))]


@pytest.mark.parametrize("kinematics", ["small", "finite"])
@pytest.mark.parametrize("points_per_ply", [1, 2])
def test_element_forces_sum_to_the_internal_force_in_every_refinement_state(
    points_per_ply, kinematics
):
    structure = build_structure(parse_config(strip("adaptive", points_per_ply, kinematics)))
    assert structure.base.kinematics == kinematics
    # small strain: a small motion; finite: the same turned through 60 degrees
    R = rotation((0.3, -1.0, 2.0), 60.0) if kinematics == "finite" else np.eye(3)
    one_ply_subelements = 0
    for name, requests in refinement_chain(structure):
        structure.refine(requests)
        deform(structure, R)
        scale = assert_forces_agree(structure, name)
        _, _, plies = structure.elements()
        one_ply_subelements = max(one_ply_subelements, int((plies[:, 1] - plies[:, 0] == 1).sum()))
        if name == "one cell":
            assert len(structure.border)  # its neighbours constrain the new extra nodes
    assert one_ply_subelements == 4 * structure.base.n_owned_cells
    assert len(structure.cohesive) == structure.base.n_owned_cells
    if kinematics == "finite":
        # the check has teeth: small strain on the turned state is far off
        structure.base.set_kinematics("small")
        assert np.abs(internal_force(structure)).max() > 10.0 * scale


@pytest.mark.parametrize(
    ("layers", "points_per_ply", "kinematics", "delaminate"),
    [
        ([2, 2], 1, "small", []),  # several-ply layers, one point per ply
        ([1, 1, 1, 1], 2, "small", [2]),  # one-ply layers, a cohesive layer boundary
        ([1, 3], 2, "finite", [1]),
    ],
)
def test_element_forces_of_layerwise_models_sum_to_the_internal_force(
    layers, points_per_ply, kinematics, delaminate
):
    data = strip("layerwise", points_per_ply, kinematics)
    data["mesh"]["layers"] = layers
    if delaminate:
        data["interfaces"] = {"delaminate": delaminate}
        data["cohesive"] = dict(COHESIVE_LAW)
    structure = build_structure(parse_config(data))
    assert len(structure.cohesive) == (structure.base.n_owned_cells // len(layers)) * len(
        delaminate
    )
    R = rotation((1.0, 2.0, 0.5), 60.0) if kinematics == "finite" else np.eye(3)
    deform(structure, R)
    assert_forces_agree(structure, f"layerwise {layers}")
    assert_form_agrees(structure, f"layerwise {layers}")


def test_one_ply_layers_with_three_points_per_ply_keep_them_in_both_paths():
    """The Python API takes any points_per_ply (a config 1 or 2): with 3, the UFL form puts
    three points in a one-ply layer, and the table must too (at least two, not exactly two).
    Finite kinematics and strains of a few %, where two points and three differ by 1e-5."""
    laminate = Laminate.from_angles(prototype_material(), [0, 90], 0.25)
    layers = [Laminate(laminate.plies[:1]), Laminate(laminate.plies[1:])]
    beam = layered_mesh(MPI.COMM_WORLD, 2.0, 1.0, 2, 1, [0.25, 0.25])
    model = build_model(beam, layers, points_per_ply=3, kinematics="finite")
    structure = Structure(model, resolve(model, [], []))
    deform(structure, rotation((1.0, -2.0, 0.5), 60.0), noise=1e-2)
    assert_forces_agree(structure, "one-ply layers, 3 points per ply")
    assert_form_agrees(structure, "one-ply layers, 3 points per ply")


@pytest.mark.parametrize("points_per_ply", [1, 2])
@pytest.mark.parametrize("kinematics", ["small", "finite"])
def test_unrefined_cells_through_the_kernel_equal_the_ufl_form(points_per_ply, kinematics):
    """An ESL strip (four unequal-angle plies, shear correction and enhanced thickness strain on,
    pre-integrated or ply by ply): its cells through the batched kernel equal the UFL form."""
    structure = build_structure(parse_config(strip("adaptive", points_per_ply, kinematics)))
    R = rotation((1.0, 2.0, 0.5), 60.0) if kinematics == "finite" else np.eye(3)
    deform(structure, R, noise=1e-3)
    assert_form_agrees(structure, f"ESL, {points_per_ply} point(s) per ply, {kinematics}")


# --- a refined [0/90/0] is LW, tractions included ---------------------------------------------
def cantilever(kind: str, points_per_ply: int) -> dict:
    """[0/90/0] of 0.25 mm plies, 6 x 1 mm in 6 x 1 cells, clamped at x = 0, 1 N down on the
    top face; adaptive: refined weakly at both interfaces from the start."""
    data = strip(kind, points_per_ply)
    data["mesh"].update(length=6.0, width=1.0, nx=6, ny=1)
    data["laminate"]["angles"] = [0, 90, 0]
    data["load"] = [{"face": "top", "force": [0.0, 0.0, -1.0], "curve": [[0.0, 1.0]]}]
    data["interfaces"] = {"refine": [1, 2], "initial": "weak"} if kind == "adaptive" else {}
    data.pop("cohesive", None)
    return data


@pytest.fixture(scope="module")
def layerwise_solution():
    structure = build_structure(parse_config(cantilever("layerwise", 2)))
    cmp.solve_linear_static(structure)
    return cmp.tip_deflection(structure), cmp.interface_tractions(structure)


@pytest.mark.parametrize("points_per_ply", [1, 2])
def test_refined_cross_ply_has_the_interface_tractions_of_lw(layerwise_solution, points_per_ply):
    """LW's one-ply cells have two points through their thickness (one-ply layers need
    points_per_ply = 2); the refined model's one-ply subelements have two whatever
    points_per_ply is: the same discretisation, so the same solution and tractions."""
    tip_lw, tractions_lw = layerwise_solution
    structure = build_structure(parse_config(cantilever("adaptive", points_per_ply)))
    result = cmp.solve_linear_static(structure)
    assert result.residual < 1e-9
    assert cmp.tip_deflection(structure) == pytest.approx(tip_lw, rel=1e-9)
    tractions = cmp.interface_tractions(structure)
    assert sorted(tractions) == sorted(tractions_lw) == [1, 2]
    for interface, (x_lw, values_lw) in tractions_lw.items():
        x, values = tractions[interface]
        np.testing.assert_allclose(x, x_lw, rtol=0.0, atol=1e-12)
        peak = np.abs(values_lw[:, :2]).max(axis=0)  # sigma_zz, tau_xz
        assert peak.min() > 0.0
        for k, name in enumerate(cmp.OUT_OF_PLANE):
            error = np.abs(values[:, k] - values_lw[:, k]).max() / peak[min(k, 1)]
            assert error < 1e-8, (interface, name, error)


# --- what the tools refuse ---------------------------------------------------------------------
def test_element_forces_refuse_ply_damage():
    data = strip("adaptive")
    data["model"]["ply_damage"] = True
    data["materials"]["prototype"]["failure"] = {
        "XT": 2000.0,
        "XC": 1200.0,
        "YT": 60.0,
        "YC": 200.0,
        "S12": 90.0,
        "G2c": 1.0,
        "G6c": 3.0,
    }
    structure = build_structure(parse_config(data))
    nodes, _, _ = structure.elements()
    with pytest.raises(ValueError, match="ply damage"):
        cmp.element_forces(structure, np.ones(len(nodes), dtype=bool))
    with pytest.raises(ValueError, match="ply damage"):
        cmp.interface_tractions(structure)


def test_linear_static_tools_refuse_finite_kinematics():
    data = copy.deepcopy(strip("layerwise", 2, "finite"))
    data["mesh"]["layers"] = [2, 2]
    structure = build_structure(parse_config(data))
    with pytest.raises(ValueError, match="finite kinematics"):
        cmp.probe_stiffness(structure)
    with pytest.raises(ValueError, match="finite kinematics"):
        cmp.solve_linear_static(structure)


def test_a_refined_structures_form_takes_its_unrefined_cells_when_next_used():
    """A refinement hands the base model's form its new cells lazily (the step does not use
    the form): the first use after it integrates exactly the cells left unrefined, whose
    energy the kernel's whole-cell elements give too."""
    structure = build_structure(parse_config(strip("adaptive", 2, "small")))
    for _, requests in list(refinement_chain(structure))[:4]:  # none .. mixed
        structure.refine(requests)
    deform(structure, np.eye(3), noise=1e-3)
    assert structure.base._cells_pending
    unrefined = structure.refinement.unrefined_cells()
    assert 0 < len(unrefined) < structure.base.n_owned_cells
    solids = next(c for c in structure.internal_forces.contributors if c.name == "solid").solids
    whole_cells = SubelementSet(
        solids.nodes[: len(unrefined)], solids.rule_of_element[: len(unrefined)], solids.rules
    )
    f_base = np.zeros_like(structure.base.u.x.array)
    f_extra = np.zeros_like(structure.extra.vectors["u"].array)
    args = structure.node_arrays.kernel_arguments(f_base, f_extra)
    energy = add_subelement_forces(whole_cells, *args, False)
    assert structure.base.local_strain_energy() == pytest.approx(energy, rel=1e-10)
    assert not structure.base._cells_pending
