"""A time line of the explicit step on every rank: does the halo exchange hide behind the
interior elements? (issue 23, item 2)

The solver starts the exchange of the displacements right after moving its owned nodes,
computes the interior elements (all nodes owned: ``NodeArrays.interior``) while the messages
travel, waits, computes the rest; then sends the internal forces' ghost shares and computes
the external loads while they travel (``RunForces.evaluate``). ``ExplicitSolver.overlap =
False`` waits for the displacements at once instead. This script runs both on the same
structure and times, on each rank, every phase of every step with ``time.perf_counter``
(CLOCK_MONOTONIC: one clock for all processes of a machine, so the ranks' time lines line up):

- ``send``: packing the owned values and starting the exchange (``Halo.forward_start``);
- ``elements``: the elements' forces: with the overlap the interior ones
  (``add_interior_force``), without it all of them (``add_force``);
- ``wait u``: ``Halo.forward_finish``, the wait for the ghosts' displacements and unpacking;
- ``send f`` / ``wait f``: the internal forces' reverse exchange (``reverse_start`` /
  ``reverse_finish``).

Cases: the 200 000-cell beam of ``benchmarks/run.py``'s ``mpi`` rows (ESL, 20 000 x 10
columns, cut into two strips: a 10-column halo) and a square plate of as many cells (cut in
two halves: a halo of one side).

Usage (it launches itself under mpiexec):

    .venv/bin/python benchmarks/overlap_trace.py [--ranks 2] [--cells 200000] [--steps 200]

writes ``overlap_trace.json`` and ``overlap_trace.md`` into ``--out`` (default
``benchmarks/results``) and the time line to ``--figure`` (default
``docs/images/overlap_trace.png``).
"""

from __future__ import annotations

import argparse
import json
import math
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent

# the spans timed in each step: (name, what the solver calls)
SPANS = ("send", "elements", "wait u", "send f", "wait f")
STEP = len(SPANS)  # the slot of the whole step
WARM_STEPS = 20


def shape_config(cells: int, shape: str) -> dict:
    """The ``mpi`` benchmark's beam config with about ``cells`` cells, as a long strip
    ("beam", 10 cells across) or a square plate ("plate")."""
    sys.path.insert(0, str(HERE))
    from run import beam_config

    data = beam_config(cells)
    if shape == "plate":
        side = max(round(math.sqrt(cells)), 2)
        data["mesh"].update(nx=side, ny=side, length=0.5 * side, width=0.5 * side)
    return data


def traced_steps(structure, probe, steps: int, overlap: bool) -> np.ndarray:
    """Collective: (steps, len(SPANS) + 1, 2) start and end times (s, perf_counter) of each
    span of ``steps`` steps on this rank (NaN: not called in that step), slot ``STEP`` the
    whole step; after ``WARM_STEPS`` untimed ones."""
    from fenics_adaptive.model.forces import overrides
    from fenics_adaptive.settings.solver import SolverSettings
    from fenics_adaptive.solver import explicit

    once = SolverSettings(end_time=1.0, output_interval=1.0)
    dt, _, _ = explicit.choose_time_step(structure, once)
    total = steps + WARM_STEPS + 1
    settings = SolverSettings(end_time=total * dt, output_interval=total * dt)
    spans = np.full((steps, STEP + 1, 2), np.nan)
    current = [-1]
    wrapped = []

    def timed(owner, name: str, slot: int) -> None:
        inner = getattr(owner, name)

        def call(*args, **kwargs):
            start = time.perf_counter()
            out = inner(*args, **kwargs)
            end = time.perf_counter()
            k = current[0]
            if k >= 0:
                if math.isnan(spans[k, slot, 0]):
                    spans[k, slot, 0] = start
                spans[k, slot, 1] = end
            return out

        setattr(owner, name, call)
        wrapped.append((owner, name))

    halo = structure.halo
    for slot, name in ((0, "forward_start"), (2, "forward_finish"), (3, "reverse_start")):
        timed(halo, name, slot)
    timed(halo, "reverse_finish", 4)
    for contributor in structure.internal_forces.contributors:
        if overrides(contributor, "add_interior_force"):
            timed(contributor, "add_interior_force" if overlap else "add_force", 1)
    # (after the wrapping: the solver's forces hold the contributors' bound methods)
    solver = explicit.ExplicitSolver(structure, settings, probe, time_step=dt)
    solver.overlap = overlap
    solver.start()
    for _ in range(WARM_STEPS):
        solver.step()
    for k in range(steps):
        current[0] = k
        spans[k, STEP, 0] = time.perf_counter()
        solver.step()
        spans[k, STEP, 1] = time.perf_counter()
    current[0] = -1
    solver.settle()
    for owner, name in wrapped:
        delattr(owner, name)  # the class's method again
    return spans


def phase_times(spans: np.ndarray, others: list[np.ndarray]) -> dict[str, np.ndarray]:
    """Per step (s): the step, its spans' durations, how long the displacements were in
    flight while the rank computed (``in flight``: from the end of ``send`` to the start of
    ``wait u``), and whether every other rank (``others``: their spans) had sent its
    displacements before this one began to wait for them (``arrived``, 1 or 0: the data
    was there to take, on a clock all processes share)."""
    out = {"step": spans[:, STEP, 1] - spans[:, STEP, 0]}
    for slot, name in enumerate(SPANS):
        out[name] = spans[:, slot, 1] - spans[:, slot, 0]
    out["in flight"] = spans[:, 2, 0] - spans[:, 0, 1]
    sent = np.max([o[:, 0, 1] for o in others], axis=0) if others else spans[:, 0, 1]
    out["arrived"] = np.where(np.isfinite(spans[:, 2, 0]), sent <= spans[:, 2, 0], np.nan)
    return out


def worker(cells: int, steps: int, shapes: list[str], out: Path, figure: Path) -> None:
    import mpi4py.MPI as MPI

    from fenics_adaptive.settings.config import parse_config
    from fenics_adaptive.simulation import build_structure

    comm = MPI.COMM_WORLD
    results = {}
    for shape in shapes:
        config = parse_config(shape_config(cells, shape))
        structure = build_structure(config, comm)
        n_cells = comm.allreduce(structure.base.n_owned_cells)
        ghosts = comm.gather(structure.halo.ghost_values)
        # each mode twice, alternating, so that a slow spell of the shared cores does not
        # fall on one mode only
        runs = {False: [], True: []}
        for overlap in (False, True, False, True):
            runs[overlap].append(traced_steps(structure, config.probe, steps, overlap))
        for overlap, spans in runs.items():
            everyone = comm.gather(np.concatenate(spans))
            if comm.rank == 0:
                results[(shape, overlap)] = (n_cells, ghosts, everyone)
    if comm.rank == 0:
        report(results, comm.size, out, steps, figure)


def report(results: dict, ranks: int, out: Path, per_run: int, figure: Path) -> None:
    """The tables (median over steps of each rank; the worst rank) and the time line."""
    rows = []
    for (shape, overlap), (n_cells, ghosts, everyone) in results.items():
        per_rank = [
            phase_times(spans, [o for q, o in enumerate(everyone) if q != r])
            for r, spans in enumerate(everyone)
        ]
        row = {
            "case": shape,
            "cells": n_cells,
            "ranks": ranks,
            "ghost_values": ghosts,
            "overlap": overlap,
        }
        for name in ("step", *SPANS, "in flight"):
            values = [
                np.nanmedian(p[name]) if np.isfinite(p[name]).any() else np.nan for p in per_rank
            ]
            row[name + "_us"] = 1e6 * max(values)
        # the steps whose exchange the solver finished in the forces (not early: a poll's)
        row["arrived"] = min(float(np.nanmean(p["arrived"])) for p in per_rank)
        arrived = [p["wait u"][p["arrived"] == 1] for p in per_rank]
        row["wait_u_arrived_us"] = 1e6 * max(
            (float(np.median(a)) for a in arrived if len(a)), default=float("nan")
        )
        rows.append(row)
    out.mkdir(parents=True, exist_ok=True)
    (out / "overlap_trace.json").write_text(json.dumps(rows, indent=1))
    lines = [
        f"one explicit step on {ranks} ranks, medians over the steps (us; the larger over "
        "ranks); `in flight`: the time the displacements travel while the rank computes; "
        "`arrived`: the share of the steps (the smaller over ranks) where every other rank had "
        "sent them when the rank began to wait for them, and its `wait u` in those steps",
        "| case | cells | ghost values per rank | overlap | step | send | elements | in flight "
        "| wait u | arrived | wait u, arrived | send f | wait f |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:

        def us(key: str, r: dict = r) -> str:
            return f"{r[key]:.0f}" if np.isfinite(r[key]) else "-"

        spans = " | ".join(
            [us(k + "_us") for k in ("step", "send", "elements", "in flight", "wait u")]
            + [f"{100 * r['arrived']:.0f} %", us("wait_u_arrived_us")]
            + [us(k + "_us") for k in ("send f", "wait f")]
        )
        lines.append(
            f"| {r['case']} | {r['cells']} | {', '.join(map(str, r['ghost_values']))} | "
            f"{'on' if r['overlap'] else 'off'} | {spans} |"
        )
    text = "\n".join(lines)
    (out / "overlap_trace.md").write_text(text + "\n")
    print(text, flush=True)
    plot(results, figure, per_run)


def plot(results: dict, path: Path, per_run: int, shown: int = 3) -> None:
    """Time lines of ``shown`` consecutive steps per rank, overlap off and on, per case
    (``per_run``: the steps of one run, the traces being two runs one after the other)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    colours = {
        "send": "tab:green",
        "elements": "tab:blue",
        "wait u": "tab:red",
        "send f": "tab:olive",
        "wait f": "tab:purple",
    }
    keys = list(results)
    fig, axes = plt.subplots(len(keys), 1, figsize=(9, 1.1 + 1.0 * len(keys) * 1.3), squeeze=False)
    for ax, key in zip(axes[:, 0], keys, strict=True):
        shape, overlap = key
        _, _, everyone = results[key]
        steps = everyone[0].shape[0]
        # the window of steps clear of the polls (every 64: the exchange finishes early
        # there) whose step times are nearest the median on every rank: typical steps, not a
        # slow spell of the shared cores
        times = np.array([spans[:, STEP, 1] - spans[:, STEP, 0] for spans in everyone])
        typical = np.abs(times - np.median(times, axis=1, keepdims=True)).max(axis=0)
        windows = [
            k
            for k in range(steps - shown)
            if all((((k + j) % per_run) + WARM_STEPS + 1) % 64 for j in range(shown))
        ]
        first = min(windows, key=lambda k: typical[k : k + shown].sum())
        origin = everyone[0][first, STEP, 0]
        for rank, spans in enumerate(everyone):
            for k in range(first, first + shown):
                start, end = spans[k, STEP]
                ax.broken_barh(
                    [(1e3 * (start - origin), 1e3 * (end - start))],
                    (rank - 0.4, 0.8),
                    color="0.85",
                )
                for slot, name in enumerate(SPANS):
                    s0, s1 = spans[k, slot]
                    if np.isfinite(s0):
                        ax.broken_barh(
                            [(1e3 * (s0 - origin), max(1e3 * (s1 - s0), 0.02))],
                            (rank - 0.4, 0.8),
                            color=colours[name],
                        )
        ax.set_yticks(range(len(everyone)), [f"rank {r}" for r in range(len(everyone))])
        ax.set_title(f"{shape}: overlap {'on' if overlap else 'off'}", fontsize=9)
    axes[-1, 0].set_xlabel("time (ms); grey: the rest of the step (update, loads, contact)")
    handles = [plt.Rectangle((0, 0), 1, 1, color=c) for c in colours.values()]
    fig.legend(handles, list(colours), loc="upper center", ncol=len(colours), fontsize=8)
    fig.tight_layout(rect=(0, 0, 1, 0.95))
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=120)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--ranks", type=int, default=2)
    parser.add_argument("--cells", type=int, default=200_000)
    parser.add_argument("--steps", type=int, default=200)
    parser.add_argument("--shapes", default="beam,plate")
    parser.add_argument("--out", type=Path, default=HERE / "results")
    parser.add_argument(
        "--figure", type=Path, default=ROOT / "docs" / "images" / "overlap_trace.png"
    )
    parser.add_argument("--worker", action="store_true", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.worker:
        worker(args.cells, args.steps, args.shapes.split(","), args.out, args.figure)
        return
    command = [str(Path(sys.executable).parent / "mpiexec"), "-n", str(args.ranks)]
    command += [sys.executable, __file__, "--worker", "--cells", str(args.cells)]
    command += ["--steps", str(args.steps), "--shapes", args.shapes, "--out", str(args.out)]
    command += ["--figure", str(args.figure)]
    subprocess.run(command, check=True)


if __name__ == "__main__":
    main()
