"""The stable step of the deformed cells under finite kinematics (issue 18 item 5).

A block of [0/90]2s plies on the ground is crushed through its thickness by 30 %: at every
history row the solver takes the step of the deformed cells (L_e = volume / largest face area
at X + u, over the plies' fastest wave speed), here recomputed by a separate path (each
hexahedron split into six tetrahedra, each face's area from its diagonals: exact for flat
faces, within 1e-4 for the slightly warped ones the crush leaves); a small-strain run
keeps its reference step, and a forced step the crushed cells cannot carry stops the run.
Units: N, mm, s, tonne.
"""

import tomllib
from pathlib import Path

import numpy as np
import pytest
from helpers import assert_restarted_history, run_quietly
from mpi4py import MPI

from fenics_adaptive.settings.config import parse_config
from fenics_adaptive.simulation import Simulation
from fenics_adaptive.solver.guards import Diverged

DATA = Path(__file__).parent / "data"
CRUSH = 0.6  # mm of the 2 mm thickness
# DOLFINx numbers a hexahedron's vertices lexicographically; these tables go round each face
CYCLIC = [0, 1, 3, 2, 4, 5, 7, 6]
# the six tetrahedra of a hexahedron (vertices 0-3 bottom, 4-7 top, counter-clockwise)
TETRAHEDRA = ((0, 1, 2, 6), (0, 2, 3, 6), (0, 3, 7, 6), (0, 7, 4, 6), (0, 4, 5, 6), (0, 5, 1, 6))
FACES = ((0, 1, 2, 3), (4, 5, 6, 7), (0, 1, 5, 4), (1, 2, 6, 5), (2, 3, 7, 6), (3, 0, 4, 7))


def crushed_block(kinematics: str = "finite", rise_time: float = 3.0e-4, damping: float = 5.0e4):
    data = tomllib.loads((DATA / "small_beam.toml").read_text())
    data["model"]["kinematics"] = kinematics
    data["mesh"].update(nx=4, ny=1)  # 5 x 2 x 2 mm cells: the thickness sets L_e
    data["clamp"] = [{"face": "bottom"}]
    data["prescribed"] = [
        {"face": "top", "component": "z", "displacement": -CRUSH, "rise_time": rise_time,
         "profile": "smooth"}
    ]  # fmt: skip
    data["solver"].update(end_time=rise_time + 2.0e-5, mass_damping=damping)
    data["output"].update(interval=2.0e-5, displacement_face="top", reaction_face="bottom")
    data["output"].pop("fields_interval", None)
    return data


def smallest_length(x: np.ndarray) -> float:
    """min over hexahedra x (n, 8, 3) of volume / largest face area, by tetrahedra and
    diagonals (not ``element.timestep``'s quadrature)."""
    x = x[:, CYCLIC]
    volume = sum(
        np.abs(
            np.einsum("ij,ij->i", x[:, b] - x[:, a], np.cross(x[:, c] - x[:, a], x[:, d] - x[:, a]))
        )
        / 6.0
        for a, b, c, d in TETRAHEDRA
    )
    areas = np.stack(
        [
            0.5 * np.linalg.norm(np.cross(x[:, c] - x[:, a], x[:, d] - x[:, b]), axis=1)
            for a, b, c, d in FACES
        ],
        axis=1,
    )
    return float((volume / areas.max(axis=1)).min())


def run(data: dict) -> Simulation:
    simulation = Simulation(parse_config(data), comm=MPI.COMM_WORLD)
    simulation.start()
    while simulation.step():
        pass
    return simulation


def test_the_step_follows_the_crushed_cells():
    simulation = run(crushed_block())
    structure, solver = simulation.structure, simulation.solver
    x = structure.cell_vertices() + structure.gather(
        structure.base.V.dofmap.list[: structure.base.n_owned_cells], "u"
    )
    speed = structure.base.cell_wave_speeds().max()
    expected = simulation.config.solver.safety_factor * smallest_length(x) / speed
    assert solver.now.dt == pytest.approx(expected, rel=1e-4)
    steps = [row.time_step for row in solver.stats.history]
    assert steps[-1] == pytest.approx(0.7 * steps[0], rel=0.03)  # the thickness 2 -> 1.4 mm
    assert np.all(np.diff(steps) <= 0.0)


def test_a_change_of_step_keeps_the_energy_balance_at_round_off():
    """The scheme's kinetic measure at t_n depends on the next step: each change of step
    books its jump (without: 1.2e-5 mJ of drift in this undamped crush, 4e-10 of the work)."""
    history = run(crushed_block(rise_time=1.0e-4, damping=0.0)).solver.stats.history
    assert history[-1].time_step < 0.7 * history[0].time_step
    balance = np.array([r.energy_balance for r in history])
    assert np.abs(balance - balance[0]).max() < 1e-13 * history[-1].external_work


def test_a_run_resumed_where_the_step_shrinks_repeats_the_whole_run(tmp_path):
    """A checkpoint on a history row is written before the step follows the cells there: the
    resumed run shrinks it the same way."""
    run_quietly(crushed_block(), tmp_path / "whole")
    first = crushed_block()
    first["solver"]["end_time"] = 1.6e-4  # a history row
    first["output"]["checkpoint_interval"] = 10_000
    run_quietly(first, tmp_path / "split")
    run_quietly(crushed_block(), tmp_path / "split", restart=tmp_path / "split")
    assert_restarted_history(tmp_path / "split", tmp_path / "whole", atol=1e-12)


def test_small_strains_keep_the_reference_step_and_a_forced_step_too_long_stops():
    small = run(crushed_block("small"))
    steps = {row.time_step for row in small.solver.stats.history}
    assert len(steps) == 1
    forced = crushed_block()
    forced["solver"]["time_step"] = small.solver.now.dt
    with pytest.raises(Diverged, match="deformed cells' stable step"):
        run(forced)
