"""How unequally MPI ranks would share the demos' adaptive runs as they refine (issue 23,
item 3).

Runs each demo's adaptive model once (serially: the refinements do not depend on the rank
count, ``tests/test_mpi.py``), reads where and when it refined (``refinement_log.csv``) and
cuts its columns as the partitioner would for 2, 4 and 8 ranks: into the grid of patches of
equal cells (``[mesh] partition = "cells"``; a one-layer mesh then gets DOLFINx's graph
partitioner, whose near-square patches this grid stands for) and of equal cost at the start
(``"cost"``, the default: an insert film's cells refined from the start weigh 3.3). At the
start and after every refinement, the imbalance of each: the costliest patch over the mean,
a cell costing 1 + 2.3 per interface it is refined at (``fenics_adaptive.parallel.balance``).
The partition is cut once, at the start; the table says how far the refinement moves it
from balance.

Usage:

    .venv/bin/python benchmarks/balance.py [--out benchmarks/results] [--cases dcb,enf,...]

writes ``balance.json`` and ``balance.md`` into ``--out``; the runs go to a temporary
folder. About 10 minutes.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import tempfile
import tomllib
from pathlib import Path

import mpi4py.MPI as MPI
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from fenics_adaptive.demos.fracture_tests import SPECIMENS  # noqa: E402
from fenics_adaptive.meshes.beam import grid_parts  # noqa: E402

from fenics_adaptive.analysis.studies import variant  # noqa: E402
from fenics_adaptive.io.refinement_log import FILE_NAME, read_log  # noqa: E402
from fenics_adaptive.parallel.balance import cell_costs  # noqa: E402
from fenics_adaptive.runner import execute  # noqa: E402
from fenics_adaptive.settings.config import parse_config  # noqa: E402
from fenics_adaptive.simulation import starting_cost  # noqa: E402

RANKS = (2, 4, 8)


def demo_table(name: str) -> tuple[str, dict]:
    """(what it is, the config table) of the adaptive run of case ``name``."""
    demos = ROOT / "demos"
    if name in ("dcb", "enf", "mmb50"):
        specimen = SPECIMENS[name]
        base = specimen.variant(tomllib.loads((demos / specimen.file).read_text()))
        return f"{name.upper()} (fracture_tests)", variant("fracture_tests", base, "adaptive")
    base = tomllib.loads((demos / f"{name}.toml").read_text())
    return name.replace("_", " "), variant(name, base, "adaptive")


def imbalance_history(config, rows: list[tuple], ranks: int, weighted: bool) -> np.ndarray:
    """(n_times, 2): time (s) and imbalance after each refinement of ``rows`` (the log), the
    columns cut into the grid of ``ranks`` patches of equal cells or (``weighted``) equal
    cost at the start."""
    mesh = config.mesh
    dx, dy = mesh.length / mesh.nx, mesh.width / mesh.ny
    ix, iy = np.meshgrid(np.arange(mesh.nx), np.arange(mesh.ny), indexing="ij")
    columns = np.stack([ix.ravel(), iy.ravel()], axis=1)
    weights = None
    cost = starting_cost(config) if weighted else None
    if cost is not None:
        weights = cost((columns[:, 0] + 0.5) * dx, (columns[:, 1] + 0.5) * dy)
    part = grid_parts(columns, ranks, weights)
    index = {(int(i), int(j)): k for k, (i, j) in enumerate(columns)}
    refined: dict[int, set[int]] = {}
    out = []
    times = sorted({r[0] for r in rows}) or [0.0]
    by_time: dict[float, list[tuple]] = {}
    for row in rows:
        by_time.setdefault(row[0], []).append(row)
    for t in times:
        for _, _, x, y, interface, *_ in by_time.get(t, []):
            column = index[(min(int(x / dx), mesh.nx - 1), min(int(y / dy), mesh.ny - 1))]
            refined.setdefault(column, set()).add(interface)
        count = np.zeros(len(columns))
        for column, interfaces in refined.items():
            count[column] = len(interfaces)
        per_rank = np.bincount(part, weights=cell_costs(count), minlength=ranks)
        out.append((t, per_rank.max() / per_rank.mean()))
    return np.array(out)


def run(name: str, folder: Path) -> dict:
    what, table = demo_table(name)
    config = parse_config(table, source=f"demos [{name}, adaptive]")
    out = folder / name
    execute(config, out, MPI.COMM_WORLD, show_progress=False, log=None)
    rows = read_log(out / FILE_NAME, math.inf) or []
    result = {
        "case": what,
        "cells": config.mesh.nx * config.mesh.ny,
        "refined_cells_at_end": len({(r[2], r[3]) for r in rows}),
        "insert_film": bool(config.delaminations),
    }
    for ranks in RANKS:
        for weighted in (False, True):
            history = imbalance_history(config, rows, ranks, weighted)
            key = f"{ranks}_{'cost' if weighted else 'cells'}"
            result[key] = {
                "start": float(history[0, 1]),
                "largest": float(history[:, 1].max()),
                "end": float(history[-1, 1]),
            }
    return result


def table(results: list[dict]) -> str:
    lines = [
        "imbalance (the costliest rank's cost over the mean) at the start, largest, at the end "
        "of each demo's adaptive run; partition of equal cells | of equal cost at the start",
        "| case | cells | refined at end | "
        + " | ".join(f"{r} ranks, cells | {r} ranks, cost" for r in RANKS)
        + " |",
        "|---|---|---|" + "---|" * (2 * len(RANKS)),
    ]
    for r in results:
        cells = []
        for ranks in RANKS:
            for kind in ("cells", "cost"):
                v = r[f"{ranks}_{kind}"]
                cells.append(f"{v['start']:.2f} / {v['largest']:.2f} / {v['end']:.2f}")
        lines.append(
            f"| {r['case']} | {r['cells']} | {r['refined_cells_at_end']} | "
            + " | ".join(cells)
            + " |"
        )
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--out", type=Path, default=ROOT / "benchmarks" / "results")
    parser.add_argument("--cases", default="plate_impact,four_point_bending,tcb,dcb,enf,mmb50")
    args = parser.parse_args()
    results = []
    with tempfile.TemporaryDirectory() as folder:
        for name in args.cases.split(","):
            results.append(run(name, Path(folder)))
            print(table(results[-1:]).splitlines()[-1], flush=True)
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "balance.json").write_text(json.dumps(results, indent=1))
    text = table(results)
    (args.out / "balance.md").write_text(text + "\n")
    print(text)


if __name__ == "__main__":
    main()
