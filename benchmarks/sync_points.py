"""Synchronisation points per explicit step, counted in MPI itself (issue 23).

Runs a few configs on this MPI job with every MPI call counted (``mpi_counter``: a PMPI
interposer preloaded by mpiexec) and reports, per case, the synchronisation points of each
kind of step: a plain step (no history row, no refinement, no indicator evaluation, no poll),
and apart the steps that record a history row, evaluate the indicators, refine or poll (every
64 steps). A synchronisation point is a call after which a rank may have waited for another
(a blocking collective, a completion of nonblocking communication, a blocking send/receive).

Usage (it launches itself under mpiexec with the counter preloaded):

    .venv/bin/python benchmarks/sync_points.py [--ranks 2] [--steps 300] [--out DIR]

writes ``sync_points.json`` and ``sync_points.md`` into DIR (default ``benchmarks/results``).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
from collections import Counter as Tally
from pathlib import Path

HERE = Path(__file__).parent
ROOT = HERE.parent
DATA = ROOT / "tests" / "data"
sys.path.insert(0, str(HERE / "mpi_counter"))

# (name, config, steps to run before counting: past the manual refinements where there are)
CASES = (
    ("esl", DATA / "small_beam.toml", 20),
    ("adaptive, refined, border", DATA / "mpi_one_rank_refinement.toml", None),
    ("adaptive, insert film, front across ranks", DATA / "mpi_front_across_ranks.toml", 20),
    ("layerwise, cohesive", DATA / "tcb_layerwise.toml", 20),
    ("adaptive, indicators, contact, ply damage", DATA / "mpi_one_rank_impact.toml", 20),
    ("esl, selective mass scaling", "thin_pulled_beam", 20),
    ("layerwise MMB, lever, rollers, mass scaling", DATA / "mmb_thin_scaled.toml", 20),
)
# the cases that wait more than twice per plain step, and why (tests/test_halo.py): none since
# the scaled mass's shares of the accelerations travel in the forces' exchange
MORE_WAITS: dict[str, int] = {}

KINDS = ("plain", "history", "indicators", "refinement", "poll")


def count_case(config_path: Path | str, warm_steps: int | None, steps: int) -> dict:
    """Collective: the synchronisation points of ``steps`` steps of a config, by kind of step."""
    from counter import Counter
    from mpi4py import MPI

    from fenics_adaptive.settings.config import load_config, parse_config
    from fenics_adaptive.simulation import Simulation

    counter = Counter()
    if isinstance(config_path, Path):
        config = load_config(config_path)
    else:  # a config of the tests' helpers (selective mass scaling)
        sys.path.insert(0, str(ROOT / "tests"))
        import helpers

        config = parse_config(getattr(helpers, config_path)())
    simulation = Simulation(config, comm=MPI.COMM_WORLD)
    simulation.start()
    solver, hook = simulation.solver, simulation.refinement
    if warm_steps is None:  # past the last manual refinement
        last = max(r.time for r in config.refinements)
        while solver.t <= last and simulation.step():
            pass
        warm_steps = 20
    for _ in range(warm_steps):
        simulation.step()
    points = {kind: [] for kind in KINDS}
    calls = {kind: Tally() for kind in KINDS}
    for _ in range(steps):
        rows, evaluations, events = (
            len(solver.stats.history),
            hook.evaluations,
            solver.now.refinements,
        )
        counter.reset()
        if not simulation.step():
            break
        if solver.now.refinements != events:
            kind = "refinement"
        elif hook.evaluations != evaluations:
            kind = "indicators"
        elif len(solver.stats.history) != rows:
            kind = "history"
        elif solver.now.step % 64 == 0:
            kind = "poll"
        else:
            kind = "plain"
        points[kind].append(counter.sync_points())
        calls[kind].update(counter.counts())
    simulation.settle()  # the free body's last reduction, before the next case
    out = {}
    for kind in KINDS:
        n = len(points[kind])
        if n:
            out[kind] = {
                "steps": n,
                "mean": sum(points[kind]) / n,
                "max": max(points[kind]),
                "calls_per_step": {k: v / n for k, v in sorted(calls[kind].items())},
            }
    return out


def worker(steps: int, out: Path) -> None:
    import mpi4py.MPI as MPI

    results = {}
    for name, config, warm in CASES:
        results[name] = count_case(config, warm, steps)
    comm = MPI.COMM_WORLD
    everyone = comm.gather(results)
    if comm.rank == 0:
        merged = {"ranks": comm.size, "cases": {}}
        for name in results:
            merged["cases"][name] = {
                kind: {
                    "steps": everyone[0][name][kind]["steps"],
                    "mean": max(r[name][kind]["mean"] for r in everyone),
                    "max": max(r[name][kind]["max"] for r in everyone),
                    "calls_per_step": everyone[0][name][kind]["calls_per_step"],
                }
                for kind in results[name]
            }
        out.mkdir(parents=True, exist_ok=True)
        (out / "sync_points.json").write_text(json.dumps(merged, indent=1))
        text = table(merged)
        (out / "sync_points.md").write_text(text + "\n")
        print(text, flush=True)


def table(merged: dict) -> str:
    lines = [
        f"synchronisation points per step, {merged['ranks']} ranks (the larger over ranks)",
        "| case | kind of step | steps | mean | max | calls per step (rank 0) |",
        "|---|---|---|---|---|---|",
    ]
    for name, kinds in merged["cases"].items():
        for kind, row in kinds.items():
            calls = ", ".join(f"{k} {v:.2g}" for k, v in row["calls_per_step"].items())
            lines.append(
                f"| {name} | {kind} | {row['steps']} | {row['mean']:.2f} | {row['max']} | {calls} |"
            )
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--ranks", type=int, default=2)
    parser.add_argument("--steps", type=int, default=300)
    parser.add_argument("--out", type=Path, default=HERE / "results")
    parser.add_argument("--worker", action="store_true", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.worker:
        worker(args.steps, args.out)
        return
    from counter import build, environment

    library = build()
    env = environment(library)
    env["PYTHONPATH"] = os.pathsep.join(filter(None, [str(ROOT), env.get("PYTHONPATH", "")]))
    command = [
        str(Path(sys.executable).parent / "mpiexec"),
        "-n",
        str(args.ranks),
        sys.executable,
        __file__,
        "--worker",
        "--steps",
        str(args.steps),
        "--out",
        str(args.out),
    ]
    subprocess.run(command, env=env, check=True)


if __name__ == "__main__":
    main()
