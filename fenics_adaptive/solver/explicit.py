"""Central-difference time integration with energy bookkeeping.

Units: N, mm, s, tonne (energies in mJ = N mm).

Staggered scheme (velocities at half steps, variable step allowed):

    a_n       = M^-1 (f_ext(t_n) - f_int(u_n))                (prescribed DOFs: their motion)
    v_{n+1/2} = v_{n-1/2} + (dt_{n-1/2} + dt_{n+1/2}) / 2 * a_n
    u_{n+1}   = u_n + dt_{n+1/2} * v_{n+1/2}

with M the lumped masses, or with ``[solver] mass_scaling = "selective"`` the base nodes'
selectively scaled mass (``model.mass_scaling``: a small matrix per column of nodes; the
energies below hold with it as written, M symmetric), and optional mass-proportional damping c
(1/s, per DOF, lumped masses only) applied implicitly to v. The DOFs come
in blocks (``structure.Block``: base nodes, extra nodes of the enrichment), each in DOLFINx
vectors (the memory of the ghosted PETSc Vecs): owned entries are updated, then the ghost entries
of u are refreshed by a forward scatter, so any number of MPI ranks gives the same result up to
the summation order of the assembly.

Energies (global, on output steps): internal work sum 1/2 (f_n + f_{n+1}).du (strain energy
plus what materials dissipate); external work of loads and of prescribed motions (reaction
forces), trapezoidal alike; damping work; and the kinetic energy the scheme conserves with
them. With v- = v_{n-1/2}, v+ = v_{n+1/2}, h = (dt_{n-1/2} + dt_{n+1/2}) / 2 and w = dt_{n+1/2} / h,
the update gives f_n.v+ = (v+ - v-).M.v+ / h (undamped), and the work of a step telescopes
into the change of

    kinetic = 1/2 v+.M.((1 - w) v+ + w v-)          (= 1/2 v+.M.v- at a constant step)

so that kinetic + internal + damping - external - refinement = 0 to round-off, not O(dt^2);
kinetic is within O(dt^2) of 1/2 v_n.M.v_n (it can be below zero at t = 0 when a motion or
load starts abruptly: the first step's impulse). With damping c the same telescoping holds with
the damping work of the updates made so far plus that of the update under way up to t_n,
(c M v_mid).(h v_mid - dt_{n+1/2}/2 v+), v_mid = (v- + v+) / 2
(``blocks.BlockState.energies_at_step``). Refinement energy: the mechanical energy refinement
adds or removes (strain and cohesive: what new nodes change, also added to the internal work;
kinetic: as the scheme measures it just before and just after, which includes the lumped
masses that move, the new nodes' motion and the jump (dt_old - dt_new) / (4 h) |v+ - v-|^2_M
of a new step size).
Dissipated = internal work - solid strain energy - recoverable cohesive energy. A second
balance from the states (``HistoryRow.state_energy_balance``) replaces the internal work by the
strain and stored cohesive energy plus the dissipation the damage laws report themselves
(``cohesive_dissipation``, ``ply_dissipation``): it checks the materials' bookkeeping too.

Guards (``guards.RunGuards``): the run stops as failed (``ElementInverted``,
``EnergyBalanceError``, both ``Diverged``) when an element inverts (checked every 64 steps and
on output steps) or when |energy balance| exceeds ``energy_error_limit`` x the largest energy of
the run so far (on output steps, from step ``guards.ENERGY_MIN_STEPS``); an explicit impactor
penalty above the largest stable one for the step is refused (``Contact.check_penalty``).

The loop is an object, ``ExplicitSolver``: its scalars are one ``SolverState`` (checkpointed by
field name), every force but the face loads comes from contributors (``model.forces``: the
structure's internal forces and tie forces, then a run's own, e.g. a rigid impactor), summed by
kind, what happens is told to observers (``observers.Observer``: history, fields, progress,
refinements, checkpoints), and a refiner returns a ``RefinementEvent`` that the solver reacts
to in one method (``react_to_refinement``). ``run()`` is the thin way to use it in one call.
The solver holds the loop; it delegates the history rows and their energy bookkeeping (sums
over ranks, the energies at t = 0, the balances) to ``history.HistoryRecorder``, the stops as
failed to ``guards.RunGuards``, and keeps each block's work arrays and per-step arithmetic in a
``blocks.BlockState``.
"""

from __future__ import annotations

import dataclasses
import math
import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from typing import ClassVar

import numpy as np
from mpi4py import MPI

from fenics_adaptive.adaptivity.events import RefinementEvent
from fenics_adaptive.errors import InputError
from fenics_adaptive.model.contact import Contact
from fenics_adaptive.model.forces import ForceContributor
from fenics_adaptive.model.loading import on_top_or_bottom
from fenics_adaptive.model.mass_scaling import adaptive_refused, selective_mass
from fenics_adaptive.model.structure import Structure
from fenics_adaptive.parallel.redistribute import PARTIAL, Layout, Rows, dof_keys
from fenics_adaptive.settings.kinds import MotionKind
from fenics_adaptive.settings.solver import Probe, SolverSettings
from fenics_adaptive.solver import guards
from fenics_adaptive.solver.blocks import BLOCK_ARRAYS, BlockState, block_work, move_block
from fenics_adaptive.solver.forces import RunForces
from fenics_adaptive.solver.guards import Diverged, RunGuards
from fenics_adaptive.solver.guards import ElementInverted as ElementInverted  # for readers
from fenics_adaptive.solver.guards import EnergyBalanceError as EnergyBalanceError
from fenics_adaptive.solver.history import COLUMNS as COLUMNS  # where readers find it
from fenics_adaptive.solver.history import HistoryRecorder, HistoryRow
from fenics_adaptive.solver.observers import Observer


class Rebalance(RuntimeError):
    """The run stopped, after writing a checkpoint, to continue on a partition cut again by
    the refinement's cost (``request_rebalance``; ``runner.execute`` continues it)."""

    def __init__(self, t: float, step: int):
        super().__init__(f"stopped at t = {t:.6g} s (step {step}) to re-balance the ranks")
        self.t, self.step = t, step


class Interrupted(RuntimeError):
    """The run was asked to stop (SIGINT, SIGTERM) and stopped after writing a checkpoint."""

    def __init__(self, t: float, step: int):
        super().__init__(f"interrupted at t = {t:.6g} s (step {step}); a checkpoint was written")
        self.t, self.step = t, step


@dataclass
class SolverState:
    """Every scalar the time loop carries from one step to the next (s, mJ). The work sums are
    this rank's shares (the history sums them over ranks). Checkpoints store each field by its
    name (``solver_<name>``); a field missing from a checkpoint takes its default."""

    t: float = 0.0  # s, t_n
    step: int = 0  # n
    dt: float = 0.0  # s, dt_{n+1/2}: the step about to be taken
    dt_prev: float = 0.0  # s, dt_{n-1/2}: the step just taken (0 before the first)
    stable: float = 0.0  # s, the stable step (with the safety factor)
    next_output: float = 0.0  # s, time of the next history row
    next_fields: float = math.inf  # s, time of the next field output
    work_int: float = 0.0  # mJ, internal work
    work_ext: float = 0.0  # mJ, work of loads and prescribed motions
    work_damp: float = 0.0  # mJ, dissipated by mass damping
    initial_energy: float = 0.0  # mJ, kinetic + strain + contributors' energy at t = 0
    initial_potential: float = 0.0  # mJ, strain + stored cohesive energy at t = 0
    largest_energy: float = 0.0  # mJ, the largest energy of the run so far (energy guard)
    # mJ: energy_balance at t = 0 (an initial velocity brings it): the guard judges the change
    initial_balance: float = 0.0
    # mJ: what the step's changes to follow the deformed cells changed the scheme's kinetic
    # measure by (it depends on the next step), with the sign that keeps the balance
    # (``ExplicitSolver.follow_deformed_step``), on rank 0
    kinetic_offset: float = 0.0
    refinements: int = 0  # refinement events so far
    # the forces, work, refinement and outputs at t_n are done (a state taken between two
    # ``step()`` calls); False for one taken right after the motion to t_n (checkpoints)
    evaluated: bool = False

    # the fields that are a rank's share of a sum (the rest are the same on every rank)
    PARTIAL_FIELDS: ClassVar[tuple[str, ...]] = (
        "work_int",
        "work_ext",
        "work_damp",
        "kinetic_offset",
    )

    def as_dict(self) -> dict[str, float | int | bool]:
        return dataclasses.asdict(self)

    @classmethod
    def from_dict(cls, values: dict) -> SolverState:
        """From ``as_dict`` or a checkpoint's solver part (0-d arrays); extra keys ignored."""
        return cls(
            **{
                f.name: type(f.default)(values[f.name])
                for f in dataclasses.fields(cls)
                if f.name in values
            }
        )


@dataclass
class RunStats:
    steps: int = 0
    wall_time: float = 0.0
    time_step: float = 0.0
    stable_time_step: float = 0.0
    critical: str = ""
    refinements: int = 0
    reaction_seconds: float = 0.0  # this rank's wall time in react_to_refinement
    history: list[HistoryRow] = field(default_factory=list)


def choose_time_step(structure: Structure, settings: SolverSettings) -> tuple[float, float, str]:
    """(step used, stable step, where the limit is). Stable = safety * min(L_e / c, cohesive)
    (``Structure.stable_time_step``: with its scaled mass if it has one, ``prepare_mass``)."""
    limit, where = structure.stable_time_step()
    stable = settings.safety_factor * limit
    if settings.time_step is None:
        return stable, stable, where
    if settings.time_step > stable * (1.0 + 1e-12):
        raise InputError(
            "solver.time_step",
            f"{settings.time_step:.4g} s exceeds the stable step {stable:.4g} s (safety factor "
            f"{settings.safety_factor}, limited by {where}); the run would blow up",
        )
    return settings.time_step, stable, where


def prepare_mass(structure: Structure, settings: SolverSettings, refines: bool) -> None:
    """Collective: give ``structure`` the mass ``settings.mass_scaling`` asks for: its scaled
    mass (``model.mass_scaling.selective_mass``, built once per target step) or none. Before
    the stable step is chosen. ``refines``: the run has a refiner. Raises InputError for what a
    scaled mass cannot do yet: mass-proportional damping, refinement."""
    if settings.mass_scaling == "none":
        structure.scaled_mass = None
        return
    if settings.mass_damping > 0.0:
        raise InputError(
            "solver.mass_damping",
            'mass-proportional damping is not yet available with mass_scaling = "selective"',
        )
    if refines:
        raise adaptive_refused()
    current, wanted = structure.scaled_mass, settings.mass_scaling_step
    if current is None or (wanted is not None and wanted != current.target_step):
        structure.scaled_mass = selective_mass(structure, wanted)


def _motion_groups(motions) -> list[tuple[Callable[[float], float], list[int], list[float]]]:
    """The motions that change, grouped by their time function (the amplitude, or its
    integral for a velocity): (function, motion indices, values), so that a step evaluates
    each function once however many motions share it (value x function(t), as
    ``PrescribedMotion.displacement``)."""
    groups: dict = {}
    for k, motion in enumerate(motions):
        if motion.constant:
            continue
        velocity = motion.kind == MotionKind.VELOCITY
        _, indices, values = groups.setdefault(
            (motion.amplitude, velocity),
            (motion.amplitude.integral if velocity else motion.amplitude, [], []),
        )
        indices.append(k)
        values.append(motion.value)
    return list(groups.values())


def _move(groups, t: float, out: np.ndarray) -> None:
    """Each changing motion's displacement at time t (s) into ``out`` (mm, by motion)."""
    for function, indices, values in groups:
        scale = function(t)
        for k, value in zip(indices, values, strict=True):
            out[k] = value * scale


# what a refiner is: called before every step, it refines the structure (collectively) or not
Refiner = Callable[[float, Structure], RefinementEvent | None]

POLL_EVERY = 64  # steps between the polls for a stop request, inversion and divergence


class ExplicitSolver:
    """The central-difference time loop of one structure, as an object with explicit state.

    ``structure``: the model to integrate; ``settings``, ``probe``: what to run and report;
    ``contributors``: force contributors beside the structure's own (``model.forces``: a rigid
    impactor, ``contact.Contact``, or a user's own; more with ``add_contributor`` before the
    start); the run sums the structure's (``Structure.contributors``: internal forces, tie
    forces) and then these, by kind. ``observers``: told of history rows, field and checkpoint
    times, progress, refinements (``observers.Observer``). ``refiner(t, structure)``: called
    before every step, refines the structure and returns the ``RefinementEvent`` or None.
    ``stop_requested()``: polled every 64 steps (as is ``request_stop()``); a stop writes a
    checkpoint (observers) and raises ``Interrupted``. ``time_step``: forces the step past the
    stability check (for tests that show what an unstable step does).

    Use: ``start()`` (or ``restore(state)``), then ``step()`` until it returns False, or
    ``run()``. Between two steps the state is complete at t_n: u_n, the forces at t_n, the
    history row of t_n if one was due; the velocity held is v_{n-1/2}.

    Every rank must make the same calls (the steps are collective)."""

    def __init__(
        self,
        structure: Structure,
        settings: SolverSettings,
        probe: Probe,
        contributors: Iterable[ForceContributor] = (),
        observers: Iterable[Observer] = (),
        refiner: Refiner | None = None,
        stop_requested: Callable[[], bool] | None = None,
        time_step: float | None = None,
    ):
        self.structure = structure
        self.settings = settings
        self.comm = structure.comm
        # a refinement's equilibration keeps the accelerations of the DOFs it moves
        structure.accelerations = lambda: (
            (self.blocks[0].acc, self.blocks[1].acc) if self.blocks else None
        )
        structure.contact_forces = lambda: self.forces.contact_force if self.blocks else None
        # the structure's contributors and the run's own (checkpointed with the solver)
        self.forces = RunForces(structure, contributors)
        self.observers: list[Observer] = list(observers)
        self.refiner = refiner
        self.stop_requested = stop_requested
        self.forced_step = time_step
        self.forced = settings.time_step is not None or time_step is not None
        self.now = SolverState()
        self.stats = RunStats()
        self.where = ""  # what limits the stable step
        self.started = False
        self._stop = False
        self._rebalance_due = False
        self._refined_now = False  # the evaluation under way refined the structure
        self._not_finite = False  # this rank saw a non-finite internal work (told at a poll)
        self._damping_changes = math.inf  # next time a stabilisation damping window closes
        self._damped = settings.mass_damping > 0.0
        self.blocks: list[BlockState] = []  # the work arrays: from start() or restore()
        self._u_arrays: list[np.ndarray] = []  # each block's u, owned + ghost entries
        # the poll's flags (stop, non-finite, inverted) summed over the ranks while the next
        # step runs, and what this rank saw (``poll``)
        self._poll_flags = np.zeros(3, dtype=np.int32)
        self._poll_request = MPI.REQUEST_NULL
        self._poll_open = False
        self._polled_inversion: str | None = None
        # a stop that a poll settled inside ``_evaluate`` (a history row waits for it on
        # several ranks) is acted on once t_n is evaluated: a checkpoint taken halfway would
        # hold the step's work and count it again when a restart evaluates t_n
        self._evaluating = False
        self._stop_due = False
        # compute the interior elements while the displacements' halo exchange is under way
        # (False: wait for it first, as on one rank; to measure what the overlap hides)
        self.overlap = True
        self._exchange_open = False
        self._exchange_also: list = []  # the requests the open exchange's wait completes
        # the step follows the deformed cells (finite kinematics, lumped masses: a scaled
        # mass's element bound is of the reference geometry; set in ``_set_up``)
        self._follows_deformation = False
        self.inversion: guards.InversionGuard | None = None
        n_motions = len(structure.motions)
        self._motion_now, self._motion_next = np.zeros(n_motions), np.zeros(n_motions)
        # the motions that change: the others (clamps) hold their one value in both arrays
        self._moving = _motion_groups(structure.motions)
        for k, motion in enumerate(structure.motions):
            self._motion_now[k] = self._motion_next[k] = motion.displacement(0.0)
        self._next_time = math.nan  # s, where _motion_next was evaluated
        self._clock = 0.0
        self.guards = RunGuards(self)
        self.recorder = HistoryRecorder(structure, probe, self.forces.added, self.guards)

    def add_contributor(self, contributor: ForceContributor) -> None:
        """One more force contributor of this run (``model.forces``), before ``start()`` or
        ``restore()``. Raises ValueError if its name is taken."""
        if self.started:
            raise RuntimeError("ExplicitSolver.add_contributor after the run started")
        self.forces.add(contributor)

    @property
    def contributors(self) -> list[ForceContributor]:
        """Every force contributor of the run: the structure's, then the run's own."""
        return self.forces.contributors

    # ------------------------------------------------------------------ read between steps
    @property
    def t(self) -> float:
        """s, the time t_n the state is at."""
        return self.now.t

    @property
    def u(self) -> np.ndarray:
        """mm, the base nodes' displacement u_n (owned DOFs, flat; a view, do not write)."""
        return self.blocks[0].u

    @property
    def v(self) -> np.ndarray:
        """mm/s, the base nodes' velocity v_{n-1/2} (owned DOFs, flat; a view)."""
        return self.blocks[0].v

    @property
    def internal_force(self) -> np.ndarray:
        """N, f_int(u_n) on the base DOFs (owned, flat; a view)."""
        return self.blocks[0].f

    @property
    def external_force(self) -> np.ndarray:
        """N, f_ext(t_n) on the base DOFs (owned, flat; a view)."""
        return self.blocks[0].f_ext

    def face_force(self, out: np.ndarray | None = None) -> np.ndarray:
        """N, the forces from outside on the top and bottom faces at t_n, besides the face
        loads, on the base DOFs (owned, flat): the reactions of the prescribed motions of those
        faces (``top``, ``bottom``, or an edge of theirs such as ``top&x0``) and the CONTACT
        contributors' forces (an impactor; not a rigid body on every node, which presses edges
        and ends). Into ``out`` if given, else a new array."""
        base = self.blocks[0]
        out = np.zeros(base.block.n_owned) if out is None else out
        out[:] = 0.0
        on_faces = np.array([on_top_or_bottom(m.face) for m in self.structure.motions], bool)
        if len(on_faces):
            held = on_faces[base.block.fixed_motion]
            out.put(base.block.fixed[held], base.reaction[held])
        contact = self.forces.contact_force
        if contact is not None:
            out += contact[0]
            for body in self.forces.contact:  # (a body on every node presses edges too)
                if isinstance(body, Contact) and body.every_node:
                    body.take_out_of(out)
        return out

    @property
    def last_row(self) -> HistoryRow | None:
        """The last history row of this run (energies in mJ), None before the first."""
        return self.stats.history[-1] if self.stats.history else None

    @property
    def interface_state(self) -> np.ndarray:
        """The structure's refinement state: NONE, WEAK or STRONG per (owned cell,
        interface)."""
        return self.structure.interface_state

    @property
    def finished(self) -> bool:
        """The state is at the end time and evaluated there."""
        s = self.now
        return s.evaluated and s.t >= self.settings.end_time - 1e-9 * s.dt

    def request_rebalance(self) -> None:
        """Collective (every rank alike): at the end of this evaluation (or of the next one),
        write a checkpoint and raise ``Rebalance``, unless the run is complete."""
        self._rebalance_due = True

    def request_stop(self) -> None:
        """Stop at the next poll (every 64 steps; on several ranks one step after it, when
        every rank knows) with a checkpoint: ``Interrupted``."""
        self._stop = True

    # ------------------------------------------------------------------ start, state
    def start(
        self,
        initial_displacement: np.ndarray | None = None,
        initial_velocity: np.ndarray | None = None,
    ) -> None:
        """Collective: begin at t = 0 from ``initial_displacement`` and ``initial_velocity``
        (mm, mm/s; base DOFs, owned + ghost entries; default zero; the velocity is taken as
        v_{-1/2}), and evaluate t = 0 (forces, the first history row)."""
        self.settle()  # nothing of an earlier run left under way
        self._not_finite = False
        dt, stable = self._set_up()
        field_interval = self.settings.field_interval
        self.now = SolverState(
            dt=dt, stable=stable, next_fields=0.0 if field_interval else math.inf
        )
        base = self.blocks[0].block
        base.u.array[:] = 0.0 if initial_displacement is None else initial_displacement
        base.v.array[:] = 0.0 if initial_velocity is None else initial_velocity
        if initial_displacement is None and initial_velocity is None:
            # from rest means the extra nodes too (a structure run before, e.g. by a timing
            # harness, keeps their last motion otherwise: energy the balance never saw put in)
            for state in self.blocks[1:]:
                state.block.u.array[:] = 0.0
                state.block.v.array[:] = 0.0
        self._begin()

    def restore(self, state: dict) -> None:
        """Collective: continue from ``state()`` (or a checkpoint's solver part,
        ``checkpoint.solver_state``) taken on the same rank of the same model; the structure
        must already be at the same moment (``checkpoint.restore_structure``)."""
        self.settle()  # nothing of an earlier run left under way
        self._not_finite = False
        self._set_up()  # as a fresh start does (the contributors' penalties)
        self.now = SolverState.from_dict(state)
        self.stats.time_step, self.stats.stable_time_step = self.now.dt, self.now.stable
        self.stats.refinements = self.now.refinements
        for index, block_state in enumerate(self.blocks):
            block_state.block.u.array[:] = state[f"block{index}_u_all"]
            block_state.block.v.array[:] = state[f"block{index}_v_all"]
            for name in BLOCK_ARRAYS[2:]:
                getattr(block_state, name)[:] = state[f"block{index}_{name}"]
        self.forces.restore(state)
        self.refresh_damping()
        self._begin()

    def state(self) -> dict[str, np.ndarray | float | int | bool]:
        """What ``restore`` needs to continue exactly (this rank): the ``SolverState`` fields
        by name, per block ``BLOCK_ARRAYS`` as ``block<i>_<name>``, the state of each of the
        run's own contributors (not the structure's: ``Structure.state``) as
        ``<name>_<key>``. Copies."""
        out: dict = self.now.as_dict()
        for index, block_state in enumerate(self.blocks):
            out[f"block{index}_u_all"] = block_state.block.u.array.copy()
            out[f"block{index}_v_all"] = block_state.block.v.array.copy()
            for name in BLOCK_ARRAYS[2:]:
                out[f"block{index}_{name}"] = getattr(block_state, name).copy()
        out.update(self.forces.state())
        return out

    def layout(self) -> dict[str, Layout]:
        """How the rows of ``state()``'s arrays are indexed, by the same names
        (``parallel.redistribute``): each block's DOFs by their stable keys, the work sums as
        each rank's share, the run's own contributors' by theirs. Raises ``NotMovable`` for
        a contributor with a state and no layout."""
        out: dict[str, Layout] = {name: PARTIAL for name in SolverState.PARTIAL_FIELDS}
        structure = self.structure
        node_keys = (structure.node_keys, structure.extra_node_keys())
        for index, (block, nodes) in enumerate(zip(structure.blocks, node_keys, strict=True)):
            keys = dof_keys(nodes)
            owned = np.arange(len(keys)) < block.n_owned
            for name in ("u_all", "v_all"):
                out[f"block{index}_{name}"] = Rows(keys, owned)
            for name in ("du", "f_old", "f_ext_old"):
                out[f"block{index}_{name}"] = Rows(keys[: block.n_owned])
            out[f"block{index}_reaction_old"] = Rows(keys[block.fixed])
        out.update(self.forces.layout(structure))
        return out

    def _set_up(self) -> tuple[float, float]:
        """Collective: the work arrays and the inversion guard of the structure as it is now;
        (step, stable step) in s for it, the contributors prepared for them."""
        prepare_mass(self.structure, self.settings, self.refiner is not None)
        # a scaled mass that adds none (thick layers) leaves the lumped arithmetic alone
        scaled_mass = self.structure.scaled_mass
        scaled = [scaled_mass if scaled_mass is not None and scaled_mass.adds_mass else None, None]
        self.blocks = [
            BlockState(b, self.settings.mass_damping, scaled_mass=m)
            for b, m in zip(self.structure.blocks, scaled, strict=True)
        ]
        self._u_arrays = [state.block.u.array for state in self.blocks]
        self.inversion = guards.InversionGuard(self.structure)
        dt, stable, self.where = choose_time_step(self.structure, self.settings)
        if self.forced_step is not None:
            dt = self.forced_step
        self.stats = RunStats(time_step=dt, stable_time_step=stable, critical=self.where)
        self.forces.prepare(self.blocks, dt, stable / self.settings.safety_factor)
        base = self.blocks[0]
        self._follows_deformation = self.structure.base.finite and base.scaled_mass is None
        if base.scaled_mass is not None:  # its acceleration shares travel with the forces
            self.structure.lumped.carry_base()
            base.late_forces(self.forces.late)
        return dt, stable

    def _begin(self) -> None:
        """The prescribed DOFs on their values at t_n; observers told; t_n evaluated (unless
        the state was taken evaluated: then only its forces are recomputed)."""
        self.set_prescribed()
        for state in self.blocks:
            state.u.put(state.block.fixed, state.u_now)
        self.structure.halo.forward(self._u_arrays)
        self.started = True
        for observer in self.observers:
            observer.on_start(self)
        self._clock = time.perf_counter()
        with np.errstate(over="ignore", invalid="ignore"):
            if self.now.evaluated:
                self.forces_and_accelerations()
            else:
                self._evaluate()

    # ------------------------------------------------------------------ the loop
    def step(self) -> bool:
        """Collective: one central-difference step t_n -> t_{n+1} and the evaluation of
        t_{n+1} (forces, work, refinement, the outputs due); returns False (and does nothing)
        once the end time is reached. A loop of one's own that stops earlier calls ``settle()``
        (on several ranks a reduction may still be under way)."""
        with np.errstate(over="ignore", invalid="ignore"):
            return self._step()

    def run(self) -> RunStats:
        """Collective: ``start()`` unless started, then step to ``settings.end_time``.
        Returns the run's statistics and history rows."""
        # a diverging run is reported by Diverged, not by floating-point warnings
        with np.errstate(over="ignore", invalid="ignore"):
            if not self.started:
                self.start()
            try:
                while self._step():
                    pass
            finally:  # also when a rank raises (the others raise alike: errors are shared)
                self.settle()
        self.stats.steps = self.now.step
        self.stats.wall_time = time.perf_counter() - self._clock
        self.stats.refinements = self.now.refinements
        for observer in self.observers:
            observer.on_finish(self.stats)
        return self.stats

    def _step(self) -> bool:
        if not self.started:
            raise RuntimeError("ExplicitSolver.step before start() or restore()")
        if self.finished:
            self._settle_poll(stop=False)  # the run is complete: a stop asks for nothing
            self.settle()
            return False
        self.advance()
        s = self.now
        polling = s.step % POLL_EVERY == 0
        # periodic, and the last state (a restart with a later end time extends the run)
        every = self.settings.checkpoint_interval
        checkpointing = bool(every) and (
            s.step % every == 0 or s.t >= self.settings.end_time - 1e-9 * s.dt
        )
        if self._poll_open or polling or checkpointing:
            self._finish_exchange()  # they read the whole state (and the poll's flags)
        if self._poll_open:  # the step's halo exchange completed the last poll's reduction
            self._settle_poll()
        if polling:
            self.poll()
        if checkpointing:
            self.checkpoint()
        self._evaluate()
        return True

    def follow_deformed_step(self) -> None:
        """Collective, at t_n evaluated (forces and accelerations with the step as it was): the
        stable step of the deformed cells (``Structure.stable_time_step(current=True)``: a cell
        that a crush made thinner steps shorter). The step falls to it when it is shorter,
        never rises (the contacts' penalties were capped for the step they started with); a
        forced step it falls below stops the run (``Diverged``), as after a refinement; a
        limit that is not a positive number (an inverted cell) is left to the guards. The
        scheme's kinetic measure at t_n depends on the next step: its jump is booked
        (``SolverState.kinetic_offset``), so that the energy balance still closes."""
        s = self.now
        limit, where = self.structure.stable_time_step(current=True)
        if not 0.0 < limit < math.inf:
            return
        stable = self.settings.safety_factor * limit
        s.stable, self.where = stable, where
        self.stats.stable_time_step, self.stats.critical = stable, where
        if s.dt <= stable * (1.0 + 1e-12):
            return
        if self.forced:
            raise Diverged(
                f"t = {s.t:.6g} s: the deformed cells' stable step is {stable:.4g} s ({where}),"
                f" below the forced step {s.dt:.4g} s"
            )
        before = self._energy_at_step()
        s.dt = stable
        self.set_prescribed()  # the prescribed DOFs' targets at the new t + dt
        self._accelerate(self.forces.contact_force)  # the same forces, the new step
        after = self._energy_at_step()
        if self.comm.rank == 0:  # one value over all ranks, booked once
            s.kinetic_offset += before - after

    def _evaluate(self) -> None:
        """Everything at t_n: forces and accelerations, the work of the step just made, a
        refinement, the outputs due; then a stop or a re-balance asked for meanwhile, unless
        this evaluation refined: the new extra nodes on a prescribed face take their values
        with the next step, and a checkpoint of now would not restore to this state (they
        wait for the next evaluation, one step later)."""
        self._evaluating = True
        self._refined_now = False
        try:
            self._evaluate_state()
        except BaseException:
            self._stop_due = False  # what failed is reported, not a stop
            raise
        finally:
            self._evaluating = False
        if self.finished:  # the run is complete: nothing to stop or re-balance
            self._stop_due = self._rebalance_due = False
            return
        if self._refined_now:
            return
        if self._stop_due:
            self._stop_due = False
            self.checkpoint()
            raise Interrupted(self.now.t, self.now.step)
        if self._rebalance_due:
            self._rebalance_due = False
            self.checkpoint()
            raise Rebalance(self.now.t, self.now.step)

    def _evaluate_state(self) -> None:
        s = self.now
        self.forces_and_accelerations()
        if s.step > 0:
            self.update_work()
        if self.refiner is not None:
            # refinement between steps: the work of the last step was counted with the old
            # structure's forces above; the new one starts from its own forces at t_n
            event = self.refiner(s.t, self.structure)
            if event:
                self._refined_now = True
                started = time.perf_counter()
                self.react_to_refinement(event)
                self.stats.reaction_seconds += time.perf_counter() - started
        if self._follows_deformation and s.t >= s.next_output - 1e-9 * s.dt:
            self.follow_deformed_step()  # where a history row is due (it waits anyway)
        if s.t >= self._damping_changes:  # a stabilisation window closed: the update from t_n
            self.refresh_damping()
        if s.t >= s.next_output - 1e-9 * s.dt or s.t >= self.settings.end_time - 1e-9 * s.dt:
            self.record_history()
            while s.next_output <= s.t + 1e-9 * s.dt:
                s.next_output += self.settings.output_interval
        if s.t >= s.next_fields - 1e-9 * s.dt:
            for observer in self.observers:
                observer.on_fields(s.t)
            while s.next_fields <= s.t + 1e-9 * s.dt:
                s.next_fields += self.settings.field_interval
        s.evaluated = True

    def set_prescribed(self) -> None:
        """The prescribed DOFs' values at t_n and t_n + dt into every block."""
        s = self.now
        if self._next_time == s.t:  # the last call's t + dt is this t, bit for bit
            np.copyto(self._motion_now, self._motion_next)
        else:
            _move(self._moving, s.t, self._motion_now)
        self._next_time = s.t + s.dt
        _move(self._moving, self._next_time, self._motion_next)
        for state in self.blocks:
            if len(state.u_now):
                self._motion_now.take(state.block.fixed_motion, out=state.u_now)
                self._motion_next.take(state.block.fixed_motion, out=state.u_next)

    def forces_and_accelerations(self) -> None:
        """Collective: the forces (``forces.RunForces``), accelerations and reactions at t_n
        for the current structure."""
        s = self.now
        # a scaled mass: its shares of the accelerations travel with the forces
        carry = self._share_accelerations if self.blocks[0].scaled_mass is not None else None
        if self._exchange_open:
            contact = self.forces.evaluate(
                s.t, self.blocks, self._finish_exchange, self.structure.halo.progress, carry
            )
        else:
            contact = self.forces.evaluate(s.t, self.blocks, carry=carry)
        self._accelerate(contact)

    def _share_accelerations(self, contact: list[np.ndarray] | None) -> np.ndarray:
        """The base block's shares of the accelerations (a scaled mass, before the forces'
        exchange: ``BlockState.share_accelerations``)."""
        s = self.now
        mean_dt = 0.5 * (s.dt_prev + s.dt)
        return self.blocks[0].share_accelerations(contact[0] if contact else None, s.dt, mean_dt)

    def _accelerate(self, contact: list[np.ndarray] | None) -> None:
        """The accelerations and reactions of every block at t_n from its forces as they are
        (``contact``: the CONTACT contributors' force per block, or None)."""
        s = self.now
        mean_dt = 0.5 * (s.dt_prev + s.dt)
        for index, state in enumerate(self.blocks):
            if state.live:
                state.accelerate(contact[index] if contact else None, s.dt, mean_dt)

    def update_work(self) -> None:
        """The work over the step just made (trapezoidal in the forces), this rank's share."""
        s = self.now
        for state in self.blocks:
            if not state.live:
                continue
            internal, external = block_work(
                state.f_old,
                state.f,
                state.f_ext_old,
                state.f_ext,
                state.du,
                state.block.fixed,
                state.reaction_old,
                state.reaction,
            )
            s.work_int += internal
            s.work_ext += external
        # the internal work sums every DOF's force and motion: a single non-finite value
        # anywhere shows here, in the step it appears (in parallel the other ranks learn it at
        # the next poll)
        if not math.isfinite(s.work_int):
            self._not_finite = True
            if self.comm.size == 1:
                self.guards.not_finite()

    def react_to_refinement(self, event: RefinementEvent) -> None:
        """Collective, the one reaction to a refinement at t_n: its potential energy change
        booked as internal work, new work arrays for the grown blocks, the stable step chosen
        again, the stabilisation of the new refinement started, the forces of the refined
        structure at t_n, the observers told."""
        s, settings, structure = self.now, self.settings, self.structure
        s.refinements += 1
        # the strain and cohesive energy the refinement changed count as internal work (booked
        # once, on rank 0), so that the dissipated energy does not jump
        if self.comm.rank == 0:
            s.work_int += event.potential_change
        # the old work arrays still hold v_{n-1/2}, a_n, the masses and damping of before
        before = self._energy_at_step()
        self.blocks = [
            BlockState(b, settings.mass_damping, old)
            for b, old in zip(structure.blocks, self.blocks, strict=True)
        ]
        self._u_arrays = [state.block.u.array for state in self.blocks]
        self.forces.resize(self.blocks)
        self.inversion.refresh()
        limit, self.where = structure.stable_time_step(current=self._follows_deformation)
        s.stable = settings.safety_factor * limit
        self.stats.stable_time_step, self.stats.critical = s.stable, self.where
        if not self.forced:
            s.dt = s.stable
        elif s.dt > s.stable * (1.0 + 1e-12):
            raise Diverged(
                f"t = {s.t:.6g} s: after refinement the stable step is {s.stable:.4g} s "
                f"({self.where}), below the forced step {s.dt:.4g} s"
            )
        self.set_prescribed()
        structure.start_stabilisation(s.t)
        self.refresh_damping()
        self.forces_and_accelerations()
        # the refinement's kinetic energy as the scheme measures it (the masses moved, the new
        # nodes' motion, a new step, the damping of the update under way), not as the structure
        # estimated it from the half-step velocities
        change = self._energy_at_step() - before
        structure.refinement.book_kinetic(change - (event.energy_change - event.potential_change))
        for observer in self.observers:
            observer.on_refinement(event, s.dt, self.where)

    def _energy_at_step(self) -> float:
        """Collective: kinetic energy + damping work of the update under way at t_n (mJ, over
        all ranks), as the history measures them (``BlockState.energies_at_step``)."""
        s = self.now
        mean_dt = 0.5 * (s.dt_prev + s.dt)
        local = sum(sum(b.energies_at_step(mean_dt, s.dt)) for b in self.blocks)
        return self.comm.allreduce(local, op=MPI.SUM)

    def refresh_damping(self) -> None:
        """Per-DOF damping: the global coefficient plus the open stabilisation windows."""
        windows = self.structure.active_damping(self.now.t)
        for index, state in enumerate(self.blocks):
            state.damping[:] = self.settings.mass_damping
            for window in windows:
                if window.block == index:
                    state.damping[window.dofs] += window.coefficient
            state.damping[state.block.fixed] = 0.0
        self._damping_changes = min((w.until for w in windows), default=math.inf)

    def advance(self) -> None:
        """t_n -> t_{n+1}: velocities, displacements (prescribed DOFs on their values), the
        constrained extra nodes, the contributors' own motion."""
        s = self.now
        mean_dt = 0.5 * (s.dt_prev + s.dt)
        damped = self._damped or self._damping_changes < math.inf
        for state in self.blocks:
            if not state.live:
                continue
            if damped:
                s.work_damp += state.damped_velocity(mean_dt)
            # u_n -> u_{n+1}; the prescribed DOFs land exactly on their prescribed values
            move_block(
                state.v,
                state.acc,
                mean_dt,
                s.dt,
                not damped,
                state.du,
                state.u,
                state.block.fixed,
                state.u_next,
                state.f,
                state.f_old,
                state.f_ext,
                state.f_ext_old,
                state.reaction,
                state.reaction_old,
            )
        self.forces.moved()
        self._start_exchange()
        self.forces.advance(mean_dt, s.dt)
        s.dt_prev = s.dt
        s.t += s.dt
        s.step += 1
        s.evaluated = False
        self.set_prescribed()

    def _start_exchange(self) -> None:
        """Collective: start the step's one exchange of the neighbours' displacements (both
        blocks at once). Its wait also completes the reductions under way (the poll's, a sum
        of owned displacements: the lever's hinge). On several ranks it is finished by the
        internal forces once they have computed the interior elements (``RunForces.evaluate``),
        so that the messages travel while they compute; with ``overlap`` False, here. On one
        rank nothing travels and no reduction is under way: only the border follows."""
        halo = self.structure.halo
        if not halo.active:  # one rank: nothing travels, no reduction is under way
            self.structure.follow_border()
            return
        halo.forward_start(self._u_arrays)
        self._exchange_also = self._pending()
        self._exchange_open = True
        if not (self.overlap and halo.active):
            self._finish_exchange()

    def _finish_exchange(self) -> None:
        """The ghosts' displacements in (waiting for them if they have not arrived), the
        border of the refined regions on its masters; nothing if no exchange is open."""
        if not self._exchange_open:
            return
        self._exchange_open = False
        self.structure.halo.forward_finish(self._u_arrays, also=self._exchange_also)
        self.structure.follow_border()

    def poll(self) -> None:
        """Collective, every 64 steps: progress; a stop request, an inversion or a non-finite
        solution on any rank. On one rank it acts at once. On several the flags are combined
        by a nonblocking reduction that the next step's halo exchange completes in its own wait
        (``_pending``), and every rank acts on them one step later, at the same step: a poll
        costs no synchronisation of its own."""
        s = self.now
        for observer in self.observers:
            observer.on_progress(s.t)
        stop = self._stop or (self.stop_requested is not None and self.stop_requested())
        inverted = self.inversion.check(s.t)
        if self.comm.size == 1:
            self._act_on_poll(stop, False, inverted, inverted is not None)
            return
        self._settle_poll()  # one still open (a caller that polls twice without a step)
        self._poll_flags[:] = (stop, self._not_finite, inverted is not None)
        self._poll_request = self.comm.Iallreduce(MPI.IN_PLACE, self._poll_flags, op=MPI.MAX)
        self._poll_open, self._polled_inversion = True, inverted

    def _settle_poll(self, stop: bool = True) -> None:
        """Act on an open poll's combined flags (waiting for them if nothing completed the
        reduction yet); ``stop``: whether a stop request still applies."""
        if not self._poll_open:
            return
        if self._poll_request:
            self._poll_request.Wait()
        self._poll_open = False
        flags = self._poll_flags
        self._act_on_poll(
            stop and bool(flags[0]), bool(flags[1]), self._polled_inversion, bool(flags[2])
        )

    def _act_on_poll(
        self, stop: bool, not_finite: bool, inverted: str | None, inverted_anywhere: bool
    ) -> None:
        """Collective when any flag is set (set alike on every rank): the run stops as failed
        (not finite, inverted: ``inverted`` is this rank's message) or with a checkpoint
        (``Interrupted``)."""
        if not_finite:
            self.guards.not_finite()
        self.guards.inverted(inverted, inverted_anywhere)
        if stop and self._evaluating:  # at the end of the evaluation (``_evaluate``)
            self._stop_due = True
        elif stop:
            self.checkpoint()
            raise Interrupted(self.now.t, self.now.step)

    def settle(self) -> None:
        """Complete every nonblocking reduction under way (the poll's, the contributors'),
        without acting on the poll: a run that ends, fails or is started again leaves none
        behind. Every rank must call it (each completes what all ranks started)."""
        self._finish_exchange()
        pending = self._pending()
        if pending:
            MPI.Request.Waitall(pending)
        self._poll_open = False

    def _pending(self) -> list:
        """The nonblocking reductions under way that the next halo exchange completes: the
        contributors' (``RunForces.pending_requests``) and the poll's."""
        pending = self.forces.pending_requests()
        if self._poll_request:
            pending.append(self._poll_request)
        return pending

    def checkpoint(self) -> None:
        self._settle_poll()  # a state the poll finds failed is not written (output step)
        for observer in self.observers:
            observer.on_checkpoint(self)

    # ------------------------------------------------------------------ history and guards
    def record_history(self) -> None:
        """Collective: the history row of t_n (observers get it), after the guards on
        inversion and finiteness, and before the energy guard (the row that breaks it is in
        the history)."""
        self._settle_poll()  # the guards' verdict first, as on one rank (output step)
        row = self.recorder.row(self.now, self.blocks, self.inversion)
        self.stats.history.append(row)
        for observer in self.observers:
            observer.on_history(row)
        self.guards.energy(row)


def run(
    structure: Structure,
    settings: SolverSettings,
    probe: Probe,
    *,
    contributors: Iterable[ForceContributor] = (),
    observers: Iterable[Observer] = (),
    refiner: Refiner | None = None,
    time_step: float | None = None,
    initial_displacement: np.ndarray | None = None,
    initial_velocity: np.ndarray | None = None,
) -> RunStats:
    """Integrate from t = 0 to ``settings.end_time``: ``ExplicitSolver(...)`` started from
    ``initial_displacement`` and ``initial_velocity`` (mm, mm/s; base DOFs, owned + ghost
    entries; default zero), then ``run()``. The arguments: those of ``ExplicitSolver``."""
    solver = ExplicitSolver(
        structure, settings, probe, contributors, observers, refiner, time_step=time_step
    )
    solver.start(initial_displacement, initial_velocity)
    return solver.run()
