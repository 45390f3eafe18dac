"""The settings package without the runtime: reading and checking a config loads neither DOLFINx
nor numba (issue 13), and the kinds and states of a config are enums that keep the TOML
strings and the int8 state arrays working."""

import json
import subprocess
import sys
import tomllib
from pathlib import Path

import numpy as np
import pytest

from fenics_adaptive.errors import InputError
from fenics_adaptive.settings.config import parse_config
from fenics_adaptive.settings.kinds import (
    ImpactorShape,
    IndicatorKind,
    InterfaceState,
    Kinematics,
    MixedModeLaw,
    ModelKind,
    MotionKind,
    Refinement,
)
from fenics_adaptive.settings.materials import CohesiveLaw
from fenics_adaptive.settings.schema import section

ROOT = Path(__file__).parent.parent
SMALL = Path(__file__).parent / "data" / "small_beam.toml"
RUNTIME = ("dolfinx", "numba", "ufl", "basix", "petsc4py")
# every run config of the demos (esl_vs_lw.toml is that demo's own table of beams and layups,
# from which it builds its configs) and of the tests
CONFIGS = sorted(
    str(path)
    for path in [*ROOT.glob("demos/*.toml"), *ROOT.glob("tests/data/*.toml")]
    if path.name != "esl_vs_lw.toml"
)

# Reads and checks every config as `fenics-adaptive check` does before it meshes (the step count
# with a step of end_time / 1000, as the mesh would give one), then lists the runtime modules
# that got imported.
CHECK_WITHOUT_RUNTIME = """
import json, sys
from fenics_adaptive.settings import adaptivity, kinds, loads, materials, schema, solver
import fenics_adaptive.settings.config as c

for path in sys.argv[2:]:
    config = c.load_config(path)
    size = c.model_size(config.mesh, config.laminate)
    assert c.estimated_memory(size) > 0 and c.estimated_step_seconds(size) > 0
    time_step = config.solver.time_step or config.solver.end_time / 1000
    c.check_step_count(config.solver, time_step)
    c.output_counts(config.solver, time_step)
runtime = json.loads(sys.argv[1])
print(json.dumps(sorted(m for m in sys.modules if m.split(".")[0] in runtime)))
"""


def test_reading_and_checking_configs_loads_neither_dolfinx_nor_numba():
    assert len(CONFIGS) >= 8  # four demos and the test data
    result = subprocess.run(
        [sys.executable, "-c", CHECK_WITHOUT_RUNTIME, json.dumps(RUNTIME), *CONFIGS],
        capture_output=True,
        text=True,
        cwd=ROOT,
        timeout=120,
    )
    assert result.returncode == 0, result.stderr
    assert json.loads(result.stdout) == []


def test_interface_states_are_the_ints_of_the_state_arrays():
    assert [int(s) for s in InterfaceState] == [0, 1, 2]
    states = np.zeros((2, 3), dtype=np.int8)
    states[0, 1] = InterfaceState.WEAK
    states[1, :] = InterfaceState.STRONG
    assert states.dtype == np.int8 and states[0, 1] == 1 and (states[1] == 2).all()
    assert InterfaceState(int(states[1, 0])) is InterfaceState.STRONG
    assert (states == InterfaceState.NONE).sum() == 2
    assert [s.label for s in InterfaceState] == ["none", "weak", "strong"]
    assert [r.state for r in Refinement] == list(InterfaceState)


@pytest.mark.parametrize(
    "kind, strings",
    [
        (ModelKind, ["esl", "adaptive", "layerwise"]),
        (Refinement, ["none", "weak", "strong"]),
        (Kinematics, ["small", "finite"]),
        (MixedModeLaw, ["bk", "power"]),
        (MotionKind, ["displacement", "velocity"]),
        (ImpactorShape, ["sphere", "cylinder", "plane"]),
    ],
)
def test_string_kinds_equal_their_toml_strings(kind, strings):
    assert list(kind) == strings  # each member == its string, in the order the errors list them
    assert [f"{member}" for member in kind] == strings
    assert ", ".join(kind) == ", ".join(strings)
    assert all(kind(s) == s and kind(s) in strings for s in strings)


def test_a_parsed_config_holds_the_enums():
    data = tomllib.loads(SMALL.read_text())
    config = parse_config(data)
    assert config.kind is ModelKind.ESL and config.kind == "esl"
    assert config.kinematics is Kinematics.SMALL
    assert config.interfaces.initial is Refinement.NONE
    assert {m.kind for m in config.motions} == {MotionKind.DISPLACEMENT}


def test_the_settings_take_plain_strings_and_keep_the_members():
    law = CohesiveLaw(K_n=1e5, K_s=1e5, N=20.0, S=40.0, GIc=0.4, GIIc=1.0, law="bk", exponent=2.0)
    assert law.law is MixedModeLaw.BK
    with pytest.raises(InputError) as raised:
        CohesiveLaw(K_n=1e5, K_s=1e5, N=20.0, S=40.0, GIc=0.4, GIIc=1.0, law="x", exponent=2.0)
    assert str(raised.value) == "cohesive.law: must be one of bk, power (got 'x')"


@pytest.mark.parametrize(
    "section, key, value, message",
    [
        ("model", "kind", "shell", "must be one of esl, adaptive, layerwise (got 'shell')"),
        ("model", "kinematics", "large", "must be one of small, finite (got 'large')"),
        ("model", "kind", "ESL", "must be one of esl, adaptive, layerwise (got 'ESL')"),
    ],
)
def test_a_bad_kind_is_refused_with_the_allowed_values(section, key, value, message):
    data = tomllib.loads(SMALL.read_text())
    data[section][key] = value
    with pytest.raises(InputError) as raised:
        parse_config(data)
    assert raised.value.key == f"{section}.{key}"
    assert raised.value.problem == message


def test_the_indicator_kinds_are_keys_of_the_indicators_section():
    assert {str(kind) for kind in IndicatorKind} <= set(section("indicators").names)


def test_the_schema_choices_are_the_enums():
    assert section("model").key("kind").choices == tuple(ModelKind)
    assert section("interfaces").key("initial").choices == tuple(Refinement)
    assert section("cohesive").key("law").choices == tuple(MixedModeLaw)


def test_the_step_time_estimate_is_the_measured_one_within_a_factor_of_two():
    """``check``'s wall-time estimate against step times measured on this machine (recorded
    with the constants in ``settings.config``): the impact plate's ESL and layerwise runs and a
    90-cell adaptive DCB; ply damage costs per ply, and ranks share the cells."""
    from fenics_adaptive.settings.config import ModelSize, estimated_step_seconds

    measured = [  # (size, cohesive elements, s per step)
        (ModelSize(2500, 5202, 16, 1), 0, 1.11e-3),
        (ModelSize(10000, 13005, 16, 4), 7500, 9.9e-3),
        (ModelSize(90, 364, 16, 1), 50, 2.47e-4),
    ]
    for size, cohesive, seconds in measured:
        estimate = estimated_step_seconds(size, 1, False, cohesive)
        assert 0.5 < estimate / seconds < 2.0, size
    size = measured[0][0]
    assert estimated_step_seconds(size, 1, True) > 10 * estimated_step_seconds(size)
    assert estimated_step_seconds(size, 2) < 0.6 * estimated_step_seconds(size)
