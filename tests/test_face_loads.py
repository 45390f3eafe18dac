"""Face loads on refined cells (``ResolvedLoads.refine``): a load on a side face of refined cells
reaches every node of the face, the extra nodes included, work-equivalently (the subelement
faces' shape functions), and border extra nodes hand their share to their masters:

- the nodal loads on a refined face add up to traction x area exactly;
- their virtual work equals the integral of traction . u over the face for a field the refined
  face represents exactly (affine everywhere; piecewise linear through the thickness with kinks
  at the ply interfaces where every cell is refined);
- a cantilever refined from the start under a tip (or side) load deflects as the layerwise
  model to round-off (with the load on the base nodes only: +1.2 % at span/thickness 5);
- refined during an explicit run, the load moves: the applied force does not jump;
- the tie forces of a strong refinement on a loaded face take the load into account;
- a caller that knows only the base DOFs is told so instead of losing the extra nodes' share.

Units: N, mm, s, tonne.
"""

import itertools

import numpy as np
import pytest
from helpers import COHESIVE_LAW, PROTOTYPE_PLY
from mpi4py import MPI

from fenics_adaptive.adaptivity import enrichment as enr
from fenics_adaptive.analysis import comparison as cmp
from fenics_adaptive.settings.config import parse_config
from fenics_adaptive.settings.kinds import InterfaceState
from fenics_adaptive.simulation import RefinementHook, build_structure
from fenics_adaptive.solver import explicit
from fenics_adaptive.solver.static import solve_static

pytestmark = pytest.mark.skipif(MPI.COMM_WORLD.size > 1, reason="serial sums over all nodes")

FORCE = (1.5, -2.0, -10.0)  # N, a load with every component


def cantilever(
    kind: str,
    face: str = "x1",
    angles=(0, 90, 90, 0),
    mesh: dict | None = None,
    force=FORCE,
    initial: str = "weak",
) -> dict:
    """A laminated cantilever (clamped at x0) under a uniform load on ``face``; adaptive ones
    refined at every interface from the start (``initial``), layerwise one cell per ply."""
    n = len(angles)
    data = {
        "model": {"kind": kind, "points_per_ply": 2},
        "mesh": {"length": 4.0, "width": 2.0, "nx": 4, "ny": 2} | (mesh or {}),
        "materials": {"prototype": dict(PROTOTYPE_PLY)},
        "laminate": {"material": "prototype", "ply_thickness": 0.25, "angles": list(angles)},
        "clamp": [{"face": "x0"}],
        "load": [{"face": face, "force": list(force), "curve": [[0.0, 1.0]]}],
        "solver": {"end_time": 1.0e-6},
        "output": {
            "interval": 1.0e-6,
            "displacement_face": "x1",
            "reaction_face": "x0",
            "component": "z",
        },
    }
    if kind == "adaptive":
        data["interfaces"] = {"refine": list(range(1, n)), "initial": initial}
    if kind == "layerwise":
        data["mesh"]["layers"] = [1] * n
    return data


def partly_refined(face: str):
    """A [0/90/90/0] cantilever, 4 x 2 cells, refined at every interface in the cells with
    y < 1 mm and at interface 2 alone in the tip cell with y > 1 mm (a subelement of two plies):
    refined cells meet less refined ones, whose shared columns' extra nodes are border nodes
    bound to base and extra masters."""
    structure = build_structure(parse_config(cantilever("adaptive", face, initial="none")))
    centre = structure.cell_vertices().mean(axis=1)
    low = np.flatnonzero(centre[:, 1] < 1.0)
    requests = [(int(c), i, InterfaceState.WEAK) for c in low for i in (1, 2, 3)]
    high = np.flatnonzero((centre[:, 1] > 1.0) & (centre[:, 0] > 3.0))
    requests += [(int(high[0]), 2, InterfaceState.WEAK)]
    assert structure.refine(requests)
    assert len(structure.border) > 0
    return structure


def nodal_loads(structure) -> tuple[np.ndarray, np.ndarray]:
    """(base, extra) nodal loads (n, 3) N at t = 0 (serial: every local DOF is owned)."""
    f_base = np.zeros(len(structure.base.u.x.array))
    f_extra = np.zeros(len(structure.extra.vectors["u"].array))
    structure.loads.external_force(0.0, f_base, f_extra)
    return f_base.reshape(-1, 3), f_extra.reshape(-1, 3)


def virtual_work(structure, u_of_X) -> float:
    """Work (mJ) of the nodal loads on the field u_of_X (n, 3) -> (n, 3) mm given at every
    node (the border nodes then follow their masters, as in a run)."""
    structure.base.u.x.array[:] = u_of_X(structure.X_base).ravel()
    X_extra = structure.extra.vectors["X"].array.reshape(-1, 3)
    structure.extra.vectors["u"].array[:] = u_of_X(X_extra).ravel()
    structure.follow_border()
    f_base, f_extra = nodal_loads(structure)
    u_base = structure.base.u.x.array.reshape(-1, 3)
    u_extra = structure.extra.vectors["u"].array.reshape(-1, 3)
    return float(np.sum(f_base * u_base) + np.sum(f_extra * u_extra))


def face_box(structure, face: str) -> tuple[np.ndarray, np.ndarray]:
    """(lower, upper) corners (3,) mm of a face of the box-shaped beam."""
    low, high = structure.X_base.min(axis=0), structure.X_base.max(axis=0)
    axis, side = {"x0": (0, 0), "x1": (0, 1), "y0": (1, 0), "y1": (1, 1), "top": (2, 1)}[face]
    low, high = low.copy(), high.copy()
    if side:
        low[axis] = high[axis]
    else:
        high[axis] = low[axis]
    return low, high


@pytest.mark.parametrize("face", ["x1", "y0", "top"])
def test_refined_face_carries_traction_times_area_and_its_extra_nodes_a_share(face):
    structure = partly_refined(face)
    f_base, f_extra = nodal_loads(structure)
    total = f_base.sum(axis=0) + f_extra.sum(axis=0)
    assert np.abs(total - FORCE).max() <= 1e-12 * np.abs(FORCE).max()
    assert structure.loads.has_extra == (face != "top")
    if face == "top":  # the refined cells' top subelements have the base nodes: nothing moves
        assert not f_extra.any()
        return
    # every free extra node on the face carries load, the border ones none (their masters do)
    n_if = structure.interface_state.shape[1]
    low, high = face_box(structure, face)
    X = structure.extra.vectors["X"].array.reshape(-1, 3)
    on_face = np.all((X >= low - 1e-9) & (X <= high + 1e-9), axis=1)
    border_nodes = np.unique((structure.border.dofs - 3 * structure.n_base) // 3)
    free = np.setdiff1d(np.flatnonzero(on_face), border_nodes)
    assert len(free)
    if face == "x1":  # the column at y = 1 mm: interfaces 1 and 3 bound, 2 free
        assert len(np.intersect1d(np.flatnonzero(on_face), border_nodes)) == 2
    assert np.all(np.abs(f_extra[free, 2]) > 0.0)
    assert not f_extra[border_nodes].any()
    assert not f_extra[~on_face].any()
    # the history's resultant of the extra block is the loads' own sum
    assert np.allclose(structure.loads.extra_resultant(0.0), f_extra.sum(axis=0), atol=1e-14)
    assert {enr.key_parts(structure.extra.owned_keys[n], n_if)[1] for n in free} == {1, 2, 3}


@pytest.mark.parametrize("face", ["x1", "y0", "top"])
def test_nodal_loads_are_work_equivalent_for_an_affine_field(face):
    """W = sum f . u = t . (a A + B int X dA), int X dA = A x the face's centroid."""
    structure = partly_refined(face)
    rng = np.random.default_rng(5)
    a, B = rng.standard_normal(3), rng.standard_normal((3, 3))
    low, high = face_box(structure, face)
    traction = structure.loads.tractions[0].vector
    sides = high - low
    area = np.prod(sides[sides > 0])
    expected = traction @ (a * area + B @ (0.5 * (low + high)) * area)
    work = virtual_work(structure, lambda X: a + X @ B.T)
    assert work == pytest.approx(expected, rel=1e-12)


@pytest.mark.parametrize("face", ["x1", "y1"])
def test_nodal_loads_are_work_equivalent_for_a_field_kinked_at_the_interfaces(face):
    """Every cell refined: the face represents any field piecewise linear through the
    thickness; its integral is the trapezoidal sum over the plies. The base nodes alone (the
    load as it was) would give the work of the chord between the outer faces instead."""
    structure = build_structure(parse_config(cantilever("adaptive", face)))
    z = structure.laminate.ply_fractions * structure.laminate.thickness
    z = z + structure.X_base[:, 2].min()
    rng = np.random.default_rng(7)
    g, v = rng.standard_normal(len(z)), rng.standard_normal(3)
    low, high = face_box(structure, face)
    length_along = np.max((high - low)[:2])
    traction = structure.loads.tractions[0].vector
    integral = length_along * np.sum(np.diff(z) * 0.5 * (g[1:] + g[:-1]))  # of g over the face
    work = virtual_work(structure, lambda X: np.interp(X[:, 2], z, g)[:, None] * v)
    assert work == pytest.approx(traction @ v * integral, rel=1e-12)
    chord = length_along * (z[-1] - z[0]) * 0.5 * (g[0] + g[-1])
    assert abs(integral - chord) > 0.1 * abs(integral)  # the test tells the two apart


@pytest.mark.slow
@pytest.mark.parametrize("face", ["x1", "y1", "top"])
def test_refined_cantilever_under_a_face_load_deflects_as_the_layerwise_model(face):
    """[0/90]2s, span/thickness 5: the fully refined element equals LW to round-off also when
    the load is on a side face (the extra nodes at the ply interfaces carry their share)."""
    mesh = {"length": 10.0, "nx": 10, "ny": 2}
    tips = {}
    for kind in ("adaptive", "layerwise"):
        data = cantilever(kind, face, [0, 90, 0, 90, 90, 0, 90, 0], mesh, force=(0, 0, -10.0))
        structure = build_structure(parse_config(data))
        result = cmp.solve_linear_static(structure)
        assert result.residual < 1e-9
        assert result.applied_force == pytest.approx([0.0, 0.0, -10.0], abs=1e-12)
        tips[kind] = cmp.tip_deflection(structure)
    assert tips["adaptive"] == pytest.approx(tips["layerwise"], rel=1e-10)


@pytest.mark.slow
def test_refinement_during_a_run_moves_the_load_without_a_jump():
    """A tip load ramped to 10 N by 2 us, then held; the cells at the tip refine at 4 us: the
    applied force stays the load (base nodes before, base and extra nodes after)."""
    data = cantilever("adaptive", "x1", mesh={"length": 8.0, "nx": 8, "ny": 1}, initial="none")
    data["load"][0]["curve"] = [[0.0, 0.0], [2.0e-6, 1.0]]
    data["refinement"] = [
        {"time": 4.0e-6, "interfaces": [1, 2, 3], "kind": "weak", "x_min": 6.0},
    ]
    data["solver"] = {"end_time": 8.0e-6}
    data["output"]["interval"] = 2.0e-7
    config = parse_config(data)
    structure = build_structure(config)
    stats = explicit.run(structure, config.solver, config.probe, refiner=RefinementHook(config))
    assert stats.refinements == 1 and structure.loads.has_extra
    history = stats.history
    times = np.array([row.time for row in history])
    applied = np.array([row.applied_force for row in history])
    amplitude = config.loads[0].amplitude
    expected = np.array([FORCE[2] * amplitude(t) for t in times])
    assert np.abs(applied - expected).max() <= 1e-12 * abs(FORCE[2])
    assert times.min() < 4.0e-6 < times.max()
    # and the extra nodes do carry most of the tip load now (3 of 4 ply levels inside)
    share = structure.loads.extra_resultant(times[-1])[2] / FORCE[2]
    assert share == pytest.approx(0.75, rel=1e-12)
    row = history[-1]
    # the step falls 4-fold at the refinement: the energy balance still closes to round-off
    # (the scheme's kinetic energy jump at the new step is booked with the refinement)
    assert max(abs(r.energy_balance) for r in history) < 1e-12 * row.external_work


def test_tie_forces_of_a_strong_refinement_on_a_loaded_face_keep_the_pairs_together():
    """At the moment of a strong refinement both nodes of every new pair get the acceleration
    the continuous interface node had, (f_load - f_int) / m, also where the face load acts on
    them (the tie force takes the net force)."""
    data = cantilever("adaptive", "x1", mesh={"nx": 4, "ny": 1})
    data["interfaces"] = {"refine": [1, 3], "delaminate": [2], "initial": "weak"}
    data["cohesive"] = dict(COHESIVE_LAW)
    # (placed, not equilibrated: the ties have the placed pairs' forces to hold)
    data["stabilisation"] = {"release_window": 1.0e-5, "equilibrate": False}
    structure = build_structure(parse_config(data))
    rng = np.random.default_rng(11)
    for vector in (structure.base.u.x.array, structure.extra.vectors["u"].array):
        vector[:] = 1e-5 * rng.standard_normal(vector.shape)

    def net_force() -> tuple[np.ndarray, np.ndarray]:
        structure.internal_force()
        _, f_load = nodal_loads(structure)
        m = structure.extra_block.mass.reshape(-1, 3)[:, 0]
        return f_load - structure.f_extra.array.reshape(-1, 3), m

    force, mass = net_force()
    n_if = structure.interface_state.shape[1]
    continuous = {
        key: force[structure.extra.index[key]] / mass[structure.extra.index[key]]
        for key in structure.extra.owned_keys
        if enr.key_parts(key, n_if)[1] == 2
    }
    cells = range(structure.base.n_owned_cells)
    assert structure.refine([(c, 2, InterfaceState.STRONG) for c in cells])
    structure.start_stabilisation(0.0)
    force, mass = net_force()
    tie = np.zeros_like(force)
    structure.stabilisation_state.add_tie_forces(0.0, tie.ravel())
    acceleration = (force + tie) / mass[:, None]
    scale = max(np.abs(a).max() for a in continuous.values())
    loaded = 0
    _, f_load = nodal_loads(structure)
    for key, expected in continuous.items():
        a_node, b_node = structure.extra.index[key], structure.extra.index[key + 1]
        assert np.abs(acceleration[a_node] - expected).max() < 1e-9 * scale
        assert np.abs(acceleration[b_node] - expected).max() < 1e-9 * scale
        loaded += bool(f_load[a_node].any() and f_load[b_node].any())
    assert loaded == 2  # the pairs on the loaded face x1 (its two columns)


def test_a_caller_without_the_extra_dofs_is_told_the_loads_reach_extra_nodes():
    refined = build_structure(parse_config(cantilever("adaptive", "x1")))
    out = np.zeros(len(refined.base.u.x.array))
    with pytest.raises(ValueError, match="out_extra"):
        refined.loads.external_force(0.0, out)
    # the static solver of the base model alone (UFL cells) would lose that share of the load
    config = parse_config(cantilever("adaptive", "x1"))
    with pytest.raises(ValueError, match="out_extra"):
        solve_static(refined.base, config.motions, refined.loads, 0.0)
    # loads on the top face stay on the base nodes: nothing to miss
    top = build_structure(parse_config(cantilever("adaptive", "top")))
    top.loads.external_force(0.0, out)
    assert out.reshape(-1, 3).sum(axis=0) == pytest.approx(FORCE, rel=1e-12)


# --- loads on part of a face, pressures and their distribution along x -------------------------


def loaded(face: str, load: dict, kind: str = "adaptive", initial: str = "weak"):
    """The 4 x 2 mm [0/90/90/0] cantilever of ``cantilever`` under the [[load]] ``load`` on
    ``face`` (a total force or a pressure)."""
    data = cantilever(kind, face, initial=initial)
    data["load"] = [{"face": face, "curve": [[0.0, 1.0]]} | load]
    return build_structure(parse_config(data))


def gauss_integral(f, low: float, high: float, breaks=(), points: int = 5) -> float:
    """The integral of f over [low, high] by Gauss-Legendre on each piece between the breaks
    (exact for polynomials of degree < 2 points on each piece)."""
    edges = np.unique(np.clip([low, *breaks, high], low, high))
    s, w = np.polynomial.legendre.leggauss(points)
    total = 0.0
    for a, b in itertools.pairwise(edges):
        x = 0.5 * (a + b) + 0.5 * (b - a) * s
        total += 0.5 * (b - a) * np.sum(w * f(x))
    return total


PRESSURE = 2.5  # MPa
DISTRIBUTION = [[0.0, 0.0], [1.5, 1.0], [4.0, 0.5]]  # a kink inside a cell too


def factor(x):
    return np.interp(x, *np.array(DISTRIBUTION).T)


@pytest.mark.parametrize("face", ["y0", "top"])
def test_a_distributed_pressure_is_work_equivalent_on_refined_and_unrefined_faces(face):
    """A pressure p f(x) on y0 (outward normal -y: the traction is p f(x) e_y) or on top
    (traction -p f(x) e_z), refined cells included: the nodal loads do the work of the exact
    integral of t . u over the face for an affine u. f has a kink at x = 1.5 mm, inside a
    cell, so the 2 x 2 Gauss integration is not exact there: the test allows its error."""
    structure = loaded(face, {"pressure": PRESSURE, "distribution": DISTRIBUTION})
    rng = np.random.default_rng(3)
    a, B = rng.standard_normal(3), rng.standard_normal((3, 3))
    low, high = face_box(structure, face)
    normal = {"y0": np.array([0.0, -1.0, 0.0]), "top": np.array([0.0, 0.0, 1.0])}[face]
    # the face spans x and one of y (top) or z (y0); the field is affine in that other
    # coordinate too, so its mean over it is the field at the mid value
    mid = 0.5 * (low + high)
    across = np.max(np.delete(high - low, [0, int(np.argmax(np.abs(normal)))]))

    def integrand(x):
        X = np.column_stack([x, np.full_like(x, mid[1]), np.full_like(x, mid[2])])
        return -PRESSURE * factor(x) * ((a + X @ B.T) @ normal)

    exact = across * gauss_integral(integrand, low[0], high[0], breaks=[1.5])
    work = virtual_work(structure, lambda X: a + X @ B.T)
    assert work == pytest.approx(exact, rel=2e-2)
    # with the kink on a cell boundary the integration is exact
    kinked_at_2 = [[0.0, 0.0], [2.0, 1.0], [4.0, 0.5]]
    structure = loaded(face, {"pressure": PRESSURE, "distribution": kinked_at_2})
    f2 = lambda x: np.interp(x, *np.array(kinked_at_2).T)  # noqa: E731

    def integrand2(x):
        X = np.column_stack([x, np.full_like(x, mid[1]), np.full_like(x, mid[2])])
        return -PRESSURE * f2(x) * ((a + X @ B.T) @ normal)

    exact = across * gauss_integral(integrand2, low[0], high[0], breaks=[2.0])
    assert virtual_work(structure, lambda X: a + X @ B.T) == pytest.approx(exact, rel=1e-12)


def test_a_uniform_pressure_on_top_is_the_equal_downward_force():
    """Two independent paths: pressure p on the top face, and the total force (0, 0, -p A)."""
    area = 4.0 * 2.0
    by_pressure = nodal_loads(loaded("top", {"pressure": PRESSURE}))
    by_force = nodal_loads(loaded("top", {"force": [0.0, 0.0, -PRESSURE * area]}))
    for a, b in zip(by_pressure, by_force, strict=True):
        np.testing.assert_allclose(a, b, rtol=0, atol=1e-13 * PRESSURE * area)


def test_a_load_on_part_of_a_face_reaches_only_the_facets_in_its_region():
    """A force on the top face's facets with centroid in x in [2, 3], y in [0, 1] mm: one
    facet (2 < x < 3, 0 < y < 1), its total the force, its moment the force at the facet's
    centre; the interlaminar estimate sees its traction on that cell only."""
    force = np.array([0.5, 0.0, -8.0])
    load = {"force": list(force), "x_min": 2.0, "x_max": 3.0, "y_min": 0.0, "y_max": 1.0}
    structure = loaded("top", load, initial="none")
    f_base, f_extra = nodal_loads(structure)
    assert not f_extra.any()
    carrying = np.flatnonzero(np.abs(f_base).sum(axis=1) > 0)
    X = structure.X_base[carrying]
    assert len(carrying) == 4
    assert sorted(np.round(X[:, 0], 9)) == [2.0, 2.0, 3.0, 3.0]
    assert sorted(np.round(X[:, 1], 9)) == [0.0, 0.0, 1.0, 1.0]
    np.testing.assert_allclose(f_base.sum(axis=0), force, rtol=1e-12)
    moment = np.cross(structure.X_base, f_base).sum(axis=0)
    centre = np.array([2.5, 0.5, structure.X_base[:, 2].max()])
    np.testing.assert_allclose(moment, np.cross(centre, force), rtol=1e-9, atol=1e-9)
    on_cells = structure.loads.cell_face_tractions(0.0, structure.base.n_owned_cells)
    cells = np.flatnonzero(np.abs(on_cells).sum(axis=(1, 2)) > 0)
    assert len(cells) == 1
    np.testing.assert_allclose(on_cells[cells[0], 1], force / 1.0, rtol=1e-9)  # 1 mm^2
    assert not on_cells[:, 0].any()


def test_the_estimate_sees_a_distributed_pressure_cell_by_cell():
    structure = loaded("top", {"pressure": PRESSURE, "distribution": [[0.0, 1.0], [4.0, 3.0]]})
    on_cells = structure.loads.cell_face_tractions(0.0, structure.base.n_owned_cells)
    x = structure.cell_vertices().mean(axis=1)[:, 0]
    expected = -PRESSURE * (1.0 + 0.5 * x)  # linear: the facet's mean is its centre's value
    np.testing.assert_allclose(on_cells[:, 1, 2], expected, rtol=1e-12)
    np.testing.assert_allclose(on_cells[:, 1, :2], 0.0, atol=1e-14)


@pytest.mark.parametrize(
    ("load", "key", "words"),
    [
        ({"force": [0, 0, 1], "pressure": 1.0}, "load[0].force", "exactly one of"),
        ({}, "load[0].force", "exactly one of"),
        (
            {"force": [0, 0, 1], "distribution": [[0, 1], [1, 2]]},
            "load[0].distribution",
            "pressure",
        ),
        (
            {"pressure": 1.0, "distribution": [[1, 1], [1, 2]]},
            "load[0].distribution[1][0]",
            "increase",
        ),
        ({"pressure": 1.0, "distribution": [[0, 1], [1]]}, "load[0].distribution[1]", "pair"),
        ({"pressure": 1.0, "x_min": 3.0, "x_max": 2.0}, "load[0].x_max", ">= x_min"),
    ],
)
def test_the_config_refuses_a_load_it_cannot_apply(load, key, words):
    from fenics_adaptive.errors import InputError

    data = cantilever("adaptive", "top")
    data["load"] = [{"face": "top", "curve": [[0.0, 1.0]]} | load]
    with pytest.raises(InputError) as error:
        parse_config(data)
    assert error.value.key == key and words in str(error.value), str(error.value)


def test_a_region_without_facets_is_refused_naming_the_load():
    from fenics_adaptive.errors import InputError

    with pytest.raises(InputError, match="no facet of face 'top'") as error:
        loaded("top", {"pressure": 1.0, "x_min": 1.1, "x_max": 1.4})
    assert error.value.key == "load[0].face"
