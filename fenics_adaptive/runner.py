"""One run from a config: mesh -> model -> loads -> explicit solver -> output folder.

Units: N, mm, s, tonne.
"""

from __future__ import annotations

import platform
import signal
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import dolfinx
import numba
from mpi4py import MPI

import fenics_adaptive
from fenics_adaptive import kernels, watchdog
from fenics_adaptive.adaptivity.equilibration import Equilibrated
from fenics_adaptive.adaptivity.events import RefinementEvent
from fenics_adaptive.element.rules import integration_warnings
from fenics_adaptive.errors import InputError, shared_errors
from fenics_adaptive.io import checkpoint, output
from fenics_adaptive.io.refinement_log import FILE_NAME as LOG_FILE
from fenics_adaptive.io.refinement_log import RefinementLog, read_log
from fenics_adaptive.io.run_folder import RunFolder
from fenics_adaptive.model.diagnostics import insert_film_area
from fenics_adaptive.model.structure import Structure
from fenics_adaptive.parallel import balance, redistribute
from fenics_adaptive.parallel.balance import refined_cost
from fenics_adaptive.settings.config import RunConfig, check_step_count
from fenics_adaptive.settings.kinds import ModelKind
from fenics_adaptive.simulation import (
    Simulation,
    build_structure,
    cuts_by_cost,
    indicator_defaults,
)
from fenics_adaptive.solver import explicit
from fenics_adaptive.solver.observers import Observer


def run_config(
    config: RunConfig,
    out_dir: str | Path,
    comm: MPI.Comm = MPI.COMM_WORLD,
    show_progress: bool = True,
    log: Callable[[str], None] | None = print,
    restart: str | Path | None = None,
    overwrite: bool = False,
) -> dict:
    """Run a config and write its results into ``out_dir``; returns the summary."""
    return execute(config, out_dir, comm, show_progress, log, restart, overwrite)[0]


def execute(
    config: RunConfig,
    out_dir: str | Path,
    comm: MPI.Comm = MPI.COMM_WORLD,
    show_progress: bool = True,
    log: Callable[[str], None] | None = print,
    restart: str | Path | None = None,
    overwrite: bool = False,
) -> tuple[dict, Structure]:
    """``run_config``, also handing back the structure in its final state (for pictures and
    further analysis). ``restart``: a checkpoint folder (or the output folder holding one) to
    continue from; the history up to the checkpoint (kept in the checkpoint) is kept, the rest
    is run again. ``out_dir`` is a run folder (``run_folder``): refused if another run holds it
    or if it is not empty and not a run folder (unless ``overwrite``); a fresh run removes
    only what the previous run there wrote, and only once the config and the model have been
    checked.

    SIGINT and SIGTERM stop the run at the next poll (every 64 steps) with a checkpoint, a
    flushed ``history.partial.csv`` and a summary saying "interrupted". On several ranks an
    adaptive run whose refinement unbalances the ranks beyond ``[mesh] rebalance`` stops with
    a checkpoint and continues from it on a partition cut by the refinement's cost (its
    fields of then on in ``rebalanced_step<N>/``; ``summary.json``: "rebalanced")."""
    out_dir = Path(out_dir)
    carried = _Carried()
    repartition = False
    while True:
        try:
            return _segment(
                config, out_dir, comm, show_progress, log, restart, overwrite, repartition, carried
            )
        except explicit.Rebalance as stop:
            carried.rebalanced.append(
                {"time_s": stop.t, "step": stop.step, "imbalance_before": carried.imbalance}
            )
            carried.stopped = time.perf_counter()
            restart, overwrite, repartition = out_dir, False, True


@dataclass
class _Carried:
    """What a run's segments (between re-balances) hand on: the wall time of those done (s),
    the re-balances so far and the imbalance the last one left."""

    wall_time: float = 0.0
    rebalanced: list = field(default_factory=list)
    imbalance: float | None = None  # when the last segment stopped to re-balance
    stopped: float = 0.0  # s (perf_counter) when it stopped, after its checkpoint
    first_step: int | None = None  # the step the first segment started from
    at_start: float | None = None  # the first segment's imbalance at its start
    largest: float = 0.0  # the largest imbalance of the segments done
    # the segments' indicator evaluations, their wall time, refining's and the solver's
    # reactions to refinements (s, the slowest rank's)
    cost: tuple[int, float, float, float] = (0, 0.0, 0.0, 0.0)


def _segment(
    config: RunConfig,
    out_dir: Path,
    comm: MPI.Comm,
    show_progress: bool,
    log: Callable[[str], None] | None,
    restart: str | Path | None,
    overwrite: bool,
    repartition: bool,
    carried: _Carried,
) -> tuple[dict, Structure]:
    """``execute`` from its start or a checkpoint up to the end time or a re-balance
    (``explicit.Rebalance``, raised after the checkpoint and the outputs are closed)."""
    folder = RunFolder(out_dir, comm, overwrite)
    # a restart into the folder of its checkpoint continues that run folder; else it is fresh
    fresh = restart is None or not _same_folder(checkpoint.locate(restart).parent, out_dir)
    folder.check(fresh)  # before the model is built: a wrong --out is refused at once
    resume, hook_state, kept_rows = None, None, []
    partition, kept_balance = {"weights": "start"}, {}
    if restart is None:
        simulation = Simulation(config, comm=comm)
    else:
        simulation, resume, hook_state, kept_rows, partition, kept_balance = _restarted(
            config, restart, comm, repartition
        )
    say = log if (log is not None and comm.rank == 0) else (lambda _: None)
    if carried.first_step is None:
        carried.first_step = int(resume["step"]) if resume is not None else 0
    if repartition:  # the imbalance of the partition just cut
        cost = balance.structure_costs(simulation.structure.interface_state).sum()
        carried.rebalanced[-1]["imbalance_after"] = balance.imbalance(comm, cost)
    summary = _summary_at_start(config, simulation, comm)
    if not repartition:
        _announce(config, simulation, summary, say)
    # still start-up: a first run's numba compilation is announced, stops at Ctrl-C and stays
    # out of the time loop and its timings
    summary["kernel_compile_time_s"] = kernels.prepare(config, comm, say)

    # the config and the model are checked: only now is anything in the folder removed
    folder.open(fresh)
    fields_dir = out_dir
    if resume is not None:
        step = int(resume["step"])
        if repartition:
            say(f"t = {float(resume['t']):.4e} s: continued on a partition cut by the refinement")
            fields_dir = out_dir / f"rebalanced_step{step}"
        else:
            say(f"restarted from the checkpoint at t = {float(resume['t']):.6e} s")
            fields_dir = out_dir / f"restart_step{step}"  # earlier fields stay
        folder.remove_recorded(fields_dir.name)  # those of an earlier restart from here
    try:
        history, fields = _open_outputs(config, simulation, out_dir, fields_dir, kept_rows, folder)
    except BaseException:
        folder.close()
        raise
    progress = output.Progress(config.solver.end_time, comm) if show_progress else None
    structure = simulation.structure
    writer = CheckpointWriter(out_dir, config, structure, history, simulation.refinement, folder)
    writer.partition = partition
    refinement_log = _refinement_log(config, structure, out_dir, restart, resume, folder)
    cut_left = carried.rebalanced[-1]["imbalance_after"] if carried.rebalanced else None
    threshold = _rebalance_threshold(config, comm)
    balance_report = BalanceReport(structure, say, threshold, cut_left, **kept_balance)
    writer.balance = balance_report
    observers = (history, fields, progress, writer, RefinementReport(structure, say))
    observers += (balance_report,)
    for observer in (*observers, refinement_log):
        if observer is not None:
            simulation.add_observer(observer)
    stop = _StopOnSignal(comm)
    simulation.solver.stop_requested = stop
    start = time.perf_counter()
    if repartition:  # the cut, the rebuild and the replay of the refinements, up to here
        carried.rebalanced[-1]["seconds"] = start - carried.stopped
    compiled: list[str] = []  # numba functions the loop compiled: none, if prepare did its job
    try:
        with kernels.compilations() as compiled:
            if resume is not None:
                simulation.restore(resume, hook_state)
            stats = simulation.run()
    except explicit.Rebalance:
        carried.wall_time += time.perf_counter() - start
        carried.imbalance = balance_report.now
        if carried.at_start is None:
            carried.at_start = balance_report.at_start
        carried.largest = max(carried.largest, balance_report.largest or 0.0)
        carried.cost = _summed(carried.cost, _adaptivity_cost(simulation, comm))
        history.close(completed=False)
        if fields is not None:
            fields.close()
        folder.close()
        raise
    except BaseException as error:
        history.close(completed=False)
        if fields is not None:
            fields.close()
        interrupted = isinstance(error, explicit.Interrupted)
        summary["status"] = "interrupted" if interrupted else "failed"
        summary["error"] = f"{type(error).__name__}: {error}"
        if interrupted:
            summary["checkpoint"] = str(out_dir / checkpoint.FOLDER)
        summary["wall_time_s"] = carried.wall_time + time.perf_counter() - start
        summary["kernels_compiled_in_loop"] = compiled
        summary["load_balance"] = _load_balance(balance_report, carried)
        try:
            output.write_summary(out_dir, summary, comm, folder.record)
        finally:
            folder.close()
        raise
    finally:
        stop.release()
        if progress is not None:
            progress.done()
        if refinement_log is not None:
            refinement_log.close()
    summary["load_balance"] = _load_balance(balance_report, carried)
    summary["kernels_compiled_in_loop"] = compiled
    stats.wall_time += carried.wall_time
    try:  # the lock is held until the last file is written
        finished = (stats, history, fields, kept_rows, carried, summary)
        return _finish(config, out_dir, comm, simulation, finished, say, folder.record)
    finally:
        folder.close()


def _rebalance_threshold(config: RunConfig, comm: MPI.Comm) -> float:
    """The imbalance that re-cuts this run's partition (``[mesh] rebalance``), 0 where none
    can help: a model that does not refine, a partition not cut by cost."""
    if config.kind != ModelKind.ADAPTIVE or not cuts_by_cost(config, comm):
        return 0.0
    return config.mesh.rebalance


def _adaptivity_cost(simulation: Simulation, comm: MPI.Comm) -> tuple[int, float, float, float]:
    """Collective: the indicator evaluations of this segment, their wall time, refining's
    and the solver's reactions to refinements (s, the slowest rank's)."""
    reaction = comm.allreduce(simulation.solver.stats.reaction_seconds, op=MPI.MAX)
    return (*simulation.refinement.cost(comm), reaction)


def _summed(a: tuple, b: tuple) -> tuple:
    return tuple(x + y for x, y in zip(a, b, strict=True))


def _restarted(
    config: RunConfig, restart: str | Path, comm: MPI.Comm, repartition: bool = False
) -> tuple[Simulation, dict, dict, list, dict, dict]:
    """Collective: the simulation of a checkpoint (the structure rebuilt from the config, its
    refinements replayed and its state put back), the solver and refinement states to resume
    from, the history rows up to the checkpoint, how the partition was cut and, on the
    partition that wrote it, the load balance's state (``BalanceReport`` keywords). On another
    number of ranks, after a re-balance, or with ``repartition``, the partition is cut anew,
    weighted by the refinement at the checkpoint (``checkpoint.read``)."""
    manifest, arrays, history_csv = checkpoint.read(restart, comm, config, repartition)
    partition = manifest.get("partition", {"weights": "start"})
    kept_balance = {}
    if isinstance(arrays, redistribute.StoredState):
        # cut anew, by the refinement at the checkpoint
        until = float(arrays.files[0]["solver_t"])
        cost = None
        if cuts_by_cost(config, comm):  # (else the cut takes no weights)
            cost = _refinement_cost(config, arrays.files, until)
        structure = build_structure(config, comm, refine_initially=False, partition_cost=cost)
        checkpoint.restore_moved_structure(structure, arrays)
        simulation = Simulation(config, comm=comm, structure=structure)
        resume = checkpoint.moved_state(arrays, "solver_", simulation.solver.layout(), comm)
        hook_state = checkpoint.moved_state(
            arrays, "hook_", simulation.refinement.layout(structure), comm
        )
        if cost is not None:
            partition = {"weights": "refinement", "time_s": until}
        else:  # (one rank, equal cells, a shell or nothing refined: a fresh start's cut)
            partition = {"weights": "start"}
    else:
        cost = None
        if partition.get("weights") == "refinement":  # the same cut as the run's, again
            logs = comm.allgather({k: v for k, v in arrays.items() if k.startswith(_LOG)})
            cost = _refinement_cost(config, logs, float(partition["time_s"]))
        structure = build_structure(config, comm, refine_initially=False, partition_cost=cost)
        checkpoint.restore_structure(structure, arrays)
        # (a partition cut anew, above, starts its load balance afresh)
        balance_then = manifest.get("load_balance", {})
        kept_balance = {
            "pending": bool(balance_then.get("rebalance_pending", False)),
            "bar": balance_then.get("bar"),
        }
        resume = checkpoint.solver_state(arrays)
        hook_state = checkpoint.hook_state(arrays)
        simulation = Simulation(config, comm=comm, structure=structure)
    simulation.time_step = float(resume["dt"])
    simulation.stable_time_step = float(resume["stable"])
    with shared_errors(comm):  # the earlier format reads the folder's CSV on each rank
        kept_rows = _kept_history(restart, manifest, history_csv, resume, config)
    return simulation, resume, hook_state, kept_rows, partition, kept_balance


_LOG = "structure_refinement_"  # the checkpoint's refinement log (and its cells' places)


def _refinement_cost(config: RunConfig, files: list[dict], until: float):
    """``cost(x, y)`` of the cells as the refinement logs of ``files`` (every rank's arrays)
    left them at time ``until`` (s), for a partition cut by it; None if nothing refined."""
    centroids, counts = checkpoint.refined_cells(files, until)
    if not len(counts):
        return None
    mesh = config.mesh
    return refined_cost(centroids, counts, min(mesh.length / mesh.nx, mesh.width / mesh.ny))


def model_summary(config: RunConfig, structure: Structure, comm: MPI.Comm) -> dict:
    """Collective: the model's size (over all ranks) as ``summary.json`` gives it."""
    model = structure.base
    n_nodes = model.V.dofmap.index_map.size_global
    return {
        "kind": config.kind,
        "cells": comm.allreduce(model.mesh.topology.index_map(3).size_local, op=MPI.SUM),
        "nodes": n_nodes,
        "dofs": 3 * n_nodes,
        "plies": config.laminate.n_plies,
        "cell_layers": len(model.beam.layer_z) - 1,
        "thickness_mm": config.laminate.thickness,
        "total_mass_tonne": structure.total_mass(),
        "extra_nodes_at_start": comm.allreduce(structure.extra.n_owned, op=MPI.SUM),
        "cohesive_elements_at_start": comm.allreduce(len(structure.cohesive), op=MPI.SUM),
        "insert_film_area_mm2": insert_film_area(structure),
    }


def _summary_at_start(config: RunConfig, simulation: Simulation, comm: MPI.Comm) -> dict:
    """Collective: ``summary.json`` as it stands before the first step: the model's size (over
    all ranks), the time step, the versions."""
    return {
        "status": "running",
        "config": config.source,
        "units": "N, mm, s, tonne (MPa, mJ)",
        "model": model_summary(config, simulation.structure, comm),
        "time_step": {
            "used_s": simulation.time_step,
            "stable_s": simulation.stable_time_step,
            "safety_factor": config.solver.safety_factor,
            "limited_by": simulation.critical,
        },
        "mass_scaling": (
            None
            if simulation.structure.scaled_mass is None
            else simulation.structure.scaled_mass.report(comm)
        ),
        "indicators": _indicator_defaults(config, simulation.structure),
        "mpi_ranks": comm.size,
        "versions": versions(),
    }


def _indicator_defaults(config: RunConfig, structure: Structure) -> dict | None:
    """[indicators]' values as the run uses them (``simulation.indicator_defaults``), or None."""
    if config.indicators is None:
        return None
    defaults = indicator_defaults(config, structure)
    at = structure.interfaces.delaminate
    return {
        "interval_s": float(defaults.interval),
        "look_ahead_s": None if defaults.lead is None else float(defaults.lead),
        "front_distance_mm": {str(i): float(defaults.front[i - 1]) for i in at},
    }


def versions() -> dict[str, str]:
    """The versions behind a result, as ``summary.json`` records them."""
    return {
        "fenics_adaptive": fenics_adaptive.__version__,
        "dolfinx": dolfinx.__version__,
        "numba": numba.__version__,
        "python": platform.python_version(),
    }


def _announce(
    config: RunConfig, simulation: Simulation, summary: dict, say: Callable[[str], None]
) -> None:
    """The model and its time step, in the log; refuses a step count above
    ``solver.max_steps`` (InputError)."""
    model, step = summary["model"], summary["time_step"]
    n_steps = check_step_count(config.solver, simulation.time_step)
    say(
        f"{config.kind} model: {model['cells']} cells, {model['nodes']} nodes "
        f"({model['dofs']} DOFs), {model['plies']} plies, {model['cell_layers']} cell layer(s), "
        f"{summary['mpi_ranks']} MPI rank(s)"
    )
    n_extra, n_cohesive = model["extra_nodes_at_start"], model["cohesive_elements_at_start"]
    if n_extra or n_cohesive:
        say(f"{n_extra} extra nodes, {n_cohesive} cohesive elements")
    if model["insert_film_area_mm2"]:
        say(f"insert films: {model['insert_film_area_mm2']:.6g} mm^2 delaminated at t = 0")
    say(
        f"time step {step['used_s']:.4e} s (stable {step['stable_s']:.4e} s with "
        f"safety factor {step['safety_factor']}, limited by {step['limited_by']}), "
        f"{n_steps} steps to {config.solver.end_time:.4e} s"
    )
    for line in integration_warnings(
        config.layer_laminates(), config.points_per_ply, config.preintegrate
    ):
        say(line)
    for line in simulation.warnings:
        say(line)
    indicators = summary.get("indicators")
    if indicators is not None:
        front = indicators["front_distance_mm"]
        at = ", ".join(f"{d:.3g} mm at interface {i}" for i, d in front.items() if d > 0)
        lead = indicators["look_ahead_s"]
        say(
            f"indicators every {indicators['interval_s']:.3e} s"
            + (f", interface stresses predicted {lead:.3e} s ahead" if lead else "")
            + (f"; delamination fronts kept refined {at} around" if at else "")
        )
    scaling = summary.get("mass_scaling")
    if scaling is not None:
        say(
            f"selective mass scaling: {scaling['elements_scaled']} of {scaling['elements']} "
            f"elements scaled (largest factors: normal {scaling['largest_normal_factor']:.3g}, "
            f"shear {scaling['largest_shear_factor']:.3g}) for a target step of "
            f"{scaling['target_step_s']:.4e} s"
        )
        if scaling["element_step_s"] < 0.97 * scaling["target_step_s"]:
            say(
                f"warning: the elements allow {scaling['element_step_s']:.4e} s, not the "
                f"target {scaling['target_step_s']:.4e} s (solver.mass_scaling_step): mass "
                "cannot shorten the in-plane modes of the smallest cells"
            )


def _refinement_log(
    config: RunConfig,
    structure: Structure,
    out_dir: Path,
    restart: str | Path | None,
    resume: dict | None,
    folder: RunFolder,
) -> RefinementLog | None:
    """Collective: the refinement log of an adaptive run (None for the other kinds), continuing
    the log of the run a restart continues, up to its checkpoint's time."""
    if config.kind != ModelKind.ADAPTIVE:
        return None
    comm, kept = structure.comm, None
    if restart is not None:
        rows = []  # rank 0 reads the log, the others only need to know whether it was there
        if comm.rank == 0:
            # a state taken before its evaluation refines at t again when the restart
            # evaluates it: the rows at t (a killed run wrote them after it) are not kept
            rows = read_log(
                checkpoint.locate(restart).parent / LOG_FILE,
                float(resume["t"]),
                inclusive=bool(resume.get("evaluated", False)),
            )
        # without it, the replayed refinements are logged without their reasons
        kept = rows if comm.bcast(rows is not None, root=0) else None
    with shared_errors(structure.comm):  # rank 0 opens the file
        return RefinementLog(out_dir, structure, kept, restart is not None, folder.record)


def _open_outputs(
    config: RunConfig,
    simulation: Simulation,
    out_dir: Path,
    fields_dir: Path,
    kept_rows: list,
    folder: RunFolder,
) -> tuple[output.HistoryWriter, output.FieldOutputs | None]:
    """Collective: the history writer (continuing ``kept_rows``) and, if fields are asked for,
    the field writers in ``fields_dir``; every file listed in the run folder's record first."""
    comm, record = simulation.structure.comm, folder.record
    record(out_dir / "history.partial.csv", out_dir / "history.csv")
    with shared_errors(comm):  # rank 0 opens the file
        history = output.HistoryWriter(out_dir, comm, kept_rows, config.body_columns)
    fields = None
    if config.solver.field_interval:
        with shared_errors(comm):  # rank 0 makes the folder; its error reaches every rank
            if comm.rank == 0:
                record(fields_dir, folder=True)
                fields_dir.mkdir(exist_ok=True)
        fields = output.FieldOutputs(fields_dir, simulation.structure, record, config.fields)
    return history, fields


class CheckpointWriter(Observer):
    """Writes the checkpoints of a run (``checkpoint.write``) when the solver says one is due:
    the solver's state, the structure's, the refinement hook's, the history so far."""

    def __init__(self, out_dir: Path, config: RunConfig, structure: Structure, history, hook,
                 folder: RunFolder):  # fmt: skip
        self.out_dir, self.config, self.structure = out_dir, config, structure
        self.history, self.hook, self.folder = history, hook, folder
        # how the run's partition was cut (the manifest's "partition"): at the start, or
        # weighted by the refinement of a moment (a re-balance)
        self.partition: dict = {"weights": "start"}
        # whether a re-balance waits (the manifest's "load_balance")
        self.balance: BalanceReport | None = None

    def on_checkpoint(self, solver: explicit.ExplicitSolver) -> None:
        with shared_errors(self.structure.comm):
            layouts, _ = checkpoint.state_layouts(solver, self.structure, self.hook)
        hook_now = self.hook.state()
        checkpoint.write(
            self.out_dir, self.structure.comm, solver.state(), self.structure, hook_now,
            self.config, self.history.text(), self.folder.record, self.folder.forget,
            layouts, self.partition,
            None if self.balance is None else self.balance.checkpointed(),
        )  # fmt: skip


class RefinementReport(Observer):
    """One line per refinement: the extra nodes and cohesive elements now, the new step."""

    def __init__(self, structure: Structure, say: Callable[[str], None]):
        self.structure, self.say = structure, say

    def on_refinement(self, event: RefinementEvent, dt: float, where: str) -> None:
        comm, structure = self.structure.comm, self.structure
        self.say(
            f"t = {event.time:.4e} s: refined; now {comm.allreduce(structure.extra.n_owned)} "
            f"extra nodes, {comm.allreduce(len(structure.cohesive))} cohesive elements; time "
            f"step {dt:.4e} s (limited by {where}){_balanced(event.equilibrated)}"
        )


def _balanced(equilibrated: Equilibrated | None) -> str:
    """What a refinement's equilibration did, for its line in the log ("" if nothing)."""
    if equilibrated is None:
        return ""
    said = (
        f"; {equilibrated.dofs} DOFs balanced in {equilibrated.steps} step(s), largest "
        f"out-of-balance force {equilibrated.imbalance:.3g} -> {equilibrated.remaining:.2g} N"
    )
    if not equilibrated.settled:
        share = equilibrated.remaining / equilibrated.imbalance
        said += (
            f" (not settled: {share:.0%} left, the balance past an interface's onset or the "
            "plies damaged; the rest rings)"
        )
    return said


class BalanceReport(Observer):
    """Collective: how unequally the ranks share the step's cost (``parallel.balance``): the
    largest rank's cost over the mean at the start (at the first history row: after the
    refinement the indicators ask for at t = 0), after each later refinement, at its
    largest. With a ``threshold`` (``[mesh] rebalance``; 0: none) a refinement that makes
    it larger than the threshold (and, after a re-balance, than 1.1 times the imbalance that
    re-balance left: ``cut_left``) asks the solver to re-balance
    (``ExplicitSolver.request_rebalance``) as soon as the state can move to another
    partition (no refinement's ties or damping windows acting: else at a later history
    row). A checkpoint keeps whether a re-balance is waiting and the bar (``checkpointed``);
    a run that continues from it on the same partition takes them back (``pending``, ``bar``),
    so that the re-balance comes when it would have in the run that was not stopped."""

    # said in the log when the run starts this unbalanced (or a refinement makes it so)
    WORTH_SAYING = 1.2
    # after a re-balance, the next only past this factor on what it left: a partition that
    # cannot do better (a few columns per rank) is not cut again and again
    GAIN = 1.1

    def __init__(
        self,
        structure: Structure,
        say: Callable[[str], None],
        threshold: float = 0.0,
        cut_left: float | None = None,
        pending: bool = False,
        bar: float | None = None,
    ):
        self.structure, self.say, self.threshold = structure, say, threshold
        self.bar = threshold if cut_left is None else max(threshold, self.GAIN * cut_left)
        if bar is not None:  # (a checkpoint's, on the partition that wrote it)
            self.bar = bar
        self.pending = pending
        # None until measured (a run that fails before its first step)
        self.at_start: float | None = None
        self.now: float | None = None
        self.largest: float | None = None
        self.solver: explicit.ExplicitSolver | None = None
        self.wanted = False  # a re-balance is due as soon as the state can move

    def _measure(self) -> float:
        local = balance.structure_costs(self.structure.interface_state).sum()
        self.now = balance.imbalance(self.structure.comm, local)
        self.largest = max(self.largest or 0.0, self.now)
        return self.now

    def on_start(self, solver) -> None:
        self.at_start = self.now = self.largest = None
        self.solver, self.wanted = solver, self.pending

    def on_history(self, row) -> None:
        if self.at_start is None:
            self.at_start = self._measure()
            if self.at_start > self.WORTH_SAYING:
                self.say(f"load imbalance {self.at_start:.2f} (the costliest rank over the mean)")
        self._rebalance_if_movable()

    def checkpointed(self) -> dict:
        """What a checkpoint keeps of this (its manifest's "load_balance")."""
        return {"rebalance_pending": self.wanted, "bar": self.bar}

    def _rebalance_if_movable(self) -> None:
        state = self.structure.stabilisation_state  # (the same on every rank)
        if self.wanted and not (state.ties or state.damping_windows):
            self.wanted = False
            self.solver.request_rebalance()

    def on_refinement(self, event: RefinementEvent, dt: float, where: str) -> None:
        if self.at_start is None:  # at t = 0: the first history row measures after it
            return
        before = self.largest or 0.0
        self._measure()
        if self.threshold and self.now > self.bar:
            if not self.wanted:
                self.say(
                    f"t = {event.time:.4e} s: load imbalance {self.now:.2f} (the costliest rank "
                    "over the mean): the partition is cut again"
                )
            self.wanted = True
            self._rebalance_if_movable()
        elif self.now > self.WORTH_SAYING and self.now > before:
            self.say(
                f"t = {event.time:.4e} s: load imbalance {self.now:.2f} (the costliest rank "
                "over the mean; the partition stays as it was cut)"
            )


def _load_balance(report: BalanceReport, carried: _Carried) -> dict:
    """``summary.json``'s "load_balance" over the whole run ("rebalanced": when the partition
    was cut again, the imbalance before and after, the seconds the cut took)."""
    at_start = carried.at_start if carried.at_start is not None else report.at_start
    return {
        "imbalance_at_start": at_start,
        "imbalance_at_end": report.now,
        "imbalance_largest": max(carried.largest, report.largest or 0.0) or None,
        "rebalanced": carried.rebalanced,
        "cost_model": (
            f"1 + {balance.REFINED_INTERFACE_COST} per refined interface, in unrefined cells"
        ),
    }


def _finish(
    config: RunConfig,
    out_dir: Path,
    comm: MPI.Comm,
    simulation: Simulation,
    finished: tuple,
    say: Callable[[str], None],
    record: Callable[..., None],
) -> tuple[dict, Structure]:
    """The end of ``execute`` after a completed time loop: the history renamed complete, the
    summary and the plots. ``finished``: (stats, history writer, field writers or None, rows
    kept by a restart, what the segments before a re-balance handed on, summary so far)."""
    stats, history, fields, kept_rows, carried, summary = finished
    structure = simulation.structure
    history.close(completed=True)
    if fields is not None:
        fields.close()

    rows = kept_rows + stats.history
    peak = max(rows, key=lambda r: abs(r.reaction_force))
    # the energy put in: by loads and motions, or by an impactor
    scale = max(max(max(abs(r.external_work), abs(r.impact_work)) for r in rows), 1e-300)
    cost = _summed(carried.cost, _adaptivity_cost(simulation, comm))  # (all segments)
    summary.update(
        {
            "status": "completed",
            "steps": stats.steps,
            "wall_time_s": stats.wall_time,
            # a restart ran only the steps after its checkpoint
            "time_per_step_s": stats.wall_time / max(stats.steps - carried.first_step, 1),
            "peak_reaction_force_N": peak.reaction_force,
            "peak_contact_force_N": max(r.contact_force for r in rows),
            "rigid_bodies": {
                name: {
                    "peak_force_N": max((r.bodies[f"{name}_force"] for r in rows), key=abs),
                    "final_force_N": rows[-1].bodies[f"{name}_force"],
                    "final_displacement_mm": rows[-1].bodies[f"{name}_displacement"],
                    # what its friction dissipated over the run (mJ; 0 without friction)
                    "friction_energy_mJ": rows[-1].bodies.get(f"{name}_friction_energy", 0.0),
                }
                for name in config.loading_bodies
            },
            "displacement_at_peak_mm": peak.displacement,
            "final": {
                "time_s": rows[-1].time,
                "displacement_mm": rows[-1].displacement,
                "reaction_force_N": rows[-1].reaction_force,
                "kinetic_energy_mJ": rows[-1].kinetic_energy,
                "internal_energy_mJ": rows[-1].internal_energy,
                "external_work_mJ": rows[-1].external_work,
                "damping_energy_mJ": rows[-1].damping_energy,
                "dissipated_energy_mJ": rows[-1].dissipated_energy,
                "refinement_energy_mJ": rows[-1].refinement_energy,
                "tie_work_mJ": rows[-1].tie_work,
            },
            "refinement_events": stats.refinements,
            "adaptivity_cost": {
                "indicator_evaluations": cost[0],
                "indicator_wall_s": cost[1],
                "refinement_wall_s": cost[2],
                "reaction_wall_s": cost[3],
            },
            "extra_nodes_at_end": comm.allreduce(structure.extra.n_owned, op=MPI.SUM),
            "cohesive_elements_at_end": comm.allreduce(len(structure.cohesive), op=MPI.SUM),
            "eroded_elements_at_end": comm.allreduce(
                structure.ply_damage_state.eroded_elements() if structure.erosion else 0,
                op=MPI.SUM,
            ),
            # judged as the energy guard judges it: the change since t = 0, where the balance
            # holds the first step's impulse of a motion or load that starts abruptly
            "max_energy_balance_error_relative": max(
                abs(r.energy_balance - rows[0].energy_balance) for r in rows
            )
            / scale,
        }
    )
    output.write_summary(out_dir, summary, comm, record)
    if comm.rank == 0:
        record(out_dir / "force_displacement.png", out_dir / "energies.png")
        output.plot_history(rows, out_dir, title=Path(config.source).stem)
    say(
        f"done: {stats.steps} steps in {stats.wall_time:.1f} s "
        f"({1e6 * stats.wall_time / max(stats.steps, 1):.0f} us/step); results in {out_dir}"
    )
    return summary, structure


def _same_folder(a: Path, b: Path) -> bool:
    try:
        return a.resolve() == b.resolve()
    except OSError:
        return False


def _kept_history(restart, manifest: dict, history_csv: str | None, resume: dict, config):
    """The history rows before the checkpoint's time (and at it, for a state taken after its
    evaluation: a stop that arrived while a history row waited for it on several ranks): those
    kept in the checkpoint (or, for the earlier format, those of its run folder). Raises
    InputError if they stop short of it (the continued history would have a gap)."""
    t = float(manifest["time_s"])
    # an evaluated state's row at t was written; one the restart evaluates writes it again
    evaluated = bool(resume.get("evaluated", False))
    if history_csv is None:
        rows = output.history_until(checkpoint.locate(restart).parent, t)
    else:
        rows = output.parse_history(history_csv, str(restart))
        rows = [r for r in rows if r.time < t or (evaluated and r.time == t)]
    interval = config.solver.output_interval
    due = float(resume["next_output"]) - interval * (1.0 + 1e-9) - float(resume["dt"])
    if t > 0.0 and (not rows or rows[-1].time < due):
        last = f"ends at t = {rows[-1].time:.6g} s" if rows else "is empty"
        raise InputError(
            "restart",
            f"the history kept for the checkpoint at t = {t:.6g} s {last}: the continued "
            "history would have a gap",
        )
    return rows


class _StopOnSignal:
    """SIGINT / SIGTERM set a flag that the solver polls (then checkpoints and stops) instead
    of killing the run mid-write. A second signal is not caught: it stops at once. A rank that
    makes no poll for ``FENICS_ADAPTIVE_STOP_TIMEOUT`` s after the signal (a hung collective)
    aborts the MPI job (``fenics_adaptive.watchdog``)."""

    SIGNALS = (signal.SIGINT, signal.SIGTERM)

    def __init__(self, comm: MPI.Comm = MPI.COMM_WORLD):
        self.requested = False
        self.previous = {}
        self.watchdog = None
        if threading.current_thread() is threading.main_thread():
            for number in self.SIGNALS:
                self.previous[number] = signal.signal(number, self._handle)
            timeout = watchdog.timeout_from_environment()
            self.watchdog = watchdog.StopWatchdog(comm.rank, timeout) if timeout > 0 else None

    def _handle(self, number, frame) -> None:
        self.requested = True
        self._restore_handlers()

    def __call__(self) -> bool:
        if self.watchdog is not None:
            self.watchdog.beat()  # called at every poll: the solver is alive
        return self.requested

    def _restore_handlers(self) -> None:
        for number, handler in self.previous.items():
            signal.signal(number, handler)
        self.previous = {}

    def release(self) -> None:
        self._restore_handlers()
        if self.watchdog is not None:
            self.watchdog.close()
            self.watchdog = None
