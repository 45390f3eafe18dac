"""Config parsing: a good config parses into the objects it describes; every malformed one is
refused with one line that names the key."""

import tomllib
from pathlib import Path

import pytest

from fenics_adaptive.config import load_config, parse_config
from fenics_adaptive.errors import InputError

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
    with pytest.raises(InputError, match="points_per_ply"):
        parse_config(data)
    data["model"]["points_per_ply"] = 2
    assert parse_config(data).points_per_ply == 2


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
