"""Selective mass scaling through the thickness (``model.mass_scaling``, ``[solver]
mass_scaling = "selective"``): the scaled mass keeps translations and momentum, each element
reaches its target step, the element bound holds against the scaled system's true highest
frequency, a cantilever swings with the same period at a third of the steps, a layerwise TCB
steps like its ESL model and keeps its force and dissipation, the energy balance stays closed
(reactions included), a restart repeats the run, and what it cannot do yet is refused.

Units: N, mm, s, tonne.
"""

import math
import tomllib
from pathlib import Path

import numpy as np
import pytest
from helpers import (
    assert_restarted_history,
    cantilever_first_period,
    crossing_times,
    esl_model,
    highest_frequency,
    run_quietly,
    thin_pulled_beam,
    thin_tcb_layerwise,
)

from fenics_adaptive.analysis.vibration import dense_system, eigenvalues
from fenics_adaptive.errors import InputError
from fenics_adaptive.io.output import read_history
from fenics_adaptive.model import loading
from fenics_adaptive.model import mass_scaling as ms
from fenics_adaptive.model.structure import Structure
from fenics_adaptive.settings.config import parse_config
from fenics_adaptive.settings.kinds import MassScaling
from fenics_adaptive.settings.loads import Amplitude, FaceLoad, PrescribedMotion, clamp
from fenics_adaptive.simulation import Simulation
from fenics_adaptive.solver import explicit
from fenics_adaptive.solver.static import solve_static

DATA = Path(__file__).parent / "data"
ROOT = Path(__file__).parents[1]
LENGTH, WIDTH = 50.0, 2.0
THIN = [0, 90, 0, 90, 90, 0, 90, 0]


def thin_cantilever(nx: int = 20, ply_thickness: float = 0.125, length: float = LENGTH, **model):
    """A [0/90/0/90]s cantilever ``length`` x 2 mm of ``nx`` cells; 8 plies of 0.125 mm: 1 mm
    thick. ``model``: to ``build_model``."""
    model = esl_model(THIN, length, WIDTH, nx, 1, ply_thickness=ply_thickness, **model)
    return model, clamp("x0")


def scaled(model, motions) -> tuple[Structure, ms.SelectiveMass]:
    structure = Structure(model, loading.resolve(model, motions, []))
    structure.scaled_mass = ms.selective_mass(structure)
    return structure, structure.scaled_mass


# The two tests below keep the plies' full transverse shear moduli (no shear correction): stiffer
# in shear, their thin cells need the tangential factor too, which the tests exercise.
def test_the_scaled_mass_keeps_translations_and_weighs_relative_motion():
    model, motions = thin_cantilever(nx=10, ply_thickness=0.05, shear_correction=False)
    structure, mass = scaled(model, motions)
    assert mass.normal_scaling.min() > 1.0  # thin cells: every one needs it
    assert 0.0 < mass.shear_scaling.max() < 0.5 * mass.normal_scaling.min()
    lumped = structure.base_block.mass
    n = len(lumped)
    out = np.empty(n)
    # a translation (each component) sees the lumped masses alone: mass and momentum unchanged
    for d in range(3):
        v = np.zeros(n)
        v[d::3] = 1.0
        np.testing.assert_allclose(mass.multiply(v, out), lumped * v, rtol=1e-12, atol=0)
    rng = np.random.default_rng(3)
    x, y = rng.standard_normal(n), rng.standard_normal(n)
    Mx, My = mass.multiply(x, np.empty(n)), mass.multiply(y, np.empty(n))
    assert np.dot(x, My) == pytest.approx(np.dot(y, Mx), rel=1e-12)  # symmetric
    # heavier than the lumped masses in anything that moves a column's nodes apart
    assert np.dot(x, Mx) > np.dot(x, lumped * x)
    top = np.isclose(structure.X_base[: n // 3, 2], structure.X_base[:, 2].max())
    rotation = np.zeros((n // 3, 3))
    rotation[:, 0] = np.where(top, 1.0, -1.0)  # tops one way, bottoms the other
    r = rotation.ravel()
    lumped_energy = np.dot(r, lumped * r)
    assert np.dot(r, mass.multiply(r, np.empty(n))) > 1.5 * lumped_energy


EDGE_NORMALS = ms.edge_normals


def tilted_normals(X: np.ndarray) -> np.ndarray:
    """The edges' unit vectors turned 30 degrees about x: every edge block couples y and z."""
    c, s = math.cos(math.pi / 6), math.sin(math.pi / 6)
    return EDGE_NORMALS(X) @ np.array([[1.0, 0.0, 0.0], [0.0, c, s], [0.0, -s, c]])


@pytest.mark.parametrize("path", ["banded", "dense", "tilted"])
def test_solve_gives_the_free_accelerations_and_the_reactions_of_the_scaled_mass(path, monkeypatch):
    """With a residual r and given accelerations a_p on the prescribed DOFs: M_s a = r on the
    free DOFs, and each reaction is (M_s a)_p - r_p (the lumped m_p a_p - r_p it starts from
    plus the scaled mass's share); by each chain's tridiagonal factors per component (edges
    along z), by the inverse of its whole matrix, and with edges that couple the components
    (as a curved shell's would)."""
    if path != "banded":
        monkeypatch.setattr(ms, "BANDED_TOLERANCE", -1.0)
    if path == "tilted":
        monkeypatch.setattr(ms, "edge_normals", tilted_normals)
    model = esl_model(THIN, 10.0, WIDTH, 4, 1, ply_thickness=0.05)
    pulled = PrescribedMotion("x1&top", "z", "displacement", 0.1, Amplitude.constant())
    structure, mass = scaled(model, [*clamp("x0"), pulled])
    assert mass.normal_scaling.min() > 1.0
    assert mass.banded.all() == (path == "banded") and mass.held.any()
    lumped = structure.base_block.mass
    n = len(lumped)
    for d in range(3):  # a translation still sees the lumped masses alone
        v = np.zeros(n)
        v[d::3] = 1.0
        np.testing.assert_allclose(mass.multiply(v, np.empty(n)), lumped * v, rtol=1e-12)
    fixed = structure.base_block.fixed
    rng = np.random.default_rng(5)
    r = rng.standard_normal(len(lumped))
    acc = r.copy()
    acc[fixed] = rng.standard_normal(len(fixed))
    a_fixed = acc[fixed].copy()
    reaction = lumped[fixed] * a_fixed - r[fixed]
    mass.solve(acc, reaction)
    np.testing.assert_array_equal(acc[fixed], a_fixed)
    Ma = mass.multiply(acc, np.empty(len(acc)))
    free = np.setdiff1d(np.arange(len(acc)), fixed)
    np.testing.assert_allclose(Ma[free], r[free], rtol=0, atol=1e-12 * np.abs(r).max())
    np.testing.assert_allclose(reaction, Ma[fixed] - r[fixed], rtol=0, atol=1e-12 * np.abs(r).max())
    # the share is there: the driven top nodes pull on the free nodes below them
    assert np.abs(Ma[fixed] - lumped[fixed] * a_fixed).max() > 1e-3 * np.abs(r).max()


@pytest.mark.parametrize("path", ["banded", "dense"])
def test_a_late_force_adds_its_size_times_the_response_to_its_shape(path, monkeypatch):
    """A force added after the forces' exchange (the MMB lever's hinge) of size s and shape w:
    the accelerations and reactions of r + s w equal those of r plus s times ``responses(w)``,
    and the response holds the prescribed DOFs (the scaled mass is linear)."""
    if path != "banded":
        monkeypatch.setattr(ms, "BANDED_TOLERANCE", -1.0)
    model = esl_model(THIN, 10.0, WIDTH, 4, 1, ply_thickness=0.05)
    pulled = PrescribedMotion("x1&top", "z", "displacement", 0.1, Amplitude.constant())
    structure, mass = scaled(model, [*clamp("x0"), pulled])
    fixed = structure.base_block.fixed
    lumped = structure.base_block.mass
    n = len(lumped)
    rng = np.random.default_rng(7)
    r, w, size = rng.standard_normal(n), np.zeros(n), 3.7
    w[2::3] = rng.uniform(0.5, 1.5, n // 3)  # every column's z, the held ones' too
    given = rng.standard_normal(len(fixed))
    whole, split = r + size * w, r.copy()
    reactions = []
    for acc in (whole, split):
        acc[fixed] = given
        reaction = lumped[fixed] * given - (r + size * w)[fixed]
        mass.solve(acc, reaction)
        reactions.append(reaction)
    accelerations, shares = mass.responses(w[None, :])
    assert np.all(accelerations[0][fixed] == 0.0) and np.abs(shares[0]).max() > 0.0
    scale = np.abs(whole).max()
    np.testing.assert_allclose(split + size * accelerations[0], whole, rtol=0, atol=1e-12 * scale)
    np.testing.assert_allclose(
        reactions[1] + size * shares[0], reactions[0], rtol=0, atol=1e-12 * np.abs(r).max()
    )


def test_each_element_reaches_its_target_with_the_least_shear_scaling():
    model, motions = thin_cantilever(nx=4, ply_thickness=0.05, shear_correction=False)
    structure = Structure(model, loading.resolve(model, motions, []))
    nodes, _, plies = structure.elements()
    X = structure.gather(nodes, "X")
    m = structure.rule_table.lumped_masses(X, plies[:, 0], plies[:, 1])
    K = ms.element_stiffness(X, structure.element_rules(plies), structure.rule_table.packed)
    mu, normals = ms.reduced_edge_masses(m), ms.edge_normals(X)

    def eigenvalues(s_t, s_n):
        blocks = ms.edge_blocks(normals, s_t[:, None] * mu, s_n[:, None] * mu)
        return ms.largest_eigenvalues(K, ms.element_scaled_mass(m, blocks))

    zero = np.zeros(len(K))
    unscaled = eigenvalues(zero, zero)
    in_plane = ms.in_plane_eigenvalues(K, m)
    assert np.all(in_plane < 0.3 * unscaled)  # the thickness sets the unscaled step
    huge = np.full(len(K), 1e7)
    np.testing.assert_allclose(eigenvalues(huge, huge), in_plane, rtol=1e-4)  # rigid edges
    target = 2.0 * in_plane.max()
    s_t, s_n, reached = ms.scaling_factors(K, m, normals, target, in_plane)
    assert np.all(reached <= target) and np.all(reached > 0.85 * target)
    np.testing.assert_allclose(reached, eigenvalues(s_t, s_n))
    # the least shear scaling: 3 % less does not reach the target, with any normal scaling
    assert np.all(eigenvalues(0.97 * s_t - 0.03, huge) > target)
    assert np.all(s_t < s_n)  # the thickness stretch is the fast mode of a thin element
    # a target above an element's own limit: it aims at IN_PLANE_MARGIN x its limit
    *_, reached = ms.scaling_factors(K, m, normals, 0.5 * in_plane.min(), in_plane)
    assert np.all(reached <= ms.IN_PLANE_MARGIN * in_plane * (1 + 1e-12))


@pytest.mark.slow
def test_the_element_bound_is_safe_and_sharp_on_the_scaled_system():
    """On a cantilever of 0.4 mm under cells of 2.5 x 2 mm: the scaled step estimate is below
    the scaled system's critical step 2 / omega_max (power iteration) and within 3 % of it
    (measured: 0.2 %), and that critical step is 1.9 x the lumped system's (measured: 1.97 x;
    6 x the lumped L_e / c estimate, which takes the fibre wave speed across the thickness)."""
    model, motions = thin_cantilever(nx=20, ply_thickness=0.05)
    structure, mass = scaled(model, motions)
    estimate, where = structure.stable_time_step()
    assert "scaled mass" in where
    fixed = structure.base_block.fixed
    critical = 2.0 / highest_frequency(model, fixed, 600, scaled_mass=mass)
    assert 0.97 * critical < estimate <= critical
    assert estimate >= 0.97 * mass.target_step
    lumped_critical = 2.0 / highest_frequency(model, fixed, 600)
    assert critical > 1.9 * lumped_critical


def test_a_clamped_plate_keeps_its_lowest_bending_frequencies():
    """A [0/90/0/90]s plate 20 x 20 mm, 0.4 mm thick, clamped on its four edges, 10 x 10
    cells: the lowest three frequencies with the scaled mass within 1 % of the lumped ones
    (measured: -0.08, -0.19, -0.19 %; with one factor for all directions, as large as the
    thickness stretch needs, -0.7, -1.8, -1.8 %), and its critical step 1.9 x the lumped one's
    (1.97 x)."""
    model = esl_model(THIN, 20.0, 20.0, 10, 10, ply_thickness=0.05)
    motions = [m for face in ("x0", "x1", "y0", "y1") for m in clamp(face)]
    structure, _ = scaled(model, motions)
    K, lumped, selective = dense_system(structure)
    np.testing.assert_allclose(selective, selective.T, rtol=0, atol=1e-12 * lumped.max())
    lam_lumped, lam_scaled = eigenvalues(K, lumped), eigenvalues(K, selective)
    ratio = np.sqrt(lam_scaled[:3] / lam_lumped[:3])
    assert np.all(np.abs(ratio - 1.0) < 0.01), ratio
    assert np.all(ratio < 1.0)  # heavier, never lighter
    assert math.sqrt(lam_lumped[-1] / lam_scaled[-1]) > 1.9
    # the element bound holds on the exact spectrum
    estimate, _ = structure.stable_time_step()
    assert estimate <= 2.0 / math.sqrt(lam_scaled[-1])


def swing(model, motions, u0, period: float, scaling: str):
    free = loading.resolve(model, motions, [])
    settings = explicit.SolverSettings(
        end_time=2.3 * period, output_interval=period / 100, mass_scaling=MassScaling(scaling)
    )
    return explicit.run(
        Structure(model, free), settings, explicit.Probe("x1", "x0", "z"), initial_displacement=u0
    )


@pytest.mark.slow
def test_a_cantilever_swings_with_the_same_period_in_a_third_of_the_steps():
    """A cantilever 0.4 mm thick under cells of 2.5 x 2 mm released from its static deflection
    under a tip load: the first bending period with the scaled mass is the lumped one's to 1e-3
    (the added rotary inertia is small), the step is 3 x longer (2 x from the scaling, the rest
    from the element bound against L_e / c), and the energy balance stays where it started (to
    1e-9 of the energy)."""
    length = 25.0
    model, motions = thin_cantilever(nx=10, ply_thickness=0.05, length=length)
    tip = loading.resolve(model, motions, [FaceLoad("x1", (0, 0, -1.0), Amplitude.constant())])
    u0 = solve_static(model, motions, tip, 0.0)
    period = cantilever_first_period(model.layer_laminates[0], WIDTH, length)
    periods = {}
    for scaling in ("none", "selective"):
        stats = swing(model, motions, u0, period, scaling)
        rows = stats.history
        up = crossing_times([r.time for r in rows], [r.displacement for r in rows])
        periods[scaling] = ((up[-1] - up[0]) / (len(up) - 1), stats.time_step)
        energy = max(r.kinetic_energy for r in rows)
        drift = [r.energy_balance - rows[0].energy_balance for r in rows]
        assert np.abs(drift).max() < 1e-9 * energy, scaling
    (lumped, dt_lumped), (selective, dt_selective) = periods["none"], periods["selective"]
    assert selective == pytest.approx(lumped, rel=1e-3)
    assert selective == pytest.approx(period, rel=0.01)
    assert dt_selective > 3.0 * dt_lumped


@pytest.mark.slow
def test_a_thin_layerwise_tcb_steps_3_x_longer_with_the_same_force_and_dissipation(tmp_path):
    """Eight mesh layers of 0.064 mm under 0.5 mm cells, both cracks growing: scaled, the stable
    step is 3 x the lumped one (measured: 3.46 x; the cohesive springs and the elements share
    it now), the peak force is the lumped run's to 0.5 % (measured 0.24 %), the force at every
    row to 2 % of the peak, the dissipated energy to 0.5 %, the delaminated
    area the same; both
    energy balances close (the work-based to round-off, the one from the states to 1e-8 of the
    external work)."""
    runs = {}
    for scaling in ("none", "selective"):
        summary = run_quietly(thin_tcb_layerwise(scaling), tmp_path / scaling)
        runs[scaling] = (summary["time_step"], read_history(tmp_path / scaling / "history.csv"))
    (lumped_step, lumped), (scaled_step, selective) = runs["none"], runs["selective"]
    assert scaled_step["used_s"] > 3.0 * lumped_step["used_s"]
    assert "cohesive" in scaled_step["limited_by"]
    force, reference = np.asarray(selective["reaction_force"]), np.asarray(lumped["reaction_force"])
    assert force.max() == pytest.approx(reference.max(), rel=5e-3)
    assert np.abs(force - reference).max() < 0.02 * reference.max()
    assert selective["dissipated_energy"][-1] == pytest.approx(
        lumped["dissipated_energy"][-1], rel=5e-3
    )
    assert lumped["delaminated_area"][-1] > 0.5  # the cracks grew
    assert selective["delaminated_area"][-1] == lumped["delaminated_area"][-1]
    work = max(selective["external_work"])
    assert np.abs(selective["energy_balance"]).max() < 1e-12 * work
    assert np.abs(selective["state_energy_balance"]).max() < 1e-8 * work


@pytest.mark.slow
def test_a_prescribed_tip_motion_closes_the_balance_with_the_scaled_reactions(tmp_path):
    """The small ESL beam with plies of 0.02 mm (0.16 mm under 2.5 x 1 mm cells), its tip's top
    edge pulled up while the nodes below it move freely: the reactions of the driven DOFs take
    the scaled mass's share (the coupling to the free nodes of their columns; without it the
    balance drifts by 6e-4 of the work), and the step is 2 x the lumped one."""
    histories = {}
    for scaling in ("none", "selective"):
        data = thin_pulled_beam(scaling, displacement=0.01)
        run_quietly(data, tmp_path / scaling)
        histories[scaling] = read_history(tmp_path / scaling / "history.csv")
    selective = histories["selective"]
    work = max(np.abs(selective["external_work"]))
    assert work > 0
    balance = np.asarray(selective["energy_balance"])
    # constant from the first step on (the impulse of a motion that starts at t = 0)
    assert np.abs(balance - balance[0]).max() < 1e-10 * work
    assert selective["time_step"][0] > 2.0 * histories["none"]["time_step"][0]


@pytest.mark.slow
def test_a_restarted_scaled_run_repeats_the_uninterrupted_one(tmp_path):
    run_quietly(thin_tcb_layerwise("selective", 1.0e-4), tmp_path / "whole")
    split = thin_tcb_layerwise("selective", 6.0e-5)
    split["output"]["checkpoint_interval"] = 500
    run_quietly(split, tmp_path / "split")
    resumed = thin_tcb_layerwise("selective", 1.0e-4)
    run_quietly(resumed, tmp_path / "split", restart=tmp_path / "split")
    assert_restarted_history(tmp_path / "split", tmp_path / "whole")


@pytest.mark.slow
def test_an_impactor_on_a_scaled_plate_meets_the_same_plate(tmp_path):
    """The plate impact demo as an ESL plate of 20 x 20 cells (1 mm under 2.5 mm cells) with
    an explicit penalty: the scaled run steps 1.6 x longer and the rigid sphere (a lumped body
    of its own) sees the same peak contact force and gives up the same energy to 0.5 %
    (measured 0.09 % and 0.02 %); the energy balance stays closed. (With the default penalty,
    which is capped by the step, the longer step makes the contact softer: give the penalty.)"""
    runs = {}
    for scaling in ("none", "selective"):
        data = tomllib.loads((ROOT / "demos" / "plate_impact.toml").read_text())
        data["model"]["kind"] = "esl"
        for name in ("interfaces", "cohesive", "indicators", "refinement", "stabilisation"):
            data.pop(name, None)
        data["mesh"].update(nx=20, ny=20)
        data["solver"].update(end_time=2.0e-4, mass_scaling=scaling)
        data["output"].pop("fields_interval", None)
        data["impactor"]["penalty"] = 1.0e3  # N/mm
        summary = run_quietly(data, tmp_path / scaling)
        runs[scaling] = (
            summary["time_step"]["used_s"],
            read_history(tmp_path / scaling / "history.csv"),
        )
    (lumped_step, lumped), (scaled_step, selective) = runs["none"], runs["selective"]
    assert scaled_step > 1.5 * lumped_step
    for name in ("contact_force", "impact_work"):
        assert max(selective[name]) == pytest.approx(max(lumped[name]), rel=5e-3), name
    assert max(lumped["impact_work"]) > 100.0  # mJ: the sphere did work on the plate
    assert np.abs(selective["energy_balance"]).max() < 1e-5 * max(selective["impact_work"])


def test_where_no_element_needs_mass_the_run_is_the_lumped_one(tmp_path):
    """The TCB of 0.256 mm plies, two per layer under 0.5 mm cells: no element needs mass
    (its in-plane modes are the fastest already), the scaled mass adds none, and at the same
    (forced) step the history is the lumped run's bit for bit."""
    data = tomllib.loads((DATA / "tcb_layerwise.toml").read_text())
    data["solver"]["end_time"] = 2.0e-5
    data["output"].pop("fields_interval", None)
    histories = {}
    for scaling in ("none", "selective"):
        data["solver"]["mass_scaling"] = scaling
        simulation = Simulation(parse_config(data))
        if scaling == "selective":
            assert not simulation.structure.scaled_mass.adds_mass
        run_quietly(data, tmp_path / scaling)
        histories[scaling] = read_history(tmp_path / scaling / "history.csv")
    for name, values in histories["none"].items():
        np.testing.assert_array_equal(histories["selective"][name], values, err_msg=name)


def test_the_run_reports_the_scaling_and_warns_of_a_target_it_cannot_reach(tmp_path):
    """summary.json says what the scaling did; a target step above what the cells' in-plane
    size allows is not silently cut: the log says so, with both steps."""
    from fenics_adaptive.runner import run_config

    lines: list[str] = []
    data = thin_tcb_layerwise("selective", 4.0e-6, mass_scaling_step=1.0e-6)
    summary = run_config(
        parse_config(data), tmp_path / "run", show_progress=False, log=lines.append
    )
    scaling = summary["mass_scaling"]
    assert scaling["target_step_s"] == 1.0e-6
    assert 0 < scaling["elements_scaled"] <= scaling["elements"] == 160
    assert scaling["element_step_s"] < 0.2 * scaling["target_step_s"]
    assert scaling["largest_normal_factor"] > scaling["largest_shear_factor"] > 0
    (warning,) = [line for line in lines if line.startswith("warning: the elements allow")]
    assert "1.0000e-06 s" in warning and "solver.mass_scaling_step" in warning
    assert any("selective mass scaling: " in line for line in lines)
    lumped = run_config(
        parse_config(thin_tcb_layerwise("none", 4.0e-6)),
        tmp_path / "lumped",
        show_progress=False,
        log=None,
    )
    assert lumped["mass_scaling"] is None


def test_the_config_names_the_choices_and_refuses_what_scaling_cannot_do_yet():
    data = thin_tcb_layerwise("selective")
    assert parse_config(data).solver.mass_scaling == MassScaling.SELECTIVE
    with pytest.raises(
        InputError, match=r"solver\.mass_scaling: must be one of none, selective \(got 'lumped'\)"
    ):
        parse_config(thin_tcb_layerwise("lumped"))
    with pytest.raises(InputError, match=r"solver\.mass_scaling_step"):
        parse_config(thin_tcb_layerwise("selective", mass_scaling_step=-1.0))
    damped = thin_tcb_layerwise("selective", mass_damping=100.0)
    with pytest.raises(InputError, match=r"solver\.mass_damping"):
        Simulation(parse_config(damped))
    adaptive = tomllib.loads((DATA / "tcb_adaptive.toml").read_text())
    adaptive["solver"]["mass_scaling"] = "selective"
    with pytest.raises(InputError, match=r"solver\.mass_scaling.*adaptive"):
        Simulation(parse_config(adaptive))
