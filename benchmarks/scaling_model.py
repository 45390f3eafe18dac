"""The constants of the scaling model (``fenics_adaptive.parallel.scaling``), measured on this
machine, and what the model predicts for the impact plate at 10 million cells (issue 23).

Measured: the step per cell of the demo's impact plate (16 plies, ESL; nx = ny = ``--cells``),
the cost of a cell refined strongly at the plate's three delamination interfaces (every cell
refined, the same plate), the extra node layers that refinement adds, and the cost of one halo
exchange on a rank (two ranks, the plate's arrays; packing, unpacking and the call). Predicted:
strong scaling of a 3163 x 3163-cell plate (10 million cells) on 1 to 1024 ranks, ESL and adaptive
with 10 % of the cells refined in a disc at the centre (the demo's refined share), with equal
cells per rank and with a partition weighted by cost; weak scaling at 10 000 and 100 000 cells
per rank. The interconnect (latency, bandwidth) is a parameter (``--latency``, ``--bandwidth``).

Usage: .venv/bin/python benchmarks/scaling_model.py [--cells 100] [--out benchmarks/results]
Writes ``scaling_model.json``, ``scaling_model.md`` there and ``docs/images/scaling_model.png``.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
import tomllib
from pathlib import Path

import mpi4py  # noqa: F401  (before dolfinx)
import numpy as np
from mpi4py import MPI

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from fenics_adaptive.analysis.studies import plate_impact_variant  # noqa: E402
from fenics_adaptive.analysis.timing import time_per_step  # noqa: E402
from fenics_adaptive.parallel.scaling import (  # noqa: E402
    Interconnect,
    StepConstants,
    step_time,
)
from fenics_adaptive.settings.config import parse_config  # noqa: E402
from fenics_adaptive.settings.kinds import InterfaceState  # noqa: E402
from fenics_adaptive.settings.solver import Probe  # noqa: E402
from fenics_adaptive.simulation import build_structure  # noqa: E402

PLATE_SIDE = 3163  # cells: 10 million cells in plane
RANKS = [2**k for k in range(11)]  # 1 ... 1024
REFINED_SHARE = 0.10


def plate(n: int) -> dict:
    """The demo's impact plate (ESL), n x n cells, without its impactor."""
    data = plate_impact_variant(
        tomllib.loads((ROOT / "demos/plate_impact.toml").read_text()), "esl"
    )
    data["mesh"]["nx"] = data["mesh"]["ny"] = n
    data.pop("impactor", None)
    data.pop("indicators", None)
    return data


def measure_cells(n: int, steps: int, repeat: int) -> dict:
    """Per-cell step of the plate, ESL and every cell refined strongly at its delamination
    interfaces; the extra node layers per refined column."""
    probe = Probe("top", "x0", "z")
    config = parse_config(plate(n))
    structure = build_structure(config)
    esl, _ = time_per_step(structure, probe, steps, repeat, statistic=np.median)
    refined = build_structure(config)
    interfaces = sorted(config.interfaces.delaminate)
    cells = range(refined.base.n_owned_cells)
    refined.refine([(c, i, InterfaceState.STRONG) for c in cells for i in interfaces])
    strong, _ = time_per_step(refined, probe, steps, repeat, statistic=np.median)
    columns = refined.base.V.dofmap.index_map.size_global / 2
    return {
        "cells": n * n,
        "cell_step": esl / (n * n),
        "refined_cost": strong / esl,
        "refined_layers": refined.extra.index_map.size_global / columns,
        "interfaces": interfaces,
    }


def exchange_worker(n: int, repeat: int) -> None:
    """On this MPI job: the median wall time of one halo exchange (forward and reverse
    alternately) of the plate's two blocks, refined everywhere (both blocks full)."""
    comm = MPI.COMM_WORLD
    config = parse_config(plate(n))
    structure = build_structure(config, comm)
    cells = range(structure.base.n_owned_cells)
    interfaces = sorted(config.interfaces.delaminate)
    structure.refine([(c, i, InterfaceState.STRONG) for c in cells for i in interfaces])
    arrays = [block.u.array for block in structure.blocks]
    halo = structure.halo
    times = []
    for k in range(repeat):
        comm.Barrier()
        start = time.perf_counter()
        (halo.forward if k % 2 == 0 else halo.reverse)(arrays)
        times.append(time.perf_counter() - start)
    slowest = comm.allreduce(float(np.median(times[repeat // 10 :])), op=MPI.MAX)
    values = comm.allreduce(halo.ghost_values + halo.shared_values, op=MPI.MAX)
    if comm.rank == 0:
        print(json.dumps({"exchange_overhead": slowest, "values": values}))


def measure_exchange(n: int, repeat: int) -> dict:
    command = [str(Path(sys.executable).parent / "mpiexec"), "-n", "2", sys.executable, __file__]
    command += ["--worker", "--cells", str(n), "--repeat", str(repeat)]
    done = subprocess.run(command, capture_output=True, text=True, check=True)
    return json.loads(done.stdout.strip().splitlines()[-1])


def predictions(constants: StepConstants, network: Interconnect) -> dict:
    """Strong scaling at 10 million cells and weak scaling at 1e4 and 1e5 cells per rank, ESL
    and adaptive (10 % refined; equal cells per rank and balanced)."""
    cases = {
        "esl": (0.0, False),
        "adaptive": (REFINED_SHARE, False),
        "adaptive, balanced": (REFINED_SHARE, True),
    }
    out = {"strong": {}, "weak": {}}
    for name, (share, balanced) in cases.items():
        times = [
            step_time(constants, network, PLATE_SIDE, PLATE_SIDE, p, share, balanced) for p in RANKS
        ]
        out["strong"][name] = {
            "ranks": RANKS,
            "step_s": [t["total"] for t in times],
            "speed_up": [times[0]["total"] / t["total"] for t in times],
            "parts_at_1024": times[-1],
        }
        for per_rank in (10_000, 100_000):
            side = [round(np.sqrt(per_rank * p)) for p in RANKS]
            weak = [
                step_time(constants, network, s, s, p, share, balanced)
                for s, p in zip(side, RANKS, strict=True)
            ]
            out["weak"][f"{name}, {per_rank} cells/rank"] = {
                "ranks": RANKS,
                "efficiency": [weak[0]["total"] / t["total"] for t in weak],
            }
    return out


def plot(result: dict, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    figure, (strong, weak) = plt.subplots(1, 2, figsize=(11, 4.2))
    colours = dict(zip(result["strong"], ("C0", "C1", "C2"), strict=False))  # one per case
    for name, row in result["strong"].items():
        strong.loglog(row["ranks"], row["speed_up"], "o-", label=name, ms=4, color=colours[name])
    strong.loglog(RANKS, RANKS, "k:", label="ideal")
    strong.set(xlabel="ranks", ylabel="speed-up", title="strong: 10 million cells (model)")
    for name, row in result["weak"].items():
        case, size = name.rsplit(", ", 1)
        style = "o-" if size.startswith("10000 ") else "s--"  # 1e4 and 1e5 cells per rank
        weak.semilogx(row["ranks"], row["efficiency"], style, label=name, ms=4,
                      color=colours[case])  # fmt: skip
    weak.set(xlabel="ranks", ylabel="efficiency", title="weak scaling (model)", ylim=(0, 1.05))
    for axes in (strong, weak):
        axes.grid(True, which="both", alpha=0.3)
        axes.legend(fontsize=7)
    figure.tight_layout()
    figure.savefig(path, dpi=110)


def table(result: dict) -> str:
    c = result["constants"]
    lines = [
        "Constants measured on this machine (2 shared vCPUs): "
        f"{1e6 * c['cell_step']:.3f} us per ESL cell-step (impact plate, {c['cells']} cells), a "
        f"refined cell {c['refined_cost']:.2f} ESL cells, {c['refined_layers']:.1f} extra node "
        f"layers per refined column, {1e6 * c['exchange_overhead']:.1f} us per halo exchange "
        f"(two ranks, {c['exchange_values']} values). Interconnect (parameters): latency "
        f"{1e6 * result['network']['latency']:.1f} us, bandwidth "
        f"{result['network']['bandwidth'] / 1e9:.0f} GB/s.",
        "",
        "| ranks | " + " | ".join(f"{n}: step (ms), speed-up" for n in result["strong"]) + " |",
        "|---|" + "---|" * len(result["strong"]),
    ]
    for k, p in enumerate(RANKS):
        cells = [
            f"{1e3 * row['step_s'][k]:.3g}, {row['speed_up'][k]:.0f}"
            for row in result["strong"].values()
        ]
        lines.append(f"| {p} | " + " | ".join(cells) + " |")
    lines += ["", "| weak scaling | efficiency at 2, 16, 128, 1024 ranks |", "|---|---|"]
    for name, row in result["weak"].items():
        picks = [row["efficiency"][RANKS.index(p)] for p in (2, 16, 128, 1024)]
        lines.append(f"| {name} | " + ", ".join(f"{e:.3f}" for e in picks) + " |")
    return "\n".join(lines) + "\n"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--cells", type=int, default=100, help="plate side in cells (n x n)")
    parser.add_argument("--steps", type=int, default=100)
    parser.add_argument("--repeat", type=int, default=5)
    parser.add_argument("--latency", type=float, default=Interconnect.latency, help="s")
    parser.add_argument("--bandwidth", type=float, default=Interconnect.bandwidth, help="B/s")
    parser.add_argument("--out", type=Path, default=ROOT / "benchmarks" / "results")
    parser.add_argument(
        "--constants",
        type=Path,
        help="take the measured constants from this scaling_model.json instead of measuring "
        "(the predictions again, e.g. after a change of the model)",
    )
    parser.add_argument("--worker", action="store_true", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.worker:
        return exchange_worker(args.cells, max(args.repeat, 200))
    if args.constants:
        stored = json.loads(args.constants.read_text())["constants"]
        exchange = {"exchange_overhead": stored.pop("exchange_overhead")}
        exchange["values"] = stored.pop("exchange_values")
        cells = stored
    else:
        cells = measure_cells(args.cells, args.steps, args.repeat)
        exchange = measure_exchange(args.cells, 400)
    constants = StepConstants(
        cell_step=cells["cell_step"],
        refined_cost=cells["refined_cost"],
        exchange_overhead=exchange["exchange_overhead"],
        refined_layers=cells["refined_layers"],
    )
    network = Interconnect(args.latency, args.bandwidth)
    result = {
        "constants": {
            **cells,
            "exchange_overhead": exchange["exchange_overhead"],
            "exchange_values": exchange["values"],
        },
        "network": {"latency": network.latency, "bandwidth": network.bandwidth},
        **predictions(constants, network),
    }
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "scaling_model.json").write_text(json.dumps(result, indent=1))
    text = table(result)
    (args.out / "scaling_model.md").write_text(text)
    plot(result, ROOT / "docs" / "images" / "scaling_model.png")
    print(text)


if __name__ == "__main__":
    main()
