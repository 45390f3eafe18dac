"""A rigid impactor (sphere or cylinder) hitting the top face: penalty contact.

The impactor is a rigid body of mass M moving in translation: a sphere of radius R about its
centre c, or a cylinder of radius R whose axis runs along y through c (a line impact across a
beam). Each top-face base node at x = X + u gets the penalty force

    g = dist(x, impactor) - R,   f = k <-g> n,   n = unit vector from the centre (axis) to x,

and the impactor gets -sum f. Both are integrated by the same central-difference scheme as the
structure (impactor velocity at half steps). The contact is frictionless and conservative: the
penalty springs store 1/2 k g^2, which the history reports with the impactor's kinetic energy
as ``impactor_energy``. So the energy balance of a bouncing ball closes up to the scheme's
O(dt^2) error.

As a force contributor (``model.forces``, name "impactor", kind CONTACT) it adds its forces on
the top-face DOFs, integrates itself (``advance``), reports the contact force, its displacement
and the energy it gave up (``impact_work``) in the history and keeps its state (centre,
velocity, initial energy and height) for checkpoints (keys ``impactor_*``).

Penalty k (N/mm per node): by default the through-thickness stiffness of the laminate over one
node's area, max C33 * A_node / h. It is capped so that a node on its spring stays well inside
the stable step: k <= 0.05 m_node (2 / dt)^2. Contact is checked on the owned top-face base
nodes only (refinement never moves the top face), so every node counts once on one rank.

Units: N, mm, s, tonne.
"""

from __future__ import annotations

import numpy as np
from mpi4py import MPI
from numba import njit

from fenics_adaptive.element.geometry import quad_areas
from fenics_adaptive.errors import InputError
from fenics_adaptive.model.forces import Contributor, ForceKind
from fenics_adaptive.model.loading import face_nodes
from fenics_adaptive.settings.kinds import ImpactorShape
from fenics_adaptive.settings.loads import Impactor


@njit(cache=True)
def penalty_forces(x, centre, radius, cylinder, penalty, f_out, total):
    """Contact forces (n, 3) on nodes at x (n, 3) into f_out and their reaction on the impactor
    into total (3,), both overwritten; returns the penalty energy."""
    total[:] = 0.0
    energy = 0.0
    for i in range(x.shape[0]):
        dx = x[i, 0] - centre[0]
        dy = 0.0 if cylinder else x[i, 1] - centre[1]
        dz = x[i, 2] - centre[2]
        distance = np.sqrt(dx * dx + dy * dy + dz * dz)
        gap = distance - radius
        if gap >= 0.0 or distance == 0.0:
            f_out[i, 0] = f_out[i, 1] = f_out[i, 2] = 0.0
            continue
        magnitude = -penalty * gap / distance
        f_out[i, 0] = magnitude * dx
        f_out[i, 1] = magnitude * dy
        f_out[i, 2] = magnitude * dz
        for d in range(3):
            total[d] -= f_out[i, d]
        energy += 0.5 * penalty * gap * gap
    return energy


class Contact(Contributor):
    """The impactor's state and its contact with the top-face nodes of a structure.

    ``nodes``: owned top-face base nodes; ``mass_of_node``: their lumped masses (for the
    penalty cap); ``X``: their reference positions; ``area``: the in-plane area of a node
    (mm^2); ``C33``, ``h``: the stiffest through-thickness modulus (MPa) and the thickness (mm)
    (for the default penalty); ``displacement``: the base displacement vector (a DOLFINx
    vector, owned + ghost entries) the contact reads. ``Contact.on(impactor, structure)``
    fills these in."""

    name = "impactor"
    kind = ForceKind.CONTACT

    @classmethod
    def on(cls, impactor: Impactor, structure) -> Contact:
        base = structure.base
        top = face_nodes(base, "top")  # collective
        owned = top[top < base.V.dofmap.index_map.size_local]
        X = structure.X_base[owned]
        corners = structure.X_base[structure.bottom_local]
        # the mean cell area over all ranks: one penalty for the whole face, as in serial
        local = np.array([quad_areas(corners).sum(), len(corners)])
        total, n_cells = structure.comm.allreduce(local, op=MPI.SUM)
        area = total / n_cells
        C33 = max(p.material.stiffness()[2, 2] for p in structure.laminate.plies)
        mass = structure.mass_base.array[3 * owned]
        h = structure.laminate.thickness
        return cls(impactor, structure.comm, owned, X, mass, area, C33, h, structure.base.u.x)

    def __init__(
        self,
        impactor: Impactor,
        comm: MPI.Comm,
        nodes,
        X,
        mass_of_node,
        area,
        C33,
        h,
        displacement=None,
    ):
        self.impactor = impactor
        self.displacement = displacement
        self.comm = comm
        self.nodes = np.asarray(nodes, dtype=np.int64)
        self.dofs = (3 * self.nodes[:, None] + np.arange(3)).ravel()
        self.X = np.ascontiguousarray(X)
        self.node_mass_min = comm.allreduce(
            float(mass_of_node.min()) if len(mass_of_node) else np.inf, op=MPI.MIN
        )
        self.natural_penalty = C33 * area / h
        self.penalty = impactor.penalty if impactor.penalty is not None else self.natural_penalty
        self.centre = np.array(impactor.position, dtype=float)
        self.velocity = np.array(impactor.velocity, dtype=float)  # v_{n-1/2}
        self.acceleration = np.zeros(3)
        self.last_dt = 0.0  # s: dt_{n-1/2}, of the last advance (0 before the first)
        self.initial = 0.0  # mJ: kinetic + penalty energy at t = 0
        self.z0 = float(self.centre[2])  # mm: the centre's height at t = 0
        self.force = np.zeros(3)  # on the impactor, global
        self.energy_penalty = 0.0  # global
        # work arrays: the step allocates nothing
        self.u = np.empty(len(self.dofs))
        self.x = np.empty((len(self.nodes), 3))
        self.f = np.empty((len(self.nodes), 3))
        self.f_dofs = np.empty(len(self.dofs))
        self.totals = np.empty(4)  # force on the impactor, penalty energy
        self.cylinder = impactor.shape == ImpactorShape.CYLINDER

    def initial_gap(self) -> float:
        """Collective: the smallest gap (mm) between the impactor and the undeformed top face."""
        dx = self.X - self.centre
        if self.cylinder:
            dx[:, 1] = 0.0
        local = float(np.min(np.linalg.norm(dx, axis=1))) if len(self.X) else np.inf
        return self.comm.allreduce(local, op=MPI.MIN) - self.impactor.radius

    def largest_stable_penalty(self, dt: float, element_step: float) -> float:
        """The largest penalty (N/mm) stable with the time step dt (s), for the lightest
        top-face node of mass m and the impactor of mass M: the spring adds k (1/m + 1/M) to
        the square of the node's highest frequency, which its elements already bring up to
        (2 / element_step)^2 (element_step: the element limit without the safety factor), and
        central differences need omega dt <= 2:
        k <= (2/dt)^2 (1 - (dt/element_step)^2) / (1/m + 1/M)."""
        share = max(1.0 - (dt / element_step) ** 2, 0.0)
        return share * (2.0 / dt) ** 2 / (1.0 / self.node_mass_min + 1.0 / self.impactor.mass)

    def check_penalty(self, dt: float, element_step: float) -> None:
        """Refuse an explicit penalty above ``largest_stable_penalty`` (InputError naming
        impactor.penalty)."""
        if self.impactor.penalty is None:
            return
        largest = self.largest_stable_penalty(dt, element_step)
        if self.penalty > largest:
            raise InputError(
                "impactor.penalty",
                f"{self.penalty:.4g} N/mm is too stiff for the time step {dt:.4g} s (lightest "
                f"top-face node {self.node_mass_min:.4g} t, impactor {self.impactor.mass:.4g} t): "
                f"the largest stable penalty is {largest:.4g} N/mm (omit it for the default)",
            )

    def limit_penalty(self, dt: float) -> None:
        """Cap the default penalty for the time step dt (an explicit penalty is kept and
        checked by the caller)."""
        cap = 0.05 * self.node_mass_min * (2.0 / dt) ** 2
        if self.impactor.penalty is None:
            self.penalty = min(self.natural_penalty, cap)

    def prepare(self, dt: float, element_step: float) -> None:
        """At the start of a run with the time step dt (s): the default penalty capped, an
        explicit one checked (``element_step``: the structure's stable step without the safety
        factor, s); the impactor's height taken as its reference."""
        self.limit_penalty(dt)
        self.check_penalty(dt, element_step)
        self.z0 = float(self.centre[2])

    def add_force(self, t: float, f_base: np.ndarray, f_extra: np.ndarray) -> None:
        """Collective: add the contact forces (N) at the current displacement into ``f_base``
        (owned base DOFs, flat) at the top-face DOFs; also the impactor's force and
        acceleration. ``f_extra`` is not touched (the top face has no extra nodes)."""
        np.take(self.displacement.array, self.dofs, out=self.u)
        np.add(self.X, self.u.reshape(-1, 3), out=self.x)
        self.totals[3] = penalty_forces(
            self.x,
            self.centre,
            self.impactor.radius,
            self.cylinder,
            self.penalty,
            self.f,
            self.totals[:3],
        )
        np.take(f_base, self.dofs, out=self.f_dofs)  # the DOFs are distinct: add in place
        self.f_dofs += self.f.reshape(-1)
        np.put(f_base, self.dofs, self.f_dofs)
        self.comm.Allreduce(MPI.IN_PLACE, self.totals, op=MPI.SUM)
        self.force[:] = self.totals[:3]
        self.energy_penalty = float(self.totals[3])
        np.divide(self.force, self.impactor.mass, out=self.acceleration)

    def advance(self, mean_dt: float, dt: float) -> None:
        """v_{n-1/2} -> v_{n+1/2}, c_n -> c_{n+1}."""
        self.velocity += mean_dt * self.acceleration
        self.centre += dt * self.velocity
        self.last_dt = dt

    def total_energy(self) -> float:
        """Kinetic energy at the full step plus the penalty energy (mJ), of the whole run."""
        v = self.velocity + 0.5 * self.last_dt * self.acceleration
        return 0.5 * self.impactor.mass * float(v @ v) + self.energy_penalty

    def energy(self) -> float:
        """This rank's share of ``total_energy`` (mJ): all of it on rank 0 (the impactor is
        one body, known to every rank)."""
        return self.total_energy() if self.comm.rank == 0 else 0.0

    def report(self, row, first: bool) -> None:
        """The contact force (N, z), the impactor's z displacement (mm) and the energy it gave
        up since t = 0 (mJ) into a history row; ``first``: the row at t = 0."""
        energy = self.total_energy()
        if first:
            self.initial = energy
        row.contact_force = float(self.force[2])
        row.impactor_displacement = float(self.centre[2] - self.z0)
        row.impact_work = self.initial - energy

    def suspect(self) -> str:
        return f"the contact penalty (impactor.penalty = {self.penalty:.4g} N/mm) too stiff for it?"

    def state(self) -> dict[str, np.ndarray]:
        return {
            "centre": self.centre.copy(),
            "velocity": self.velocity.copy(),
            "initial": np.array(self.initial),
            "z0": np.array(self.z0),
            "last_dt": np.array(self.last_dt),
        }

    def restore(self, state: dict) -> None:
        self.centre[:] = state["centre"]
        self.velocity[:] = state["velocity"]
        self.initial = float(state["initial"])
        self.z0 = float(state["z0"])
        self.last_dt = float(state["last_dt"])
