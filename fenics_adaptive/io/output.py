"""Results on disk: history table, summary, plots, fields for ParaView, progress on the terminal.

A run writes into its output folder
  history.csv              one row per output step (columns below; units N, mm, s, mJ)
  summary.json             run facts and headline numbers, written last ("status" says how the
                           run ended)
  force_displacement.png   reaction force vs probe displacement
  energies.png             energy balance vs time
  displacement.bp/         displacement field over time (ADIOS2/VTX, opens in ParaView >= 5.9)
  elements.pvd, elements/  the enriched mesh as computed: subelements, extra and cohesive elements
  plies.pvd, plies/        every ply of every cell as a slab: stress, Hashin indices, damage
  checkpoint/              the state to restart from (``checkpoint``)
The field files come every ``fields_interval``. Every name is added to the folder's run
manifest before it is written (``run_folder``): a fresh run into the folder removes what the
manifest lists and nothing else. While running, the history is written to
history.partial.csv and only renamed to history.csv when the run completes: a file named
history.csv is always a finished run.
"""

from __future__ import annotations

import base64
import csv
import io
import json
import math
import os
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import TextIO

import dolfinx.io
import numpy as np
from mpi4py import MPI

from fenics_adaptive.adaptivity.indicators import ply_failure_indices, ply_strains
from fenics_adaptive.element.geometry import slab_vertices, thickness_weight
from fenics_adaptive.errors import InputError, shared_errors
from fenics_adaptive.materials.ply_damage import S_D, S_FC, S_FT, S_MC, S_MT, nominal_ply_stresses
from fenics_adaptive.solver.explicit import COLUMNS, HistoryRow
from fenics_adaptive.solver.observers import Observer

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
    "refinement_energy": "mJ",
    "delaminated_area": "mm^2",
    "time_step": "s",
    "contact_force": "N",
    "impactor_displacement": "mm",
    "impact_work": "mJ",
    "cohesive_dissipation": "mJ",
    "ply_dissipation": "mJ",
    "state_energy_balance": "mJ",
    "energy_balance": "mJ",
}


# the header of history.csv: each column's name with its unit, as ``kinetic_energy_mJ``
UNIT_SUFFIX = {"s": "s", "mm": "mm", "N": "N", "mJ": "mJ", "mm^2": "mm2"}
HEADER = [f"{name}_{UNIT_SUFFIX[COLUMN_UNITS[name]]}" for name in COLUMNS]
# header cell -> column name; a header without units (files before 0.2) reads as well
_NAME_OF = {**{name: name for name in COLUMNS}, **dict(zip(HEADER, COLUMNS, strict=True))}


def column_name(header_cell: str) -> str:
    """The column name (a ``HistoryRow`` field or ``energy_balance``) of a history.csv header
    cell, with or without its unit suffix; an unknown cell is returned as it is."""
    return _NAME_OF.get(header_cell, header_cell)


def _cells(row: HistoryRow) -> list[str]:
    """A history row as CSV cells: full double precision, so a restart reads it back exactly."""
    return [repr(float(getattr(row, name))) for name in COLUMNS]


def history_text(rows: list[HistoryRow]) -> str:
    """History rows as the CSV text of history.csv (header and rows)."""
    buffer = io.StringIO(newline="")
    writer = csv.writer(buffer)
    writer.writerow(HEADER)
    writer.writerows(_cells(row) for row in rows)
    return buffer.getvalue()


def parse_history(text: str, source: str) -> list[HistoryRow]:
    """History rows from CSV text (as ``history_text`` writes it). Raises InputError naming
    ``source`` if it is not such a table."""
    try:
        table = list(csv.reader(io.StringIO(text, newline="")))
        header, body = [column_name(cell) for cell in table[0]], table[1:]
        index = {name: header.index(name) for name in HistoryRow.__dataclass_fields__}
        return [HistoryRow(**{n: float(r[i]) for n, i in index.items()}) for r in body]
    except (IndexError, ValueError) as error:
        raise InputError("restart", f"{source} is not a history table ({error})") from None


class HistoryWriter(Observer):
    """CSV history, full double precision, flushed every row (rank 0 only). Keeps the rows
    (rank 0) for the checkpoints (``text``). An observer of the solver (``on_history``)."""

    def __init__(self, out_dir: Path, comm: MPI.Comm, rows: list[HistoryRow] = ()):
        self.partial = out_dir / "history.partial.csv"
        self.final = out_dir / "history.csv"
        self.file: TextIO | None = None
        self.rows: list[HistoryRow] = []
        if comm.rank == 0:
            self.file = open(self.partial, "w", newline="")
            self.writer = csv.writer(self.file)
            self.writer.writerow(HEADER)
        for row in rows:  # a restart keeps the rows up to its checkpoint
            self(row)

    def __call__(self, row: HistoryRow) -> None:
        if self.file is None:
            return
        self.rows.append(row)
        self.writer.writerow(_cells(row))
        self.file.flush()

    def on_history(self, row: HistoryRow) -> None:
        self(row)

    def text(self) -> str:
        """The rows so far as CSV text (rank 0; empty elsewhere)."""
        return history_text(self.rows) if self.file is not None else ""

    def close(self, completed: bool) -> None:
        if self.file is None:
            return
        self.file.close()
        self.file = None
        if completed:
            os.replace(self.partial, self.final)


def read_history(path: str | Path) -> dict[str, list[float]]:
    """A history.csv as a dict of lists by column name (``time``, ``kinetic_energy``, ...: the
    header's names without their unit suffix)."""
    with open(path, newline="") as f:
        rows = list(csv.reader(f))
    header, body = rows[0], rows[1:]
    return {column_name(name): [float(r[i]) for r in body] for i, name in enumerate(header)}


def history_until(out_dir: Path, t: float) -> list[HistoryRow]:
    """The rows before time t (s) of the history in ``out_dir``, for a checkpoint of the
    earlier format that kept no history of its own. ``history.partial.csv`` first: when both
    exist it is the newer (a later run that has not completed), and ``history.csv`` the run
    before it. A run resumed at t writes its row at t itself if t is an output time."""
    for name in ("history.partial.csv", "history.csv"):
        if (out_dir / name).exists():
            rows = parse_history((out_dir / name).read_text(), str(out_dir / name))
            return [row for row in rows if row.time < t]
    raise InputError("restart", f"no history.csv in {out_dir} to continue")


def json_safe(value):
    """``value`` with every non-finite float as the string "inf", "-inf" or "nan" (JSON has
    no such numbers; Python's ``float()`` reads these strings back) and NumPy scalars and
    arrays as Python numbers and lists."""
    if isinstance(value, dict):
        return {str(k): json_safe(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [json_safe(v) for v in value]
    if isinstance(value, np.ndarray):
        return json_safe(value.tolist())
    if isinstance(value, np.generic):
        value = value.item()
    if isinstance(value, float) and not math.isfinite(value):
        return "nan" if math.isnan(value) else ("inf" if value > 0 else "-inf")
    return value


def write_summary(
    out_dir: Path, summary: dict, comm: MPI.Comm, record: Callable[..., None] | None = None
) -> None:
    """summary.json, written whole (to summary.json.partial, then renamed): always valid
    JSON (``json_safe``; ``allow_nan=False`` so that a value it misses fails here)."""
    if comm.rank == 0:
        tmp = out_dir / "summary.json.partial"
        if record is not None:
            record(tmp, out_dir / "summary.json")
        tmp.write_text(json.dumps(json_safe(summary), indent=2, allow_nan=False) + "\n")
        os.replace(tmp, out_dir / "summary.json")


def pyplot():
    """matplotlib.pyplot on the file-only Agg backend, imported on first use: it adds 31 MiB
    and 0.3 s to every process that imports this module, and most never plot."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def plot_history(history: list[HistoryRow], out_dir: Path, title: str) -> None:
    plt = pyplot()
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
    """Displacement field over time for ParaView (VTX: ADIOS2 .bp folder). ADIOS2 names the
    files in the folder itself; the run manifest lists the folder (and, after each write,
    the files it holds)."""

    def __init__(self, out_dir: Path, functions: list, record: Callable[..., None] | None = None):
        self.folder = out_dir / "displacement.bp"
        self.comm = functions[0].function_space.mesh.comm
        self.record = record
        if record is not None and self.comm.rank == 0:
            record(self.folder, folder=True)
        self.writer = dolfinx.io.VTXWriter(self.comm, self.folder, functions, engine="BP4")

    def __call__(self, t: float) -> None:
        self.writer.write(t)
        self._record_files()

    def _record_files(self) -> None:
        if self.record is not None and self.comm.rank == 0 and self.folder.is_dir():
            self.record(*sorted(self.folder.iterdir()))

    def close(self) -> None:
        self.writer.close()
        self._record_files()


# DOLFINx hexahedron vertex order -> VTK_HEXAHEDRON order (cyclic faces)
_VTK_HEX = np.array([0, 1, 3, 2, 4, 5, 7, 6])
_VTK_QUAD = np.array([0, 1, 3, 2])


class _VtuSeries:
    """One .vtu per output time in ``<out>/<name>/`` (per rank, with a .pvtu in parallel),
    collected with its times in ``<out>/<name>.pvd`` for ParaView."""

    def __init__(
        self, out_dir: Path, name: str, comm: MPI.Comm, record: Callable[..., None] | None = None
    ):
        self.name, self.comm = name, comm
        self.folder = out_dir / name
        self.record = record if record is not None else (lambda *paths, folder=False: None)
        self.pvd = out_dir / f"{name}.pvd"
        with shared_errors(comm):  # rank 0's file errors reach every rank
            if comm.rank == 0:
                self.record(self.folder, folder=True)
                self.folder.mkdir(parents=True, exist_ok=True)
        self.steps: list[tuple[float, str]] = []

    def write(self, t: float, X, connectivity, offsets, types, point_data, cell_data) -> None:
        stem = f"{self.name}_{len(self.steps):06d}"
        parallel = self.comm.size > 1
        piece = f"{stem}_r{self.comm.rank}.vtu" if parallel else f"{stem}.vtu"
        with shared_errors(self.comm):  # file errors on any rank reach every rank
            if self.comm.rank == 0:  # every rank's file names, before any is written
                pieces = [f"{stem}_r{r}.vtu" for r in range(self.comm.size)] + [f"{stem}.pvtu"]
                names = pieces if parallel else [piece]
                self.record(self.pvd, *(self.folder / n for n in names))
            write_vtu(self.folder / piece, X, connectivity, offsets, types, point_data, cell_data)
            if parallel and self.comm.rank == 0:
                _write_pvtu(
                    self.folder / f"{stem}.pvtu", stem, self.comm.size, point_data, cell_data
                )
            self.steps.append((t, f"{self.name}/{stem}.{'pvtu' if parallel else 'vtu'}"))
            if self.comm.rank == 0:
                entries = "\n".join(
                    f'    <DataSet timestep="{time!r}" file="{path}"/>' for time, path in self.steps
                )
                self.pvd.write_text(
                    '<?xml version="1.0"?>\n<VTKFile type="Collection" version="0.1">\n'
                    f"  <Collection>\n{entries}\n  </Collection>\n</VTKFile>\n"
                )


def _combined_nodes(structure) -> tuple[np.ndarray, np.ndarray]:
    """Reference positions and displacements (n_base + n_extra, 3) of all local nodes."""
    s = structure
    X = np.vstack([s.X_base, s.extra.vectors["X"].array.reshape(-1, 3)])
    u = np.vstack([s.base.u.x.array.reshape(-1, 3), s.extra.vectors["u"].array.reshape(-1, 3)])
    return X, u


class ElementWriter:
    """The enriched mesh for ParaView: every solid element as it is computed (unrefined cells,
    and the subelements of refined ones, so the extra nodes and the sublaminates show, as in the
    paper's Figure 4), the cohesive elements as quads with their damage, displacements on all
    nodes (base and extra). Written to ``elements/`` and ``elements.pvd``."""

    def __init__(self, out_dir: Path, structure, record: Callable[..., None] | None = None):
        self.structure = structure
        self.comm = structure.comm
        self.series = _VtuSeries(out_dir, "elements", self.comm, record)

    def __call__(self, t: float) -> None:
        s = self.structure
        X, u = _combined_nodes(s)
        nodes, owners, plies = s.elements()
        solids = nodes[:, _VTK_HEX]
        cohesive = s.cohesive.nodes[:, :4][:, _VTK_QUAD]
        damage = s.cohesive.damage[s.cohesive.damage_row].mean(axis=1)
        connectivity = np.concatenate([solids.ravel(), cohesive.ravel()])
        offsets = np.concatenate(
            [
                8 * np.arange(1, len(solids) + 1),
                8 * len(solids) + 4 * np.arange(1, len(cohesive) + 1),
            ]
        )
        types = np.concatenate([np.full(len(solids), 12), np.full(len(cohesive), 9)])
        cell_data = {
            "first_ply": np.concatenate([plies[:, 0] + 1, np.zeros(len(cohesive))]),
            "last_ply": np.concatenate([plies[:, 1], np.zeros(len(cohesive))]),
            "cohesive_damage": np.concatenate([np.full(len(solids), -1.0), damage]),
            "rank": np.full(len(solids) + len(cohesive), float(self.comm.rank)),
        }
        # when each refinable interface of the element's cell refined (s), NaN while it has
        # not: the refinement log's times as fields
        refinable = sorted(set(s.interfaces.refine) | set(s.interfaces.delaminate))
        for name, since in (("weak_time", s.weak_since), ("strong_time", s.strong_since)):
            times = np.where(np.isfinite(since), since, np.nan)[owners]
            for interface in refinable:
                cell_data[f"{name}_{interface}"] = np.concatenate(
                    [times[:, interface - 1], np.full(len(cohesive), np.nan)]
                )
        point_data = {
            "displacement": u,
            "extra_node": np.r_[np.zeros(s.n_base), np.ones(len(u) - s.n_base)],
        }
        self.series.write(t, X, connectivity, offsets, types, point_data, cell_data)

    def close(self) -> None:
        pass


# Per-ply cell data of PlyWriter: material-frame stress components (MPa)
STRESS_NAMES = ("s11", "s22", "s33", "s23", "s13", "s12")


class PlyWriter:
    """Ply-by-ply results for ParaView: each ply of each cell as its own hexahedron (the slab
    between the ply's bottom and top within the element that holds it), with the ply number and
    angle, the material-frame stress at the ply's centre (MPa, with the matrix damage of the
    ply), the Hashin exposure factors (largest so far when the ply damage model runs, else of
    the current stress; only for materials with failure data) and the matrix damage. Written to
    ``plies/`` and ``plies.pvd``; threshold on ``ply`` to look at one ply of the laminate."""

    def __init__(self, out_dir: Path, structure, record: Callable[..., None] | None = None):
        self.structure = structure
        self.series = _VtuSeries(out_dir, "plies", structure.comm, record)

    def __call__(self, t: float) -> None:
        s = self.structure
        plies = s.laminate.plies
        fractions = s.laminate.ply_fractions
        X, u = _combined_nodes(s)
        nodes, cells, spans = s.elements()
        counts = spans[:, 1] - spans[:, 0]
        element = np.repeat(np.arange(len(nodes)), counts)
        ply = np.concatenate([np.arange(a, b) for a, b in spans]) if len(spans) else element
        s0 = thickness_weight(fractions, ply, spans[element, 0], spans[element, 1])
        s1 = thickness_weight(fractions, ply + 1, spans[element, 0], spans[element, 1])
        slab_points = []
        for values in (X, u):
            lower, upper = values[nodes[element, :4]], values[nodes[element, 4:]]
            slab_points.append(slab_vertices(lower, upper, s0, s1).reshape(-1, 3))
        n = len(element)
        connectivity = (8 * np.arange(n)[:, None] + _VTK_HEX[None, :]).ravel()
        offsets = 8 * np.arange(1, n + 1)
        owner = cells[element]
        damage = s.damage_state[:, :, S_D] if s.ply_damage else None
        stress = nominal_ply_stresses(ply_strains(s), plies, damage)[owner, ply]
        cell_data = {
            "ply": ply + 1.0,
            "angle": np.array([p.angle for p in plies])[ply],
            **{name: stress[:, i] for i, name in enumerate(STRESS_NAMES)},
        }
        if s.ply_damage:
            for name, slot in (("FT", S_FT), ("FC", S_FC), ("MT", S_MT), ("MC", S_MC)):
                cell_data[f"hashin_{name}"] = s.damage_state[owner, ply, slot]
            cell_data["matrix_damage"] = s.damage_state[owner, ply, S_D]
        elif all(p.material.name in s.failures for p in plies):
            cell_data["hashin_max"] = ply_failure_indices(s)[owner, ply]
        point_data = {"displacement": slab_points[1]}
        types = np.full(n, 12)
        self.series.write(t, slab_points[0], connectivity, offsets, types, point_data, cell_data)

    def close(self) -> None:
        pass


def _encode(values: np.ndarray, dtype: str) -> str:
    """Inline binary DataArray payload: base64 of a UInt32 byte count and the raw data."""
    raw = np.ascontiguousarray(values, dtype=dtype).tobytes()
    return base64.b64encode(np.uint32(len(raw)).tobytes() + raw).decode("ascii")


def _data_array(name: str, values: np.ndarray, components: int = 1) -> str:
    return (
        f'<DataArray type="Float64" Name="{name}" NumberOfComponents="{components}" '
        f'format="binary">{_encode(values, "<f8")}</DataArray>'
    )


def write_vtu(path, X, connectivity, offsets, types, point_data, cell_data) -> None:
    """Write one VTK unstructured-grid piece: points X (n, 3) mm, cells as VTK connectivity,
    offsets and types, point and cell data {name: array} in the run's units."""
    pd = "".join(_data_array(k, v, 3 if np.ndim(v) == 2 else 1) for k, v in point_data.items())
    cd = "".join(_data_array(k, v) for k, v in cell_data.items())
    path.write_text(
        '<?xml version="1.0"?>\n<VTKFile type="UnstructuredGrid" version="0.1" '
        'byte_order="LittleEndian" header_type="UInt32">\n'
        f'<UnstructuredGrid><Piece NumberOfPoints="{len(X)}" NumberOfCells="{len(types)}">\n'
        '<Points><DataArray type="Float64" NumberOfComponents="3" format="binary">'
        f"{_encode(X, '<f8')}</DataArray></Points>\n"
        '<Cells><DataArray type="Int64" Name="connectivity" format="binary">'
        f"{_encode(connectivity, '<i8')}</DataArray>"
        '<DataArray type="Int64" Name="offsets" format="binary">'
        f"{_encode(offsets, '<i8')}</DataArray>"
        '<DataArray type="UInt8" Name="types" format="binary">'
        f"{_encode(types, 'u1')}</DataArray></Cells>\n"
        f"<PointData>{pd}</PointData>\n<CellData>{cd}</CellData>\n"
        "</Piece></UnstructuredGrid></VTKFile>\n"
    )


def _write_pvtu(path, name, ranks, point_data, cell_data) -> None:
    def declare(data):
        return "".join(
            f'<PDataArray type="Float64" Name="{k}" '
            f'NumberOfComponents="{3 if np.ndim(v) == 2 else 1}"/>'
            for k, v in data.items()
        )

    pieces = "".join(f'<Piece Source="{name}_r{r}.vtu"/>' for r in range(ranks))
    path.write_text(
        '<?xml version="1.0"?>\n<VTKFile type="PUnstructuredGrid" version="0.1">\n'
        '<PUnstructuredGrid GhostLevel="0"><PPoints><PDataArray type="Float64" '
        'NumberOfComponents="3"/></PPoints>'
        f"<PPointData>{declare(point_data)}</PPointData>"
        f"<PCellData>{declare(cell_data)}</PCellData>{pieces}"
        "</PUnstructuredGrid></VTKFile>\n"
    )


class FieldOutputs(Observer):
    """All field outputs of a run: the base displacement (VTX), the enriched mesh and the
    ply-by-ply results (VTU series). ``record``: the run folder's ``RunFolder.record``. An
    observer of the solver (``on_fields``)."""

    def __init__(self, out_dir: Path, structure, record: Callable[..., None] | None = None):
        self.writers = [
            FieldWriter(out_dir, [structure.base.u], record),
            ElementWriter(out_dir, structure, record),
            PlyWriter(out_dir, structure, record),
        ]

    def __call__(self, t: float) -> None:
        for writer in self.writers:
            writer(t)

    def on_fields(self, t: float) -> None:
        self(t)

    def close(self) -> None:
        for writer in self.writers:
            writer.close()


class Progress(Observer):
    """Progress on stderr (rank 0): a live bar on a terminal, otherwise one line every
    ``every`` seconds. Silent for the first ``quiet_for`` seconds, so short runs print nothing.
    An observer of the solver (``on_progress``)."""

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

    def on_progress(self, t: float) -> None:
        self(t)

    def done(self) -> None:
        if self.enabled and self.shown and self.tty:
            sys.stderr.write("\n")
            sys.stderr.flush()
