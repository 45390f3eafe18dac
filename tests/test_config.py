"""Config parsing: a good config parses into the objects it describes; every malformed one is
refused with one line that names the key."""

import copy
import math
import tomllib
from dataclasses import replace
from pathlib import Path

import pytest

from fenics_adaptive.errors import InputError
from fenics_adaptive.settings.config import load_config, parse_config

SMALL = Path(__file__).parent / "data" / "small_beam.toml"


def base() -> dict:
    return tomllib.loads(SMALL.read_text())


def test_small_config_parses():
    config = load_config(SMALL)
    assert config.kind == "esl"
    assert config.laminate.n_plies == 8
    assert config.laminate.thickness == pytest.approx(2.0)
    assert config.mesh.layers == (8,)
    assert [p.angle for p in config.laminate.plies] == [0, 90, 0, 90, 90, 0, 90, 0]
    assert len(config.motions) == 4  # clamp x/y/z + the pulled tip
    pulled = config.motions[-1]
    assert pulled.displacement(2.0e-4) == pytest.approx(0.05)
    assert pulled.displacement(0.5e-4) == pytest.approx(0.025)  # smoothstep midpoint
    assert config.solver.safety_factor == 0.9
    assert config.probe.reaction_face == "x1"


def test_layerwise_layers_group_plies():
    data = base()
    data["model"]["kind"] = "layerwise"
    data["mesh"]["layers"] = [2, 2, 2, 2]
    config = parse_config(data)
    assert [lam.n_plies for lam in config.layer_laminates()] == [2, 2, 2, 2]
    assert "x1_layer3" in config.face_names


def mutate(path: str, value, delete: bool = False):
    data = base()
    keys = path.split(".")
    node = data
    for key in keys[:-1]:
        node = node[int(key)] if isinstance(node, list) else node[key]
    if delete:
        del node[keys[-1]]
    elif isinstance(node, list):
        node[int(keys[-1])] = value
    else:
        node[keys[-1]] = value
    return data


DELETE = object()
MALFORMED = [
    # (path to change, new value, key named in the error)
    ("model", DELETE, "model"),
    ("model.kind", "shell", "model.kind"),
    ("model.colour", "red", "model.colour"),
    ("model.points_per_ply", 3, "model.points_per_ply"),
    ("mesh.nx", 0, "mesh.nx"),
    ("mesh.ny", 2.5, "mesh.ny"),
    ("mesh.length", -20.0, "mesh.length"),
    ("mesh.width", "2", "mesh.width"),
    ("mesh.layers", [4, 4], "mesh.layers"),
    ("materials.prototype.E1", -1.0, "materials.prototype.E1"),
    ("materials.prototype.nu12", 3.0, "materials.prototype.nu12"),
    ("materials.prototype.Young", 1.0, "materials.prototype.Young"),
    ("materials.prototype.rho", DELETE, "materials.prototype.rho"),
    ("laminate.material", "steel", "laminate.material"),
    ("laminate.ply_thickness", 0.0, "laminate.ply_thickness"),
    ("laminate.angles", [], "laminate.angles"),
    ("laminate.angles", [0, 400], "laminate.angles[1]"),
    ("laminate.angles", [0, "ninety"], "laminate.angles[1]"),
    ("clamp.0.face", "x2", "clamp[0].face"),
    ("prescribed.0.component", "w", "prescribed[0].component"),
    ("prescribed.0.velocity", 1.0, "prescribed[0].displacement"),
    ("prescribed.0.rise_time", -1.0, "prescribed[0].rise_time"),
    ("prescribed.0.profile", "cubic", "prescribed[0].profile"),
    ("solver.end_time", 0.0, "solver.end_time"),
    ("solver.safety_factor", 1.5, "solver.safety_factor"),
    ("solver.mass_damping", -1.0, "solver.mass_damping"),
    ("solver.dt", 1e-8, "solver.dt"),
    ("output.interval", 1.0, "output.interval"),
    ("output.reaction_face", "top", "output.reaction_face"),
    ("output.component", 2, "output.component"),
]


@pytest.mark.parametrize(("path", "value", "key"), MALFORMED, ids=[m[0] for m in MALFORMED])
def test_malformed_config_names_the_key(path, value, key):
    data = mutate(path, value, delete=value is DELETE)
    with pytest.raises(InputError) as caught:
        parse_config(data)
    assert caught.value.key == key, str(caught.value)
    assert "\n" not in str(caught.value)


def test_layers_in_an_esl_model_are_refused():
    data = base()
    data["mesh"]["layers"] = [8]
    with pytest.raises(InputError, match=r"mesh\.layers"):
        parse_config(data)


def test_single_integration_point_through_a_layer_is_refused():
    data = base()
    data["model"]["kind"] = "layerwise"  # default: one mesh layer per ply
    assert parse_config(data).points_per_ply == 2  # the default
    data["model"]["points_per_ply"] = 1
    with pytest.raises(InputError, match="points_per_ply"):
        parse_config(data)


def test_not_toml_and_missing_file(tmp_path):
    bad = tmp_path / "bad.toml"
    bad.write_text("[mesh\nlength = 1")
    with pytest.raises(InputError, match="not valid TOML"):
        load_config(bad)
    with pytest.raises(InputError, match="cannot read"):
        load_config(tmp_path / "absent.toml")


IMPACTOR = {
    "shape": "sphere",
    "radius": 5.0,
    "mass": 1e-5,
    "position": [10.0, 1.0, 8.0],
    "velocity": [0.0, 0.0, -1000.0],
}
BAD_IMPACTORS = [
    ("shape", "cube"),
    ("radius", 0.0),
    ("mass", -1.0),
    ("position", [1.0, 2.0]),
    ("velocity", [0.0, 0.0, "fast"]),
    ("penalty", 0.0),
    ("spin", 3.0),
]


@pytest.mark.parametrize(("key", "value"), BAD_IMPACTORS, ids=[b[0] for b in BAD_IMPACTORS])
def test_malformed_impactor_names_the_key(key, value):
    data = base()
    data["impactor"] = {**IMPACTOR, key: value}
    with pytest.raises(InputError) as caught:
        parse_config(data)
    assert caught.value.key.split("[")[0] == f"impactor.{key}", str(caught.value)


def test_impactor_parses_and_one_inside_the_plate_is_refused(tmp_path):
    from fenics_adaptive.runner import run_config

    data = base()
    data["impactor"] = dict(IMPACTOR)
    config = parse_config(data)
    assert config.impactor.velocity == (0.0, 0.0, -1000.0)
    data["impactor"]["position"] = [10.0, 1.0, 6.0]  # top face at z = 2, radius 5
    with pytest.raises(InputError, match="inside the top face") as caught:
        run_config(parse_config(data), tmp_path, show_progress=False, log=None)
    assert caught.value.key == "impactor.position"


# ------------------------------------------------------------------ every bad input: one line
TCB_LW = Path(__file__).parent / "data" / "tcb_layerwise.toml"
FOUR_POINT = Path(__file__).parent.parent / "demos" / "four_point_bending.toml"


def refused(data: dict) -> InputError:
    with pytest.raises(InputError) as caught:
        parse_config(data)
    assert "\n" not in str(caught.value)
    return caught.value


def test_a_list_where_a_choice_is_expected_is_refused():
    data = tomllib.loads(TCB_LW.read_text())
    data["cohesive"]["law"] = ["bk"]  # unhashable: once a TypeError
    error = refused(data)
    assert error.key == "cohesive.law" and "must be one of bk, power" in error.problem


@pytest.mark.parametrize("bad", [float("nan"), float("inf"), -float("inf")])
def test_every_number_must_be_finite(bad):
    data = base()
    data["load"] = [{"face": "top", "force": [0.0, 0.0, bad], "rise_time": 1e-4}]
    assert refused(data).key == "load[0].force[2]"
    data = base()
    data["impactor"] = {**IMPACTOR, "velocity": [0.0, 0.0, bad]}
    assert refused(data).key == "impactor.velocity[2]"
    for path in ("solver.end_time", "materials.prototype.E1", "mesh.length", "solver.mass_damping"):
        error = refused(mutate(path, bad))
        assert error.key == path and "finite" in error.problem


@pytest.mark.parametrize(
    ("nx", "ny", "key"), [(10**9, 2, "mesh.nx"), (1e9, 2, "mesh.nx"), (10**5, 10**5, "mesh.nx")]
)
def test_a_model_too_large_is_refused_before_meshing_with_its_estimate(nx, ny, key):
    data = base()
    data["mesh"].update(nx=nx, ny=ny, length=1e5, width=1e5)
    error = refused(data)
    assert error.key == key
    assert "GB" in error.problem and "model.max_memory = 16 GB" in error.problem
    data["model"]["max_memory"] = 1e9  # the documented way to raise the limit
    if ny == 2:  # 1e9 x 2 cells of 1e-4 x 5e4 mm: now the aspect ratio refuses them
        assert refused(data).key == "mesh.ny"  # (more cells along the long side)


def test_an_integral_float_is_an_integer_and_a_fraction_is_not():
    assert parse_config(mutate("mesh.nx", 8.0)).mesh.nx == 8
    assert refused(mutate("mesh.nx", 8.5)).key == "mesh.nx"
    assert refused(mutate("mesh.nx", True)).key == "mesh.nx"


@pytest.mark.parametrize(
    ("path", "value", "key"),
    [
        ("laminate.ply_thickness", 1e-300, "laminate.ply_thickness"),  # once a Gmsh error
        ("laminate.ply_thickness", -0.25, "laminate.ply_thickness"),
        ("mesh.length", 0.0, "mesh.length"),
        ("mesh.width", -2.0, "mesh.width"),
        ("mesh.length", 1e5, "mesh.nx"),  # cells of 12 500 x 1 x 2 mm: aspect 12 500
        ("mesh.width", 1e-4, "mesh.ny"),  # cells 5e-5 mm wide, below the smallest size
        ("mesh.nx", 10**6, "mesh.nx"),  # cells of 2e-5 mm, below the smallest size
    ],
)
def test_degenerate_geometry_is_refused(path, value, key):
    assert refused(mutate(path, value)).key == key


def test_plies_of_very_different_thickness_in_one_cell_are_refused():
    data = base()
    del data["laminate"]["angles"], data["laminate"]["ply_thickness"], data["laminate"]["material"]
    data["laminate"]["plies"] = [
        {"material": "prototype", "angle": 0.0, "thickness": t} for t in (2.0, 1e-4, 1e-4, 2.0)
    ]
    assert refused(data).key == "laminate"
    data["laminate"]["plies"][1]["thickness"] = data["laminate"]["plies"][2]["thickness"] = 0.1
    assert parse_config(data).laminate.n_plies == 4


@pytest.mark.parametrize(
    ("section", "face", "key"),
    [
        ("clamp", "x0&x1", "clamp[1].face"),
        ("clamp", "bottom&top", "clamp[1].face"),
        ("probe", "x0&x1", "output.displacement_face"),
        ("probe", "y0&y1&top", "output.displacement_face"),
    ],
)
def test_faces_that_share_no_node_are_refused(section, face, key):
    data = base()
    if section == "clamp":
        data["clamp"].append({"face": face})
    else:
        data["output"]["displacement_face"] = face
    error = refused(data)
    assert error.key == key and "holds no node" in error.problem


def test_a_load_on_an_edge_or_a_pad_without_nodes_is_refused():
    data = base()
    data["load"] = [{"face": "x1&top", "force": [0.0, 0.0, 1.0], "rise_time": 1e-4}]
    assert refused(data).key == "load[0].face"
    data = base()
    data["clamp"][0].update(face="bottom", x_min=0.1, x_max=2.4)  # nodes at 0, 2.5, 5, ...
    assert refused(data).key == "clamp[0].face"
    data["clamp"][0]["x_max"] = 2.5
    assert parse_config(data).motions[0].x_range == (0.1, 2.5)


def test_split_layer_boundaries_have_two_node_sets():
    data = tomllib.loads(TCB_LW.read_text())  # interface 2 (layers 0 | 1) delaminates
    data["output"]["displacement_face"] = "top_layer0&bottom_layer1"
    assert refused(data).key == "output.displacement_face"
    data["output"]["displacement_face"] = "top_layer1&bottom_layer2"  # interface 4: shared
    assert parse_config(data).probe.displacement_face == "top_layer1&bottom_layer2"


def test_a_clamp_and_a_motion_on_one_dof_are_refused_naming_both():
    data = base()
    data["clamp"].append({"face": "x1&top"})  # the pulled end x1 moves in z
    error = refused(data)
    assert error.key == "prescribed[0].face" and "clamp[1].face" in error.problem
    # two zero motions on shared nodes agree: fine
    data = base()
    data["prescribed"].append(
        {"face": "x0", "component": "z", "displacement": 0.0, "rise_time": 1e-4}
    )
    assert len(parse_config(data).motions) == 5


@pytest.mark.parametrize(
    ("section", "entry", "key"),
    [
        ("matrix_strength", {"plies": [1], "factor": 0.9, "x_min": 15.0, "x_max": 5.0}, "x_max"),
        ("matrix_strength", {"plies": [1], "factor": 0.9, "x_min": 21.0}, "x_min"),  # no cell
        ("matrix_strength", {"plies": [1], "factor": 0.9, "x_min": 5.1, "x_max": 5.2}, "x_max"),
        (
            "refinement",
            {"time": 0.0, "interfaces": [4], "kind": "weak", "x_min": 3.0, "x_max": 2.0},
            "x_max",
        ),
        ("clamp", {"face": "bottom", "x_min": 5.0, "x_max": 2.0}, "x_max"),
    ],
)
def test_swapped_or_empty_ranges_are_refused(section, entry, key):
    data = tomllib.loads(FOUR_POINT.read_text())
    data[section] = [*data.get(section, []), entry]
    error = refused(data)
    assert error.key == f"{section}[{len(data[section]) - 1}].{key}", str(error)


UNIT_SLIPS = [
    ("materials.prototype.rho", 1600.0, "1.6e-09 (kg/m^3 -> tonne/mm^3)"),
    ("materials.prototype.rho", 1.6, "1.6e-09 (g/cm^3 -> tonne/mm^3)"),
    ("materials.prototype.E1", 1.0e11, "100000 (Pa -> MPa)"),
    ("materials.prototype.G12", 5.0, "5000 (GPa -> MPa)"),
]


@pytest.mark.parametrize(("path", "value", "suggestion"), UNIT_SLIPS)
def test_unit_slips_are_refused_with_the_likely_value(path, value, suggestion):
    error = refused(mutate(path, value))
    assert error.key == path
    assert "implausible" in error.problem and f"did you mean {suggestion}?" in error.problem
    data = mutate(path, value)
    data["model"]["check_units"] = False  # the documented switch for unusual materials
    parse_config(data)


def test_unit_slips_of_strengths_and_fracture_energies():
    data = tomllib.loads(FOUR_POINT.read_text())
    data["materials"]["im7_8552"]["failure"]["YT"] = 62.3e6
    error = refused(data)
    assert error.key == "materials.im7_8552.failure.YT" and "62.3 (Pa -> MPa)" in error.problem
    data = tomllib.loads(FOUR_POINT.read_text())
    data["cohesive"]["GIc"] = 277.0
    error = refused(data)
    assert error.key == "cohesive.GIc" and "0.277 (J/m^2 -> N/mm)" in error.problem
    data = tomllib.loads(FOUR_POINT.read_text())
    data["cohesive"]["K_n"] = 1e14
    assert "100000 (N/m^3 -> N/mm^3)" in refused(data).problem


def test_max_steps_and_energy_error_limit_are_passed_through():
    from fenics_adaptive.settings.solver import SolverSettings

    config = parse_config(base())
    defaults = SolverSettings(end_time=1.0, output_interval=1.0)
    assert config.solver.max_steps == defaults.max_steps
    assert config.solver.energy_error_limit == defaults.energy_error_limit
    data = base()
    data["solver"].update(max_steps=1e6, energy_error_limit=0.2)
    config = parse_config(data)
    assert config.solver.max_steps == 10**6 and config.solver.energy_error_limit == 0.2
    for name, value in (("max_steps", 0), ("energy_error_limit", 0.0), ("max_steps", 2.5)):
        assert refused(mutate(f"solver.{name}", value)).key == f"solver.{name}"


def test_step_count_is_the_runs_and_refused_above_max_steps():
    from fenics_adaptive.settings.config import check_step_count, output_counts, step_count

    assert step_count(2e-4, 1e-7) == 2000  # 2e-4 / 1e-7 is 2000.0000000000002 in floats
    assert step_count(2e-4, 1.1289e-7) == 1772
    assert step_count(1e300, 1e-307) == math.inf
    solver = replace(parse_config(base()).solver, max_steps=2000)
    assert check_step_count(solver, 1e-7) == 2000
    with pytest.raises(InputError) as caught:
        check_step_count(solver, 0.99e-7)
    assert caught.value.key == "solver.max_steps" and "2021 steps" in caught.value.problem
    assert output_counts(solver, 1e-7) == (21, 3)  # every 1e-5 s, fields every 1e-4 s
    with pytest.raises(InputError, match=r"take 1e\+307 steps of 1e-07 s"):
        check_step_count(replace(solver, end_time=1e300), 1e-7)
    with pytest.raises(InputError, match=r"take 2e\+303 steps of 1e-307 s"):
        check_step_count(solver, 1e-307)
    with pytest.raises(InputError, match="over 1e308 steps of 1e-307 s"):
        check_step_count(replace(solver, end_time=1e300), 1e-307)


def test_non_utf8_and_bad_toml_name_the_file_once(tmp_path):
    bad = tmp_path / "case.toml"
    bad.write_bytes(SMALL.read_bytes().replace(b"prototype", b"prot\xf6type", 1))
    with pytest.raises(InputError) as caught:
        load_config(bad)
    assert caught.value.key == str(bad) and "not UTF-8" in caught.value.problem
    assert str(bad) not in caught.value.problem


# ------------------------------------------------------------------ the schema and the parser
def every_config() -> list[tuple[str, dict]]:
    """The demos' and tests' configs (and the demos' variants), plus the keys none of them
    uses, each in a config of its own."""
    from fenics_adaptive.analysis.studies import STUDIES

    root = Path(__file__).parent.parent
    configs = [
        (p.name, tomllib.loads(p.read_text()))
        for p in sorted((root / "tests" / "data").glob("*.toml"))
    ]
    for name, study in STUDIES.items():
        text = (root / "demos" / f"{name}.toml").read_text()
        configs += [
            (f"{name}:{run}", study.make_variant(tomllib.loads(text), run)) for run in study.runs
        ]
    plies = base()
    for key in ("material", "angles", "ply_thickness"):
        del plies["laminate"][key]
    plies["laminate"]["plies"] = [
        {"material": "prototype", "angle": a, "thickness": 0.5} for a in (0, 90, 90, 0)
    ]
    plies["clamp"] = [{"face": "x0", "x": 0.0}, {"face": "bottom", "x_min": 5.0, "x_max": 10.0}]
    plies["prescribed"][0].update(x_min=20.0, x_max=20.0)
    del plies["prescribed"][0]["rise_time"], plies["prescribed"][0]["profile"]
    plies["prescribed"][0]["curve"] = [[0.0, 0.0], [1e-4, 1.0]]
    plies["solver"].update(max_steps=10**7, energy_error_limit=0.1)
    plies["load"] = [{"face": "top", "force": [0.0, 0.0, -1.0], "rise_time": 1e-4}]
    configs.append(("plies", plies))
    tcb = tomllib.loads((root / "tests" / "data" / "tcb_adaptive.toml").read_text())
    tcb["interfaces"]["initial"] = "none"
    tcb["refinement"] = [{"time": 1e-5, "interfaces": [2], "kind": "strong"}]
    tcb["delamination"] = [
        {"interface": 6, "x_min": 8.0, "x_max": 10.0, "y_min": 0.0, "y_max": 0.5}
    ]
    configs.append(("refinement", tcb))
    layerwise = tomllib.loads((root / "tests" / "data" / "tcb_layerwise.toml").read_text())
    layerwise["solver"].update(mass_scaling="selective", mass_scaling_step=5e-8)
    configs.append(("selective mass scaling", layerwise))
    bodies = tomllib.loads((root / "tests" / "data" / "three_point_bending.toml").read_text())
    bodies["rigid"][2].update(displacement=[0.0, 0.0, -0.5], curve=[[0.0, 0.0], [4e-3, 1.0]])
    for key in ("velocity", "rise_time", "profile"):
        del bodies["rigid"][2][key]
    bodies["rigid"].append(
        {
            "name": "ball",
            "shape": "sphere",
            "radius": 1.0,
            "position": [30.0, 2.5, 6.0],
            "face": "top",
            "motion": "free",
            "mass": 1e-6,
            "velocity": [0.0, 0.0, -100.0],
            "penalty": 1.0e4,
        }
    )
    configs.append(("rigid bodies", bodies))
    for name in ("fracture_tests_enf", "fracture_tests_mmb"):
        configs.append((name, tomllib.loads((root / "demos" / f"{name}.toml").read_text())))
    lever = copy.deepcopy(configs[-1][1])
    for key in ("velocity", "rise_time", "profile"):
        del lever["lever"][key]
    lever["lever"].update(displacement=-5.0, curve=[[0.0, 0.0], [1e-2, 1.0]])
    configs.append(("lever by displacement", lever))
    shells = {
        "panel": {"kind": "panel", "radius": 30.0, "length": 20.0, "angle": 60.0, "start": 0.0,
                  "n_around": 4, "n_along": 2, "reference": "bottom", "orientation": "hoop"},
        "hat": {"kind": "hat", "length": 40.0, "width": 20.0, "height": 10.0, "flange": 5.0,
                "size": 5.0, "n_along": 4, "direction": [1.0, 0.0, 0.0]},
        "plate_with_hole": {"kind": "plate_with_hole", "length": 40.0, "width": 20.0,
                            "hole_radius": 4.0, "size": 4.0},
        "file": {"kind": "file", "file": str(root / "tests" / "data" / "shell_strip.geo"),
                 "surface": "skin", "normal": [0.0, 0.0, 1.0]},
    }  # fmt: skip
    for kind, mesh in shells.items():
        shell = copy.deepcopy(base())
        shell["mesh"] = mesh
        side = "left" if kind == "file" else "x0"
        shell["clamp"] = [{"face": side}]
        for table in ("prescribed", "load"):
            shell.pop(table, None)
        shell["output"] = {"interval": shell["solver"]["end_time"], "displacement_face": "top",
                           "reaction_face": side, "component": "z"}  # fmt: skip
        configs.append((f"shell {kind}", shell))
    return configs


def test_every_key_the_parser_reads_is_in_the_schema_and_back():
    from fenics_adaptive.settings.schema import all_keys

    seen: set[str] = set()
    for name, data in every_config():
        try:
            parse_config(data, seen=seen)
        except InputError as error:
            pytest.fail(f"{name}: {error}")
    assert seen == all_keys(), (sorted(all_keys() - seen), sorted(seen - all_keys()))


def test_unknown_keys_are_refused_with_the_schema_keys():
    error = refused(mutate("solver.dt", 1e-8))
    assert error.key == "solver.dt" and "allowed: end_time, safety_factor" in error.problem
    error = refused({**base(), "solvers": {}})
    assert error.key == "solvers" and "unknown section" in error.problem


def test_schema_defaults_are_the_dataclass_defaults():
    from fenics_adaptive.settings.adaptivity import IndicatorSettings, Stabilisation
    from fenics_adaptive.settings.schema import section
    from fenics_adaptive.settings.solver import SolverSettings

    solver = SolverSettings(end_time=1.0, output_interval=1.0)
    for name in ("safety_factor", "mass_damping", "max_steps", "energy_error_limit"):
        assert section("solver").key(name).default == getattr(solver, name), name
    indicators = IndicatorSettings(interval=1.0)
    for name in ("spread", "front_distance", "matrix_damage"):
        assert section("indicators").key(name).default == getattr(indicators, name), name
    for name in ("damping", "damping_window", "release_window", "equilibrate"):
        assert section("stabilisation").key(name).default == getattr(Stabilisation(), name)


def test_reference_markdown_has_a_table_per_section_with_every_key():
    from fenics_adaptive.settings.schema import SECTIONS, reference_markdown

    text = reference_markdown()
    for s in SECTIONS:
        heading = f"## `[[{s.name}]]`" if s.array else f"## `[{s.name}]`"
        assert heading in text, heading
        table = text.split(heading, 1)[1].split("\n## ", 1)[0]
        rows = [line for line in table.splitlines() if line.startswith("| `")]
        assert [row.split("`")[1] for row in rows] == list(s.names)
    assert "`max_steps` | integer | - | 1e9 |" in text


def test_schema_module_imports_neither_dolfinx_nor_numba():
    import subprocess
    import sys

    code = (
        "import sys; from fenics_adaptive.settings.schema import reference_markdown; "
        "reference_markdown(); print(sorted(m for m in sys.modules if m.split('.')[0] in "
        "('dolfinx', 'numba', 'ufl')))"
    )
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip() == "[]"


@pytest.mark.slow
def test_face_node_sets_of_the_parser_are_the_meshs():
    """The parser's node sets of faces (which it checks before meshing) against the nodes the
    mesh really has on them, for every face and pair of faces of a layerwise model with split
    (delaminating) and shared layer boundaries, with and without an x range."""
    import itertools

    from fenics_adaptive.model.loading import face_nodes
    from fenics_adaptive.settings.config import _nodes_box, _split_boundaries
    from fenics_adaptive.simulation import build_structure

    data = tomllib.loads(TCB_LW.read_text())
    data["mesh"].update(nx=4, ny=2)
    config = parse_config(data)
    split = _split_boundaries(config.kind, config.mesh, config.interfaces)
    assert split == (True, False, True)
    model = build_structure(config).base
    faces = config.face_names
    for face in [*faces, *(f"{a}&{b}" for a, b in itertools.combinations(faces, 2))]:
        for x_range in (None, (2.5, 5.0), (0.1, 2.4)):
            box = _nodes_box(face, x_range, config.mesh, split)
            count = (
                0
                if box is None
                else ((box[0][1] - box[0][0] + 1) * (box[1][1] - box[1][0] + 1) * len(box[2]))
            )
            assert count == len(face_nodes(model, face, x_range)), (face, x_range)


def test_too_many_plies_and_a_motion_against_a_symmetry_plane_are_refused():
    error = refused(mutate("laminate.angles", [0.0] * 257))
    assert error.key == "laminate.angles" and "257 plies" in error.problem
    data = tomllib.loads(TCB_LW.read_text())  # symmetry at interface 4: top_layer1, u_z = 0
    data["prescribed"][0]["face"] = "x1&top_layer1"
    error = refused(data)
    assert error.key == "interfaces.symmetry" and "prescribed[0].face" in error.problem


def test_odd_key_names_keep_the_message_on_one_line():
    data = base()
    data["solver"]["end\ntime"] = 1.0
    assert refused(data).key == "solver.'end\\ntime'"
    data = base()
    data["materials"]["a\nb"] = data["materials"]["prototype"]
    assert refused(data).key == "materials.'a\\nb'"
    assert refused({**base(), "x\ny": {}}).key == "'x\\ny'"


def test_resolution_refuses_what_the_parser_would_with_the_key():
    """The loads' resolution on the mesh (the backstop for motions made outside the parser,
    such as a layerwise model's symmetry planes) names the config keys too."""
    from fenics_adaptive.settings.loads import Amplitude, PrescribedMotion
    from fenics_adaptive.simulation import build_structure

    config = parse_config(base())
    pull = PrescribedMotion("x1&top", "z", "displacement", 1.0, Amplitude.constant(1.0), key="k1")
    with pytest.raises(InputError) as caught:
        build_structure(replace(config, motions=(*config.motions, pull)))
    assert caught.value.key == "k1" and "prescribed[0]" not in caught.value.key
    assert "both prescribe component z" in caught.value.problem
    nowhere = replace(pull, face="x0&x1", key="k2")
    with pytest.raises(InputError) as caught:
        build_structure(replace(config, motions=(*config.motions[:3], nowhere)))
    assert caught.value.key == "k2" and "no nodes" in caught.value.problem
