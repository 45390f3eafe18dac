"""``fenics-adaptive static``: the static solve of a config at its end time, checked against an
independent solver (the UFL-assembled stiffness), beam theory (DCB, ENF, three-point bending)
and Clapeyron's theorem, with the run's result files."""

import copy
import csv
import json
import tomllib
from pathlib import Path

import numpy as np
import pytest
from dolfinx import fem

from fenics_adaptive import cli
from fenics_adaptive.analysis import lefm, studies
from fenics_adaptive.errors import InputError
from fenics_adaptive.io.output import read_history
from fenics_adaptive.model.loading import face_dofs
from fenics_adaptive.settings.config import load_config, parse_config
from fenics_adaptive.simulation import build_structure
from fenics_adaptive.solver.static import solve_static
from fenics_adaptive.static_runner import (
    INTERLAMINAR_FILE,
    cohesive_tractions,
    solve_config,
    static_config,
)

DATA = Path(__file__).parent / "data"
ROOT = Path(__file__).parents[1]


def toml(path: Path) -> dict:
    with open(path, "rb") as file:
        return tomllib.load(file)


def static(data: dict, out: Path) -> dict:
    return static_config(parse_config(data), out, log=None)


def test_static_command_equals_the_assembled_linear_solve_and_writes_a_run_folder(tmp_path):
    """The small ESL beam pulled at its end: reaction and energy as the UFL-assembled stiffness
    (``solver.static``, PETSc) gives them, one history row, the run's field files."""
    out = tmp_path / "static"
    assert cli.main(["static", str(DATA / "small_beam.toml"), "--out", str(out), "--quiet"]) == 0
    history = read_history(out / "history.csv")
    assert len(history["time"]) == 1
    summary = json.loads((out / "summary.json").read_text())
    assert summary["status"] == "completed" and summary["analysis"] == "static"

    config = load_config(DATA / "small_beam.toml")
    structure = build_structure(config)
    model = structure.base
    u = solve_static(model, config.motions, structure.loads, config.solver.end_time)
    f = fem.Function(model.V).x
    model.internal_force(f)
    reaction = f.array[face_dofs(model, "x1", "z")].sum()
    assert history["reaction_force"][0] == pytest.approx(reaction, rel=1e-9)
    assert history["displacement"][0] == pytest.approx(0.05, rel=1e-12)
    strain_energy = 0.5 * float(f.array @ u)  # the assembled solution's, by Clapeyron
    assert history["internal_energy"][0] == pytest.approx(strain_energy, rel=1e-9)
    assert history["external_work"][0] == pytest.approx(strain_energy, rel=1e-9)
    assert summary["static"]["relative_residual"] < 1e-9

    for name in ("elements.pvd", "plies.pvd", "cohesive.pvd", "displacement.xdmf"):
        assert (out / name).is_file(), name
    with open(out / INTERLAMINAR_FILE) as file:
        rows = list(csv.DictReader(file))
    n_cells, n_plies = config.mesh.nx * config.mesh.ny, config.laminate.n_plies
    assert len(rows) == n_cells * (n_plies + 1)
    # the faces are free of load: the estimate vanishes there
    faces = [r for r in rows if r["interface"] in ("0", str(n_plies))]
    assert max(abs(float(r["tau_xz_MPa"])) for r in faces) < 1e-9
    # a second static into the folder replaces what the first wrote, and only that
    (out / "notes.txt").write_text("mine")
    assert cli.main(["static", str(DATA / "small_beam.toml"), "--out", str(out), "--quiet"]) == 0
    assert (out / "notes.txt").read_text() == "mine"


def test_static_dcb_open_film_matches_beam_theory_in_every_model(tmp_path):
    """A DCB with an insert film opened at its load line: the film opens (no contact), the
    layerwise and the strongly refined adaptive model agree, and the stiffness lies between
    simple beam theory (arms clamped at the crack tip) and corrected beam theory (the root
    rotation, a + chi h). Refined only under the film, the border constraint holds the front:
    still in equilibrium with the solver's own forces and energy-consistent (Clapeyron)."""
    base = studies.dcb_quick(toml(ROOT / "demos" / "fracture_tests.toml"))
    config = parse_config(base)
    film = base["delamination"][0]
    crack = film["x_max"] - film["x_min"]
    arm = lefm.arm_thickness(config.laminate, film["interface"])
    material = config.laminate.plies[0].material
    EI = material.E1 * config.mesh.width * arm**3 / 12.0
    chi = lefm.root_rotation_correction(material)

    forces = {}
    partly = studies.fracture_variant(base, "refined_from_start")
    del partly["interfaces"]["initial"]  # refined under the film only
    runs = {
        "layerwise": studies.fracture_variant(base, "layerwise"),
        "adaptive": studies.fracture_variant(base, "refined_from_start"),
        "partly": partly,
    }
    for name, data in runs.items():
        summary = static(data, tmp_path / name)
        history = read_history(tmp_path / name / "history.csv")
        assert summary["static"]["relative_residual"] < 1e-9, name
        assert summary["static"]["insert_film_penetration_mm"] == 0.0, name
        assert history["external_work"][0] == pytest.approx(history["internal_energy"][0], 1e-9)
        assert history["delaminated_area"][0] == pytest.approx(crack * config.mesh.width)
        assert history["crack_growth_area"][0] == 0.0
        opening = 2.0 * history["displacement"][0]
        forces[name] = history["reaction_force"][0] / opening  # N/mm
    assert forces["adaptive"] == pytest.approx(forces["layerwise"], rel=1e-9)
    simple = 3.0 * EI / (2.0 * crack**3)
    corrected = 3.0 * EI / (2.0 * (crack + chi * arm) ** 3)
    assert corrected < forces["layerwise"] < simple
    assert forces["layerwise"] == pytest.approx(corrected, rel=0.06)
    # the unrefined cells ahead of the film cannot rotate the arms' roots: stiffer
    assert forces["partly"] > forces["layerwise"]
    # the upper arm is held by its load line, the interface and (a little, 3e-5 of the load,
    # far from the crack) its clamped end: the cohesive tractions the LW file gives, times
    # their areas, balance the load line's force
    with open(tmp_path / "layerwise" / INTERLAMINAR_FILE) as file:
        rows = list(csv.DictReader(file))
    structure, _, solution = solve_config(parse_config(runs["layerwise"]))
    _, areas, tractions = cohesive_tractions(structure, solution.u)
    assert [float(r["sigma_zz_MPa"]) for r in rows] == pytest.approx(tractions[:, 0], rel=1e-8)
    reaction = read_history(tmp_path / "layerwise" / "history.csv")["reaction_force"][0]
    assert float(areas @ tractions[:, 0]) == pytest.approx(reaction, rel=1e-4)
    film = structure.cohesive.inserted()
    assert np.all(tractions[film, 0] <= 0.0) and np.all(tractions[film, 1:] == 0.0)


def test_static_enf_closes_the_film_and_matches_beam_theory(tmp_path):
    """ENF on rigid rollers, loaded by a rigid nose: the arms slide on each other without
    overlapping (frictionless contact through the compression branch), the compliance is the
    standard's beam theory plus shear (within 2 %), the rollers balance the nose, and the
    bodies' work is the strain energy (Clapeyron). The beam theory's 3 a^3 term is that of two
    arms bending together over the crack: an arm of the cracked part that did not press on
    the other (no contact) would make the beam far softer than it."""
    data = toml(DATA / "enf.toml")
    config = parse_config(data)
    summary = static(data, tmp_path / "enf")
    static_summary = summary["static"]
    assert static_summary["relative_residual"] < 1e-8
    assert static_summary["insert_film_penetration_mm"] < 1e-4
    bodies = summary["rigid_bodies"]
    nose = bodies["nose"]["force_N"][2]
    assert bodies["left"]["force_N"][2] + bodies["right"]["force_N"][2] == pytest.approx(
        -nose, rel=1e-6
    )
    material = config.laminate.plies[0].material
    film = data["delamination"][0]
    left, right = (b["position"][0] for b in data["rigid"][:2])
    half_span = 0.5 * (right - left)
    crack = right - film["x_min"]
    arm = lefm.arm_thickness(config.laminate, film["interface"])
    width = config.mesh.width
    bending = (2 * half_span**3 + 3 * crack**3) / (8 * material.E1 * width * arm**3)
    shear = 3 * half_span / (10 * material.G12 * width * arm)
    deflection = -summary["final"]["displacement_mm"]  # the bottom face under the nose
    assert deflection / nose == pytest.approx(bending + shear, rel=0.02)
    history = read_history(tmp_path / "enf" / "history.csv")
    assert abs(history["energy_balance"][0]) < 1e-3 * history["internal_energy"][0]


def test_static_three_point_bending_on_rollers_matches_timoshenko(tmp_path):
    """An ESL beam resting on two rigid rollers, pushed by a rigid nose: held by contact only
    (the iteration starts from an unsupported beam), Timoshenko's compliance within 3 %."""
    data = toml(DATA / "three_point_bending.toml")
    config = parse_config(data)
    summary = static(data, tmp_path / "tpb")
    nose = summary["rigid_bodies"]["nose"]["force_N"][2]
    span = data["rigid"][1]["position"][0] - data["rigid"][0]["position"][0]
    material = config.laminate.plies[0].material
    width, h = config.mesh.width, config.laminate.thickness
    bending = span**3 / (48 * material.E1 * width * h**3 / 12)
    shear = span / (4 * (5 / 6) * material.G12 * width * h)
    deflection = -summary["final"]["displacement_mm"]
    assert deflection / nose == pytest.approx(bending + shear, rel=0.03)


def test_static_of_a_one_ply_laminate_writes_its_faces_estimate(tmp_path):
    """A laminate of one ply has no inner interface: its interlaminar estimate is the two
    faces' (zero where nothing loads them). It once divided by the bubble's trapezoidal mean,
    zero over a single ply, and the check failed after solving. The small beam with its plies
    made one 1 mm ply: its reaction as the assembled linear solve gives it."""
    data = toml(DATA / "small_beam.toml")
    data["laminate"] = {"material": data["laminate"]["material"], "ply_thickness": 1.0,
                        "angles": [0.0]}  # fmt: skip
    data.pop("interfaces", None)
    data.pop("cohesive", None)
    out = tmp_path / "one_ply"
    summary = static(data, out)
    assert summary["status"] == "completed"
    config = parse_config(data)
    structure = build_structure(config)
    u = solve_static(structure.base, config.motions, structure.loads, config.solver.end_time)
    f = fem.Function(structure.base.V).x
    structure.base.internal_force(f)
    reaction = f.array[face_dofs(structure.base, "x1", "z")].sum()
    assert summary["final"]["reaction_force_N"] == pytest.approx(reaction, rel=1e-9)
    assert np.abs(u).max() > 0.0
    with open(out / INTERLAMINAR_FILE) as file:
        rows = list(csv.DictReader(file))
    assert len(rows) == config.mesh.nx * config.mesh.ny * 2  # the bottom and top faces
    for column in ("sigma_zz_MPa", "tau_xz_MPa", "tau_yz_MPa"):
        values = np.array([float(r[column]) for r in rows])
        assert np.all(np.isfinite(values)) and np.abs(values).max() < 1e-9


def test_static_refuses_what_has_no_static_equilibrium(tmp_path):
    data = toml(DATA / "three_point_bending.toml")
    free = copy.deepcopy(data)
    nose = free["rigid"][2]
    for key in ("velocity", "rise_time", "profile"):
        nose.pop(key, None)
    nose.update(motion="free", mass=1e-4, velocity=[0.0, 0.0, -1000.0])
    with pytest.raises(InputError, match=r"rigid\.nose\.motion"):
        static(free, tmp_path / "free")
    (tmp_path / "taken").write_text("a file")
    path = str(DATA / "three_point_bending.toml")
    assert cli.main(["static", path, "--out", str(tmp_path / "taken"), "--quiet"]) == 2
    assert (tmp_path / "taken").read_text() == "a file"


def test_static_demo_enf_converges_where_its_film_faces_touch_without_pressure(tmp_path):
    """The shipped ENF (demos/fracture_tests_enf.toml: a 65-element film whose faces slide on
    each other with next to no pressure, the beam held by rollers it rests on) at 1.5 mm of
    nose travel: Newton settles (a closed film zone opens one element per step, so the budget
    grows with the film), the faces do not overlap, and the compliance is the beam theory's
    with shear."""
    data = toml(ROOT / "demos" / "fracture_tests_enf.toml")
    data["solver"]["end_time"] = 6.0e-3
    config = parse_config(data)
    summary = static(data, tmp_path / "enf")
    assert summary["static"]["relative_residual"] < 1e-8
    assert summary["static"]["insert_film_penetration_mm"] < 1e-4
    nose = summary["rigid_bodies"]["nose"]
    assert nose["displacement_mm"] < -1.0
    material = config.laminate.plies[0].material
    left, right = (body["position"][0] for body in data["rigid"][:2])
    theory = lefm.enf_compliance(
        right - data["delamination"][0]["x_min"],
        0.5 * (right - left),
        material.E1,
        material.G12,
        config.mesh.width,
        lefm.arm_thickness(config.laminate, data["delamination"][0]["interface"]),
    )
    deflection = -summary["final"]["displacement_mm"]  # the bottom face under the nose
    assert deflection / nose["force_N"][2] == pytest.approx(theory, rel=0.02)


def test_static_adaptive_film_starts_refined_as_the_run_starts(tmp_path):
    """An adaptive beam with an insert film and the indicators at their defaults: a run
    refines strongly ahead of the film's front at t = 0 (the front band), and the static
    check solves that same model (it once solved the film's cells alone refined: 2.7 % stiffer
    than the run's quasi-static answer, which the layerwise model's is, on an outside case)."""
    from fenics_adaptive.settings.kinds import InterfaceState
    from fenics_adaptive.simulation import RefinementHook
    from fenics_adaptive.static_runner import build_static

    data = toml(DATA / "small_beam.toml")
    data["model"]["kind"] = "adaptive"
    data["mesh"].update(nx=20)
    data["laminate"].update(ply_thickness=0.5, angles=[0, 90, 90, 0])
    data["interfaces"] = {"delaminate": [3]}
    data["delamination"] = [{"interface": 3, "x_min": 10.0, "x_max": 20.0}]
    data["indicators"] = {}
    data["cohesive"] = {"K_n": 1.0e5, "K_s": 1.0e5, "N": 30.0, "S": 60.0, "GIc": 0.3,
                        "GIIc": 0.8, "law": "bk", "exponent": 2.0}  # fmt: skip
    config = parse_config(data)
    structure, _, _ = build_static(config)
    run = build_structure(config)
    film = (run.interface_state[:, 2] == InterfaceState.STRONG).sum()
    RefinementHook(config)(0.0, run)  # the run's first evaluation, at rest
    assert (run.interface_state[:, 2] == InterfaceState.STRONG).sum() > film  # the band
    np.testing.assert_array_equal(structure.interface_state, run.interface_state)
