"""The TCB demo, short version (20 mm beam): the propagation branch against beam-theory LEFM,
and the adaptive run against the layerwise reference."""

import tomllib
from pathlib import Path

import numpy as np
import pytest

from fenics_adaptive.analysis.lefm import lefm_comparison
from fenics_adaptive.analysis.studies import tcb_quick, tcb_variant
from fenics_adaptive.settings.config import parse_config
from fenics_adaptive.simulation import RefinementHook, build_structure
from fenics_adaptive.solver import explicit

# Each test runs a shortened demo to its end (seconds to minutes).
pytestmark = pytest.mark.slow

ROOT = Path(__file__).parents[1]


def run(name: str):
    base = tcb_quick(tomllib.loads((ROOT / "demos" / "tcb.toml").read_text()))
    config = parse_config(tcb_variant(base, name))
    structure = build_structure(config)
    stats = explicit.run(structure, config.solver, config.probe, refiner=RefinementHook(config))
    history = {
        name: [getattr(r, name) for r in stats.history]
        for name in (
            "displacement",
            "reaction_force",
            "delaminated_area",
            "dissipated_energy",
            "external_work",
            "energy_balance",
            "state_energy_balance",
        )
    }
    return config, history


@pytest.fixture(scope="module")
def reference():
    return run("reference")


def test_propagation_follows_beam_theory_lefm(reference):
    """Once the crack is longer than 5 arm thicknesses the force stays within -10/+12 % of
    the LEFM branch P = K^1.5 / sqrt(3 E I delta). Measured (mean, min, max) 1.075, 1.039,
    1.114 with the bending stiffness integrated exactly and the laminate's shear correction
    on the two-ply layers (the defaults since issue 14; 1.071, 1.041, 1.095 without the
    correction); mean 1.00 with one point per ply, whose two-ply layers bent 25 % too easily
    (P ~ (E I)^(1/4): 0.75^(1/4) = 0.93), so that agreement was partly an integration error.
    What makes the rest is not yet measured."""
    config, history = reference
    result = lefm_comparison(config, history)
    assert result["points"] >= 20
    assert result["crack_length_range_mm"][1] > 3.5  # the crack did run
    assert 0.9 <= result["force_over_lefm_min"] and result["force_over_lefm_max"] <= 1.12
    assert 0.97 <= result["force_over_lefm_mean"] <= 1.09
    assert result["root_rotation_chi"] == pytest.approx(1.6, abs=0.05)


def test_adaptive_joins_the_reference_after_refinement(reference):
    _, ref = reference
    _, adaptive = run("adaptive")
    F, F_ref = np.array(adaptive["reaction_force"]), np.array(ref["reaction_force"])
    delta = np.array(adaptive["displacement"])
    joined = delta > 0.01
    assert np.abs(F - F_ref)[joined].max() < 0.06 * np.abs(F_ref).max()
    assert adaptive["dissipated_energy"][-1] == pytest.approx(
        ref["dissipated_energy"][-1], rel=0.01
    )
    assert adaptive["delaminated_area"][-1] == pytest.approx(ref["delaminated_area"][-1], abs=0.25)


@pytest.mark.parametrize("name", ["reference", "adaptive"])
def test_state_energy_balance_agrees_with_the_work_balance(reference, name):
    """The balance from the states (kinetic + strain + stored cohesive + the cohesive law's own
    dissipation increments) equals the one from the work of the internal forces: measured
    2.4e-8 of the work for the adaptive run, 3.7e-9 for the reference (release-day values)."""
    history = reference[1] if name == "reference" else run(name)[1]
    work = max(abs(w) for w in history["external_work"])
    state = np.array(history["state_energy_balance"])
    assert np.abs(state - np.array(history["energy_balance"])).max() < 1e-6 * work
    assert np.abs(state).max() < 1e-3 * work
