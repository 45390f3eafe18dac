"""The loading lever of a mixed-mode bending (MMB) test, ASTM D6671 (``settings.loads.Lever``).

The lever is a rigid, massless bar. Along it lie, in this order: the hinge (pinned to a node
line of the specimen, the upper arm's end), the saddle (a rigid body resting on the top face at
mid-span, half-span L from the hinge) and the load point (c beyond the saddle), pushed down
by a prescribed displacement w_P(t). Being rigid, its z displacement is linear along it, so

    w_s = (L w_P + c w_h) / (L + c)

puts the saddle where the load point and the hinge's displacement w_h (the mean of its nodes)
say. Being massless, it is in equilibrium: with F_s the force of the structure on the saddle
(z, up), moments about the load point and the force balance give

    H = F_s c / (L + c)  on the hinge (pulling the upper arm up),
    P = F_s L / (L + c)  on the load point (the test's load),

and the work P dw_P of the load point equals F_s dw_s + H dw_h, so the lever neither stores
nor makes energy. The run splits P into the mode I pair P (3c - L) / (4L) at the arms' ends
and the mode II load P (c + L) / L at mid-span (Reeder and Crews 1990): c sets the mixity
(``analysis.lefm.mmb_load_arm``).

Each step (``add_force``, at t_n with u_n): w_h from this rank's hinge nodes (one reduction),
the saddle moved to w_s, its contact forces (``contact.Contact``), then H shared equally by the
hinge nodes (the mean w_h is their work-conjugate displacement). The work the lever gives the
structure is the saddle's drive work plus the hinge's, each summed by the trapezoidal rule
like an impactor's, so the run's energy balance closes to the scheme's O(dt^2).

Units: N, mm, s, tonne (mJ).
"""

from __future__ import annotations

import numpy as np
from mpi4py import MPI

from fenics_adaptive.errors import InputError
from fenics_adaptive.model.contact import Contact
from fenics_adaptive.model.forces import Contributor, ForceKind
from fenics_adaptive.model.loading import face_nodes
from fenics_adaptive.settings.loads import Lever


class LoadingLever(Contributor):
    """The MMB lever: moves its saddle (a ``Contact`` with motion "lever") and pulls its
    hinge. ``LoadingLever.on(settings, saddle, structure)`` builds it; ``half_span`` L and
    ``load_arm`` c in mm."""

    name = "lever"
    kind = ForceKind.CONTACT

    @classmethod
    def on(cls, settings: Lever, saddle: Contact, structure) -> LoadingLever:
        """Collective: the lever of ``settings`` on ``structure``, carrying ``saddle``.
        Raises InputError if the hinge has no nodes or lies under the saddle."""
        base = structure.base
        nodes = face_nodes(base, settings.hinge)  # collective
        owned = nodes[nodes < base.V.dofmap.index_map.size_local]
        x = structure.X_base[owned, 0]
        count, x_sum = structure.comm.allreduce(np.array([len(owned), x.sum()]), op=MPI.SUM)
        if count == 0:
            raise InputError("lever.hinge", f"{settings.hinge!r} holds no node")
        half_span = abs(float(saddle.origin[0]) - x_sum / count)
        if half_span < 1e-9 * base.beam.length:
            raise InputError("lever.hinge", "the hinge lies under the saddle (L = 0): the "
                             "saddle goes at mid-span, the hinge at the arm's end")  # fmt: skip
        return cls(settings, saddle, structure.comm, owned, int(count), half_span,
                   structure.base.u.x)  # fmt: skip

    def __init__(self, settings: Lever, saddle: Contact, comm: MPI.Comm, hinge_nodes,
                 hinge_count: int, half_span: float, displacement):  # fmt: skip
        self.settings = settings
        self.saddle = saddle
        saddle.every_step = True  # its force, over all ranks, pulls the hinge each step
        self.comm = comm
        self.displacement = displacement  # the base displacement vector (owned + ghosts)
        self.hinge_dofs = 3 * np.asarray(hinge_nodes, dtype=np.int64) + 2  # z, owned
        self.hinge_count = hinge_count  # over all ranks
        self.half_span = half_span  # mm: L
        self.load_arm = settings.load_arm  # mm: c
        self.hinge_share = self.load_arm / (self.half_span + self.load_arm)  # H / F_s
        self.load_share = self.half_span / (self.half_span + self.load_arm)  # P / F_s
        self.hinge_force = 0.0  # N: H, up on the structure
        self.hinge_displacement = 0.0  # mm: w_h
        self.load_point = 0.0  # mm: w_P
        self.hinge_work = 0.0  # mJ: the work of H on the structure so far
        self.started = False  # whether add_force ran (the trapezoidal rule needs a last value)
        self.uz = np.empty(len(self.hinge_dofs))  # work arrays: the step allocates nothing
        self.f_hinge = np.empty(len(self.hinge_dofs))
        self.sums = np.empty(1)
        # the hinge's displacement summed over the ranks, started when the structure moved
        # (``moved``) and completed by the solver's halo exchange; None: not started for the
        # state add_force sees (t = 0, a refinement's second evaluation, a restart)
        self._hinge_request: MPI.Request | None = None
        self._hinge = 0.0  # mm: the hinge's displacement of the last add_force

    def moved(self) -> None:
        """The owned displacements of the next state are known: start their hinge sum."""
        self._sum_hinge()
        self._hinge_request = (
            self.comm.Iallreduce(MPI.IN_PLACE, self.sums, op=MPI.SUM)
            if self.comm.size > 1
            else MPI.REQUEST_NULL
        )

    def _drop_hinge_sum(self) -> None:
        """Forget a hinge sum started for a state that is no longer the next one (a new run,
        a restart), completing it first (every rank started it; the solver's ``settle`` has
        done so as a rule)."""
        if self._hinge_request:
            self._hinge_request.Wait()
        self._hinge_request = None

    def _sum_hinge(self) -> None:
        np.take(self.displacement.array, self.hinge_dofs, out=self.uz)
        self.sums[0] = self.uz.sum()

    def pending_request(self):
        """The hinge's sum while the halo exchange runs, the saddle's force's while the
        reverse exchange runs."""
        if self._hinge_request:
            return self._hinge_request
        return self.saddle.pending_request()

    def add_force(self, t: float, f_base: np.ndarray, f_extra: np.ndarray) -> None:
        """Collective: the saddle moved by the lever and its contact forces at time t (s),
        added to the owned base DOFs of ``f_base`` (N); its force's sum over the ranks is
        started, and the hinge's force follows in ``complete``."""
        if self._hinge_request is None:  # no sum started for this state: sum it now
            self._sum_hinge()
            if self.comm.size > 1:
                self.comm.Allreduce(MPI.IN_PLACE, self.sums, op=MPI.SUM)
        else:
            if self._hinge_request:  # (the halo exchange's wait completed it, as a rule)
                self._hinge_request.Wait()
            self._hinge_request = None
        self._hinge = float(self.sums[0]) / self.hinge_count
        self.load_point = self.settings.load_point(t)
        self.saddle.centre[2] = self.saddle.origin[2] + (
            self.load_share * self.load_point + self.hinge_share * self._hinge
        )
        self.saddle.add_force(t, f_base, f_extra)

    def complete(self, t: float, f_base: np.ndarray, f_extra: np.ndarray) -> None:
        """The hinge's force (the saddle's share, summed over the ranks in the reverse
        exchange's wait) added to the owned hinge DOFs of ``f_base`` (N), and its work."""
        self.saddle.finish()
        force, hinge = self.hinge_share * float(self.saddle.force[2]), self._hinge
        if self.started:
            self.hinge_work += 0.5 * (self.hinge_force + force) * (hinge - self.hinge_displacement)
        self.started = True
        self.hinge_force, self.hinge_displacement = force, hinge
        self.late_force_size = force
        np.take(f_base, self.hinge_dofs, out=self.f_hinge)  # distinct DOFs: add in place
        self.f_hinge += force / self.hinge_count
        np.put(f_base, self.hinge_dofs, self.f_hinge)

    def late_force_shape(self, n_owned: int) -> np.ndarray:
        """The hinge force's shape: 1 / (hinge nodes) on each owned hinge node's z DOF."""
        shape = np.zeros(n_owned)
        shape[self.hinge_dofs] = 1.0 / self.hinge_count
        return shape

    def prepare(self, dt: float, element_step: float) -> None:
        self._drop_hinge_sum()  # a run starts afresh
        self.saddle.prepare(dt, element_step)

    def advance(self, mean_dt: float, dt: float) -> None:
        self.saddle.advance(mean_dt, dt)  # the saddle keeps its clock; add_force moves it

    def energy(self) -> float:
        """The saddle's penalty energy, this rank's share (mJ): a massless lever holds none."""
        return self.saddle.energy()

    def report(self, row, first: bool) -> None:
        """The saddle's columns, the load point's force P (N, the force the structure pushes
        back with, z: up) and displacement w_P (mm), the hinge's force H (N, on the structure)
        and displacement w_h (mm); the lever's work on the structure into ``impact_work``."""
        self.saddle.report(row, first)
        row.bodies["lever_force"] = self.load_share * float(self.saddle.force[2])
        row.bodies["lever_displacement"] = self.load_point
        row.bodies["hinge_force"] = self.hinge_force
        row.bodies["hinge_displacement"] = self.hinge_displacement
        row.impact_work += self.hinge_work

    def suspect(self) -> str:
        return self.saddle.suspect()

    def state(self) -> dict[str, np.ndarray]:
        return {
            **{f"saddle_{key}": value for key, value in self.saddle.state().items()},
            "hinge_force": np.array(self.hinge_force),
            "hinge_displacement": np.array(self.hinge_displacement),
            "hinge_work": np.array(self.hinge_work),
            "started": np.array(self.started),
        }

    def layout(self, structure) -> dict:
        """The saddle's rows as a contact's (``Contact.layout``); the hinge's values are the
        same on every rank."""
        return {f"saddle_{key}": value for key, value in self.saddle.layout(structure).items()}

    def restore(self, state: dict) -> None:
        self._drop_hinge_sum()
        self.saddle.restore({key[len("saddle_"):]: value for key, value in state.items()
                             if key.startswith("saddle_")})  # fmt: skip
        self.hinge_force = float(state["hinge_force"])
        self.hinge_displacement = float(state["hinge_displacement"])
        self.hinge_work = float(state["hinge_work"])
        self.started = bool(state["started"])
