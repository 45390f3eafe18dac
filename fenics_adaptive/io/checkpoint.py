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
import os
import re
import zipfile
from collections.abc import Callable
from pathlib import Path

import numpy as np
from mpi4py import MPI

from fenics_adaptive.errors import InputError, shared_errors
from fenics_adaptive.model.structure import Structure
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
) -> Path:
    """Collective: write the checkpoint of this moment into ``out_dir/checkpoint``; returns
    that folder. ``history_csv``: the run's history so far (rank 0's; CSV text), kept with the
    state so that a restart continues exactly this history. ``record(path, folder=...)`` is
    told every name before it is written (the run folder's manifest), ``forget(path, ...)``
    the names of the superseded generation once they are removed.

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
        if not isinstance(manifest["config_fingerprint"], str):
            raise TypeError("config_fingerprint is not a string")
    except (OSError, UnicodeDecodeError) as error:
        raise _damaged(path, f"cannot be read ({error})") from None
    except ValueError as error:
        raise _damaged(path, f"is not valid JSON ({error})") from None
    except (KeyError, TypeError) as error:
        raise _damaged(path, f"lacks an entry ({error})") from None
    return manifest


def read(folder: str | Path, comm: MPI.Comm, config: RunConfig) -> tuple[dict, dict, str | None]:
    """Collective: (manifest, this rank's arrays, the history CSV text kept with the
    checkpoint or None for the earlier format) of the checkpoint in ``folder``. Raises
    InputError, on every rank, when it cannot continue this config on this number of ranks
    or when a file of it is damaged or missing."""
    manifest, where = None, None
    with shared_errors(comm):
        if comm.rank == 0:
            where = locate(folder)
            manifest = _read_manifest(where / MANIFEST)
            if manifest["mpi_ranks"] != comm.size:
                raise InputError(
                    "restart",
                    f"the checkpoint was written by {manifest['mpi_ranks']} MPI rank(s); "
                    f"restart it on as many (this run has {comm.size})",
                )
            if manifest["config_fingerprint"] != fingerprint(config):
                raise InputError(
                    "restart",
                    f"the config differs from the one that wrote {where} "
                    f"({manifest['config']}) in more than solver.end_time and "
                    "output.checkpoint_interval",
                )
    manifest, where = comm.bcast((manifest, where), root=0)
    arrays, history = {}, None
    with shared_errors(comm):
        ranks = manifest.get("ranks")
        entry = ranks[comm.rank] if isinstance(ranks, list) else None
        name = entry.get("name") if isinstance(entry, dict) else f"rank{comm.rank}.npz"
        if not isinstance(name, str) or Path(name).name != name:
            raise _damaged(where / MANIFEST, "names no valid file for this rank")
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
        if comm.rank == 0 and "history" in manifest:
            entry = manifest["history"]
            path = where / str(entry.get("name"))
            try:
                history = _read_checked(path, entry).decode()
            except UnicodeDecodeError:
                raise _damaged(path, "is not text") from None
    history = comm.bcast(history, root=0)
    return manifest, arrays, history


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
    prefix = "structure_"
    structure.restore(
        {k.removeprefix(prefix): v for k, v in arrays.items() if k.startswith(prefix)}
    )


def solver_state(arrays: dict) -> dict:
    """The solver's part of a checkpoint, as ``ExplicitSolver.restore`` takes it."""
    out = {}
    for name, value in arrays.items():
        if name.startswith("solver_"):
            out[name.removeprefix("solver_")] = value[()] if value.ndim == 0 else value
    return out


def hook_state(arrays: dict) -> dict:
    return {n.removeprefix("hook_"): v for n, v in arrays.items() if n.startswith("hook_")}
