"""Checkpoints of a running simulation, and restart from one.

A checkpoint is a folder ``<out>/checkpoint/``:

- ``rank<r>.npz``: what rank r needs to continue: the solver state (time, step, the work sums,
  u and v with their ghosts, the last forces; ``explicit.SOLVER_SCALARS``, ``BLOCK_ARRAYS``),
  the structure's history-dependent state (ply damage, cohesive damage, tie forces, damping
  windows, refinement energy) and the log of its refinements;
- ``checkpoint.json``: time, step, number of ranks and the fingerprint of the config. Written
  last: a folder without it is not a checkpoint.

It is written to ``checkpoint.partial/`` first and renamed into place, so a run killed while
writing keeps its previous checkpoint.

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
import json
import os
import shutil
from pathlib import Path

import numpy as np
from mpi4py import MPI

from fenics_adaptive.config import RunConfig
from fenics_adaptive.errors import InputError
from fenics_adaptive.structure import DampingWindow, Structure, Ties

FOLDER = "checkpoint"
MANIFEST = "checkpoint.json"


def fingerprint(config: RunConfig) -> str:
    """Hash of everything in a config that a restart must not change."""
    solver = dataclasses.replace(config.solver, end_time=0.0, checkpoint_interval=None)
    frozen = dataclasses.replace(config, solver=solver, source="")
    return hashlib.sha256(repr(frozen).encode()).hexdigest()[:16]


def structure_state(structure: Structure) -> dict[str, np.ndarray]:
    """The structure's history-dependent arrays (this rank)."""
    log = structure.refinement_log
    ties, windows = structure.ties, structure.damping_windows
    state = {
        "refinement_times": np.array([t for t, _ in log], dtype=float),
        "refinement_counts": np.array([len(r) for _, r in log], dtype=np.int64),
        "refinement_requests": np.concatenate(
            [np.asarray(r, dtype=np.int64).reshape(-1, 3) for _, r in log] or [np.zeros((0, 3))]
        ).astype(np.int64),
        "refinement_energy": np.array(structure.refinement_energy),
        "cohesive_damage": structure.cohesive.damage,
        "cohesive_history": structure.cohesive.history,
        "tie_counts": np.array([len(tie.a) for tie in ties], dtype=np.int64),
        "tie_a": np.concatenate([tie.a for tie in ties] or [np.zeros(0, np.int64)]),
        "tie_b": np.concatenate([tie.b for tie in ties] or [np.zeros(0, np.int64)]),
        "tie_force": np.concatenate([tie.force for tie in ties] or [np.zeros((0, 3))]),
        "tie_times": np.array([[tie.start, tie.window] for tie in ties]).reshape(-1, 2),
        "window_counts": np.array([len(w.dofs) for w in windows], dtype=np.int64),
        "window_dofs": np.concatenate([w.dofs for w in windows] or [np.zeros(0, np.int32)]),
        "window_values": np.array([[w.block, w.coefficient, w.until] for w in windows]).reshape(
            -1, 3
        ),
    }
    if structure.ply_damage:
        state["ply_damage"] = structure.damage_state
    return state


def write(
    out_dir: Path,
    comm: MPI.Comm,
    solver_state: dict,
    structure: Structure,
    hook_state: dict[str, np.ndarray],
    config: RunConfig,
) -> Path:
    """Collective: write the checkpoint of this moment; returns its folder."""
    final = out_dir / FOLDER
    partial = out_dir / (FOLDER + ".partial")
    if comm.rank == 0:
        shutil.rmtree(partial, ignore_errors=True)
        partial.mkdir(parents=True)
    comm.barrier()
    arrays = {f"solver_{k}": np.asarray(v) for k, v in solver_state.items()}
    arrays.update({f"structure_{k}": v for k, v in structure_state(structure).items()})
    arrays.update({f"hook_{k}": np.asarray(v) for k, v in hook_state.items()})
    np.savez(partial / f"rank{comm.rank}.npz", **arrays)
    comm.barrier()
    if comm.rank == 0:
        manifest = {
            "time_s": float(solver_state["t"]),
            "step": int(solver_state["step"]),
            "mpi_ranks": comm.size,
            "config_fingerprint": fingerprint(config),
            "config": config.source,
        }
        (partial / MANIFEST).write_text(json.dumps(manifest, indent=2) + "\n")
        old = out_dir / (FOLDER + ".old")
        shutil.rmtree(old, ignore_errors=True)
        if final.exists():
            os.replace(final, old)
        os.replace(partial, final)
        shutil.rmtree(old, ignore_errors=True)
    comm.barrier()
    return final


def read(folder: str | Path, comm: MPI.Comm, config: RunConfig) -> tuple[dict, dict]:
    """(manifest, this rank's arrays) of a checkpoint folder. Raises InputError when it cannot
    continue this config on this number of ranks."""
    folder = Path(folder)
    if (folder / FOLDER / MANIFEST).exists():  # the run's output folder was given
        folder = folder / FOLDER
    if not (folder / MANIFEST).exists():
        raise InputError("restart", f"{folder} holds no complete checkpoint ({MANIFEST} missing)")
    manifest = json.loads((folder / MANIFEST).read_text())
    if manifest["mpi_ranks"] != comm.size:
        raise InputError(
            "restart",
            f"the checkpoint was written by {manifest['mpi_ranks']} MPI rank(s); restart it on "
            f"as many (this run has {comm.size})",
        )
    if manifest["config_fingerprint"] != fingerprint(config):
        raise InputError(
            "restart",
            f"the config differs from the one that wrote {folder} ({manifest['config']}) in "
            "more than solver.end_time and output.checkpoint_interval",
        )
    with np.load(folder / f"rank{comm.rank}.npz") as data:
        arrays = {name: data[name] for name in data.files}
    return manifest, arrays


def restore_structure(structure: Structure, arrays: dict) -> None:
    """Collective: replay the logged refinements on a structure built from the config without
    its initial refinement, then put the stored state back."""
    times = arrays["structure_refinement_times"]
    counts = arrays["structure_refinement_counts"]
    requests = arrays["structure_refinement_requests"]
    offsets = np.concatenate([[0], np.cumsum(counts)])
    for k, t in enumerate(times):
        chunk = requests[offsets[k] : offsets[k + 1]]
        structure.refine([tuple(int(x) for x in r) for r in chunk], float(t))
        structure.discard_stabilisation_requests()
    structure.refinement_energy = float(arrays["structure_refinement_energy"])
    structure.cohesive.damage[:] = arrays["structure_cohesive_damage"]
    structure.cohesive.history[:] = arrays["structure_cohesive_history"]
    if structure.ply_damage:
        structure.damage_state[:] = arrays["structure_ply_damage"]
    ties, start = [], 0
    for n, (t0, window) in zip(
        arrays["structure_tie_counts"], arrays["structure_tie_times"], strict=True
    ):
        a = arrays["structure_tie_a"][start : start + n]
        b = arrays["structure_tie_b"][start : start + n]
        force = arrays["structure_tie_force"][start : start + n]
        ties.append(Ties(a, b, force, float(t0), float(window)))
        start += n
    structure.ties = ties
    windows, start = [], 0
    for n, (block, coefficient, until) in zip(
        arrays["structure_window_counts"], arrays["structure_window_values"], strict=True
    ):
        dofs = arrays["structure_window_dofs"][start : start + n].astype(np.int32)
        windows.append(DampingWindow(int(block), dofs, float(coefficient), float(until)))
        start += n
    structure.damping_windows = windows


def solver_state(arrays: dict) -> dict:
    """The solver's part of a checkpoint, as ``explicit.run(resume=...)`` takes it."""
    out = {}
    for name, value in arrays.items():
        if name.startswith("solver_"):
            out[name.removeprefix("solver_")] = value[()] if value.ndim == 0 else value
    return out


def hook_state(arrays: dict) -> dict:
    return {n.removeprefix("hook_"): v for n, v in arrays.items() if n.startswith("hook_")}
