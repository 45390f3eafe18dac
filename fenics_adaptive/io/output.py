"""Results on disk: history table, summary, plots, fields for ParaView, progress on the terminal.

A run writes into its output folder
  history.csv              one row per output step (columns below; units N, mm, s, mJ)
  summary.json             run facts and headline numbers, written last ("status" says how the
                           run ended)
  force_displacement.png   reaction force vs probe displacement
  energies.png             energy balance vs time
  displacement.xdmf, .h5   displacement of the base mesh over time (XDMF/HDF5, any ParaView)
  elements.pvd, elements/  the enriched mesh as computed: subelements and extra nodes
  cohesive.pvd, cohesive/  the cohesive elements: interface, damage
  plies.pvd, plies/        every ply of every cell as a slab: stress, Hashin indices, damage
  checkpoint/              the state to restart from (``checkpoint``)
The field files come every ``fields_interval``. Every name is added to the folder's run
manifest before it is written (``run_folder``): a fresh run into the folder removes what the
manifest lists and nothing else. While running, the history is written to
history.partial.csv and only renamed to history.csv when the run completes: a file named
history.csv is always a finished run.
"""

from __future__ import annotations

import csv
import io
import json
import math
import os
import sys
import time
import zlib
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import TextIO

import dolfinx.io
import numpy as np
from mpi4py import MPI

from fenics_adaptive.adaptivity.indicators import (
    ply_failure_indices,
    ply_shear_scale,
    ply_strains,
)
from fenics_adaptive.element.geometry import slab_vertices, thickness_weight
from fenics_adaptive.errors import InputError, shared_errors
from fenics_adaptive.materials.ply_damage import (
    S_D,
    S_DF,
    S_FC,
    S_FT,
    S_MC,
    S_MT,
    nominal_ply_stresses,
)
from fenics_adaptive.settings.solver import FieldSelection
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
    "tie_work": "mJ",
    "cohesive_dissipation": "mJ",
    "ply_dissipation": "mJ",
    "fibre_dissipation": "mJ",
    "eroded_energy": "mJ",
    "state_energy_balance": "mJ",
    "crack_growth_area": "mm^2",
    "energy_balance": "mJ",
}


# the header of history.csv: each column's name with its unit, as ``kinetic_energy_mJ``
UNIT_SUFFIX = {"s": "s", "mm": "mm", "N": "N", "mJ": "mJ", "mm^2": "mm2"}
HEADER = [f"{name}_{UNIT_SUFFIX[COLUMN_UNITS[name]]}" for name in COLUMNS]
# header cell -> column name; a header without units (files before 0.2) reads as well
_NAME_OF = {**{name: name for name in COLUMNS}, **dict(zip(HEADER, COLUMNS, strict=True))}


# a rigid body's history columns by their ending: ``<name>_force``, ``<name>_friction_energy``,
# ``<name>_displacement``, and their units (what ``body_unit`` gives and ``column_name`` reads)
BODY_UNITS = (("_force", "N"), ("_energy", "mJ"), ("_displacement", "mm"))


def body_unit(column: str) -> str:
    """The unit of a rigid body's history column (``BODY_UNITS``; mm for any other)."""
    return next((unit for ending, unit in BODY_UNITS if column.endswith(ending)), "mm")


def history_header(bodies: Sequence[str] = ()) -> list[str]:
    """The header of history.csv: every history's columns, then the rigid bodies' ``bodies``
    (``HistoryRow.bodies`` keys), each with its unit."""
    return HEADER + [f"{name}_{UNIT_SUFFIX[body_unit(name)]}" for name in bodies]


def column_name(header_cell: str) -> str:
    """The column name (a ``HistoryRow`` field, ``energy_balance`` or a rigid body's column)
    of a history.csv header cell, with or without its unit suffix; an unknown cell is returned
    as it is."""
    if header_cell in _NAME_OF:
        return _NAME_OF[header_cell]
    for ending, unit in BODY_UNITS:
        suffix = f"_{UNIT_SUFFIX[unit]}"
        if header_cell.endswith(ending + suffix):
            return header_cell.removesuffix(suffix)
    return header_cell


def _cells(row: HistoryRow, bodies: Sequence[str] = ()) -> list[str]:
    """A history row as CSV cells: full double precision, so a restart reads it back exactly."""
    return [repr(float(getattr(row, name))) for name in COLUMNS] + [
        repr(float(row.bodies[name])) for name in bodies
    ]


def history_text(rows: list[HistoryRow]) -> str:
    """History rows as the CSV text of history.csv (header and rows)."""
    bodies = list(rows[0].bodies) if rows else []
    buffer = io.StringIO(newline="")
    writer = csv.writer(buffer)
    writer.writerow(history_header(bodies))
    writer.writerows(_cells(row, bodies) for row in rows)
    return buffer.getvalue()


def parse_history(text: str, source: str) -> list[HistoryRow]:
    """History rows from CSV text (as ``history_text`` writes it). Raises InputError naming
    ``source`` if it is not such a table."""
    try:
        table = list(csv.reader(io.StringIO(text, newline="")))
        header, body = [column_name(cell) for cell in table[0]], table[1:]
        fields = [n for n in HistoryRow.__dataclass_fields__ if n != "bodies"]
        index = {name: header.index(name) for name in fields}
        bodies = {n: i for i, n in enumerate(header) if n not in index and n != "energy_balance"}
        return [
            HistoryRow(
                **{n: float(r[i]) for n, i in index.items()},
                bodies={n: float(r[i]) for n, i in bodies.items()},
            )
            for r in body
        ]
    except (IndexError, ValueError) as error:
        raise InputError("restart", f"{source} is not a history table ({error})") from None


class HistoryWriter(Observer):
    """CSV history, full double precision, flushed every row (rank 0 only). Keeps the rows
    (rank 0) for the checkpoints (``text``). An observer of the solver (``on_history``)."""

    def __init__(
        self,
        out_dir: Path,
        comm: MPI.Comm,
        rows: list[HistoryRow] = (),
        bodies: Sequence[str] = (),
    ):
        """``rows``: the rows a restart keeps; ``bodies``: the rigid bodies' columns
        (``HistoryRow.bodies`` keys), in order."""
        self.partial = out_dir / "history.partial.csv"
        self.final = out_dir / "history.csv"
        self.file: TextIO | None = None
        self.rows: list[HistoryRow] = []
        self.bodies = list(bodies)
        if comm.rank == 0:
            self.file = open(self.partial, "w", newline="")
            self.writer = csv.writer(self.file)
            self.writer.writerow(history_header(self.bodies))
        for row in rows:  # a restart keeps the rows up to its checkpoint
            self(row)

    def __call__(self, row: HistoryRow) -> None:
        if self.file is None:
            return
        self.rows.append(row)
        self.writer.writerow(_cells(row, self.bodies))
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
    """Displacement of the base mesh over time, as XDMF (``displacement.xdmf``, the XML a reader
    opens) with its HDF5 data (``displacement.h5``): the mesh once, then one displacement per
    output time. Every ParaView build reads it (the Xdmf3 readers), Debian's included; adaptive
    runs' cracks are in the element series (``ElementWriter``), not here: the base mesh is the
    ESL one."""

    def __init__(self, out_dir: Path, functions: list, record: Callable[..., None] | None = None):
        self.path = out_dir / "displacement.xdmf"
        self.functions = functions
        mesh = functions[0].function_space.mesh
        if record is not None and mesh.comm.rank == 0:
            record(self.path, self.path.with_suffix(".h5"))
        self.file = dolfinx.io.XDMFFile(mesh.comm, self.path, "w")
        self.file.write_mesh(mesh)

    def __call__(self, t: float) -> None:
        for function in self.functions:
            self.file.write_function(function, t)

    def close(self) -> None:
        self.file.close()


# DOLFINx hexahedron vertex order -> VTK_HEXAHEDRON order (cyclic faces)
_VTK_HEX = np.array([0, 1, 3, 2, 4, 5, 7, 6])
_VTK_QUAD = np.array([0, 1, 3, 2])
VTK_HEXAHEDRON, VTK_QUAD = 12, 9


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

    def write(self, t: float, X, cells: np.ndarray, cell_type: int, point_data, cell_data) -> None:
        """Write one time: points X (n, 3) mm, ``cells`` (m, k) VTK-ordered point indices of one
        ``cell_type``, point and cell data {name: array} (their dtypes kept)."""
        stem = f"{self.name}_{len(self.steps):06d}"
        parallel = self.comm.size > 1
        piece = f"{stem}_r{self.comm.rank}.vtu" if parallel else f"{stem}.vtu"
        with shared_errors(self.comm):  # file errors on any rank reach every rank
            if self.comm.rank == 0:  # every rank's file names, before any is written
                pieces = [f"{stem}_r{r}.vtu" for r in range(self.comm.size)] + [f"{stem}.pvtu"]
                names = pieces if parallel else [piece]
                self.record(self.pvd, *(self.folder / n for n in names))
            write_vtu(self.folder / piece, X, cells, cell_type, point_data, cell_data)
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


def cell_frames_or_global(structure, cells: np.ndarray) -> np.ndarray:
    """(n, 3, 3) material frames (rows: axis 1, axis 2, normal) of the owned ``cells``: a curved
    shell's own (``LayeredModel.cell_frames``), else the global x, y, z."""
    frames = structure.base.cell_frames()
    if frames is None:
        return np.broadcast_to(np.eye(3), (len(cells), 3, 3)).copy()
    return frames[np.asarray(cells, dtype=np.int64)]


def _combined_nodes(structure) -> tuple[np.ndarray, np.ndarray]:
    """Reference positions and displacements (n_base + n_extra, 3) of all local nodes."""
    s = structure
    X = np.vstack([s.X_base, s.extra.vectors["X"].array.reshape(-1, 3)])
    u = np.vstack([s.base.u.x.array.reshape(-1, 3), s.extra.vectors["u"].array.reshape(-1, 3)])
    return X, u


def _compact(nodes: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The nodes ``nodes`` (m, k) uses, and ``nodes`` renumbered into that list: a file holds
    only the points of its cells."""
    used, inverse = np.unique(nodes, return_inverse=True)
    return used, inverse.reshape(nodes.shape).astype(np.int64)


def _in_box(X: np.ndarray, nodes: np.ndarray, box: tuple[float, ...] | None) -> np.ndarray:
    """Which elements of ``nodes`` (m, k) have their reference centroid in ``box`` (x_min,
    x_max, y_min, y_max, z_min, z_max; mm); all of them without a box."""
    if box is None:
        return np.ones(len(nodes), dtype=bool)
    centre = X[nodes].mean(axis=1) if len(nodes) else np.zeros((0, 3))
    low, high = np.array(box[0::2]), np.array(box[1::2])
    return np.all((centre >= low) & (centre <= high), axis=1)


class SeriesWriter:
    """A VTU series (``<name>/``, ``<name>.pvd``) of what ``structure`` holds, limited as
    ``selection`` says (``FieldSelection``); subclasses write one time in ``__call__``."""

    name = ""

    def __init__(
        self,
        out_dir: Path,
        structure,
        record: Callable[..., None] | None = None,
        selection: FieldSelection | None = None,
    ):
        self.structure = structure
        self.selection = selection or FieldSelection()
        self.series = _VtuSeries(out_dir, self.name, structure.comm, record)

    def close(self) -> None:
        pass


class ElementWriter(SeriesWriter):
    """The enriched mesh for ParaView: every solid element as it is computed (unrefined cells,
    and the subelements of refined ones, so the extra nodes and the sublaminates show, as in the
    paper's Figure 4), displacements on all their nodes (base and extra). Written to
    ``elements/`` and ``elements.pvd``; the cohesive elements are ``CohesiveWriter``'s."""

    name = "elements"

    def __call__(self, t: float) -> None:
        s = self.structure
        X, u = _combined_nodes(s)
        nodes, owners, plies = s.elements()
        kept = _in_box(X, nodes, self.selection.box)
        nodes, owners, plies = nodes[kept], owners[kept], plies[kept]
        used, cells = _compact(nodes[:, _VTK_HEX])
        frames = cell_frames_or_global(s, owners)
        cell_data = {
            "first_ply": (plies[:, 0] + 1).astype(np.int32),
            "last_ply": plies[:, 1].astype(np.int32),
            "rank": np.full(len(nodes), s.comm.rank, dtype=np.int32),
            # the material frame before the ply angle: axis 1, axis 2, the normal
            "axis_1": frames[:, 0],
            "axis_2": frames[:, 1],
            "normal": frames[:, 2],
        }
        # when each refinable interface of the element's cell refined (s), NaN while it has
        # not: the refinement log's times as fields
        refinable = sorted(set(s.interfaces.refine) | set(s.interfaces.delaminate))
        for name, since in (("weak_time", s.weak_since), ("strong_time", s.strong_since)):
            times = np.where(np.isfinite(since), since, np.nan)[owners]
            for interface in refinable:
                cell_data[f"{name}_{interface}"] = times[:, interface - 1]
        point_data = {
            "displacement": u[used],
            "extra_node": (used >= s.n_base).astype(np.uint8),
        }
        self.series.write(t, X[used], cells, VTK_HEXAHEDRON, point_data, cell_data)


class CohesiveWriter(SeriesWriter):
    """The cohesive elements for ParaView, each as a quadrilateral of its own four points on the
    interface's mid-surface (the mean of its lower and upper faces' displacements), with the
    ``opening`` (upper minus lower face displacement, mm) at its points, its interface (1-based)
    the mean damage of its four integration points (0 intact, 1 open) and ``insert`` (1: an
    insert film's element, [[delamination]], failed from t = 0). Written to
    ``cohesive/`` and ``cohesive.pvd``."""

    name = "cohesive"

    def __call__(self, t: float) -> None:
        s = self.structure
        X, u = _combined_nodes(s)
        cohesive = s.cohesive
        kept = _in_box(X, cohesive.nodes[:, :4], self.selection.box)
        lower = cohesive.nodes[kept, :4][:, _VTK_QUAD].ravel()
        upper = cohesive.nodes[kept, 4:][:, _VTK_QUAD].ravel()
        n = int(kept.sum())
        cell_data = {
            "interface": cohesive.interface[kept].astype(np.int32),
            "cohesive_damage": cohesive.damage[cohesive.damage_row[kept]].mean(axis=1),
            "insert": cohesive.inserted()[kept].astype(np.uint8),
            "rank": np.full(n, s.comm.rank, dtype=np.int32),
        }
        point_data = {
            "displacement": 0.5 * (u[lower] + u[upper]),
            "opening": u[upper] - u[lower],
        }
        cells = np.arange(4 * n, dtype=np.int64).reshape(n, 4)
        self.series.write(t, X[lower], cells, VTK_QUAD, point_data, cell_data)


# Per-ply cell data of PlyWriter: material-frame stress components (MPa)
STRESS_NAMES = ("s11", "s22", "s33", "s23", "s13", "s12")


def written_ply_stresses(structure) -> np.ndarray:
    """(n_owned_cells, n_plies, 6) material-frame stress (MPa) of every (cell, ply) as its
    element carries it, as ``PlyWriter`` writes it: the damaged secant stress of the strain
    (with the ply damage model's state) with the transverse shears the ply carries in its
    element (``ply_shear_scale``, applied in the shell frame, where they are defined), as the
    ply damage law sees it."""
    plies = structure.laminate.plies
    strains = ply_shear_scale(structure) * ply_strains(structure)
    if not structure.ply_damage:
        return nominal_ply_stresses(strains, plies)
    damage = structure.damage_state
    return nominal_ply_stresses(strains, plies, damage[:, :, S_D], damage[:, :, S_DF])


class PlyWriter(SeriesWriter):
    """Ply-by-ply results for ParaView: each ply of each cell as its own hexahedron (the slab
    between the ply's bottom and top within the element that holds it), with the ply number and
    angle, the material-frame stress at the ply's centre (MPa, with the matrix damage of the
    ply), the Hashin exposure factors (largest so far when the ply damage model runs, else of
    the current stress; only for materials with failure data) and the matrix damage. Written to
    ``plies/`` and ``plies.pvd``; threshold on ``ply`` to look at one ply of the laminate.
    ``selection``: the plies, the box and every how many field frames (the largest output)."""

    name = "plies"
    calls = 0  # field outputs so far (ply_every counts them)

    def __call__(self, t: float) -> None:
        due = self.calls % self.selection.ply_every == 0
        self.calls += 1
        if due:
            self.write(t)

    def write(self, t: float) -> None:
        s = self.structure
        plies = s.laminate.plies
        fractions = s.laminate.ply_fractions
        X, u = _combined_nodes(s)
        nodes, cells, spans = s.elements()
        kept = _in_box(X, nodes, self.selection.box)
        nodes, cells, spans = nodes[kept], cells[kept], spans[kept]
        counts = spans[:, 1] - spans[:, 0]
        element = np.repeat(np.arange(len(nodes)), counts)
        ply = np.concatenate([np.arange(a, b) for a, b in spans]) if len(spans) else element
        if self.selection.plies is not None:
            wanted = np.isin(ply + 1, self.selection.plies)
            element, ply = element[wanted], ply[wanted]
        s0 = thickness_weight(fractions, ply, spans[element, 0], spans[element, 1])
        s1 = thickness_weight(fractions, ply + 1, spans[element, 0], spans[element, 1])
        slab_points = []
        for values in (X, u):
            lower, upper = values[nodes[element, :4]], values[nodes[element, 4:]]
            slab_points.append(slab_vertices(lower, upper, s0, s1).reshape(-1, 3))
        n = len(element)
        connectivity = 8 * np.arange(n)[:, None] + _VTK_HEX[None, :]
        owner = cells[element]
        stress = written_ply_stresses(s)[owner, ply]
        angle = np.array([p.angle for p in plies], dtype=float)[ply]
        frames = cell_frames_or_global(s, owner)
        radians = np.radians(angle)[:, None]
        cell_data = {
            "ply": (ply + 1).astype(np.int32),
            "angle": angle,
            # the fibres: the ply angle turned from axis 1 about the normal
            "fibre": np.cos(radians) * frames[:, 0] + np.sin(radians) * frames[:, 1],
            **{name: stress[:, i] for i, name in enumerate(STRESS_NAMES)},
        }
        if s.ply_damage:
            for name, slot in (("FT", S_FT), ("FC", S_FC), ("MT", S_MT), ("MC", S_MC)):
                cell_data[f"hashin_{name}"] = s.damage_state[owner, ply, slot]
            cell_data["matrix_damage"] = s.damage_state[owner, ply, S_D]
            cell_data["fibre_damage"] = s.damage_state[owner, ply, S_DF]
        elif all(p.material.name in s.failures for p in plies):
            cell_data["hashin_max"] = ply_failure_indices(s)[owner, ply]
        point_data = {"displacement": slab_points[1]}
        self.series.write(t, slab_points[0], connectivity, VTK_HEXAHEDRON, point_data, cell_data)


# numpy dtype -> VTK XML type name
_VTK_TYPES = {
    np.dtype(np.float64): "Float64",
    np.dtype(np.float32): "Float32",
    np.dtype(np.int64): "Int64",
    np.dtype(np.int32): "Int32",
    np.dtype(np.uint8): "UInt8",
}
# uncompressed bytes per zlib block (VTK's own writers' default)
_BLOCK = 1 << 15


def _vtk_array(values: np.ndarray) -> np.ndarray:
    """``values`` little-endian and contiguous, in a type VTK names (bool as UInt8)."""
    values = np.asarray(values)
    if values.dtype == bool:
        values = values.astype(np.uint8)
    if values.dtype.newbyteorder("=") not in _VTK_TYPES:
        raise TypeError(f"no VTK type for {values.dtype}")
    return np.ascontiguousarray(values, dtype=values.dtype.newbyteorder("<"))


def _compressed(values: np.ndarray) -> bytes:
    """One DataArray of VTK's appended raw data, zlib compressed: a UInt64 header (number of
    blocks, block size, size of the last block, compressed size of each block), the blocks."""
    raw = values.tobytes()
    blocks = [zlib.compress(raw[i : i + _BLOCK], 6) for i in range(0, len(raw), _BLOCK)]
    last = len(raw) - _BLOCK * (len(blocks) - 1) if blocks else 0
    header = np.array([len(blocks), _BLOCK, last, *map(len, blocks)], dtype="<u8")
    return header.tobytes() + b"".join(blocks)


def _components(values: np.ndarray) -> int:
    return values.shape[1] if values.ndim == 2 else 1


def write_vtu(path, X, cells, cell_type: int, point_data, cell_data) -> None:
    """Write one VTK unstructured-grid piece (.vtu, zlib-compressed appended raw binary, as
    VTK's own writers do): points X (n, 3) mm, ``cells`` (m, k) point indices in VTK order, all
    of ``cell_type`` (12 hexahedron, 9 quadrilateral), point and cell data {name: array} in the
    run's units, each written in its own dtype (integers stay integers)."""
    cells = np.asarray(cells, dtype=np.int64)
    arrays = [
        ("Points", None, np.asarray(X, dtype=np.float64).reshape(-1, 3)),
        ("Cells", "connectivity", cells.ravel()),
        ("Cells", "offsets", cells.shape[1] * np.arange(1, len(cells) + 1, dtype=np.int64)),
        ("Cells", "types", np.full(len(cells), cell_type, dtype=np.uint8)),
        *(("PointData", k, v) for k, v in point_data.items()),
        *(("CellData", k, v) for k, v in cell_data.items()),
    ]
    sections: dict[str, list[str]] = {"Points": [], "Cells": [], "PointData": [], "CellData": []}
    payload, offset = [], 0
    for section, name, values in arrays:
        values = _vtk_array(values)
        data = _compressed(values)
        label = f' Name="{name}"' if name else ""
        sections[section].append(
            f'<DataArray type="{_VTK_TYPES[values.dtype.newbyteorder("=")]}"{label} '
            f'NumberOfComponents="{_components(values)}" format="appended" offset="{offset}"/>'
        )
        payload.append(data)
        offset += len(data)
    xml = (
        '<?xml version="1.0"?>\n<VTKFile type="UnstructuredGrid" version="1.0" '
        'byte_order="LittleEndian" header_type="UInt64" '
        'compressor="vtkZLibDataCompressor">\n'
        f'<UnstructuredGrid><Piece NumberOfPoints="{len(arrays[0][2])}" '
        f'NumberOfCells="{len(cells)}">\n'
        + "".join(f"<{k}>{''.join(v)}</{k}>\n" for k, v in sections.items())
        + '</Piece></UnstructuredGrid>\n<AppendedData encoding="raw">\n_'
    )
    path.write_bytes(xml.encode() + b"".join(payload) + b"\n</AppendedData></VTKFile>\n")


def _write_pvtu(path, name, ranks, point_data, cell_data) -> None:
    def declare(data):
        return "".join(
            f'<PDataArray type="{_VTK_TYPES[_vtk_array(v).dtype.newbyteorder("=")]}" '
            f'Name="{k}" NumberOfComponents="{_components(np.asarray(v))}"/>'
            for k, v in data.items()
        )

    pieces = "".join(f'<Piece Source="{name}_r{r}.vtu"/>' for r in range(ranks))
    path.write_text(
        '<?xml version="1.0"?>\n<VTKFile type="PUnstructuredGrid" version="1.0" '
        'byte_order="LittleEndian" header_type="UInt64">\n'
        '<PUnstructuredGrid GhostLevel="0"><PPoints><PDataArray type="Float64" '
        'NumberOfComponents="3"/></PPoints>'
        f"<PPointData>{declare(point_data)}</PPointData>"
        f"<PCellData>{declare(cell_data)}</PCellData>{pieces}"
        "</PUnstructuredGrid></VTKFile>\n"
    )


class FieldOutputs(Observer):
    """All field outputs of a run: the base displacement (XDMF), the enriched mesh, the
    cohesive elements and the ply-by-ply results (VTU series), limited as ``selection`` says.
    ``record``: the run folder's ``RunFolder.record``. An observer of the solver
    (``on_fields``)."""

    def __init__(
        self,
        out_dir: Path,
        structure,
        record: Callable[..., None] | None = None,
        selection: FieldSelection | None = None,
    ):
        self.writers = [
            FieldWriter(out_dir, [structure.base.u], record),
            ElementWriter(out_dir, structure, record, selection),
            CohesiveWriter(out_dir, structure, record, selection),
            PlyWriter(out_dir, structure, record, selection),
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
