"""The plate impact demo, short version (a 20 x 20 mm plate, a 10 g sphere at 5 m/s): the
adaptive run refines only around the impact point, delaminates there, and follows the
layerwise reference's contact force; ESL, blind to delamination, is stiffer. The small plate
loads its interfaces faster than the demo's, so it refines earlier (at 60 % of the strength on
recovered stresses instead of 90 %)."""

import tomllib
from pathlib import Path

import numpy as np
import pytest

from fenics_adaptive.analysis.studies import plate_impact_variant
from fenics_adaptive.runner import execute
from fenics_adaptive.settings.config import parse_config
from fenics_adaptive.settings.kinds import InterfaceState

# Each test runs a shortened demo to its end (seconds to minutes).
pytestmark = pytest.mark.slow

ROOT = Path(__file__).parents[1]


def small_plate(name: str) -> dict:
    base = tomllib.loads((ROOT / "demos" / "plate_impact.toml").read_text())
    base["mesh"].update(length=20.0, width=20.0, nx=20, ny=20)
    base["impactor"].update(mass=1.0e-5, position=[10.0, 10.0, 10.01], velocity=[0.0, 0.0, -5000.0])
    base["indicators"]["interface_stress"] = 0.6
    base["solver"]["end_time"] = 1.2e-4
    return plate_impact_variant(base, name)


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    out = tmp_path_factory.mktemp("impact")
    results = {}
    for name in ("esl", "adaptive", "layerwise"):
        config = parse_config(small_plate(name), source=name)
        summary, structure = execute(config, out / name, show_progress=False, log=None)
        results[name] = (summary, structure)
    return results


def test_adaptive_refines_around_the_impact_point_only(runs):
    summary, structure = runs["adaptive"]
    refined = (structure.interface_state == InterfaceState.STRONG).any(axis=1)
    assert 0.0 < refined.mean() < 0.5
    centres = structure.X_base[structure.bottom_local[refined]].mean(axis=1)
    assert np.abs(centres[:, :2] - 10.0).max() < 8.0  # none at the clamped edges
    assert summary["final"]["dissipated_energy_mJ"] > 0.0  # it delaminated


def test_adaptive_follows_the_layerwise_contact_force(runs):
    peak = {name: runs[name][0]["peak_contact_force_N"] for name in runs}
    # measured +1.7 % (+0.2 % with ties that never let go, +2.4 % with ties as stiff as their
    # cohesive elements where they let go); +2.3 % once the kernels' sums were reordered (the
    # edge-sampled thickness strain of curved cells; this plate is flat: its layerwise peak
    # moved by 3e-15), the refinement's on-off decisions turning round-off into 0.6 %; +3.0 %
    # with the refinements' equilibration (12.5 % of the cells refined against 16 %, 0.45 mJ
    # dissipated against 0.67, the layerwise 0.18: less ringing, fewer fronts started; +1.9 %
    # with a static target instead of the kept accelerations)
    assert peak["adaptive"] == pytest.approx(peak["layerwise"], rel=0.035)
    # measured +2.7 % (+7 % without the shear correction, whose ESL was also too stiff in shear)
    assert peak["esl"] > 1.015 * peak["layerwise"]
    for summary, _ in runs.values():
        assert summary["max_energy_balance_error_relative"] < 0.01
