"""The explicit solver as an object (issue 13): stepping it by hand is the run, its state
round-trips, observers and refiners see what happens.

The case: the short TCB beam opened by its prescribed arm motions, refined strongly at
interfaces 2 and 6 at 4 us (tie forces released over 3 us, a damping window of 3 us), 300
steps. Units: N, mm, s, tonne.
"""

import tomllib
from pathlib import Path

import numpy as np
import pytest

from fenics_adaptive.settings.config import parse_config
from fenics_adaptive.settings.kinds import InterfaceState
from fenics_adaptive.simulation import RefinementHook, build_structure
from fenics_adaptive.solver import explicit
from fenics_adaptive.solver.observers import Observer

DATA = Path(__file__).parent / "data"
T_REFINE = 4.0e-6  # s
END = 1.2e-5  # s: 300 steps of 4e-8 s


def tcb_refined_late(forced_step: bool = True, x_min: float = 5.0):
    """Config of the TCB beam unrefined at t = 0 and refined strongly at T_REFINE over
    x >= x_min (mm)."""
    data = tomllib.loads((DATA / "tcb_adaptive.toml").read_text())
    data["interfaces"]["initial"] = "none"
    data["solver"]["end_time"] = END
    if not forced_step:
        del data["solver"]["time_step"]
    data["output"]["interval"] = 2.0e-7
    del data["output"]["fields_interval"]
    entry = {"interfaces": [2, 6], "kind": "strong", "time": T_REFINE, "x_min": x_min}
    data["refinement"] = [entry]
    data["stabilisation"] = {"damping": 5.0e4, "damping_window": 3.0e-6, "release_window": 3e-6}
    return parse_config(data)


def solver_of(config, observers=()):
    structure = build_structure(config)
    return explicit.ExplicitSolver(
        structure,
        config.solver,
        config.probe,
        observers=observers,
        refiner=RefinementHook(config),
    )


def motion_arrays(solver):
    return [(b.block.u.array.copy(), b.block.v.array.copy()) for b in solver.blocks]


@pytest.fixture(scope="module")
def whole_run():
    """The case run by ``run()``: (solver, stats)."""
    solver = solver_of(tcb_refined_late())
    return solver, solver.run()


def test_stepping_by_hand_is_the_run(whole_run):
    """start() and step() until it says the end is reached give bit for bit the u, v and
    history of run(); between steps the state is at t_n with the forces of t_n."""
    reference, stats = whole_run
    solver = solver_of(tcb_refined_late())
    solver.start()
    steps, times = 0, [solver.t]
    while solver.step():
        steps += 1
        times.append(solver.t)
        if steps == 10:  # the forces read between steps are those of u_n
            f = solver.internal_force.copy()
            solver.structure.internal_force()
            np.testing.assert_array_equal(solver.internal_force, f)
    assert steps == stats.steps == 300
    np.testing.assert_allclose(np.diff(times), 4.0e-8, rtol=1e-9)
    for (u, v), (u_ref, v_ref) in zip(motion_arrays(solver), motion_arrays(reference), strict=True):
        np.testing.assert_array_equal(u, u_ref)
        np.testing.assert_array_equal(v, v_ref)
    assert solver.stats.history == stats.history
    assert solver.last_row == stats.history[-1]
    # the physics of the case: refined once, strongly, and the balance closed
    assert stats.refinements == 1
    assert (solver.interface_state[:, [1, 5]] == InterfaceState.STRONG).any()
    work = max(abs(r.external_work) for r in stats.history)
    assert work > 0.0
    assert max(abs(r.energy_balance) for r in stats.history) < 0.01 * work
    # the probe face is prescribed: its displacement is the prescribed one
    (arm,) = [m for m in solver.structure.motions if m.face == "x1&top" and m.component == "z"]
    for row in stats.history:
        assert row.displacement == pytest.approx(arm.displacement(row.time), rel=1e-12, abs=1e-15)


def test_state_and_restore_continue_bit_for_bit(whole_run):
    """The state taken between two steps after the refinement (ties and damping window open),
    restored on a structure rebuilt from the config and the structure's checkpoint state,
    continues exactly as the uninterrupted run."""
    reference, stats = whole_run
    config = tcb_refined_late()
    first = solver_of(config)
    first.start()
    while first.t < 5.0e-6:
        first.step()
    assert first.now.refinements == 1 and first.structure.ties
    state = first.state()
    structure_state = first.structure.state()
    hook_state = first.refiner.state()
    t_taken = first.t
    first.step()  # the state handed out is a copy: stepping on does not change it
    assert state["t"] == t_taken

    structure = build_structure(config, refine_initially=False)
    structure.restore(structure_state)
    hook = RefinementHook(config)
    hook.restore(hook_state)
    second = explicit.ExplicitSolver(structure, config.solver, config.probe, refiner=hook)
    second.restore(state)
    assert second.t == t_taken
    resumed = second.run()
    for (u, v), (u_ref, v_ref) in zip(motion_arrays(second), motion_arrays(reference), strict=True):
        np.testing.assert_array_equal(u, u_ref)
        np.testing.assert_array_equal(v, v_ref)
    later = [r for r in stats.history if r.time > t_taken + 1e-12]
    assert resumed.history == later
    assert resumed.steps == stats.steps and resumed.refinements == 1


class Recorder(Observer):
    """Everything an observer is told, in order."""

    def __init__(self):
        self.calls = []
        self.rows = []
        self.refinements = []

    def on_start(self, solver):
        self.calls.append("start")

    def on_history(self, row):
        self.calls.append("history")
        self.rows.append(row)

    def on_refinement(self, event, dt, where):
        self.calls.append("refinement")
        self.refinements.append((event, dt, where))

    def on_finish(self, stats):
        self.calls.append("finish")


def test_an_observer_and_a_refinement_event():
    """An observer of one's own gets the history rows at the output times, and one
    refinement: the solver reacts once, with the step chosen again for the refined structure
    (no forced step here): all cells refined, a subelement limits it now."""
    config = tcb_refined_late(forced_step=False, x_min=0.0)
    recorder = Recorder()
    solver = solver_of(config, [recorder])
    events = []
    hook = solver.refiner

    def refiner(t, structure):
        event = hook(t, structure)
        if event is not None:
            events.append(event)
        return event

    solver.refiner = refiner
    solver.start()
    dt_before, where_before = solver.now.dt, solver.where
    stats = solver.run()

    assert recorder.calls[0] == "start" and recorder.calls[-1] == "finish"
    assert recorder.calls.count("refinement") == 1 and len(events) == 1
    assert recorder.rows == stats.history
    times = np.array([r.time for r in recorder.rows])
    # a row at the first step at or past each multiple of the output interval, and the end
    due = np.arange(0.0, END - 1e-12, config.solver.output_interval)
    assert len(times) == len(due) + 1
    assert np.all((times[:-1] >= due - 1e-9 * dt_before) & (times[:-1] < due + dt_before))
    assert times[-1] >= END - 1e-9 * dt_before

    (event,) = events
    event_seen, dt, where = recorder.refinements[0]
    assert event_seen is event
    assert T_REFINE <= event.time < T_REFINE + dt_before
    assert len(event.cells) and len(event.new_strong) and event.new_extra_nodes > 0
    assert set(event.new_strong[:, 1]) == {2, 6}
    # the step re-chosen for the refined structure: its stable step, and the rows use it
    stable, _, _ = explicit.choose_time_step(solver.structure, config.solver)
    assert dt == stable == solver.now.dt <= dt_before
    assert where_before.startswith("cell") and where.startswith("subelement of cell")
    assert solver.stats.critical == where
    assert {r.time_step for r in stats.history if r.time > event.time} == {dt}
    assert {r.time_step for r in stats.history if r.time < event.time} == {dt_before}
    # the potential energy change is booked as internal work: no jump of the dissipation
    before = [r for r in stats.history if r.time < event.time][-1]
    after = next(r for r in stats.history if r.time >= event.time)
    assert abs(after.dissipated_energy - before.dissipated_energy) < 1e-3 * max(
        abs(after.external_work), 1e-300
    )
