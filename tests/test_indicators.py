"""Refinement indicators: recovered out-of-plane stresses, the interface initiation indicator,
manual triggers and spreading."""

import tomllib
from pathlib import Path

import numpy as np
import pytest
from fenics_adaptive.meshes import esl_mesh
from mpi4py import MPI

from fenics_adaptive.adaptivity import indicators as ind
from fenics_adaptive.adaptivity.events import Reason
from fenics_adaptive.errors import InputError
from fenics_adaptive.materials.laminate import Laminate, PlyMaterial
from fenics_adaptive.model import loading
from fenics_adaptive.model.forms import build_model
from fenics_adaptive.model.structure import Structure
from fenics_adaptive.settings.adaptivity import IndicatorSettings
from fenics_adaptive.settings.config import parse_config
from fenics_adaptive.settings.kinds import InterfaceState
from fenics_adaptive.settings.loads import Amplitude, FaceLoad, clamp
from fenics_adaptive.simulation import RefinementHook, build_structure, probe_displacement
from fenics_adaptive.solver import explicit
from fenics_adaptive.solver.static import solve_static

DATA = Path(__file__).parent / "data"
PLY = PlyMaterial("ply", E1=1e5, E2=1e4, G12=5e3, nu12=0.25, nu23=0.25, rho=1.6e-9)


def loaded_cantilever(angles, force=-1.0):
    """50 x 2 x 2 mm cantilever, tip load, static: the exact transverse shear is known."""
    laminate = Laminate.from_angles(PLY, angles, 0.25)
    beam = esl_mesh(MPI.COMM_WORLD, 50.0, 2.0, 50, 2, laminate.thickness)
    model = build_model(beam, [laminate])
    motions = clamp("x0")
    load = FaceLoad("x1", (0.0, 0.0, force), Amplitude.constant())
    loads = loading.resolve(model, motions, [load])
    solve_static(model, motions, loads, 0.0)
    return Structure(model, loads), laminate


def beam_shear(laminate, shear_force, width):
    """Narrow-beam laminate theory: tau_xz(z) = -V / (b EI) * b * sum E_x,k int z dz, from the
    bottom face, z measured from the mid-plane."""
    EI = laminate.narrow_beam_bending_stiffness(width)
    z = laminate.ply_fractions * laminate.thickness - 0.5 * laminate.thickness
    E_x = [1.0 / np.linalg.inv(p.stiffness())[0, 0] for p in laminate.plies]
    first_moment = np.concatenate(
        [[0.0], np.cumsum([E * (z[k + 1] ** 2 - z[k] ** 2) / 2 for k, E in enumerate(E_x)])]
    )
    return -shear_force / EI * first_moment


@pytest.mark.parametrize("angles", [[0] * 8, [0, 90, 0, 90, 90, 0, 90, 0]])
def test_recovered_transverse_shear_matches_beam_theory(angles):
    structure, laminate = loaded_cantilever(angles)
    recovered = ind.recovered_interface_stresses(structure)
    x = structure.X_base[structure.bottom_local][:, :, 0].mean(axis=1)
    mid_span = (x > 15.0) & (x < 35.0)
    tau = recovered[mid_span, :, 1].mean(axis=0)
    expected = beam_shear(laminate, -1.0, 2.0)
    peak = np.abs(expected).max()
    assert peak == pytest.approx(3 / (2 * 4.0), rel=0.02) or angles != [0] * 8
    assert np.abs(tau - expected).max() < 0.03 * peak
    # each ply of the ESL element carries its share of the laminate's shear flow
    # (``materials.laminate.ply_shear_factors``): beam theory's over the ply
    constitutive = ind.ply_stresses(structure)[mid_span, :, 4].mean(axis=0)
    assert np.abs(constitutive - 0.5 * (expected[1:] + expected[:-1])).max() < 0.04 * peak
    # no peel stress in a tip-loaded cantilever away from its ends
    assert np.abs(recovered[mid_span, :, 0]).max() < 0.02 * peak


def test_interface_indicator_flags_the_most_stressed_interface():
    structure, _ = loaded_cantilever([0] * 8, force=-60.0)  # tau_max = 22.5 MPa
    recovered = ind.recovered_interface_stresses(structure)
    index = ind.interface_initiation(recovered, strength_n=20.0, strength_s=40.0)
    x = structure.X_base[structure.bottom_local][:, :, 0].mean(axis=1)
    inner = (x > 5.0) & (x < 45.0)
    # the mid-plane (interface 4) carries the peak shear: 22.5 / 40
    assert index[inner, 3].mean() == pytest.approx(22.5 / 40.0, rel=0.03)
    assert index[inner].argmax(axis=1).tolist() == [3] * inner.sum()


def tcb(**changes):
    data = tomllib.loads((DATA / "tcb_adaptive.toml").read_text())
    data["interfaces"]["initial"] = "none"
    data.update(changes)
    return data


def test_manual_refinement_by_displacement():
    data = tcb(refinement=[{"displacement": 0.0023, "interfaces": [2, 6], "kind": "strong"}])
    data["solver"]["end_time"] = 2.0e-5
    config = parse_config(data)
    structure = build_structure(config)
    hook = RefinementHook(config)
    at = []

    def refiner(t, s):
        displacement = probe_displacement(s, config.probe)
        changed = hook(t, s)
        if changed:
            at.append(displacement)
        return changed

    stats = explicit.run(structure, config.solver, config.probe, refiner=refiner)
    assert stats.refinements == 1
    assert (structure.interface_state[:, [1, 5]] == InterfaceState.STRONG).all()
    assert (structure.interface_state[:, 3] == InterfaceState.NONE).all()
    # on the first step past 0.0023 mm (the tip moves at most 1000 mm/s x 4e-8 s per step)
    assert 0.0023 <= at[0] < 0.0023 + 1000.0 * 4e-8


def test_spread_reaches_the_neighbours_once_per_ring():
    structure = build_structure(parse_config(tcb()))
    x = structure.X_base[structure.bottom_local][:, :, 0].mean(axis=1)
    middle = int(np.argmin(np.abs(x - 5.25)))
    one = ind.spread(structure, [(middle, 2, InterfaceState.STRONG)], 1)
    two = ind.spread(structure, [(middle, 2, InterfaceState.STRONG)], 2)
    cells = lambda requests: sorted(np.round(x[[c for c, _, _ in requests]], 6))  # noqa: E731
    assert cells(one) == [4.75, 5.25, 5.75]
    assert cells(two) == [4.25, 4.75, 5.25, 5.75, 6.25]
    assert {(i, k) for _, i, k in two} == {(2, InterfaceState.STRONG)}


def test_front_keeps_a_started_delamination_inside_the_refined_region():
    """A cohesive element that has started to fail asks for strong refinement of the cells
    whose centroid lies within the front distance of its cell's, at its interface only;
    undamaged ones ask for nothing, nor do cells already strong; each request notes its
    distance."""
    structure = build_structure(parse_config(tcb()))
    x = structure.X_base[structure.bottom_local][:, :, 0].mean(axis=1)
    middle = int(np.argmin(np.abs(x - 5.25)))
    structure.refine(
        [(c, 2, InterfaceState.STRONG) for c in np.flatnonzero(np.abs(x - 5.25) < 0.3)]
    )
    distances = np.array([0.0, 1.01, 0.0, 0.0, 0.0, 0.0, 0.0])  # mm, interface 2 only
    assert ind.front_requests(structure, distances)[0] == []
    structure.cohesive.damage[structure.damage_rows[(middle, 2)], 1] = 0.01
    reasons = {}
    requests, _ = ind.front_requests(structure, distances, reasons)
    assert sorted(np.round(x[[c for c, _, _ in requests]], 6)) == [4.25, 4.75, 5.75, 6.25]
    assert {(i, k) for _, i, k in requests} == {(2, InterfaceState.STRONG)}
    for cell, interface, kind in requests:
        assert reasons[(cell, interface, kind)].indicator == "front"
        assert reasons[(cell, interface, kind)].value == pytest.approx(abs(x[cell] - 5.25))
    distances[1] = 0.99
    nearer = ind.front_requests(structure, distances)[0]
    assert sorted(np.round(x[[c for c, _, _ in nearer]], 6)) == [4.75, 5.75]


def test_front_searches_only_around_delaminations_started_since_the_last_call():
    """Given the started delaminations an earlier call searched around (and whose requests
    were refined), a call asks for what a call that knows nothing asks for: nothing more
    around the known ones, the same around a new one."""
    structure = build_structure(parse_config(tcb()))
    x = structure.X_base[structure.bottom_local][:, :, 0].mean(axis=1)
    near = lambda at: np.flatnonzero(np.abs(x - at) < 0.3)  # noqa: E731
    structure.refine([(c, 2, InterfaceState.STRONG) for c in near(3.25)])
    structure.refine([(c, 2, InterfaceState.STRONG) for c in near(7.25)])
    distances = np.array([0.0, 1.01, 0.0, 0.0, 0.0, 0.0, 0.0])
    first = int(np.argmin(np.abs(x - 3.25)))
    structure.cohesive.damage[structure.damage_rows[(first, 2)], 1] = 0.01
    requests, known = ind.front_requests(structure, distances)
    assert len(requests) == 4 and len(known) == 1
    structure.refine(requests)
    again, still = ind.front_requests(structure, distances, known=known)
    assert again == [] and still.tolist() == known.tolist()
    second = int(np.argmin(np.abs(x - 7.25)))
    structure.cohesive.damage[structure.damage_rows[(second, 2)], 1] = 0.01
    fresh, _ = ind.front_requests(structure, distances)
    reasons = {}
    incremental, known = ind.front_requests(structure, distances, reasons, known)
    assert sorted(incremental) == sorted(fresh)
    assert sorted(np.round(x[[c for c, _, _ in incremental]], 6)) == [6.25, 6.75, 7.75, 8.25]
    assert len(known) == 2
    assert all(reasons[r].value == pytest.approx(abs(x[r[0]] - 7.25)) for r in incremental)


def test_front_distance_is_the_process_zone_plus_two_sublaminates():
    """By default an interface keeps M E2 G_c / tau0^2 (Turon et al. 2007, M = 1, the longer
    of the two modes) plus twice its thinner sublaminate refined around a started
    delamination; a distance given in the config is every delaminable interface's."""
    config = parse_config(tcb())
    structure = build_structure(config)
    law = config.cohesive
    zone = 10000.0 * max(law.GIc / law.N**2, law.GIIc / law.S**2)  # E2 = 10 GPa
    # interfaces 2 and 6 delaminate: interface 2 splits plies 1-2 (2 x 0.256 mm) from 3-6
    expected = np.zeros(7)
    expected[[1, 5]] = zone + 2.0 * 2 * 0.256
    assert ind.front_distances(structure, law) == pytest.approx(expected, rel=1e-12)
    assert ind.front_distances(structure, law, 3.0) == pytest.approx(3.0 * (expected > 0))
    thick = ind.sublaminate_thicknesses(structure.laminate, (2, 6))
    assert thick == pytest.approx(0.256 * np.array([1, 2, 1, 2, 1, 2, 1]))


def test_indicators_run_as_often_as_a_front_could_cross_its_band():
    """By default every 2 h / sqrt(G12 / rho): the time a shear wave (faster than any
    delamination front) takes to cross the band kept refined ahead of a process zone at the
    interface where it is narrowest; a config's interval is kept. TCB: interfaces 2, 4, 6
    may refine, so every sublaminate is two plies."""
    from fenics_adaptive.simulation import indicator_defaults

    config = parse_config(tcb(indicators={"interface_stress": 0.9}))
    structure = build_structure(config)
    material = config.laminate.plies[0].material
    expected = 2 * 2 * 0.256 / np.sqrt(material.G12 / material.rho)
    assert ind.default_interval(structure) == pytest.approx(expected, rel=1e-12)
    times = indicator_defaults(config, structure)
    assert times.interval == pytest.approx(expected, rel=1e-12)
    assert times.front == pytest.approx(ind.front_distances(structure, config.cohesive))
    assert times.lead == times.interval  # (no ties' release window)
    config = parse_config(tcb(indicators={"interface_stress": 0.9, "interval": 1e-6}))
    assert indicator_defaults(config, structure).interval == 1e-6


def test_the_look_ahead_predicts_over_the_interval_and_the_release_window():
    """A strong refinement acts once its tie has faded over the release window, and a cell
    that crosses just after an evaluation waits for the next: the look-ahead's lead is both;
    off, there is none."""
    from fenics_adaptive.simulation import indicator_defaults

    data = tcb(indicators={"interface_stress": 0.9, "interval": 1e-6})
    data["stabilisation"] = {"release_window": 2e-5}
    config = parse_config(data)
    structure = build_structure(config)
    assert indicator_defaults(config, structure).lead == pytest.approx(2.1e-5, rel=1e-15)
    data["indicators"]["look_ahead"] = False
    assert indicator_defaults(parse_config(data), structure).lead is None
    data["indicators"].update(look_ahead=True, interface_stress=0.0)  # (nothing to predict)
    assert indicator_defaults(parse_config(data), structure).lead is None


def test_front_rings_are_refused_with_what_replaced_them():
    data = tcb(indicators={"interval": 1e-6, "interface_stress": 0.9, "front": 2})
    with pytest.raises(InputError, match=r"indicators\.front: no longer a key: .*front_distance"):
        parse_config(data)


def failure_cantilever(ply_damage: bool):
    """[90/0/0/90] ESL cantilever under a tip load, the matrix of the outer 90-degree plies
    loaded in transverse tension/compression by bending, strongest at the clamp."""
    data = {
        "model": {"kind": "adaptive", "ply_damage": ply_damage},
        "mesh": {"length": 20.0, "width": 1.0, "nx": 20, "ny": 2},
        "materials": {
            "ply": {
                "E1": 1e5,
                "E2": 1e4,
                "G12": 5e3,
                "nu12": 0.25,
                "nu23": 0.25,
                "rho": 1.6e-9,
                "failure": {
                    "XT": 2000.0,
                    "XC": 1200.0,
                    "YT": 50.0,
                    "YC": 200.0,
                    "S12": 80.0,
                    "G2c": 0.3,
                    "G6c": 0.8,
                },
            }
        },
        "laminate": {"material": "ply", "ply_thickness": 0.25, "angles": [90, 0, 0, 90]},
        "interfaces": {"refine": [1, 2], "delaminate": [1]},
        "cohesive": {
            "K_n": 1e5,
            "K_s": 1e5,
            "N": 50.0,
            "S": 80.0,
            "GIc": 0.3,
            "GIIc": 0.8,
            "law": "bk",
            "exponent": 2.0,
        },
        "clamp": [{"face": "x0"}],
        "prescribed": [{"face": "x1", "component": "z", "displacement": -1.0, "rise_time": 1.0}],
        "solver": {"end_time": 1e-4},
        "output": {
            "interval": 1e-5,
            "displacement_face": "x1",
            "reaction_face": "x0",
            "component": "z",
        },
    }
    return parse_config(data)


def test_ply_failure_indicator_refines_next_to_the_failing_ply():
    config = failure_cantilever(ply_damage=False)
    structure = build_structure(config)
    x, z = structure.X_base[:, 0], structure.X_base[:, 2]
    u = structure.base.u.x.array.reshape(-1, 3)
    u[:, 2] = 0.02 * x**2  # pure bending, curvature 0.04/mm, no transverse shear
    u[:, 0] = -0.04 * x * (z - 0.5)
    index = ind.ply_failure_indices(structure)
    # transverse strain of the outer 90-degree plies: +-0.04 * 0.375 = 1.5 %: the bottom one in
    # tension far beyond YT = 50 MPa, the top one in compression, below YC = 200 MPa
    assert index[:, 0].min() > 2.0
    top = index[:, 3]
    assert 0.3 < top.min() and top.max() < 1.0
    assert index[:, 1].max() < 1.0  # the 0-degree plies carry it along their fibres
    n = structure.base.n_owned_cells

    def asked(fraction):
        settings = IndicatorSettings(interval=1.0, ply_failure=fraction)
        return ind.indicator_requests(structure, settings, (50.0, 80.0))

    # ply 1 -> the nearest refinable interface above it: 1, in every cell
    assert sorted(asked(1.0)) == [(c, 1, InterfaceState.WEAK) for c in range(n)]
    # each request's reason is the indicator and the index of the ply that asked
    reasons = {}
    settings = IndicatorSettings(interval=1.0, ply_failure=1.0)
    ind.indicator_requests(structure, settings, (50.0, 80.0), reasons=reasons)
    assert {r.indicator for r in reasons.values()} == {"ply_failure"}
    for (cell, _, _), reason in reasons.items():
        assert reason.value == index[cell, 0] >= 1.0
    # just below the top ply's index it asks too -> the nearest refinable interface below: 2
    both = asked(0.99 * top.min())
    assert sorted({(i, k) for _, i, k in both}) == [
        (1, InterfaceState.WEAK),
        (2, InterfaceState.WEAK),
    ]
    assert asked(1.01 * index.max()) == []


def test_matrix_damage_indicator_delaminates_next_to_a_cracked_ply():
    config = failure_cantilever(ply_damage=True)
    structure = build_structure(config)
    from fenics_adaptive.materials.ply_damage import S_D

    structure.damage_state[3, 0, S_D] = 0.2  # cell 3: bottom 90-degree ply cracking
    structure.damage_state[7, 2, S_D] = 0.5  # cell 7: a ply away from interface 1
    settings = IndicatorSettings(interval=1.0, matrix_damage=True)
    reasons = {}
    requests = ind.indicator_requests(structure, settings, (50.0, 80.0), reasons=reasons)
    assert requests == [(3, 1, InterfaceState.STRONG)]
    assert reasons == {(3, 1, InterfaceState.STRONG): Reason("matrix_damage", 0.2)}
    assert structure.refine(requests)
    assert structure.interface_state[3, 0] == InterfaceState.STRONG
    assert ind.indicator_requests(structure, settings, (50.0, 80.0)) == []


def test_ply_strains_follow_each_refinement_and_keep_the_unchanged_elements_maps():
    """The indicators keep what their element loop reads until the structure refines
    (``ElementData``); a refinement gives them the new elements, the maps of the elements it
    did not change are kept, and they equal those of a build from scratch (bit for bit); the
    ply strains then equal the enhanced-strain parameters of each element computed afresh."""
    structure = build_structure(parse_config(tcb()))
    rng = np.random.default_rng(3)
    x = structure.X_base[structure.bottom_local][:, :, 0].mean(axis=1)
    for step, (interface, kind, near) in enumerate(
        [
            (4, InterfaceState.WEAK, 3.0),
            (2, InterfaceState.STRONG, 3.0),
            (6, InterfaceState.STRONG, 7.0),
        ]
    ):
        before = ind.element_data(structure)
        structure.refine([(c, interface, kind) for c in np.flatnonzero(np.abs(x - near) < 1.6)])
        structure.base.u.x.array[:] = 1e-3 * rng.standard_normal(structure.base.u.x.array.shape)
        structure.extra.vectors["u"].array[:] = 1e-3 * rng.standard_normal(
            structure.extra.vectors["u"].array.shape
        )
        kept = ind.element_data(structure)
        assert kept is not before and kept.subelements is structure.refined_cells.subelements
        fresh = ind.ElementData.of(structure)
        assert np.array_equal(kept.keys, fresh.keys)
        assert np.array_equal(kept.centre_maps, fresh.centre_maps)
        assert np.array_equal(kept.shear_roots, fresh.shear_roots)
        # the cohesive rows grown from the ones before, the ply ranges, the stiffnesses kept
        for name in ("cohesive_rows", "patterns", "pattern", "stiffness"):
            assert np.array_equal(getattr(kept, name), getattr(fresh, name)), name
        rows = [[c, i, r] for (c, i), r in structure.damage_rows.items()]
        assert kept.cohesive_rows.tolist() == rows and (len(rows) > 0) == (step > 0)
        assert ind.element_data(structure) is kept  # no refinement: nothing made again
        # the strains read the centre parameters of each element, as computed afresh
        nodes, _, plies = structure.elements()
        alpha = structure.rule_table.enhanced_parameters(
            structure.gather(nodes, "X"), structure.gather(nodes, "u"), plies
        ).mean(axis=1)
        u = np.concatenate([structure.base.u.x.array, structure.extra.vectors["u"].array])
        from_maps = np.einsum("eai,eai->e", kept.centre_maps, u.reshape(-1, 3)[nodes])
        np.testing.assert_allclose(from_maps, alpha, rtol=1e-12, atol=1e-12 * abs(alpha).max())
        assert len(kept.nodes) > len(before.nodes) or step == 0


def test_the_look_ahead_continues_the_rise_of_the_last_lead_time():
    """predicted(t) = I(t) + max(0, I(t) - I(t - lead)): a steady rise is predicted exactly
    one lead ahead (I(t - lead) interpolated between evaluations that do not fall on it), a
    fall predicts the present index, and before one lead has passed the rise is taken from the
    first evaluation. Its state restores the same predictions; it keeps about lead / interval
    snapshots."""
    lead, dt = 1.0, 0.3
    history = ind.IndexHistory(lead)
    rate = np.array([[0.1, -0.05]])  # (one cell, two interfaces) per s

    def index(t):
        return 0.5 + rate * t

    t = 0.0
    assert history.predict(t, index(t)) == pytest.approx(index(t), abs=1e-15)
    for _ in range(6):
        t += dt
        predicted = history.predict(t, index(t))
        if t < lead:
            expected = index(t) + np.maximum(0.0, index(t) - index(0.0))
        else:
            expected = np.maximum(index(t + lead), index(t))  # a rise continued, a fall not
        assert predicted == pytest.approx(expected, abs=1e-14)
        assert len(history.times) <= lead / dt + 2
    restored = ind.IndexHistory(lead, **history.state())
    t += dt
    assert restored.predict(t, index(t)) == pytest.approx(history.predict(t, index(t)), abs=0)
    # the same time again, or an earlier one (a restored run): its snapshot replaced, in order
    assert history.predict(t, index(t)) == pytest.approx(np.maximum(index(t + lead), index(t)))
    history.predict(t - dt, index(t - dt))
    assert history.times == sorted(history.times) and history.times[-1] == t - dt
    with pytest.raises(ValueError, match="lead"):
        ind.IndexHistory(-1.0)


def test_the_look_ahead_does_not_stretch_a_rise_over_a_gap_longer_than_its_lead():
    """Evaluations further apart than the lead (steps longer than the interval, or no
    release window): I(t - lead) lies between the last snapshot and now, so a steady rise is
    still predicted exactly one lead ahead, not the whole gap's rise. Snapshots closer than
    lead / SNAPSHOTS_PER_LEAD replace the last: their number stays bounded."""
    lead = 0.1
    history = ind.IndexHistory(lead)
    for t in (0.0, 1.0, 2.0):
        predicted = history.predict(t, np.array([[0.5 * t]]))
    assert predicted == pytest.approx(0.5 * (2.0 + lead), abs=1e-14)
    dense = ind.IndexHistory(lead)
    for t in np.arange(0.0, 1.0, lead / 1000):
        dense.predict(t, np.array([[t]]))
    assert len(dense.times) <= ind.SNAPSHOTS_PER_LEAD + 2
    assert dense.predict(1.0, np.array([[1.0]])) == pytest.approx(1.0 + lead, rel=1e-12)
