"""Why each cell refined: the refinement log of a run, ``refinement_log.csv``.

Units: s (time), mm (cell centre).

One row per (cell, interface) and state it reached (weak, then strong), in the order of the
refinements: ``time_s, cell, x_mm, y_mm, interface, state, indicator, value``. ``cell`` is the
cell's index in the generated mesh (the same whatever the number of MPI ranks), ``x_mm``,
``y_mm`` the centre of its bottom face, interfaces count from 1 at the bottom, ``indicator``
and ``value`` say who asked and what it measured (``adaptivity.events.Reason``; ``initial`` for
the refinement of ``[interfaces] initial`` and ``refine``, present at t = 0). The same times are
in the element output as the cell fields ``weak_time_<i>`` / ``strong_time_<i>``.

A restart keeps the rows up to its checkpoint's time from the log of the run it continues (when
that log is there; otherwise the replayed refinements are listed with indicator ``restart``).
"""

from __future__ import annotations

import csv
import math
from collections.abc import Callable
from pathlib import Path
from typing import TextIO

import numpy as np

from fenics_adaptive.adaptivity.events import Reason, RefinementEvent
from fenics_adaptive.settings.kinds import InterfaceState
from fenics_adaptive.solver.observers import Observer

FILE_NAME = "refinement_log.csv"
COLUMNS = ("time_s", "cell", "x_mm", "y_mm", "interface", "state", "indicator", "value")
_STATE_NAMES = {InterfaceState.WEAK: "weak", InterfaceState.STRONG: "strong"}


def log_rows(structure, pairs: np.ndarray, state: int, times, reasons) -> list[tuple]:
    """Rows of the log for this rank's (local cell, interface) ``pairs`` that reached ``state``
    (WEAK or STRONG) at ``times`` (s, one per pair or one for all), for ``reasons`` (one
    ``Reason`` per pair)."""
    pairs = np.asarray(pairs, dtype=np.int64).reshape(-1, 2)
    if not len(pairs):
        return []
    cells = pairs[:, 0]
    original = structure.base.mesh.topology.original_cell_index[cells]
    centre = structure.X_base[structure.bottom_local[cells]].mean(axis=1)
    times = np.broadcast_to(np.asarray(times, dtype=float), (len(pairs),))
    return [
        (float(t), int(c), float(x), float(y), int(i), _STATE_NAMES[state], r.indicator, r.value)
        for t, c, (x, y, _), (_, i), r in zip(times, original, centre, pairs, reasons, strict=True)
    ]


def state_rows(structure, indicator: str, until: float = math.inf) -> list[tuple]:
    """Rows for every interface already refined on this rank at or before ``until`` (s), all
    attributed to ``indicator``, times from the structure's ``weak_since`` / ``strong_since``."""
    rows = []
    for state, since in (
        (InterfaceState.WEAK, structure.weak_since),
        (InterfaceState.STRONG, structure.strong_since),
    ):
        pairs = np.argwhere(np.isfinite(since) & (since <= until))
        times = since[pairs[:, 0], pairs[:, 1]]
        pairs[:, 1] += 1  # interfaces count from 1
        rows += log_rows(structure, pairs, state, times, [Reason(indicator)] * len(pairs))
    return rows


def read_log(path: Path, until: float, inclusive: bool = True) -> list[tuple] | None:
    """The rows of the log at ``path`` with time <= ``until`` (s; < without ``inclusive``),
    or None when it does not exist."""
    if not path.is_file():
        return None
    with open(path, newline="") as file:
        reader = csv.reader(file)
        header = next(reader, None)
        if header is None or tuple(header) != COLUMNS:
            return None
        rows = []
        for t, c, x, y, i, state, indicator, value in reader:
            if float(t) < until or (inclusive and float(t) == until):
                rows.append((float(t), int(c), float(x), float(y), int(i), state, indicator,
                             float(value)))  # fmt: skip
    return rows


class RefinementLog(Observer):
    """Writes ``refinement_log.csv`` in ``out_dir``: rank 0 writes, every rank sends its rows
    (an observer of the solver: ``on_start``, ``on_refinement``; flushed at every refinement).

    structure: the run's structure.
    kept: rows of the run a restart continues (``read_log``), or None: then the refinements
        the structure holds when the run starts are logged as ``initial`` (a fresh run: the
        ``[interfaces]`` refinement) or, for a restart, as ``restart`` (the replayed ones, whose
        reasons were in a log that is gone).
    restart: whether the run continues from a checkpoint.
    record: the run folder's ``record`` (rank 0), told of the file before it is written.
    """

    def __init__(
        self,
        out_dir: Path,
        structure,
        kept: list[tuple] | None = None,
        restart: bool = False,
        record: Callable[..., None] | None = None,
    ):
        self.structure, self.comm = structure, structure.comm
        self.file: TextIO | None = None
        self.unexplained = None if kept is not None else ("restart" if restart else "initial")
        if self.comm.rank == 0:
            path = Path(out_dir) / FILE_NAME
            if record is not None:
                record(path)
            self.file = open(path, "w", newline="")
            self.writer = csv.writer(self.file)
            self.writer.writerow(COLUMNS)
            self._write(kept or [])

    def on_start(self, solver) -> None:
        if self.unexplained is not None:
            rows = self._gathered(state_rows(self.structure, self.unexplained))
            self.unexplained = None
            if self.file is not None:
                self._write(rows)

    def _gathered(self, rows: list[tuple]) -> list[tuple]:
        """Collective: every rank's rows on rank 0, in time then cell order."""
        everyone = self.comm.gather(rows, root=0)
        if self.comm.rank != 0:
            return []
        return sorted((r for part in everyone for r in part), key=lambda r: (r[0], r[1], r[4]))

    def _write(self, rows: list[tuple]) -> None:
        for row in rows:
            self.writer.writerow([repr(v) if isinstance(v, float) else v for v in row])
        self.file.flush()

    def on_refinement(self, event: RefinementEvent, dt: float, where: str) -> None:
        rows = log_rows(
            self.structure, event.new_weak, InterfaceState.WEAK, event.time, event.weak_reasons
        ) + log_rows(
            self.structure,
            event.new_strong,
            InterfaceState.STRONG,
            event.time,
            event.strong_reasons,
        )
        rows = self._gathered(rows)
        if self.file is not None:
            self._write(rows)

    def close(self) -> None:
        if self.file is not None:
            self.file.close()
            self.file = None
