"""Rigid impactor contact: penalty forces against the analytic surface, and a ball bouncing on
a stiff elastic plate with the total energy (plate, ball, penalty springs) conserved."""

import tomllib
from pathlib import Path

import numpy as np
import pytest

from fenics_adaptive.model.contact import Contact, add_penalty_forces
from fenics_adaptive.settings.config import parse_config
from fenics_adaptive.settings.loads import Impactor, RigidBody
from fenics_adaptive.settings.solver import SolverSettings
from fenics_adaptive.simulation import build_structure
from fenics_adaptive.solver import explicit

DATA = Path(__file__).parent / "data"


NO_NORMAL = np.zeros(3)  # (a sphere's or a cylinder's: the kernels read a plane's only)
ONES = np.ones(3)  # each node's spring weight


def test_penalty_force_points_away_from_the_centre_and_stores_its_energy():
    X = np.array([[0.0, 0.0, 0.5], [0.6, 0.0, 0.3], [0.0, 0.0, 1.0]])  # reference positions
    u = np.array([[0.0, 0.0, 0.4], [0.0, 0.0, 0.5], [0.0, 0.0, 1.0]])  # two end inside R = 1
    nodes = np.array([2, 0, 1])  # each node's place in the flat u and f
    u_flat = np.zeros(9)
    u_flat.reshape(3, 3)[nodes] = u
    f = np.ones(9)  # forces already there are added to
    on_body = np.zeros(3)
    active = np.ones(3, dtype=bool)
    energy = add_penalty_forces(
        u_flat, nodes, active, X, np.zeros(3), 1.0, -1, NO_NORMAL, 100.0, ONES, f, on_body
    )
    added = f.reshape(3, 3)[nodes] - 1.0
    np.testing.assert_allclose(added[0], [0.0, 0.0, 100.0 * 0.1])
    assert np.all(added[2] == 0.0)
    np.testing.assert_allclose(on_body, -added.sum(axis=0))
    assert energy == pytest.approx(0.5 * 100.0 * (0.1**2 + 0.0**2))  # the second sits on R
    # a cylinder along y ignores y
    f_cyl = np.ones(9)
    shifted = X + np.array([0.0, 5.0, 0.0])
    add_penalty_forces(
        u_flat, nodes, active, shifted, np.zeros(3), 1.0, 1, NO_NORMAL, 100.0, ONES, f_cyl,
        np.zeros(3),
    )  # fmt: skip
    np.testing.assert_allclose(f_cyl, f)
    # a node erosion has freed touches nothing
    f_freed = np.ones(9)
    freed = np.array([False, True, True])
    add_penalty_forces(
        u_flat, nodes, freed, X, np.zeros(3), 1.0, -1, NO_NORMAL, 100.0, ONES, f_freed, on_body
    )
    assert np.all(f_freed == 1.0) and np.all(on_body == 0.0)


def clamped_plate():
    data = tomllib.loads((DATA / "small_beam.toml").read_text())
    data["mesh"].update(length=10.0, width=10.0, nx=12, ny=12)
    data["clamp"] = [{"face": face} for face in ("x0", "x1", "y0", "y1")]
    data.pop("prescribed")
    data["output"].update(displacement_face="top", reaction_face="x0", interval=2e-6)
    data["output"].pop("fields_interval")
    return parse_config(data)


@pytest.mark.slow
def test_ball_bouncing_on_a_plate_conserves_the_total_energy():
    """A 1 g steel-like ball at 1 m/s hits the middle of a clamped plate and bounces: plate
    kinetic + strain energy + ball kinetic + penalty energy stays at the ball's initial
    kinetic energy within 1 %, and the ball leaves upwards."""
    config = clamped_plate()
    structure = build_structure(config)
    ball = Impactor("sphere", 2.0, 1.0e-6, (5.0, 5.0, 2.0 + 2.0 + 0.005), (0.0, 0.0, -1000.0))
    contact = Contact.on(ball, structure)
    settings = SolverSettings(end_time=8.0e-5, output_interval=1e-6)
    stats = explicit.run(structure, settings, config.probe, contributors=[contact])
    rows = stats.history
    initial = 0.5 * ball.mass * 1000.0**2  # mJ
    assert max(r.contact_force for r in rows) > 0.0  # they touched
    for r in rows:
        total = r.kinetic_energy + r.internal_energy + (initial - r.impact_work)
        assert total == pytest.approx(initial, rel=0.01)
    assert contact.velocity[2] > 0.0  # bounced
    assert rows[-1].contact_force == 0.0  # and left
    assert max(abs(r.energy_balance) for r in rows) < 0.01 * initial


class CountingComm:
    """A communicator that counts the collectives called through it (one rank, which it says
    is one of two: on one rank the sums skip MPI altogether)."""

    size = 2

    def __init__(self, comm):
        self.comm, self.calls = comm, 0

    def __getattr__(self, name):
        attribute = getattr(self.comm, name)
        if name.lower() in ("allreduce", "bcast", "barrier", "allgather", "gather"):
            self.calls += 1
        return attribute


def test_a_fixed_body_sums_its_force_over_the_ranks_only_when_it_reports():
    """A fixed body (a support) calls no collective in the steps between history rows; its
    report then gives the force, penalty energy and work of the same body summed every step
    (a free body's motion needs its force every step, so it still sums it there)."""
    from fenics_adaptive.solver.history import HistoryRow

    config = clamped_plate()
    structure = build_structure(config)
    support = RigidBody("pin", "sphere", 2.0, (5.0, 5.0, 2.0 + 2.0 - 0.01), motion="fixed")
    deferred, summed = Contact.on(support, structure), Contact.on(support, structure)
    summed.every_step = True
    counter = CountingComm(deferred.comm)
    deferred.comm = counter
    f = np.zeros_like(structure.base.u.x.array)
    rows = []
    for contact in (deferred, summed):
        row = HistoryRow(*([0.0] * 12))
        contact.add_force(0.0, f, f)
        contact.report(row, first=True)
        calls = counter.calls
        for _ in range(3):
            contact.add_force(0.0, f, f)
        if contact is deferred:
            assert counter.calls == calls == 1  # the first report's only
        contact.report(row, first=False)
        rows.append(row)
    assert counter.calls == 2  # one per report
    assert rows[0].bodies["pin_force"] == rows[1].bodies["pin_force"] > 0.0
    assert rows[0].impact_work == rows[1].impact_work
    assert Contact.on(Impactor("sphere", 2.0, 1e-6, (5, 5, 5), (0, 0, -1)), structure).every_step
