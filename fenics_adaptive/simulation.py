"""A config built into a model and a solver, driven from Python: ``Simulation``.

Units: N, mm, s, tonne (stress MPa, energy mJ = N mm).

The data flow of one run: the config's mesh (``meshes.beam``), the model on it
(``model.forms``), its loads and the structure the solver integrates (``build_structure``), the
refinement the config and any Python indicator ask for (``RefinementHook``), an impactor if the
config has one (``model.contact``), and the explicit solver (``solver.explicit``). ``Simulation``
holds them; ``run()`` integrates to the end time, ``start()`` + ``step()`` advance one step at
a time with the state readable in between, observers of one's own (``solver.observers``) see
the run's events. ``runner.execute`` (the ``fenics-adaptive run`` command) is a ``Simulation``
plus a run folder: history file, fields, checkpoints, summary and plots.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np
from mpi4py import MPI

from fenics_adaptive.adaptivity.events import RefinementEvent, note, refine
from fenics_adaptive.adaptivity.indicators import (
    IndexHistory,
    default_interval,
    front_distances,
    front_requests,
    indicator_requests,
    laminate_front_distances,
    spread,
)
from fenics_adaptive.adaptivity.refinement import Request
from fenics_adaptive.errors import InputError, shared_errors
from fenics_adaptive.materials.cohesive import cohesive_zone_length
from fenics_adaptive.meshes.beam import BeamMesh, layered_mesh
from fenics_adaptive.meshes.shell import (
    axial_direction,
    constant_direction,
    hoop_direction,
    shell_mesh,
    toward,
)
from fenics_adaptive.meshes.surface import shell_surface
from fenics_adaptive.model.assembly import CohesiveSet
from fenics_adaptive.model.contact import Contact
from fenics_adaptive.model.forces import ForceContributor
from fenics_adaptive.model.forms import build_model
from fenics_adaptive.model.layerwise import cohesive_pairs
from fenics_adaptive.model.lever import LoadingLever
from fenics_adaptive.model.loading import face_dofs, resolve
from fenics_adaptive.model.structure import Structure, cells_in_x_range
from fenics_adaptive.parallel.balance import film_cost
from fenics_adaptive.parallel.redistribute import Rows
from fenics_adaptive.settings.adaptivity import Delamination
from fenics_adaptive.settings.config import RunConfig
from fenics_adaptive.settings.kinds import (
    InterfaceState,
    MaterialAxis,
    MeshKind,
    ModelKind,
    MotionKind,
    Partition,
    Refinement,
    RigidMotion,
)
from fenics_adaptive.settings.loads import Amplitude, PrescribedMotion, RigidBody
from fenics_adaptive.solver.explicit import (
    ExplicitSolver,
    HistoryRow,
    RunStats,
    choose_time_step,
    prepare_mass,
)
from fenics_adaptive.solver.observers import Observer


@dataclass(frozen=True)
class PythonIndicator:
    """A refinement indicator written in Python.

    ``function(structure, t)``: called every ``interval`` seconds of simulated time (0: before
    every step) on every rank at the same steps, so it may use collectives; returns this
    rank's requests ``(cell, interface, InterfaceState.WEAK or STRONG)`` (cells: owned local
    indices, interfaces counted from 1 at the bottom). Requests for interfaces already in that
    state are ignored; interfaces the config does not let refine are refused (InputError)."""

    function: Callable[[Structure, float], Iterable[Request]]
    interval: float = 0.0  # s
    name: str = ""  # in the refinement log; the function's name when empty

    def __post_init__(self):
        if not callable(self.function):
            raise TypeError(f"an indicator must be callable, not {type(self.function).__name__}")
        if not self.name:
            label = getattr(self.function, "__name__", type(self.function).__name__)
            object.__setattr__(self, "name", label)
        if not (math.isfinite(self.interval) and self.interval >= 0.0):
            raise ValueError(f"indicator interval must be >= 0 s, not {self.interval!r}")


def build_structure(
    config: RunConfig,
    comm: MPI.Comm = MPI.COMM_WORLD,
    refine_initially: bool = True,
    partition_cost: Callable[[np.ndarray, np.ndarray], np.ndarray] | None = None,
) -> Structure:
    """Mesh, model, loads and (for adaptive, unless a restart replays it) the initial
    refinement of a config. ``partition_cost``: ``cost(x, y)`` of the cells to cut the
    ranks' patches by with ``[mesh] partition = "cost"`` (default: their cost at the start,
    ``starting_cost``; a restart's re-balanced partition: ``balance.refined_cost``)."""
    layers = config.layer_laminates()
    boundaries = config.layer_boundaries
    # on several ranks, patches of equal cost (``parallel.balance``)
    cost = (partition_cost or starting_cost(config)) if cuts_by_cost(config, comm) else None
    beam = build_mesh(
        config,
        comm,
        [laminate.thickness for laminate in layers],
        [b in config.interfaces.delaminate for b in boundaries],
        cost,
    )
    model = build_model(
        beam,
        layers,
        config.points_per_ply,
        kinematics=config.kinematics,
        shear_correction=config.shear_correction,
        enhanced_strain=config.enhanced_strain,
        preintegrate=config.preintegrate,
    )
    motions = list(config.motions)
    cohesive = None
    params = config.cohesive.as_array() if config.cohesive is not None else None
    if config.kind == ModelKind.LAYERWISE:
        for interface in config.interfaces.symmetry:
            top = f"top_layer{boundaries.index(interface)}"
            motions.append(
                PrescribedMotion(top, "z", MotionKind.DISPLACEMENT, 0.0, Amplitude.constant(0))
            )
        if config.interfaces.delaminate:
            with shared_errors(comm):  # each rank checks its own columns
                pairs = cohesive_pairs(beam, model.V)
            cohesive = CohesiveSet(
                pairs.nodes,
                np.arange(len(pairs), dtype=np.int64),
                np.zeros((len(pairs), 4)),
                params,
                np.array(boundaries, dtype=np.int32)[pairs.boundary],
            )
    loads = resolve(model, motions, config.loads)
    structure = Structure(
        model,
        loads,
        cohesive,
        config.interfaces,
        params,
        config.stabilisation,
        config.failures,
        config.ply_damage,
        config.erosion,
        config.erosion_volume_ratio,
    )
    if not config.mesh.structured:  # a plate's regions were checked with its config
        check_regions_hold_cells(structure, config)
    for region in config.matrix_strength:
        cells = cells_in_x_range(structure, region.x_min, region.x_max)
        structure.scale_matrix_strength(cells, region.plies, region.factor)
    if refine_initially:  # a restart replays the refinements and restores the damage instead
        if config.kind == ModelKind.ADAPTIVE and (
            config.interfaces.initial != Refinement.NONE or config.delaminations
        ):
            structure.refine(initial_refinement(structure, config), balance=False)
        insert_films(structure, config.delaminations)
    return structure


def check_regions_hold_cells(structure: Structure, config: RunConfig) -> None:
    """Collective: every region of the config that picks cells by their centroid (an insert
    film, a manual refinement, a matrix strength) holds at least one cell of the mesh, else
    it would do nothing: InputError naming its table. The config checks a plate's itself."""
    centres = structure.cell_vertices().mean(axis=1)
    x, y = (centres[:, 0], centres[:, 1]) if len(centres) else (np.zeros(0), np.zeros(0))
    regions = [
        (f"delamination[{k}]", film.region.holds(x, y))
        for k, film in enumerate(config.delaminations)
    ]
    regions += [
        (f"{name}[{k}]", (x >= entry.x_min) & (x <= entry.x_max))
        for name, entries in (("refinement", config.refinements),
                              ("matrix_strength", config.matrix_strength))
        for k, entry in enumerate(entries)
    ]  # fmt: skip
    counts = structure.comm.allreduce(
        np.array([int(np.count_nonzero(inside)) for _, inside in regions], dtype=np.int64),
        op=MPI.SUM,
    )
    for (key, _), count in zip(regions, counts, strict=True):
        if count == 0:
            raise InputError(key, "its region holds no cell centroid of the mesh (x, y in mm)")


def build_mesh(
    config: RunConfig,
    comm: MPI.Comm,
    thicknesses: list[float],
    split: list[bool],
    cost: Callable[[np.ndarray, np.ndarray], np.ndarray] | None = None,
) -> BeamMesh:
    """The mesh of a config's [mesh]: the structured plate (``meshes.beam.layered_mesh``; on
    several ranks in patches of equal ``cost``), or a shell's surface extruded through the
    layers ``thicknesses`` (mm, bottom to top; ``split``: their boundaries with own nodes on
    each side; ``meshes.shell``). Collective."""
    mesh = config.mesh
    if mesh.shell is None:
        return layered_mesh(
            comm, mesh.length, mesh.width, mesh.nx, mesh.ny, thicknesses, split, cost
        )
    shape = mesh.shell
    surface = None
    with shared_errors(comm):  # Gmsh works on rank 0
        if comm.rank == 0:
            try:
                surface = shell_surface(shape.kind, dict(shape.sizes), shape.file, shape.surface)
            except ValueError as error:
                key, _, problem = str(error).partition(": ")
                raise InputError(key if key.startswith("mesh.") else "mesh", problem) from error
    x_axis = np.array([1.0, 0.0, 0.0])
    if shape.direction is not None:
        direction = constant_direction(shape.direction)
    elif shape.orientation == MaterialAxis.HOOP:
        direction = hoop_direction(x_axis)
    else:  # along the axis of a tube, panel or hat; global x projected for the others
        direction = axial_direction(x_axis)
    outward = None
    if shape.kind in (MeshKind.TUBE, MeshKind.PANEL):
        outward = lambda p: p * np.array([0.0, 1.0, 1.0])  # noqa: E731  away from the axis
    elif shape.kind in (MeshKind.HAT, MeshKind.PLATE_WITH_HOLE):
        outward = toward([0.0, 0.0, 1.0])
    elif shape.normal is not None:
        outward = toward(shape.normal)
    return shell_mesh(comm, surface, thicknesses, split, str(shape.reference), direction, outward)


def cuts_by_cost(config: RunConfig, comm: MPI.Comm) -> bool:
    """Whether the partition of this config's mesh is cut by the cells' cost (``cost`` of
    ``build_mesh``): a plate on several ranks with ``[mesh] partition = "cost"`` (a shell is
    bisected by counts)."""
    mesh = config.mesh
    return comm.size > 1 and mesh.partition == Partition.COST and mesh.shell is None


def starting_cost(config: RunConfig) -> Callable[[np.ndarray, np.ndarray], np.ndarray] | None:
    """``cost(x, y)`` (mm) per step of the cells of a config as its run starts, in unrefined
    cells (``parallel.balance.film_cost``): an adaptive model's cells under an insert film and,
    with ``[indicators]``, within the front distance of it (refined at t = 0); None when every
    cell costs the same."""
    if config.kind != ModelKind.ADAPTIVE:
        return None
    front = None
    if config.indicators is not None and config.cohesive is not None:
        front = laminate_front_distances(
            config.laminate,
            config.interfaces.delaminate,
            config.cohesive,
            config.indicators.front_distance,
        )
    return film_cost(config.delaminations, front)


def process_zone_warnings(config: RunConfig) -> list[str]:
    """A warning for each interface that may delaminate whose cohesive process zone is
    shorter than a cell of the plate (``cohesive.cohesive_zone_length`` with the larger
    transverse modulus of the two plies: Hillerborg's length, on the long side): the crack
    then starts late and jumps cell by cell (a DCB of 2 mm cells and a 0.8 mm zone peaked at
    7.7 x the theory's initiation load). The cells that count are those along which a crack
    can grow: both in-plane sizes, or the length's alone on a beam one cell wide. Shells are
    not checked."""
    mesh, law = config.mesh, config.cohesive
    if law is None or mesh.shell is not None or not config.interfaces.delaminate:
        return []
    sizes = [mesh.length / mesh.nx] if mesh.ny == 1 else [mesh.width / mesh.ny]
    if mesh.ny > 1 and mesh.nx > 1:
        sizes.append(mesh.length / mesh.nx)
    size = max(sizes)
    plies = config.laminate.plies
    short = {}
    for i in config.interfaces.delaminate:
        zone = cohesive_zone_length(law, max(plies[i - 1].material.E2, plies[i].material.E2))
        if zone < size:
            short[i] = zone
    if not short:
        return []
    which = ", ".join(map(str, short))
    lengths = ", ".join(f"{zone:.3g}" for zone in short.values())
    return [
        f"warning: the cohesive process zone of interface(s) {which} ({lengths} mm: E2 Gc / "
        f"strength^2) is shorter than the cells ({size:.3g} mm): delamination starts late and "
        "grows cell by cell; cells of a third of it resolve it, or lower strengths with the "
        "same Gc (Turon et al. 2007)"
    ]


def schedule_warnings(config: RunConfig, time_step: float = 0.0) -> list[str]:
    """A warning for each output or refinement the run ends before: field output whose
    ``fields_interval`` is longer than ``solver.end_time`` (a frame at t = 0 alone: frames are
    written every interval from t = 0, not at the end), and a [[refinement]] entry due at a
    time after the end, with no displacement that could make it due before. ``time_step``
    (s): the run's, by which its last step may pass the end (what falls within it is not
    warned of)."""
    solver, warnings = config.solver, []
    last = solver.end_time + time_step  # s: the last step ends before this
    if solver.field_interval and solver.field_interval >= last:
        warnings.append(
            f"warning: output.fields_interval = {solver.field_interval:g} s is longer than "
            f"solver.end_time = {solver.end_time:g} s: fields are written at t = 0 alone"
        )
    for k, entry in enumerate(config.refinements):
        if entry.time >= last and entry.displacement == math.inf:
            warnings.append(
                f"warning: [[refinement]] {k + 1} is due at t = {entry.time:g} s, after "
                f"solver.end_time = {solver.end_time:g} s: it does not refine before the end"
            )
    return warnings


def initial_refinement(structure: Structure, config: RunConfig) -> list[Request]:
    """Every owned cell refined at the listed interfaces (weak at ``refine``, and at
    ``delaminate`` weak or strong as ``initial`` says), and strongly at an insert film's
    interface where the film lies ([[delamination]])."""
    interfaces = config.interfaces
    strong = interfaces.initial == Refinement.STRONG
    cells = range(structure.base.n_owned_cells)
    requests = []
    if interfaces.initial != Refinement.NONE:
        requests += [(c, i, InterfaceState.WEAK) for c in cells for i in interfaces.refine]
        delaminate = InterfaceState.STRONG if strong else InterfaceState.WEAK
        requests += [(c, i, delaminate) for c in cells for i in interfaces.delaminate]
    centroids = structure.cell_vertices().mean(axis=1)
    for film in config.delaminations:
        under = np.flatnonzero(film.region.holds(centroids[:, 0], centroids[:, 1]))
        requests += [(int(c), film.interface, InterfaceState.STRONG) for c in under]
    return requests


def insert_films(structure: Structure, films: Iterable[Delamination]) -> None:
    """Fail the cohesive elements of the insert films ``films`` (those whose centroid lies in
    a film's region at its interface: an LW model's, or an adaptive model's after its initial
    refinement), marking them as inserts (``CohesiveSet.delaminate``)."""
    cohesive = structure.cohesive
    films = list(films)
    if not films or not len(cohesive):
        return
    centroids = structure.gather(cohesive.nodes[:, :4], "X").mean(axis=1)
    for film in films:
        on_film = film.region.holds(centroids[:, 0], centroids[:, 1])
        at = (cohesive.interface == film.interface) & on_film
        cohesive.delaminate(np.flatnonzero(at))


class IndicatorDefaults(NamedTuple):
    """The [indicators] values that depend on the model, the config's where given."""

    front: np.ndarray  # mm per interface kept refined around a delamination (front_distances)
    interval: float  # s between evaluations (default_interval)
    lead: float | None  # s the look-ahead predicts over (IndexHistory); None: no look-ahead


def indicator_defaults(config: RunConfig, structure: Structure) -> IndicatorDefaults:
    """The [indicators] values that depend on the model, the config's where given: the front
    distance per interface (mm, ``indicators.front_distances``), the interval between
    evaluations (s, ``indicators.default_interval``) and the look-ahead's lead (s: the interval
    plus the ties' release window; None without the look-ahead or the interface-stress
    indicator it predicts for)."""
    settings = config.indicators
    front = front_distances(structure, config.cohesive, settings.front_distance)
    interval = default_interval(structure) if settings.interval is None else settings.interval
    lead = None
    if settings.look_ahead and settings.interface_stress is not None:
        lead = interval + config.stabilisation.release_window
    return IndicatorDefaults(front, interval, lead)


def film_fronts(config: RunConfig, structure: Structure) -> list[Request]:
    """Collective: the strong refinements around the insert films ([[delamination]]) that a
    run's [indicators] ask for at t = 0 (``front_requests`` with the front distance of
    ``indicator_defaults``: the band a film's front keeps refined ahead of it), for a model
    that starts from rest without running its indicators (the static check); empty without
    indicators or films."""
    if config.indicators is None or not config.delaminations or config.cohesive is None:
        return []
    front = indicator_defaults(config, structure).front
    if not front.any():
        return []
    return front_requests(structure, front)[0]


class RefinementHook:
    """The solver's refiner (``ExplicitSolver(refiner=...)``): the config's manual
    [[refinement]] entries and its [indicators]; returns the ``RefinementEvent`` of a
    refinement, or None. Decisions are taken on the same steps on every rank (time, or the global
    probe displacement), so the collective refinement is entered by all. Its state (which
    manual entries are still pending, when the indicators run next, the look-ahead's past
    indices) goes into checkpoints."""

    def __init__(self, config: RunConfig, indicators: Iterable[PythonIndicator] = ()):
        self.config = config
        self.python = list(indicators)  # indicators written in Python, after the config's
        self.python_next = np.zeros(len(self.python))  # s: when each is evaluated next
        self.pending = list(range(len(config.refinements)))  # manual entries not yet done
        self.next_check = 0.0  # s: next indicator evaluation
        self.by_displacement = any(m.displacement < math.inf for m in config.refinements)
        self.probe_dofs: np.ndarray | None = None
        cohesive = config.cohesive
        self.strengths = (cohesive.N, cohesive.S) if cohesive is not None else None
        # the indicators' defaults that depend on the model, set at their first evaluation
        self.defaults: IndicatorDefaults | None = None
        # [indicators] look_ahead: the past interface-stress indices (``IndexHistory``), per
        # rank, made with the defaults (from a checkpoint's ``restored_indices``, if any)
        self.index_history: IndexHistory | None = None
        self.restored_indices: dict[str, np.ndarray] = {}
        # the started delaminations whose surroundings are refined (``front_requests``'
        # keys): not kept in checkpoints, a restart searches around all of them once
        self.front_known = np.zeros(0, np.int64)
        # N, the forces from outside on the base DOFs besides the face loads (reactions,
        # contact) at the time of the call: the solver's, set by ``Simulation``
        self.face_force: Callable[[], np.ndarray] | None = None
        # this rank's wall time (s) in the indicators' evaluations and in refinements, and
        # the evaluations made, since the hook was made (a restart starts them again)
        self.evaluations = 0
        self.indicator_seconds = 0.0
        self.refinement_seconds = 0.0

    def _resolve(self, structure: Structure) -> None:
        if self.defaults is None:
            self.defaults = indicator_defaults(self.config, structure)
            if self.defaults.lead is not None:
                self.index_history = IndexHistory(self.defaults.lead, **self.restored_indices)

    @property
    def active(self) -> bool:
        """Whether anything can refine: manual entries, [indicators] or Python indicators."""
        config = self.config
        return bool(config.refinements or config.indicators is not None or self.python)

    def add(self, indicator: PythonIndicator) -> None:
        """One more indicator written in Python, first evaluated at the next step."""
        self.python.append(indicator)
        self.python_next = np.append(self.python_next, 0.0)

    def state(self) -> dict[str, np.ndarray]:
        return {
            "pending": np.array(self.pending, dtype=np.int64),
            "next_check": self.next_check,
            "python_next_check": self.python_next.copy(),
        } | self._history_state()

    def layout(self, structure: Structure) -> dict:
        """How the rows of ``state()``'s arrays are indexed (``parallel.redistribute``): the
        look-ahead's snapshots by owned cell (axis 1); the rest is the same on every rank."""
        return {"index_snapshots": Rows(structure.cell_keys(), axis=1)}

    def _history_state(self) -> dict[str, np.ndarray]:
        """The look-ahead's past indices (this rank's cells: a checkpoint is per rank), or
        those restored and not yet taken up by an evaluation."""
        past = self.restored_indices if self.index_history is None else self.index_history.state()
        return {f"index_{k}": v for k, v in past.items()}

    def restore(self, state: dict[str, np.ndarray]) -> None:
        self.pending = [int(k) for k in state["pending"]]
        self.front_known = np.zeros(0, np.int64)  # of the structure restored: search all once
        self.next_check = float(state["next_check"])
        stored = np.asarray(state.get("python_next_check", np.zeros(0)), dtype=float)
        if len(stored) != len(self.python):
            raise InputError(
                "restart",
                f"the checkpoint was written with {len(stored)} Python indicator(s), this run "
                f"has {len(self.python)}: register the same indicators to restart",
            )
        self.python_next[:] = stored
        # (a checkpoint of a run without the look-ahead has none: it starts afresh)
        self.restored_indices = {
            k.removeprefix("index_"): v for k, v in state.items() if k.startswith("index_")
        }
        self.defaults, self.index_history = None, None  # (made again at the next evaluation)

    def __call__(self, t: float, structure: Structure) -> RefinementEvent | None:
        config, settings = self.config, self.config.indicators
        displacement = 0.0
        if self.by_displacement:
            if self.probe_dofs is None:
                self.probe_dofs = face_dofs(
                    structure.base,
                    config.probe.displacement_face,
                    config.probe.component,
                    x_range=config.probe.displacement_x,
                )
            displacement = probe_displacement(structure, config.probe, self.probe_dofs)
        due = [k for k in self.pending if config.refinements[k].due(t, displacement)]
        requests, reasons = [], {}
        for k in due:
            self.pending.remove(k)
            entry = config.refinements[k]
            cells = cells_in_x_range(structure, entry.x_min, entry.x_max)
            asked = [(int(c), i, entry.kind) for c in cells for i in entry.interfaces]
            note(reasons, asked, "manual")
            requests += asked
        evaluate = settings is not None and t >= self.next_check
        front_known = self.front_known
        if evaluate:
            started = time.perf_counter()
            self._resolve(structure)
            face_force = self.face_force() if self.face_force is not None else None
            requests += indicator_requests(
                structure, settings, self.strengths, t, reasons, face_force, self.index_history
            )
            self.next_check = t + self.defaults.interval
            if settings.spread:
                around = spread(structure, requests, settings.spread)
                note(reasons, around, "spread")
                requests += around
            if self.defaults.front.any():
                around, front_known = front_requests(
                    structure, self.defaults.front, reasons, self.front_known
                )
                requests += around
            self.evaluations += 1
            self.indicator_seconds += time.perf_counter() - started
        python_due = np.flatnonzero(self.python_next <= t)  # the same on every rank
        for k in python_due:
            indicator = self.python[k]
            asked = [tuple(int(x) for x in r) for r in indicator.function(structure, t)]
            note(reasons, asked, indicator.name)
            requests += asked
            self.python_next[k] = t + indicator.interval
        if not due and not evaluate and not len(python_due):
            return None
        started = time.perf_counter()
        event = refine(structure, requests, t, reasons)
        self.refinement_seconds += time.perf_counter() - started
        self.front_known = front_known  # (the surroundings of the new ones refined now)
        return event

    def cost(self, comm: MPI.Comm) -> tuple[int, float, float]:
        """Collective: (evaluations of the indicators so far, the wall time (s, the slowest
        rank's) spent in them, and in refining)."""
        local = np.array([self.indicator_seconds, self.refinement_seconds])
        slowest = np.empty(2)
        comm.Allreduce(local, slowest, op=MPI.MAX)
        return self.evaluations, float(slowest[0]), float(slowest[1])


def probe_displacement(structure: Structure, probe, dofs: np.ndarray | None = None) -> float:
    """Mean displacement of the probe face in the probe component, over all ranks (``dofs``:
    the probe's owned DOFs, if already known)."""
    if dofs is None:
        dofs = face_dofs(
            structure.base, probe.displacement_face, probe.component, x_range=probe.displacement_x
        )
    local = np.array([structure.base.u.x.array[dofs].sum(), len(dofs)], dtype=float)
    total, count = structure.comm.allreduce(local, op=MPI.SUM)
    return total / max(count, 1.0)


class Simulation:
    """A config built into a structure and an explicit solver, ready to run.

    ``config``: a ``RunConfig`` (``load_config(path)``, ``parse_config(dict)``).
    ``observers``: ``Observer`` instances told of the run's events (history rows, field times,
    refinements, checkpoints, the end); more with ``add_observer``. ``indicators``:
    ``PythonIndicator`` instances (or ``add_indicator``). ``contributors``: force contributors
    of one's own (``model.forces.Contributor``; or ``add_contributor``), summed after the
    structure's and the impactor's. ``comm``: the MPI communicator; every
    rank makes the same calls. ``structure``: an already built structure of this config (a
    restart restores one, ``runner.execute``); by default it is built here.

    Building checks what can only be checked on the model and raises ``InputError``: a forced
    time step above the stable one, an impactor that starts inside the plate or whose penalty
    is too stiff for the step.

    Use: ``run()`` to the end time; or ``start()``, then ``step()`` until it returns False,
    reading ``t``, ``u``, ``v``, ``internal_force``, ``external_force``, ``history``,
    ``interface_state``, ``structure`` between steps."""

    def __init__(
        self,
        config: RunConfig,
        observers: Iterable[Observer] = (),
        indicators: Iterable[PythonIndicator] = (),
        comm: MPI.Comm = MPI.COMM_WORLD,
        structure: Structure | None = None,
        contributors: Iterable[ForceContributor] = (),
    ):
        self.config = config
        self.structure = structure if structure is not None else build_structure(config, comm)
        self.refinement = RefinementHook(config, indicators)
        prepare_mass(self.structure, config.solver, self.refinement.active)
        # s: the step a fresh run takes and the stable one, and what limits it
        self.time_step, self.stable_time_step, self.critical = choose_time_step(
            self.structure, config.solver
        )
        # lines for the run's log and ``check``: what the config allows but likely did not mean
        self.warnings: list[str] = process_zone_warnings(config)
        self.warnings += schedule_warnings(config, self.time_step)
        run_contributors: list[ForceContributor] = []
        bodies = [config.impactor.body()] if config.impactor is not None else []
        for body in [*bodies, *config.rigid_bodies]:
            contact = self._contact(body)
            if body.motion == RigidMotion.LEVER:  # the lever moves it and reports it
                contact = LoadingLever.on(config.lever, contact, self.structure)
            run_contributors.append(contact)
        run_contributors += contributors
        self.solver = ExplicitSolver(
            self.structure,
            config.solver,
            config.probe,
            contributors=run_contributors,
            observers=observers,
            refiner=self.refinement if self.refinement.active else None,
        )
        # the interlaminar estimate takes the supports' and the impactor's forces on the faces
        self.refinement.face_force = self.solver.face_force

    def _contact(self, body: RigidBody) -> Contact:
        """Collective: the contact of a rigid body, refused (InputError) if the body starts
        inside its face or its penalty is too stiff for the time step."""
        contact = Contact.on(body, self.structure)
        contact.check_penalty(
            self.time_step, self.stable_time_step / self.config.solver.safety_factor
        )
        gap = contact.initial_gap()
        if gap <= 0.0:
            what = "impactor" if body.name == "impactor" else "body"
            if body.face == "all":
                where = "touching or inside the structure; move it off along its normal"
                if body.normal is None:
                    where = "touching or inside the structure; move it away"
                raise InputError(f"{contact.key}.position", f"the {what} starts {where}")
            side = "above" if body.face == "top" else "below"
            raise InputError(
                f"{contact.key}.position",
                f"the {what} starts {-gap:.4g} mm inside the {body.face} face; place it {side}",
            )
        self._check_reach(body, contact)
        return contact

    def _check_reach(self, body: RigidBody, contact: Contact) -> None:
        """Collective: a warning for a body that cannot touch its face: moved along its path
        (its velocity, or its prescribed motion's direction; a held one or one at rest: across
        the flat laminate, as the laminate bends towards it) it passes beside every node of
        the face."""
        direction = np.zeros(3)
        if body.motion in (RigidMotion.FREE, RigidMotion.PRESCRIBED):
            direction = np.asarray(body.velocity if body.motion == RigidMotion.FREE else body.path)
        if not np.any(direction):  # held (or at rest)
            if self.structure.base.curved:
                return
            direction = np.array([0.0, 0.0, 1.0])
        clearance = contact.path_clearance(direction)
        if clearance > 0.0:
            self.warnings.append(
                f"warning: {contact.key} cannot touch the structure's {body.face} face: along "
                f"its path it passes {clearance:.4g} mm beside the nearest node of it (check "
                "position)"
            )

    # ------------------------------------------------------------------ set up
    def add_observer(self, observer: Observer) -> None:
        """Tell ``observer`` of the run's events from now on."""
        self.solver.observers.append(observer)

    def add_contributor(self, contributor: ForceContributor) -> None:
        """Add ``contributor``'s force to the run from its start (``model.forces``: its
        ``kind`` says where its force and work go); before ``start()`` or ``run()``."""
        self.solver.add_contributor(contributor)

    def add_indicator(
        self, function: Callable[[Structure, float], Iterable[Request]], interval: float = 0.0
    ) -> PythonIndicator:
        """Refine where ``function(structure, t)`` asks, every ``interval`` s (0: before every
        step); see ``PythonIndicator``. Returns the registered indicator."""
        indicator = PythonIndicator(function, interval)
        self.refinement.add(indicator)
        self.solver.refiner = self.refinement
        return indicator

    def start(
        self,
        initial_displacement: np.ndarray | None = None,
        initial_velocity: np.ndarray | None = None,
    ) -> None:
        """Collective: begin at t = 0 (``ExplicitSolver.start``; mm and mm/s on the base DOFs,
        owned + ghost entries, default zero) and evaluate t = 0: forces and the first history
        row."""
        self.solver.start(initial_displacement, initial_velocity)

    def restore(self, solver_state: dict, refinement_state: dict | None = None) -> None:
        """Collective: continue from a solver state (``ExplicitSolver.state()`` or a
        checkpoint's) and the refinement hook's state; the structure must already be at that
        moment."""
        if refinement_state:
            self.refinement.restore(refinement_state)
        self.solver.restore(solver_state)

    # ------------------------------------------------------------------ advance
    def step(self) -> bool:
        """Collective: one explicit step (``start()`` first); False once the end time is
        reached. A loop that stops before then calls ``settle()``."""
        return self.solver.step()

    def settle(self) -> None:
        """Collective: complete the nonblocking reductions a step leaves under way on several
        ranks (a free body's force, the poll: ``ExplicitSolver.settle``); ``run()`` and the
        last ``step()`` do it themselves."""
        self.solver.settle()

    def run(self) -> RunStats:
        """Collective: to ``config.solver.end_time`` (starting at t = 0 unless started);
        returns the statistics and the history rows."""
        return self.solver.run()

    # ------------------------------------------------------------------ read between steps
    @property
    def t(self) -> float:
        """s, the time of the current state."""
        return self.solver.t

    @property
    def u(self) -> np.ndarray:
        """mm, base-node displacements (owned DOFs, x y z interleaved; a view: do not write)."""
        return self.solver.u

    @property
    def v(self) -> np.ndarray:
        """mm/s, base-node velocities v_{n-1/2} (owned DOFs; a view)."""
        return self.solver.v

    @property
    def internal_force(self) -> np.ndarray:
        """N, internal force on the base DOFs at t (owned; a view)."""
        return self.solver.internal_force

    @property
    def external_force(self) -> np.ndarray:
        """N, external force (loads) on the base DOFs at t (owned; a view)."""
        return self.solver.external_force

    @property
    def history(self) -> list[HistoryRow]:
        """The history rows so far (every ``output.interval`` s): displacement, forces,
        energies (mJ)."""
        return self.solver.stats.history

    @property
    def interface_state(self) -> np.ndarray:
        """(owned cells, interfaces) int8 array of ``InterfaceState`` values (a view)."""
        return self.structure.interface_state
