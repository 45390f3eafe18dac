"""Checkpoints of a running simulation, and restart from one.

A checkpoint is a folder ``<out>/checkpoint/`` holding one generation (number N, counting up
over the checkpoints written into the folder):

- ``rank<r>-<N>.npz``: what rank r needs to continue: the solver state (time, step, the work
  sums, u and v with their ghosts, the last forces: ``ExplicitSolver.state()``, the
  ``explicit.SolverState`` fields by name, ``BLOCK_ARRAYS``, the contributors' states), the
  structure's history-dependent state (ply damage, cohesive damage, tie forces, damping
  windows, refinement energy) and the log of its refinements;
- ``history-<N>.csv``: the run's history rows up to the checkpoint, so that a restart continues
  exactly the history of this state, whatever history files the folder holds by then;
- ``checkpoint.json``: time, step, number of ranks, the fingerprint of the config, the
  generation and the name, size and SHA-256 of each file above. It is the commit: the files
  of generation N are written and fsync'ed (files and folder) first, then ``checkpoint.json``
  is written to ``checkpoint.json.partial``, fsync'ed and renamed over the previous one in one
  step, then the files of the previous generation are removed. A kill at any moment leaves
  ``checkpoint.json`` naming one complete generation (the previous one until the rename, the
  new one after it); files of an uncommitted or superseded generation are ignored and removed
  by the next checkpoint. A file that does not match its size or checksum is refused.

Restart rebuilds the structure from the config and replays the logged refinements in order.
The lumped masses, extra nodes, maps and border constraints then come out exactly as they were.
The stored arrays are put back on top. The resumed run repeats the uninterrupted one bit for bit
on the same number of ranks. The config may differ only in ``solver.end_time`` and
``output.checkpoint_interval``, so that a finished run can also be extended.

Units: those of the run (N, mm, s, tonne).
"""

from __future__ import annotations

import dataclasses
import hashlib
import io
import json
import math
import os
import re
import zipfile
from collections.abc import Callable
from pathlib import Path

import numpy as np
from mpi4py import MPI

from fenics_adaptive.errors import InputError, shared_errors
from fenics_adaptive.model.structure import Structure
from fenics_adaptive.parallel import redistribute
from fenics_adaptive.settings.config import RunConfig
from fenics_adaptive.solver.explicit import SolverState

FOLDER = "checkpoint"
MANIFEST = "checkpoint.json"


def fingerprint(config: RunConfig) -> str:
    """Hash of everything in a config that a restart must not change."""
    solver = dataclasses.replace(config.solver, end_time=0.0, checkpoint_interval=None)
    frozen = dataclasses.replace(config, solver=solver, source="")
    return hashlib.sha256(repr(frozen).encode()).hexdigest()[:16]


def _sync_folder(folder: Path) -> None:
    """fsync a folder, so that the names created or renamed in it survive a crash."""
    fd = os.open(folder, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def write_durably(path: Path, data: bytes) -> None:
    """Write ``data`` to ``path`` and fsync the file (the step a test interrupts)."""
    with open(path, "wb") as f:
        f.write(data)
        f.flush()
        os.fsync(f.fileno())


def _entry(name: str, data: bytes) -> dict:
    return {"name": name, "bytes": len(data), "sha256": hashlib.sha256(data).hexdigest()}


_GENERATION = re.compile(r"(rank\d+|history)-(\d+)\.(npz|csv)")


def _next_sequence(folder: Path) -> int:
    """One more than any checkpoint generation in the folder (committed or not)."""
    sequences = [0]
    for entry in folder.iterdir():
        match = _GENERATION.fullmatch(entry.name)
        if match:
            sequences.append(int(match.group(2)))
    try:
        sequences.append(int(json.loads((folder / MANIFEST).read_text()).get("sequence", 0)))
    except (OSError, ValueError, AttributeError, TypeError):
        pass
    return max(sequences) + 1


def write(
    out_dir: Path,
    comm: MPI.Comm,
    solver_state: dict,
    structure: Structure,
    hook_state: dict[str, np.ndarray],
    config: RunConfig,
    history_csv: str = "",
    record: Callable[..., None] | None = None,
    forget: Callable[..., None] | None = None,
    layouts: dict | None = None,
    partition: dict | None = None,
    load_balance: dict | None = None,
) -> Path:
    """Collective: write the checkpoint of this moment into ``out_dir/checkpoint``; returns
    that folder. ``history_csv``: the run's history so far (rank 0's; CSV text), kept with the
    state so that a restart continues exactly this history. ``record(path, folder=...)`` is
    told every name before it is written (the run folder's manifest), ``forget(path, ...)``
    the names of the superseded generation once they are removed.

    ``layouts``: how each array's rows are indexed (``state_layouts``; None: this checkpoint
    continues on the same partition only); ``partition``: how the run's partition was cut
    (the manifest's "partition"); ``load_balance``: whether a re-balance waits, and the
    imbalance that asks for one (the manifest's "load_balance", ``runner.BalanceReport``).

    Protocol (see the module): the new generation's files, fsync'ed, then ``checkpoint.json``
    replaced atomically (the commit), then the older generation's files removed."""
    folder = out_dir / FOLDER
    sequence = None
    with shared_errors(comm):
        if comm.rank == 0:
            if record is not None:
                record(folder, folder=True)
            folder.mkdir(parents=True, exist_ok=True)
            sequence = _next_sequence(folder)
    sequence = comm.bcast(sequence, root=0)
    arrays = {f"solver_{k}": np.asarray(v) for k, v in solver_state.items()}
    arrays.update({f"structure_{k}": v for k, v in structure.state().items()})
    arrays.update({f"hook_{k}": np.asarray(v) for k, v in hook_state.items()})
    movable = comm.allreduce(layouts is not None, op=MPI.LAND)
    with shared_errors(comm):
        if movable:
            arrays = redistribute.annotate(arrays, layouts)
        # where the logged refinements were: a restart cuts a re-balanced partition by them
        arrays[REQUEST_CELLS], arrays[REQUEST_CENTROIDS] = structure.request_cells()
    entry = None
    with shared_errors(comm):
        buffer = io.BytesIO()
        np.savez(buffer, **arrays)
        data = buffer.getvalue()
        name = f"rank{comm.rank}-{sequence}.npz"
        if comm.rank == 0 and record is not None:
            record(*(folder / f"rank{r}-{sequence}.npz" for r in range(comm.size)))
        write_durably(folder / name, data)
        entry = _entry(name, data)
    entries = comm.gather(entry, root=0)
    with shared_errors(comm):
        if comm.rank == 0:
            history = history_csv.encode()
            history_name = f"history-{sequence}.csv"
            if record is not None:
                record(folder / history_name, folder / MANIFEST, folder / (MANIFEST + ".partial"))
            write_durably(folder / history_name, history)
            manifest = {
                "time_s": float(solver_state["t"]),
                "step": int(solver_state["step"]),
                "mpi_ranks": comm.size,
                "config_fingerprint": fingerprint(config),
                "config": config.source,
                "sequence": sequence,
                # whether each array says how its rows are indexed (another partition can
                # read it), and how this run's partition was cut
                "movable": movable,
                "partition": partition or {"weights": "start"},
                "load_balance": load_balance or {},
                "ranks": entries,
                "history": _entry(history_name, history),
            }
            _sync_folder(folder)  # the new files exist before the commit names them
            partial = folder / (MANIFEST + ".partial")
            write_durably(partial, (json.dumps(manifest, indent=2) + "\n").encode())
            commit(partial, folder / MANIFEST)
            removed = remove_superseded(folder, sequence)
            if forget is not None:
                forget(*removed)
    return folder


# the original cell of each logged refinement request, for another partition's replay
REQUEST_CELLS = "structure_refinement_requests@cells"
REQUEST_CENTROIDS = "structure_refinement_requests@xy"  # (their in-plane centroids, mm)


def state_layouts(solver, structure: Structure, hook) -> tuple[dict | None, str]:
    """(layouts of every array a checkpoint of this moment holds, by their checkpoint names,
    or None; why not, or ""): ``parallel.redistribute``. None while a refinement's ties or
    damping windows act, or with a force contributor that has a state and no layout."""
    try:
        layouts = {f"solver_{k}": v for k, v in solver.layout().items()}
        layouts.update({f"structure_{k}": v for k, v in structure.layout().items()})
        layouts.update({f"hook_{k}": v for k, v in hook.layout(structure).items()})
    except redistribute.NotMovable as reason:
        return None, str(reason)
    return layouts, ""


def commit(partial: Path, final: Path) -> None:
    """The one step that makes a checkpoint current: an atomic rename, made durable."""
    os.replace(partial, final)
    _sync_folder(final.parent)


def remove_superseded(folder: Path, sequence: int) -> list[Path]:
    """Remove the files of every generation but ``sequence`` (and of the unnumbered format);
    returns them."""
    removed = []
    for old in folder.iterdir():
        match = _GENERATION.fullmatch(old.name)
        if (match and int(match.group(2)) != sequence) or _LEGACY.fullmatch(old.name):
            old.unlink()
            removed.append(old)
    return removed


_LEGACY = re.compile(r"rank\d+\.npz")  # the files of the earlier, unnumbered format


def locate(folder: str | Path) -> Path:
    """The checkpoint folder meant by ``folder``: a checkpoint folder itself or the output
    folder of a run holding one (also the leftovers of the earlier two-rename format: the
    newer of ``checkpoint.partial/`` and ``checkpoint.old/``). Raises InputError without a
    complete one."""
    folder = Path(folder)
    for candidate in (
        folder,
        folder / FOLDER,
        folder / (FOLDER + ".partial"),
        folder / (FOLDER + ".old"),
    ):
        if (candidate / MANIFEST).is_file():
            return candidate
    raise InputError("restart", f"{folder} holds no complete checkpoint ({MANIFEST} missing)")


def _damaged(path: Path, problem: str) -> InputError:
    return InputError("restart", f"the checkpoint file {path} {problem}; it cannot be continued")


def _read_checked(path: Path, entry: dict | None) -> bytes:
    """A checkpoint file's bytes, checked against its manifest entry (size, SHA-256)."""
    try:
        data = path.read_bytes()
    except FileNotFoundError:
        raise _damaged(path, "is missing") from None
    except OSError as error:
        raise _damaged(path, f"cannot be read ({error.strerror})") from None
    if entry is not None:
        if len(data) != entry.get("bytes"):
            raise _damaged(path, f"has {len(data)} bytes, not {entry.get('bytes')} (truncated?)")
        if hashlib.sha256(data).hexdigest() != entry.get("sha256"):
            raise _damaged(path, "does not match its checksum (damaged)")
    return data


def _read_manifest(path: Path) -> dict:
    try:
        manifest = json.loads(path.read_text())
        for key, kind in (("time_s", float), ("step", int), ("mpi_ranks", int)):
            manifest[key] = kind(manifest[key])
        if not (math.isfinite(manifest["time_s"]) and manifest["time_s"] >= 0.0):
            raise TypeError(f"time_s = {manifest['time_s']} is not a time")
        if manifest["step"] < 0 or manifest["mpi_ranks"] < 1:
            raise TypeError("step or mpi_ranks out of range")
        if not isinstance(manifest["config_fingerprint"], str):
            raise TypeError("config_fingerprint is not a string")
    except (OSError, UnicodeDecodeError) as error:
        raise _damaged(path, f"cannot be read ({error})") from None
    except ValueError as error:
        raise _damaged(path, f"is not valid JSON ({error})") from None
    except (KeyError, TypeError) as error:
        raise _damaged(path, f"lacks an entry ({error})") from None
    return manifest


def read(
    folder: str | Path, comm: MPI.Comm, config: RunConfig, repartition: bool = False
) -> tuple[dict, dict | redistribute.StoredState, str | None]:
    """Collective: (manifest, this rank's arrays, the history CSV text kept with the
    checkpoint or None for the earlier format) of the checkpoint in ``folder``. On another
    number of ranks than wrote it, or with ``repartition``, every rank's arrays instead
    (``redistribute.StoredState``: the run continues on a partition of its own). Raises
    InputError, on every rank, when it cannot continue this config on this number of ranks
    or when a file of it is damaged or missing."""
    manifest, where = None, None
    with shared_errors(comm):
        if comm.rank == 0:
            where = locate(folder)
            manifest = _read_manifest(where / MANIFEST)
            if manifest["config_fingerprint"] != fingerprint(config):
                raise InputError(
                    "restart",
                    f"the config differs from the one that wrote {where} "
                    f"({manifest['config']}) in more than solver.end_time and "
                    "output.checkpoint_interval",
                )
            if config.solver.end_time < manifest["time_s"] * (1.0 - 1e-12):
                raise InputError(
                    "solver.end_time",
                    f"{config.solver.end_time:g} s is before the checkpoint's time "
                    f"({manifest['time_s']:.6g} s), from which a restart continues",
                )
            moves = repartition or int(manifest["mpi_ranks"]) != comm.size
            repartition = moves
            if moves and not manifest.get("movable", False):
                raise InputError(
                    "restart",
                    f"the checkpoint was written by {manifest['mpi_ranks']} MPI rank(s) and "
                    "cannot move to another partition (written while a refinement's ties or "
                    "damping windows acted, or by an earlier version); restart it on as many "
                    f"(this run has {comm.size})",
                )
    manifest, where, repartition = comm.bcast((manifest, where, repartition), root=0)
    ranks = manifest.get("ranks")
    if repartition:
        with shared_errors(comm):  # (every rank reads every file)
            files = [_rank_arrays(where, ranks, r) for r in range(int(manifest["mpi_ranks"]))]
        arrays = redistribute.StoredState(files, comm.rank, comm.size)
    else:
        arrays = _rank_arrays(where, ranks, comm.rank, comm)
    first = arrays.files[0] if isinstance(arrays, redistribute.StoredState) else arrays
    with shared_errors(comm):
        stored = (float(first["solver_t"]), int(first["solver_step"]))
        if stored != (manifest["time_s"], manifest["step"]):
            said = f"{manifest['time_s']:.9g} s, step {manifest['step']}"
            raise _damaged(where / MANIFEST, f"says {said}; its files {stored[0]:.9g} s, "
                           f"step {stored[1]}")  # fmt: skip
    history = None
    with shared_errors(comm):
        if comm.rank == 0 and "history" in manifest:
            entry = manifest["history"]
            path = where / str(entry.get("name"))
            try:
                history = _read_checked(path, entry).decode()
            except UnicodeDecodeError:
                raise _damaged(path, "is not text") from None
    history = comm.bcast(history, root=0)
    return manifest, arrays, history


def _rank_arrays(where: Path, ranks, rank: int, comm: MPI.Comm = MPI.COMM_SELF) -> dict:
    """Collective over ``comm``: the arrays of the file of old rank ``rank``, checked."""
    arrays = {}
    with shared_errors(comm):
        entry = ranks[rank] if isinstance(ranks, list) and rank < len(ranks) else None
        name = entry.get("name") if isinstance(entry, dict) else f"rank{rank}.npz"
        if not isinstance(name, str) or Path(name).name != name:
            raise _damaged(where / MANIFEST, f"names no valid file for rank {rank}")
        path = where / name
        data = _read_checked(path, entry)
        try:
            with np.load(io.BytesIO(data)) as archive:
                arrays = {key: archive[key] for key in archive.files}
        except (ValueError, OSError, EOFError, zipfile.BadZipFile) as error:
            raise _damaged(path, f"is not a readable NumPy archive ({error})") from None
        missing = [k for k in _REQUIRED if k not in arrays]
        if missing:
            raise _damaged(path, f"lacks {', '.join(missing[:3])}")
    return arrays


# what a checkpoint's arrays must hold, whatever the model
_REQUIRED = (
    *(f"solver_{f.name}" for f in dataclasses.fields(SolverState)),
    "structure_refinement_times",
    "structure_refinement_counts",
    "structure_refinement_requests",
    "structure_refinement_energy",
    "structure_cohesive_damage",
    "structure_tie_counts",
    "structure_window_counts",
)


def restore_structure(structure: Structure, arrays: dict) -> None:
    """Collective: replay the logged refinements on a structure built from the config without
    its initial refinement, then put the stored state back (``Structure.restore``)."""
    structure.restore(_named(arrays, "structure_"))


def solver_state(arrays: dict) -> dict:
    """The solver's part of a checkpoint, as ``ExplicitSolver.restore`` takes it."""
    return {k: v[()] if v.ndim == 0 else v for k, v in _named(arrays, "solver_").items()}


def hook_state(arrays: dict) -> dict:
    """The refinement hook's part of a checkpoint, as ``RefinementHook.restore`` takes it."""
    return _named(arrays, "hook_")


def _named(arrays: dict, prefix: str) -> dict:
    """The arrays named ``prefix``* without the prefix, their layouts left out."""
    named = (k for k in arrays if k.startswith(prefix) and "@" not in k)
    return {k.removeprefix(prefix): arrays[k] for k in named}


def refined_cells(files: list[dict], until: float = math.inf) -> tuple[np.ndarray, np.ndarray]:
    """(in-plane centroids (n, 2) mm, how many interfaces each is refined at (n,)) of every
    cell the refinement logs of ``files`` (the arrays of every rank) refined up to time
    ``until`` (s)."""
    cells, centroids, interfaces = [], [], []
    for f in files:
        times = f["structure_refinement_times"]
        counts = f["structure_refinement_counts"]
        keep = np.repeat(times <= until * (1.0 + 1e-12), counts)
        cells.append(f[REQUEST_CELLS][keep])
        centroids.append(f[REQUEST_CENTROIDS].reshape(-1, 2)[keep])
        interfaces.append(f["structure_refinement_requests"].reshape(-1, 3)[keep, 1])
    cells, centroids = np.concatenate(cells), np.concatenate(centroids)
    interfaces = np.concatenate(interfaces)
    if len(cells) == 0:
        return np.zeros((0, 2)), np.zeros(0, np.int64)
    _, first = np.unique(np.stack([cells, interfaces], axis=1), axis=0, return_index=True)
    _, at, counts = np.unique(cells[first], return_index=True, return_counts=True)
    return centroids[first][at], counts


def _moved_refinement_log(stored: redistribute.StoredState, structure: Structure) -> dict:
    """The stored refinement log as this rank replays it: each entry's requests of the cells
    this rank owns (every rank has every entry, perhaps empty: the replay is collective)."""
    order = np.argsort(structure.original_cell)
    owned = structure.original_cell[order]
    times = stored.files[0]["structure_refinement_times"]
    parts = []
    for f in stored.files:
        offsets = np.concatenate([[0], np.cumsum(f["structure_refinement_counts"])])
        parts.append((offsets, f["structure_refinement_requests"].reshape(-1, 3), f[REQUEST_CELLS]))
    counts, requests = [], []
    for k in range(len(times)):
        entry = []
        for offsets, rows, cells in parts:
            rows, cells = rows[offsets[k] : offsets[k + 1]], cells[offsets[k] : offsets[k + 1]]
            at = np.minimum(np.searchsorted(owned, cells), max(len(owned) - 1, 0))
            mine = owned[at] == cells if len(owned) else np.zeros(len(cells), dtype=bool)
            entry.append(np.column_stack([order[at[mine]], rows[mine, 1:]]))
        entry = np.concatenate(entry).astype(np.int64).reshape(-1, 3)
        counts.append(len(entry))
        requests.append(entry)
    return {
        "refinement_times": times,
        "refinement_counts": np.array(counts, dtype=np.int64),
        "refinement_requests": np.concatenate(requests or [np.zeros((0, 3), np.int64)]),
        "refinement_energy": stored.files[0]["structure_refinement_energy"],
    }


def restore_moved_structure(structure: Structure, stored: redistribute.StoredState) -> None:
    """Collective: a checkpoint written on another partition (``read``) put on ``structure``
    (built from the config without its initial refinement): the logged refinements replayed
    on the cells this rank owns, then every stored array's rows found by their keys."""
    structure.replay(_moved_refinement_log(stored, structure))
    state = moved_state(stored, "structure_", structure.layout(), structure.comm)
    structure.put_back({k: v for k, v in state.items() if not k.startswith("refinement_")})


def moved_state(
    stored: redistribute.StoredState, prefix: str, layouts: dict, comm: MPI.Comm
) -> dict:
    """Collective: this rank's arrays named ``prefix``* of a checkpoint written on another
    partition, by the ``layouts`` of this partition's objects (names without the prefix).
    Raises InputError, on every rank, for a row no old rank stored (a checkpoint that does
    not belong to this model)."""
    out = {}
    with shared_errors(comm):
        for name in stored.names(prefix):
            key = name.removeprefix(prefix)
            try:
                value = stored.value(name, layouts.get(key))
            except (KeyError, ValueError) as error:
                raise InputError(
                    "restart", f"the checkpoint cannot be moved to this partition: {error}"
                ) from None
            out[key] = value[()] if np.ndim(value) == 0 else value
    return out
