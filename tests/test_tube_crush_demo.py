"""The tube crush demo, short version (the pole 0.75 mm down): the three runs and their
files, the adaptive run refined under the pole only, the energy balances kept; ESL, blind
to delamination, at least as stiff as the layerwise reference."""

import json
from pathlib import Path

import pytest

# The demo runs three models of a 768-cell tube (tens of seconds).
pytestmark = pytest.mark.slow

ROOT = Path(__file__).parents[1]


@pytest.fixture(scope="module")
def results(tmp_path_factory):
    from fenics_adaptive.demos import tube_crush

    out = tmp_path_factory.mktemp("tube")
    tube_crush.main(["--out", str(out), "--end-time", "1.6e-4"])
    return out, json.loads((out / "summary.json").read_text())["runs"]


def test_the_demo_writes_its_runs_and_its_figure(results):
    out, runs = results
    assert set(runs) == {"esl", "adaptive", "layerwise"}
    assert (out / "tube_crush.png").is_file()
    for name in runs:
        assert (out / name / "history.csv").is_file()
        assert runs[name]["depth_mm"] == pytest.approx(0.7, abs=0.1)


def test_adaptive_refines_under_the_pole_and_layerwise_delaminates(results):
    _, runs = results
    assert 0.0 < runs["adaptive"]["refined_cell_fraction"] < 0.3
    assert runs["layerwise"]["delaminated_area_mm2"] > 0.0
    assert runs["esl"]["peak_force_N"] >= runs["layerwise"]["peak_force_N"]
    for run in runs.values():
        assert run["max_energy_balance_error_mJ"] <= 0.01 * run["energy_absorbed_mJ"]
