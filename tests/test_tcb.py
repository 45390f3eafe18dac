"""The paper's Figure 5 claim and the refinement bookkeeping in dynamic runs:
- a TCB beam refined from the start (interfaces 2, 6 strong, 4 weak with the symmetry
  condition) and the LW reference mesh of the same sublaminates give the same reaction-force
  history, over a run that propagates both delaminations;
- refining in the middle of a run conserves mass and momentum, and energy up to what the
  cohesive law dissipates and the lumped-mass redistribution (measured);
- 1 and 2 MPI ranks give the same history with refinements that cross the partition boundary.
"""

import subprocess
import sys
import tomllib
from pathlib import Path

import numpy as np
import pytest
from fenics_adaptive.meshes import esl_mesh
from mpi4py import MPI

from fenics_adaptive.adaptivity.events import refine
from fenics_adaptive.io.output import read_history
from fenics_adaptive.model.forms import build_model
from fenics_adaptive.model.loading import resolve
from fenics_adaptive.model.structure import Structure, cells_in_x_range
from fenics_adaptive.runner import run_config
from fenics_adaptive.settings.adaptivity import Interfaces
from fenics_adaptive.settings.config import parse_config
from fenics_adaptive.settings.kinds import InterfaceState
from fenics_adaptive.settings.materials import CohesiveLaw
from fenics_adaptive.settings.solver import Probe, SolverSettings
from fenics_adaptive.simulation import build_structure
from fenics_adaptive.solver import explicit

DATA = Path(__file__).parent / "data"
MPIEXEC = Path(sys.executable).parent / "mpiexec"


def run(name: str, **changes):
    data = tomllib.loads((DATA / name).read_text())
    for section, values in changes.items():
        data[section].update(values)
    config = parse_config(data)
    structure = build_structure(config)
    stats = explicit.run(structure, config.solver, config.probe)
    return structure, stats


def failed_per_interface(structure: Structure) -> dict[int, int]:
    failed = structure.cohesive.failed()
    interfaces = structure.cohesive.interface
    return {int(i): int(failed[interfaces == i].sum()) for i in np.unique(interfaces)}


@pytest.fixture(scope="module")
def tcb_runs():
    return run("tcb_adaptive.toml"), run("tcb_layerwise.toml")


@pytest.mark.slow
def test_refined_from_the_start_equals_the_layerwise_reference(tcb_runs):
    (_, a), (_, b) = tcb_runs
    force_a = np.array([r.reaction_force for r in a.history])
    force_b = np.array([r.reaction_force for r in b.history])
    assert len(force_a) == len(force_b) == 101
    assert np.abs(force_a - force_b).max() <= 1e-8 * np.abs(force_b).max()
    for name in ("kinetic_energy", "internal_energy", "dissipated_energy"):
        x = np.array([getattr(r, name) for r in a.history])
        y = np.array([getattr(r, name) for r in b.history])
        assert np.abs(x - y).max() <= 1e-8 * np.abs(y).max(), name


@pytest.mark.slow
def test_both_delaminations_propagate(tcb_runs):
    (adaptive, a), (layerwise, _) = tcb_runs
    by_interface = failed_per_interface(adaptive)
    # 0.5 mm cells: several cells of each delaminating interface have failed, symmetrically
    assert by_interface[2] >= 4 and by_interface[2] == by_interface[6]
    assert failed_per_interface(layerwise) == by_interface
    # the dissipated energy lies between GIc x the failed area and (mode II allowing) GIIc x
    # the area that has any damage (the process zone ahead of the crack)
    law = CohesiveLaw.from_mapping(
        tomllib.loads((DATA / "tcb_adaptive.toml").read_text())["cohesive"]
    )
    cell_area = 0.5 * 0.5
    damaged = (adaptive.cohesive.damage[adaptive.cohesive.damage_row].max(axis=1) > 0).sum()
    failed = sum(by_interface.values())
    dissipated = a.history[-1].dissipated_energy
    assert law.GIc * failed * cell_area <= dissipated <= law.GIIc * damaged * cell_area


def free_beam_refined_halfway(step_fraction: float):
    """A free beam (no supports, no loads) in bending vibration, refined at 2e-5 s: weak at 4,
    strong at 2 and 6, in the cells with x >= 5 mm. Returns the run's history and the (mass,
    momentum, kinetic energy) just before and after the refinement."""
    data = tomllib.loads((DATA / "tcb_adaptive.toml").read_text())
    laminate = parse_config(data).laminate
    law = CohesiveLaw.from_mapping(data["cohesive"])
    beam = esl_mesh(MPI.COMM_WORLD, 10.0, 0.5, 20, 1, laminate.thickness)
    model = build_model(beam, [laminate])
    structure = Structure(
        model,
        resolve(model, [], []),
        interfaces=Interfaces(refine=(4,), delaminate=(2, 6)),
        law_params=law.as_array(),
    )
    x = model.V.tabulate_dof_coordinates()
    velocity = np.zeros_like(x)
    velocity[:, 2] = 2000.0 * np.sin(np.pi * x[:, 0] / 10.0) + 300.0
    velocity[:, 0] = 400.0 * (x[:, 2] - 1.024) * np.cos(np.pi * x[:, 0] / 10.0)
    events = {}

    def refine_halfway(t, s):
        if "before" in events or t < 2.0e-5:
            return None
        events["before"] = (s.total_mass(), s.momentum(), s.kinetic_energy())
        cells = cells_in_x_range(s, 5.0, np.inf)
        requests = [(c, 4, InterfaceState.WEAK) for c in cells]
        requests += [(c, i, InterfaceState.STRONG) for c in cells for i in (2, 6)]
        event = refine(s, requests, t)
        assert event is not None
        events["after"] = (s.total_mass(), s.momentum(), s.kinetic_energy())
        return event

    # the same step before and after refinement: a fraction of the refined structure's limit
    # (found on a copy: a structure owns its model)
    other = build_model(esl_mesh(MPI.COMM_WORLD, 10.0, 0.5, 20, 1, laminate.thickness), [laminate])
    probe = Structure(
        other,
        resolve(other, [], []),
        interfaces=Interfaces(refine=(4,), delaminate=(2, 6)),
        law_params=law.as_array(),
    )
    probe.refine([(c, i, InterfaceState.STRONG) for c in range(20) for i in (2, 6)])
    dt = step_fraction * probe.stable_time_step()[0]
    settings = SolverSettings(end_time=6.0e-5, output_interval=1e-6, time_step=dt)
    stats = explicit.run(
        structure,
        settings,
        Probe("x1", "x1", "z"),
        refiner=refine_halfway,
        initial_velocity=velocity.ravel(),
    )
    assert stats.refinements == 1
    return stats.history, events["before"], events["after"], structure


def energy_drift(history) -> float:
    """Largest change of the energy balance, relative to the initial (kinetic) energy."""
    total = history[0].kinetic_energy
    return max(abs(r.energy_balance - total) for r in history) / total


@pytest.mark.slow
def test_refinement_mid_run_conserves_mass_and_momentum():
    history, (m0, p0, k0), (m1, p1, k1), structure = free_beam_refined_halfway(0.3)
    assert m1 == pytest.approx(m0, rel=1e-14)
    assert np.abs(p1 - p0).max() < 1e-12 * np.abs(p0).max()
    assert np.abs(structure.momentum() - p0).max() < 1e-10 * np.abs(p0).max()
    # the kinetic energy the lumped masses' redistribution changed, booked as such, with the
    # strain energy the refinement changed: the subelements' own shear factors and enhanced
    # thickness strains (4e-3 of the kinetic energy) and the equilibration, which moves the
    # refined cells' nodes, base nodes included, until each has the acceleration it had (the
    # refined half is stiffer in shear: 3.4e-2 of the kinetic energy in all)
    # (the solver books the kinetic part as its full-step measure sees it, which the force
    # change of the refinement and of the equilibration shifts: measured 7.9e-7 mJ, 3.3e-5 of
    # the kinetic energy, from the half-step estimate k1 - k0; the balance stays closed,
    # ``energy_drift`` below)
    potential = structure.last_refinement_potential
    assert history[-1].refinement_energy == pytest.approx(
        k1 - k0 + potential, abs=1e-4 * history[0].kinetic_energy
    )
    assert energy_drift(history) < 1e-12
    assert abs(k1 - k0) < 1e-3 * history[0].kinetic_energy
    assert 0.0 < potential < 5e-2 * history[0].kinetic_energy  # refining stiffens the shear


@pytest.mark.slow
@pytest.mark.parametrize("step_fraction", [0.3, 0.1])
def test_energy_balance_across_refinement_closes_to_round_off(step_fraction):
    """Kinetic + internal - refinement energy stays at its initial value to round-off, whatever
    the step: the history measures the energies the scheme conserves and the refinement books
    the kinetic energy change as the scheme sees it."""
    history = free_beam_refined_halfway(step_fraction)[0]
    assert energy_drift(history) < 1e-12


def late_refinement(tmp_path: Path) -> Path:
    text = (DATA / "tcb_adaptive.toml").read_text().replace('initial = "strong"', "")
    text += """
[[refinement]]
time = 2.0e-5
interfaces = [4]
kind = "weak"
x_min = 2.0

[[refinement]]
time = 2.0e-5
interfaces = [2, 6]
kind = "strong"
x_min = 2.0
"""
    path = tmp_path / "late.toml"
    path.write_text(text)
    return path


@pytest.mark.slow
def test_manual_refinement_from_the_config(tmp_path):
    summary = run_config(
        parse_config(tomllib.loads(late_refinement(tmp_path).read_text())),
        tmp_path / "out",
        show_progress=False,
        log=None,
    )
    assert summary["refinement_events"] == 1
    assert summary["cohesive_elements_at_end"] == 2 * 16  # cells with centroid x >= 2 mm
    assert summary["extra_nodes_at_end"] == 17 * 2 * 5
    # a late strong refinement excites the new interface's fast modes and the step drops: the
    # balance still closes to round-off (it was 7.7e-4 with the kinetic energy at v_n)
    assert summary["max_energy_balance_error_relative"] < 1e-12


@pytest.mark.mpi
def test_two_ranks_reproduce_the_serial_history_with_refinement(tmp_path):
    config = late_refinement(tmp_path)
    histories = []
    for ranks in (1, 2):
        out = tmp_path / f"ranks{ranks}"
        command = [sys.executable, "-m", "fenics_adaptive", "run", str(config), "--out", str(out)]
        if ranks > 1:
            command = [str(MPIEXEC), "-n", str(ranks), *command]
        result = subprocess.run(command, capture_output=True, text=True, timeout=600)
        assert result.returncode == 0, result.stderr
        histories.append(read_history(out / "history.csv"))
    serial, parallel = histories
    assert serial["time"] == parallel["time"]
    for column in ("reaction_force", "kinetic_energy", "dissipated_energy", "refinement_energy"):
        a, b = np.array(serial[column]), np.array(parallel[column])
        assert np.abs(a - b).max() <= 1e-10 * np.abs(a).max(), column
    assert max(serial["dissipated_energy"]) > 0.1
