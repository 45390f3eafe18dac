"""Insert films ([[delamination]]): a region of an interface delaminated at t = 0.

- the config refuses films it cannot build, naming the key;
- a layerwise model and an adaptive one start with the same failed cohesive elements, the
  film's cells (by centroid), and report them in ``delaminated_area`` but not in
  ``crack_growth_area``;
- the triple cantilever beam with a film at both cracks: the layerwise model and the adaptive
  one refined from the start give the same history (two independent assemblies), the crack
  grows from the film's front with no energy dissipated by the film itself;
- an adaptive model refined only where the film is, then ahead of it, restarts from a
  checkpoint to the uninterrupted history.
"""

import tomllib
from pathlib import Path

import numpy as np
import pytest
from helpers import assert_restarted_history, run_quietly

from fenics_adaptive.errors import InputError
from fenics_adaptive.io.output import read_history
from fenics_adaptive.model.diagnostics import delaminated_areas
from fenics_adaptive.settings.config import parse_config
from fenics_adaptive.settings.kinds import InterfaceState
from fenics_adaptive.simulation import build_structure
from fenics_adaptive.solver import explicit

DATA = Path(__file__).parent / "data"
LENGTH, WIDTH = 10.0, 0.5  # mm, the TCB files' beam


def tcb(kind: str, film: float = 3.0, **solver) -> dict:
    """The TCB beam (layerwise, or adaptive refined strongly from the start) with an insert
    film ``film`` mm long at the loaded end of both delaminating interfaces."""
    data = tomllib.loads((DATA / f"tcb_{kind}.toml").read_text())
    data["delamination"] = [
        {"interface": i, "x_min": LENGTH - film, "x_max": LENGTH} for i in (2, 6)
    ]
    data["solver"].update(solver)
    return data


@pytest.mark.parametrize(
    ("change", "key", "words"),
    [
        (
            lambda d: d["delamination"][0].update(interface=4),
            "delamination[0].interface",
            "does not delaminate",
        ),
        (lambda d: d["delamination"][0].update(x_max=6.0), "delamination[0].x_max", "> x_min"),
        (
            lambda d: d["delamination"][0].update(x_min=9.8, x_max=10.0),
            "delamination[0].x_max",
            "no cell centroid",
        ),
        (
            lambda d: d["delamination"][0].update(x_min=-10.0),
            "delamination[0].x_min",
            "beyond the mesh (x from 0 to 10 mm)",
        ),
        (
            lambda d: d["delamination"][0].update(y_min=0.0, y_max=0.7),
            "delamination[0].y_max",
            "beyond the mesh (y from 0 to 0.5 mm)",
        ),
        (
            lambda d: d["delamination"][0].update(y_min=0.3, y_max=0.4),
            "delamination[0].y_max",
            "no cell centroid along y",
        ),
        (lambda d: d["delamination"][0].pop("x_min"), "delamination[0].x_min", "missing"),
        (lambda d: d["delamination"][0].update(depth=1.0), "delamination[0].depth", "unknown"),
    ],
)
def test_the_config_refuses_a_film_it_cannot_build(change, key, words):
    data = tcb("layerwise")
    data["delamination"][0]["x_min"] = 6.0
    change(data)
    with pytest.raises(InputError) as error:
        parse_config(data)
    assert error.value.key == key and words in str(error.value), str(error.value)


def test_an_esl_model_has_no_film():
    data = tcb("adaptive")
    data["model"]["kind"] = "esl"
    del data["interfaces"], data["cohesive"]
    with pytest.raises(InputError, match="ESL model has no interfaces") as error:
        parse_config(data)
    assert error.value.key == "delamination[0].interface"


@pytest.mark.parametrize("kind", ["layerwise", "adaptive"])
def test_both_models_start_with_the_film_s_cells_failed(kind):
    """Films of 3 mm on interface 6 and of 1.2 mm over half the width on interface 2 (cells of
    0.5 mm x 0.25 mm): the cells whose centroid lies in each, failed, counted as delaminated
    but not grown. The adaptive model refines only there (initial = "none")."""
    data = tcb(kind)
    data["mesh"]["ny"] = 2
    data["delamination"] = [
        {"interface": 6, "x_min": 7.0, "x_max": 10.0},
        {"interface": 2, "x_min": 8.8, "x_max": 10.0, "y_min": 0.0, "y_max": 0.25},
    ]
    if kind == "adaptive":
        data["interfaces"]["initial"] = "none"
    structure = build_structure(parse_config(data))
    cohesive = structure.cohesive
    films = {6: 6 * 2, 2: 2 * 1}  # cells along x (centroids 7.25 .. 9.75; 9.25, 9.75) x across
    cell_area = 0.5 * 0.25
    total, grown = delaminated_areas(structure)
    assert total == pytest.approx(sum(films.values()) * cell_area, rel=1e-12)
    assert grown == 0.0
    for interface, count in films.items():
        at = cohesive.interface == interface
        assert (cohesive.failed() & at).sum() == (cohesive.inserted() & at).sum() == count
    if kind == "adaptive":  # strong exactly under the films, nothing else refined
        assert len(cohesive) == sum(films.values())
        assert (structure.interface_state == InterfaceState.STRONG).sum() == len(cohesive)
        assert (structure.interface_state == InterfaceState.WEAK).sum() == 0
    assert cohesive.history.sum() == 0.0  # a film was never bonded: nothing dissipated


@pytest.fixture(scope="module")
def tcb_with_films():
    runs = {}
    for kind in ("layerwise", "adaptive"):
        config = parse_config(tcb(kind, end_time=4.0e-4))
        structure = build_structure(config)
        runs[kind] = structure, explicit.run(structure, config.solver, config.probe)
    return runs


def column(stats, name: str) -> np.ndarray:
    return np.array([getattr(row, name) for row in stats.history])


def test_a_film_gives_the_same_history_in_both_models(tcb_with_films):
    (_, lw), (_, adaptive) = tcb_with_films["layerwise"], tcb_with_films["adaptive"]
    for name in ("reaction_force", "internal_energy", "cohesive_dissipation", "crack_growth_area"):
        a, b = column(adaptive, name), column(lw, name)
        assert np.abs(a - b).max() <= 1e-8 * np.abs(b).max(), name


def test_the_crack_grows_from_the_film_s_front(tcb_with_films):
    structure, stats = tcb_with_films["layerwise"]
    film_area = 2 * 3.0 * WIDTH
    total, grown = column(stats, "delaminated_area"), column(stats, "crack_growth_area")
    np.testing.assert_allclose(total - grown, film_area, rtol=1e-12)
    assert grown[-1] >= 2 * 2 * 0.5 * WIDTH  # at least two cells grown at each crack
    cohesive = structure.cohesive
    X = structure.gather(cohesive.nodes[:, :4], "X").mean(axis=1)
    # the grown crack is contiguous with the film: every failed cell lies beyond the front
    # less the grown length, at each interface
    for interface in (2, 6):
        at = (cohesive.interface == interface) & cohesive.failed() & ~cohesive.inserted()
        grown_length = at.sum() * 0.5
        assert X[at, 0].min() > LENGTH - 3.0 - grown_length
    # the film dissipates nothing: what the cohesive law dissipated lies between GIc x the
    # grown area and GIIc x the damaged area outside the film
    law = parse_config(tcb("layerwise")).cohesive
    damaged = (cohesive.damage[cohesive.damage_row].max(axis=1) > 0) & ~cohesive.inserted()
    dissipated = column(stats, "cohesive_dissipation")[-1]
    assert law.GIc * grown[-1] <= dissipated <= law.GIIc * damaged.sum() * 0.5 * WIDTH
    # the film's faces have come apart (and carry no traction: the kinematic test in
    # test_cohesive_model.py checks that and their contact)
    u = structure.gather(cohesive.nodes, "u")
    film_opening = (u[:, 4:, 2] - u[:, :4, 2])[cohesive.inserted()].mean(axis=1)
    assert film_opening.min() > 0.0


@pytest.mark.slow
def test_an_adaptive_film_restarts_to_the_uninterrupted_history(tmp_path):
    def data(end_time: float, every: int | None = None) -> dict:
        d = tcb("adaptive", end_time=end_time)
        d["interfaces"]["initial"] = "none"
        # ahead of the film, the cells refine at 1e-4 s (before the checkpoint)
        d["refinement"] = [{"interfaces": [2, 6], "kind": "strong", "time": 1.0e-4, "x_min": 5.0}]
        d["output"].pop("fields_interval", None)
        if every is not None:
            d["output"]["checkpoint_interval"] = every
        return d

    run_quietly(data(4.0e-4), tmp_path / "whole")
    run_quietly(data(2.0e-4, every=1000), tmp_path / "split")
    summary = run_quietly(data(4.0e-4), tmp_path / "split", restart=tmp_path / "split")
    assert_restarted_history(tmp_path / "split", tmp_path / "whole")
    whole = read_history(tmp_path / "whole" / "history.csv")
    assert whole["crack_growth_area"][-1] > 0.0
    assert summary["cohesive_elements_at_end"] == 2 * 10  # the cells at x > 5 mm


@pytest.mark.parametrize(("nx", "warned"), [(22, True), (45, False)])
def test_a_process_zone_shorter_than_the_cells_is_warned_of(nx, warned):
    """The quick DCB's interface at strengths 100 / 130 MPa: a process zone of 1.03 mm (the
    longer of the modes' E2 Gc / strength^2), warned of under cells of 2.05 mm, not under
    cells of 1 mm; the beam is one cell wide, its 25.4 mm width does not count."""
    from fenics_adaptive.simulation import process_zone_warnings

    data = tomllib.loads(
        (Path(__file__).parent / "data" / "mpi_front_across_ranks.toml").read_text()
    )
    data["cohesive"].update(N=100.0, S=130.0)
    data["mesh"]["nx"] = nx
    warnings = process_zone_warnings(parse_config(data))
    assert bool(warnings) == warned
    if warned:
        (line,) = warnings
        assert "interface(s) 4 (1.03 mm" in line and "cells (2.05 mm)" in line, line
