"""Force contributors (``model.forces``): a user's own, added through the public API, against
the closed form; the structure's own, one per term of the internal force.

The user's contributor: springs to ground on the z DOFs of every base node, each as stiff as
kappa times the node's lumped mass. A free beam given a uniform velocity v0 then moves as a
rigid body on the springs (its elements do no work): u_z(t) = v0 / omega sin(omega t),
omega = sqrt(kappa), spring energy 1/2 M v0^2 sin^2(omega t). As an EXTERNAL contributor its
work is the external work, as an INTERNAL one the internal work and the stored strain energy.
For a linear spring the solver's trapezoidal work over a step equals the change of the spring
energy exactly, so the bookkeeping is checked to round-off. Units: N, mm, s, tonne.
"""

import math
import tomllib
from pathlib import Path

import numpy as np
import pytest
from mpi4py import MPI

import fenics_adaptive as fa
from fenics_adaptive.model.forces import ForceKind

DATA = Path(__file__).parent / "data"
PERIOD = 4.0e-5  # s: about 360 steps of the small beam
OMEGA = 2.0 * math.pi / PERIOD  # rad/s
V0 = 100.0  # mm/s


class MassSprings(fa.Contributor):
    """A spring to ground on the z DOF of every owned base node, of stiffness kappa times the
    node's lumped mass (N/mm), as a contributor of kind ``kind``."""

    name = "springs"

    def __init__(self, structure, kappa: float, kind: ForceKind):
        self.kind = kind
        block = structure.base_block
        self.dofs = np.arange(2, block.n_owned, 3)
        self.k = kappa * block.mass[self.dofs]  # N/mm
        self.u = structure.base.u.x.array  # mm, owned + ghost entries
        self.sign = 1.0 if kind is ForceKind.INTERNAL else -1.0  # f_int = k u, f_ext = -k u
        self.u_z, self.force = np.zeros(len(self.dofs)), np.zeros(len(self.dofs))

    def add_force(self, t, f_base, f_extra):
        np.take(self.u, self.dofs, out=self.u_z)
        np.multiply(self.k, self.u_z, out=self.force)
        self.force *= self.sign
        f_base[self.dofs] += self.force

    def energy(self):
        return 0.5 * float(np.dot(self.k * self.u_z, self.u_z))


def free_beam() -> fa.RunConfig:
    """The small cross-ply beam without loads, free in z (u_x = 0 on the face x = 0 only),
    one period long."""
    data = tomllib.loads((DATA / "small_beam.toml").read_text())
    del data["clamp"]
    fixed_x = {"face": "x0", "component": "x", "displacement": 0.0, "rise_time": 1.0e-5}
    data["prescribed"] = [fixed_x]
    data["solver"]["end_time"] = PERIOD
    data["output"].update(interval=PERIOD / 40, reaction_face="x0")
    del data["output"]["fields_interval"]
    return fa.parse_config(data, source="free beam")


@pytest.mark.parametrize("kind", [ForceKind.EXTERNAL, ForceKind.INTERNAL])
def test_a_spring_to_ground_of_one_s_own_moves_the_beam_as_the_closed_form(kind):
    config = free_beam()
    simulation = fa.Simulation(config)
    springs = MassSprings(simulation.structure, OMEGA**2, kind)
    simulation.add_contributor(springs)
    mass = simulation.structure.total_mass()  # tonne
    velocity = np.zeros_like(simulation.structure.base.u.x.array)
    velocity[2::3] = V0
    energies = []

    class SpringEnergy(fa.Observer):
        def on_history(self, row):
            energies.append(MPI.COMM_WORLD.allreduce(springs.energy()))

    simulation.add_observer(SpringEnergy())
    simulation.start(initial_velocity=velocity)
    simulation.run()
    rows = simulation.history
    t = np.array([row.time for row in rows])
    amplitude = V0 / OMEGA  # mm
    exact = amplitude * np.sin(OMEGA * t)
    # the scheme's phase error over one period, (omega dt)^2 / 24 x 2 pi: below 1e-4 here
    displacement = np.array([row.displacement for row in rows])
    assert np.abs(displacement - exact).max() < 1e-4 * amplitude
    energies = np.array(energies)
    kinetic0 = 0.5 * mass * V0**2  # mJ
    assert energies.max() == pytest.approx(kinetic0, rel=1e-4)
    assert np.allclose(energies, kinetic0 * np.sin(OMEGA * t) ** 2, rtol=0, atol=2e-4 * kinetic0)
    # each kind in its place of the balance, to round-off
    scale = 1e-12 * kinetic0
    for row, energy in zip(rows, energies, strict=True):
        if kind is ForceKind.EXTERNAL:
            assert row.external_work == pytest.approx(-energy, abs=scale)
            assert abs(row.internal_energy) < scale  # a rigid motion: the elements do no work
        else:
            assert row.internal_energy == pytest.approx(energy, abs=scale)
            assert row.external_work == 0.0
        assert abs(row.dissipated_energy) < scale  # the spring stores what it takes
        # kinetic + spring energy at full steps oscillates by (omega dt)^2 / 4 of the energy
        # under central differences (7.86e-5 measured, 7.86e-5 in theory)
        bound = 0.26 * (OMEGA * simulation.time_step) ** 2
        assert row.energy_balance == pytest.approx(kinetic0, rel=bound)


def test_contributors_are_named_once_and_added_before_the_start():
    simulation = fa.Simulation(free_beam())
    structure = simulation.structure
    assert [c.name for c in structure.contributors] == ["solid", "cohesive", "ties"]
    simulation.add_contributor(MassSprings(structure, 1.0, ForceKind.INTERNAL))
    with pytest.raises(ValueError, match="unique names"):
        simulation.add_contributor(MassSprings(structure, 1.0, ForceKind.EXTERNAL))
    assert [c.name for c in simulation.solver.forces.added] == ["springs"]
    simulation.start()
    with pytest.raises(RuntimeError, match="after the run started"):
        simulation.add_contributor(MassSprings(structure, 1.0, ForceKind.EXTERNAL))
