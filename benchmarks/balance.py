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
from fenics_adaptive.runner import BalanceReport, execute  # noqa: E402
from fenics_adaptive.settings.config import parse_config  # noqa: E402
from fenics_adaptive.simulation import starting_cost  # noqa: E402

RANKS = (2, 4, 8)
GAIN = BalanceReport.GAIN


def demo_table(name: str) -> tuple[str, dict]:
    """(what it is, the config table) of the adaptive run of case ``name``."""
    demos = ROOT / "demos"
    if name in ("dcb", "enf", "mmb50"):
        specimen = SPECIMENS[name]
        base = specimen.variant(tomllib.loads((demos / specimen.file).read_text()))
        return f"{name.upper()} (fracture_tests)", variant("fracture_tests", base, "adaptive")
    base = tomllib.loads((demos / f"{name}.toml").read_text())
    return name.replace("_", " "), variant(name, base, "adaptive")


KINDS = ("cells", "cost", "rebalanced")


def imbalance_history(config, rows: list[tuple], ranks: int, kind: str) -> np.ndarray:
    """(n_times, 3): time (s), imbalance after each refinement of ``rows`` (the log) and the
    re-balances so far: the columns cut into the grid of ``ranks`` patches of equal cells
    ("cells") or of equal cost at the start ("cost"), or ("rebalanced") cut again by the cost
    of the moment whenever a refinement makes the imbalance exceed the run's threshold
    (``[mesh] rebalance``, and 1.1 x the imbalance the last re-balance left:
    ``runner.BalanceReport``; here at once, where a run waits for a refinement's ties and
    damping windows to end)."""
    mesh = config.mesh
    dx, dy = mesh.length / mesh.nx, mesh.width / mesh.ny
    ix, iy = np.meshgrid(np.arange(mesh.nx), np.arange(mesh.ny), indexing="ij")
    columns = np.stack([ix.ravel(), iy.ravel()], axis=1)
    weights = None
    cost = starting_cost(config) if kind != "cells" else None
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
    cut_at, cuts = None, 0  # the imbalance the last re-balance left, the re-balances so far
    for t in times:
        for _, _, x, y, interface, *_ in by_time.get(t, []):
            column = index[(min(int(x / dx), mesh.nx - 1), min(int(y / dy), mesh.ny - 1))]
            refined.setdefault(column, set()).add(interface)
        count = np.zeros(len(columns))
        for column, interfaces in refined.items():
            count[column] = len(interfaces)
        costs = cell_costs(count)
        now = _imbalance(part, costs, ranks)
        bar = config.mesh.rebalance if cut_at is None else max(config.mesh.rebalance, GAIN * cut_at)
        if kind == "rebalanced" and now > bar:
            part = grid_parts(columns, ranks, costs)
            now = cut_at = _imbalance(part, costs, ranks)
            cuts += 1
        out.append((t, now, cuts))
    return np.array(out)


def _imbalance(part: np.ndarray, costs: np.ndarray, ranks: int) -> float:
    per_rank = np.bincount(part, weights=costs, minlength=ranks)
    return float(per_rank.max() / per_rank.mean())


def run(name: str, folder: Path, reuse: bool = False) -> dict:
    what, table = demo_table(name)
    config = parse_config(table, source=f"demos [{name}, adaptive]")
    out = folder / name
    if not (reuse and (out / FILE_NAME).exists()):
        execute(config, out, MPI.COMM_WORLD, show_progress=False, log=None, overwrite=True)
    rows = read_log(out / FILE_NAME, math.inf) or []
    result = {
        "case": what,
        "cells": config.mesh.nx * config.mesh.ny,
        "refined_cells_at_end": len({(r[2], r[3]) for r in rows}),
        "insert_film": bool(config.delaminations),
    }
    for ranks in RANKS:
        for kind in KINDS:
            history = imbalance_history(config, rows, ranks, kind)
            result[f"{ranks}_{kind}"] = {
                "start": float(history[0, 1]),
                "largest": float(history[:, 1].max()),
                "end": float(history[-1, 1]),
                "rebalances": int(history[-1, 2]),
            }
    return result


def table(results: list[dict]) -> str:
    lines = [
        "imbalance (the costliest rank's cost over the mean) at the start, largest, at the end "
        "of each demo's adaptive run; partition of equal cells | of equal cost at the start | "
        "re-balanced by the refinement's cost past the threshold (the re-balances in brackets)",
        "| case | cells | refined at end | "
        + " | ".join(f"{r} ranks, {kind}" for r in RANKS for kind in KINDS)
        + " |",
        "|---|---|---|" + "---|" * (len(KINDS) * len(RANKS)),
    ]
    for r in results:
        cells = []
        for ranks in RANKS:
            for kind in KINDS:
                v = r[f"{ranks}_{kind}"]
                cell = f"{v['start']:.2f} / {v['largest']:.2f} / {v['end']:.2f}"
                cells.append(cell + (f" ({v['rebalances']})" if kind == "rebalanced" else ""))
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
    parser.add_argument(
        "--runs",
        type=Path,
        default=None,
        help="keep the demos' runs in this folder and reuse those already there (default: a "
        "temporary folder)",
    )
    args = parser.parse_args()
    results = []
    with tempfile.TemporaryDirectory() as scratch:
        folder = args.runs or Path(scratch)
        for name in args.cases.split(","):
            results.append(run(name, folder, reuse=args.runs is not None))
            print(table(results[-1:]).splitlines()[-1], flush=True)
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "balance.json").write_text(json.dumps(results, indent=1))
    text = table(results)
    (args.out / "balance.md").write_text(text + "\n")
    print(text)


if __name__ == "__main__":
    main()
