"""The tube impact demo, short version (the first 30 µs: the plate pushes the end in and its
fibres start to break): the three runs and their files, the plate slowed by the tube, the
energy balances kept, the adaptive and layerwise plates' forces alike."""

import json

import pytest

# The demo runs three models of a 2448-cell tube with ply damage (tens of seconds).
pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def results(tmp_path_factory):
    from fenics_adaptive.demos import tube_impact

    out = tmp_path_factory.mktemp("tube_impact")
    tube_impact.main(["--out", str(out), "--end-time", "3.0e-5"])
    return out, json.loads((out / "summary.json").read_text())["runs"]


def test_the_demo_writes_its_runs_and_its_figure(results):
    out, runs = results
    assert set(runs) == {"esl", "adaptive", "layerwise"}
    assert (out / "tube_impact.png").is_file()
    for name in runs:
        assert (out / name / "history.csv").is_file()


def test_the_plate_pushes_the_end_in_and_gives_its_energy_to_the_tube(results):
    """30 µs at 10 m/s less what the tube slows it: 0.25-0.3 mm of travel; the plate's lost
    kinetic energy is in the tube, the energy balance closed to 1 % of it."""
    _, runs = results
    for run in runs.values():
        assert 0.2 < run["largest_travel_mm"] < 0.3
        assert run["energy_given_mJ"] > 500.0  # (about 0.9 J by then)
        assert run["max_energy_balance_error_mJ"] <= 0.01 * run["energy_given_mJ"]
    assert runs["adaptive"]["peak_force_N"] == pytest.approx(
        runs["layerwise"]["peak_force_N"], rel=0.05
    )
