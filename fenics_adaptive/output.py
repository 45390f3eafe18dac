"""Results on disk: history table, summary, plots, fields for ParaView, progress on the terminal.

A run writes into its output folder
  history.csv              one row per output step (columns below; units N, mm, s, mJ)
  summary.json             run facts and headline numbers, written last ("status" says how the
                           run ended)
  force_displacement.png   reaction force vs probe displacement
  energies.png             energy balance vs time
  displacement.bp/         displacement field over time (ADIOS2/VTX, opens in ParaView >= 5.9)
While running, the history is written to history.partial.csv and only renamed to history.csv
when the run completes: a file named history.csv is always a finished run.
"""

from __future__ import annotations

import csv
import json
import os
import sys
import time
from pathlib import Path
from typing import TextIO

import matplotlib

matplotlib.use("Agg")
import dolfinx.io
import matplotlib.pyplot as plt
from mpi4py import MPI

from fenics_adaptive.explicit import COLUMNS, HistoryRow

COLUMN_UNITS = {
    "time": "s",
    "displacement": "mm",
    "reaction_force": "N",
    "applied_force": "N",
    "kinetic_energy": "mJ",
    "internal_energy": "mJ",
    "external_work": "mJ",
    "damping_energy": "mJ",
    "dissipated_energy": "mJ",
    "time_step": "s",
    "energy_balance": "mJ",
}

RESULT_FILES = ("history.csv", "summary.json", "force_displacement.png", "energies.png")


class HistoryWriter:
    """CSV history, full double precision, flushed every row (rank 0 only)."""

    def __init__(self, out_dir: Path, comm: MPI.Comm):
        self.partial = out_dir / "history.partial.csv"
        self.final = out_dir / "history.csv"
        self.file: TextIO | None = None
        if comm.rank == 0:
            self.file = open(self.partial, "w", newline="")
            self.writer = csv.writer(self.file)
            self.writer.writerow(COLUMNS)

    def __call__(self, row: HistoryRow) -> None:
        if self.file is None:
            return
        values = [getattr(row, name) for name in COLUMNS]
        self.writer.writerow([repr(float(x)) for x in values])
        self.file.flush()

    def close(self, completed: bool) -> None:
        if self.file is None:
            return
        self.file.close()
        self.file = None
        if completed:
            os.replace(self.partial, self.final)


def read_history(path: str | Path) -> dict[str, list[float]]:
    with open(path, newline="") as f:
        rows = list(csv.reader(f))
    header, body = rows[0], rows[1:]
    return {name: [float(r[i]) for r in body] for i, name in enumerate(header)}


def write_summary(out_dir: Path, summary: dict, comm: MPI.Comm) -> None:
    if comm.rank == 0:
        tmp = out_dir / "summary.json.partial"
        tmp.write_text(json.dumps(summary, indent=2, sort_keys=False) + "\n")
        os.replace(tmp, out_dir / "summary.json")


def clear_previous_results(out_dir: Path, comm: MPI.Comm) -> None:
    """Remove the results of an earlier run in the same folder so that none of them can be
    mistaken for this run's."""
    if comm.rank == 0:
        for name in (*RESULT_FILES, "history.partial.csv"):
            (out_dir / name).unlink(missing_ok=True)
    comm.barrier()


def plot_history(history: list[HistoryRow], out_dir: Path, title: str) -> None:
    t = [r.time * 1e3 for r in history]
    fig, ax = plt.subplots(figsize=(6, 4), layout="constrained")
    ax.plot([r.displacement for r in history], [r.reaction_force for r in history], "-")
    ax.set_xlabel("displacement (mm)")
    ax.set_ylabel("reaction force (N)")
    ax.set_title(title)
    ax.grid(alpha=0.3)
    fig.savefig(out_dir / "force_displacement.png", dpi=150)
    plt.close(fig)

    fig, ax = plt.subplots(figsize=(6, 4), layout="constrained")
    for name, label in (
        ("external_work", "external work"),
        ("internal_energy", "internal"),
        ("kinetic_energy", "kinetic"),
        ("damping_energy", "damping"),
        ("energy_balance", "balance (kin + int + damp - ext)"),
    ):
        ax.plot(t, [getattr(r, name) for r in history], label=label)
    ax.set_xlabel("time (ms)")
    ax.set_ylabel("energy (mJ)")
    ax.set_title(title)
    ax.legend()
    ax.grid(alpha=0.3)
    fig.savefig(out_dir / "energies.png", dpi=150)
    plt.close(fig)


class FieldWriter:
    """Displacement field over time for ParaView (VTX: ADIOS2 .bp folder)."""

    def __init__(self, out_dir: Path, functions: list):
        self.writer = dolfinx.io.VTXWriter(
            functions[0].function_space.mesh.comm,
            out_dir / "displacement.bp",
            functions,
            engine="BP4",
        )

    def __call__(self, t: float) -> None:
        self.writer.write(t)

    def close(self) -> None:
        self.writer.close()


class Progress:
    """Progress on stderr (rank 0): a live bar on a terminal, otherwise one line every
    ``every`` seconds. Silent for the first ``quiet_for`` seconds, so short runs print nothing."""

    def __init__(
        self, end_time: float, comm: MPI.Comm, every: float = 10.0, quiet_for: float = 2.0
    ):
        self.end_time = end_time
        self.enabled = comm.rank == 0
        self.tty = sys.stderr.isatty()
        self.every = 0.25 if self.tty else every
        self.quiet_for = quiet_for
        self.start = time.perf_counter()
        self.last = self.start + quiet_for - self.every
        self.shown = False

    def __call__(self, t: float) -> None:
        if not self.enabled:
            return
        now = time.perf_counter()
        if now - self.last < self.every:
            return
        self.last = now
        self.shown = True
        fraction = min(t / self.end_time, 1.0)
        elapsed = now - self.start
        eta = elapsed * (1.0 - fraction) / fraction if fraction > 0 else float("inf")
        text = (
            f"t = {t:.4e} s of {self.end_time:.4e} s  {elapsed:6.1f} s elapsed, ~{eta:.0f} s left"
        )
        if self.tty:
            width = 30
            bar = "#" * int(width * fraction) + "-" * (width - int(width * fraction))
            sys.stderr.write(f"\r[{bar}] {100 * fraction:5.1f} %  {text}")
        else:
            sys.stderr.write(f"progress {100 * fraction:5.1f} %  {text}\n")
        sys.stderr.flush()

    def done(self) -> None:
        if self.enabled and self.shown and self.tty:
            sys.stderr.write("\n")
            sys.stderr.flush()
