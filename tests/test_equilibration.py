"""Equilibration of the nodes of the refined cells (``adaptivity.equilibration``): the cohesive
tangent against the bilinear element's closed form, one Newton step to equilibrium on a bent
cantilever (the tangent is exact), the strain energy it releases, the loads a refinement moves
onto its new nodes, and the runs it changes (small and finite kinematics)."""

import tomllib
from pathlib import Path

import numpy as np
from mpi4py import MPI

from fenics_adaptive.adaptivity.equilibration import face_loads
from fenics_adaptive.materials.cohesive import cohesive_tangents
from fenics_adaptive.settings.adaptivity import Stabilisation
from fenics_adaptive.settings.config import parse_config
from fenics_adaptive.settings.kinds import InterfaceState
from fenics_adaptive.settings.materials import CohesiveLaw
from fenics_adaptive.simulation import Simulation
from fenics_adaptive.static_runner import solve_config

DATA = Path(__file__).parent / "data"


def cantilever(**changes) -> dict:
    data = tomllib.loads((DATA / "bent_cantilever.toml").read_text())
    for section, values in changes.items():
        data.setdefault(section, {}).update(values)
    return data


def test_cohesive_tangent_is_the_bilinear_elements_penalty_matrix():
    """At zero opening an intact 8-node element of area A is the consistent spring layer:
    K_ab = diag(K_s, K_s, K_n) int N_a N_b dA between lower and upper faces, with the sign
    pattern [[K, -K], [-K, K]]; a rigid motion costs nothing."""
    law = CohesiveLaw(2.0e5, 1.0e5, 30.0, 60.0, 0.3, 0.8, "bk", 2.0)
    X = np.zeros((1, 8, 3))
    X[0, :4, :2] = X[0, 4:, :2] = [[0.0, 0.0], [2.0, 0.0], [0.0, 3.0], [2.0, 3.0]]
    K = np.empty((1, 24, 24))
    cohesive_tangents(X, np.zeros((1, 8, 3)), law.as_array(), np.zeros((1, 4)), 1e-6, K)
    area = 6.0
    # int N_a N_b dA of the bilinear square (exact with 2 x 2 Gauss): A/36 (4, 2, 2, 1)
    shares = np.array([[4, 2, 2, 1], [2, 4, 1, 2], [2, 1, 4, 2], [1, 2, 2, 4]]) * area / 36.0
    penalty = np.diag([1.0e5, 1.0e5, 2.0e5])
    spring = np.kron(shares, penalty)
    expected = np.block([[spring, -spring], [-spring, spring]])
    assert np.allclose(K[0], expected, rtol=1e-8, atol=1e-6 * np.abs(expected).max())
    rigid = np.tile([0.3, -0.2, 0.7], 8)
    assert np.abs(K[0] @ rigid).max() < 1e-6 * np.abs(K[0]).max()


def bent_and_refined(equilibrate: bool):
    """The cantilever's ESL static state at 4.68e-4 s (94 % of the push), then every interface
    of every cell made strong at once."""
    data = cantilever(stabilisation={"equilibrate": equilibrate}, solver={"end_time": 4.68e-4})
    data.pop("refinement")
    structure, _, _ = solve_config(parse_config(data), MPI.COMM_SELF)
    n = structure.base.n_owned_cells
    structure.refine([(c, i, InterfaceState.STRONG) for c in range(n) for i in (1, 2, 3)], 4.68e-4)
    return structure


def test_one_newton_step_balances_the_freed_dofs_and_lowers_the_strain_energy():
    """Refining a bent ESL cantilever everywhere leaves its new nodes tens of newtons out of
    balance where the split element's field put them (the ESL spreads its shear evenly; the
    plies need a zig-zag and the cohesive elements an opening to carry it). One Newton step
    with the assembled tangent brings every freed DOF to balance to round-off (the tangent is
    exact for small strain), checked with the structure's own force evaluation. The beam is
    at rest in static equilibrium under its prescribed tip (held), so every moving DOF's
    target is no force: the balanced state is the refined beam's static solution, with less
    strain energy than the placed one (it minimises the energy over the DOFs that move)."""
    placed = bent_and_refined(False)
    balanced = bent_and_refined(True)
    report = balanced.last_equilibrated
    assert placed.last_equilibrated is None
    assert report.steps == 1 and report.dofs > 0
    assert report.imbalance > 20.0  # N, against a tip force of about 140 N
    assert report.remaining < 1e-9 * report.imbalance
    assert 0.0 < report.moved < 0.01  # mm: a zig-zag and a penalty opening, not a new shape

    def free_force(structure):
        structure.internal_force(4.68e-4)
        f = structure.f_extra.array[: 3 * structure.extra.n_owned]
        free = np.ones(len(f), dtype=bool)
        free[structure.extra_block.fixed] = False
        free[structure.border.dofs - 3 * structure.n_base] = False
        return np.abs(f[free]).max()

    assert free_force(placed) > 20.0
    assert free_force(balanced) < 1e-9 * report.imbalance
    energy = [sum(s.internal_forces.energies()) for s in (placed, balanced)]
    assert energy[1] < energy[0] - 0.01  # mJ, of about 174


def test_a_loaded_end_refined_keeps_every_dof_in_balance():
    """A cantilever in static equilibrium under a tip load on its end face, its end cell
    refined weakly: the refinement moves three quarters of the load from the cell's base nodes
    onto its new extra nodes, and the balance gives each DOF of the cell the load it now has
    (the end's base nodes a quarter; counted at the old share, they were left 20 N out of
    balance and their neighbours took it). Every free DOF stays in balance, to 1e-5 of the load
    (the held neighbours' share of the cell's small motion)."""
    data = tomllib.loads((DATA / "finite_cantilever.toml").read_text())
    data["model"]["kinematics"] = "small"
    data["mesh"]["nx"] = 10
    data["stabilisation"] = {"equilibrate": True}
    structure, _, _ = solve_config(parse_config(data), MPI.COMM_SELF)
    t = data["solver"]["end_time"]

    def out_of_balance() -> tuple[float, float]:
        structure.internal_force(t)
        base_load, extra_load = face_loads(structure, t)
        n_base, n_extra = len(base_load), len(extra_load)
        base = base_load - structure.f_base.array[:n_base]
        base[structure.base_block.fixed] = 0.0
        extra = extra_load - structure.f_extra.array[:n_extra]
        return np.abs(base).max(), np.abs(extra).max(initial=0.0)

    assert max(out_of_balance()) < 1e-8 * 26.7
    x = structure.X_base[structure.bottom_local].mean(axis=1)[:, 0]
    end = np.flatnonzero(x > 90.0)
    structure.refine([(int(c), i, InterfaceState.WEAK) for c in end for i in (2, 4, 6)], t)
    report = structure.last_equilibrated
    assert report.imbalance > 10.0 and report.remaining < 1e-9 * report.imbalance
    base, extra = out_of_balance()
    assert extra < 1e-8 * 26.7
    assert base < 1e-5 * 26.7


def test_a_beam_refined_near_its_peak_carries_its_load_as_the_layerwise_one_does():
    """The cantilever refined strongly everywhere at 94 % of its push, run on to the end: the
    layerwise model carries it intact at -141.8 N. Placed where the ESL field puts them, the new
    nodes' out-of-balance forces ring the interfaces past their strength and the beam
    delaminates end to end; balanced, it stays intact and ends within 5 % of the layerwise
    force."""
    results = {}
    for equilibrate in (False, True):
        data = cantilever(stabilisation={"equilibrate": equilibrate})
        simulation = Simulation(parse_config(data))
        simulation.run()
        row = simulation.history[-1]
        results[equilibrate] = (row.reaction_force, row.delaminated_area)
    assert results[False][1] > 100.0  # mm^2 of 120
    force, area = results[True]
    assert area == 0.0
    assert abs(force / -141.8 - 1.0) < 0.01


def test_under_finite_kinematics_the_refined_beam_carries_its_load_as_the_layerwise_one_does():
    """The same late refinement under finite kinematics, where the layerwise beam's interfaces
    next to its pushed end are already softening (the pushed face cannot turn: its plies are
    all moved down alike), so that the balance cannot settle with the undamaged tangent: the
    base nodes of the refined cells move with the new ones, and the beam stays intact as the
    layerwise one does and ends within 2 % of its force (with the base held it delaminated
    end to end)."""
    results = {}
    for kind in ("adaptive", "layerwise"):
        data = cantilever(model={"kind": kind, "kinematics": "finite"})
        if kind == "layerwise":
            data.pop("refinement")
        simulation = Simulation(parse_config(data))
        simulation.run()
        row = simulation.history[-1]
        results[kind] = (row.reaction_force, row.delaminated_area)
    force, area = results["adaptive"]
    assert area == 0.0 and results["layerwise"][1] == 0.0
    assert abs(force / results["layerwise"][0] - 1.0) < 0.02


def test_the_default_balances_models_without_ply_damage_only():
    """Left out, ``equilibrate`` is on without ply damage and off with it (the balance is
    found with the undamaged plies' tangent); given, it is what it says."""
    assert Stabilisation().equilibrates(ply_damage=False)
    assert not Stabilisation().equilibrates(ply_damage=True)
    assert Stabilisation(equilibrate=True).equilibrates(ply_damage=True)
    assert not Stabilisation(equilibrate=False).equilibrates(ply_damage=False)
    assert parse_config(cantilever()).stabilisation.equilibrate is None


def test_a_balance_that_stops_short_says_so_in_the_log():
    """Where the modified-Newton steps stop above the tolerance (the balanced state past an
    interface's onset: its softening is not in the tangent), the refinement's log line says
    how much is left."""
    from fenics_adaptive.adaptivity.equilibration import Equilibrated
    from fenics_adaptive.runner import _balanced

    done = Equilibrated(dofs=12, imbalance=74.3, remaining=3.1e-9, steps=1, moved=2e-3)
    short = Equilibrated(dofs=1062, imbalance=86.8, remaining=8.7, steps=3, moved=4e-3)
    assert done.settled and "not settled" not in _balanced(done)
    assert not short.settled
    assert "86.8 -> 8.7 N (not settled: 10% left" in _balanced(short)
