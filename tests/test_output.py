"""Output files: the enriched-mesh, cohesive and ply VTU series read back with VTK's own
reader (types, names, values), the displacement XDMF, the field selection, the history columns'
documentation, and summary.json as valid JSON whatever its values."""

import json
import tomllib
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pytest

from fenics_adaptive.adaptivity.indicators import to_material_frame
from fenics_adaptive.io.output import (
    COLUMN_UNITS,
    HEADER,
    STRESS_NAMES,
    CohesiveWriter,
    ElementWriter,
    FieldWriter,
    HistoryWriter,
    PlyWriter,
    json_safe,
    parse_history,
    read_history,
    write_summary,
)
from fenics_adaptive.materials.laminate import ply_shear_factors
from fenics_adaptive.materials.ply_damage import strain_rotation
from fenics_adaptive.settings.config import parse_config
from fenics_adaptive.settings.solver import FieldSelection
from fenics_adaptive.simulation import build_structure
from fenics_adaptive.solver.explicit import COLUMNS
from fenics_adaptive.solver.history import HistoryRow

DATA = Path(__file__).parent / "data"


def cell_points(cell) -> list[int]:
    return [cell.GetPointId(k) for k in range(cell.GetNumberOfPoints())]


def read_vtu(path: Path) -> dict:
    """A .vtu through VTK's XML reader (what ParaView runs): points, cells (k points each),
    VTK cell types, and every point and cell array with its VTK type name."""
    from vtkmodules.util.numpy_support import vtk_to_numpy
    from vtkmodules.vtkIOXML import vtkXMLUnstructuredGridReader

    reader = vtkXMLUnstructuredGridReader()
    reader.SetFileName(str(path))
    reader.Update()
    assert reader.GetErrorCode() == 0
    grid = reader.GetOutput()
    out = {
        "points": vtk_to_numpy(grid.GetPoints().GetData()) if grid.GetNumberOfPoints() else None,
        "types": np.array([grid.GetCellType(i) for i in range(grid.GetNumberOfCells())]),
        "cells": np.array([cell_points(grid.GetCell(i)) for i in range(grid.GetNumberOfCells())]),
        "point": {},
        "cell": {},
    }
    for kind, data in (("point", grid.GetPointData()), ("cell", grid.GetCellData())):
        for i in range(data.GetNumberOfArrays()):
            array = data.GetArray(i)
            out[kind][array.GetName()] = (vtk_to_numpy(array), array.GetDataTypeAsString())
    return out


def test_every_history_column_has_a_unit():
    assert set(COLUMN_UNITS) == set(COLUMNS)


def test_the_history_header_carries_the_units_and_reads_back_exactly(tmp_path):
    """history.csv's header is ``<column>_<unit>``; numpy reads the units with the names,
    ``read_history`` and the restart's parser give the plain names and the exact values, also
    from a file of the earlier header without units."""
    from mpi4py import MPI

    rng = np.random.default_rng(3)
    fields = [name for name in HistoryRow.__dataclass_fields__ if name != "bodies"]
    bodies = ["nose_force", "nose_displacement"]  # a [[rigid]] body's columns
    rows = [
        HistoryRow(
            **dict(zip(fields, rng.normal(size=len(fields)), strict=True)),
            bodies=dict(zip(bodies, rng.normal(size=2), strict=True)),
        )
        for _ in range(3)
    ]
    writer = HistoryWriter(tmp_path, MPI.COMM_SELF, bodies=bodies)
    for row in rows:
        writer.on_history(row)
    writer.close(completed=True)
    path = tmp_path / "history.csv"
    header = path.read_text().splitlines()[0].split(",")
    assert header == [*HEADER, "nose_force_N", "nose_displacement_mm"]
    assert header[:5] == [
        "time_s",
        "displacement_mm",
        "reaction_force_N",
        "applied_force_N",
        "kinetic_energy_mJ",
    ]
    assert "delaminated_area_mm2" in header and "energy_balance_mJ" in header
    table = np.genfromtxt(path, delimiter=",", names=True)
    np.testing.assert_array_equal(table["kinetic_energy_mJ"], [r.kinetic_energy for r in rows])
    columns = read_history(path)
    assert list(columns) == [*COLUMNS, *bodies]
    np.testing.assert_array_equal(columns["energy_balance"], [r.energy_balance for r in rows])
    assert parse_history(path.read_text(), str(path)) == rows
    # the earlier header (names only) reads the same
    old = path.read_text().replace(",".join(HEADER), ",".join(COLUMNS), 1)
    assert old.splitlines()[0].startswith(",".join(COLUMNS) + ",nose_force_N")
    assert parse_history(old, "old") == rows


def refined_beam():
    data = tomllib.loads((DATA / "tcb_adaptive.toml").read_text())  # refined from the start
    structure = build_structure(parse_config(data))
    rng = np.random.default_rng(0)
    structure.base.u.x.array[:] = rng.normal(size=structure.base.u.x.array.shape)
    extra_u = structure.extra.vectors["u"].array
    extra_u[:] = rng.normal(size=extra_u.shape)
    return structure


def test_element_file_holds_subelements_and_extra_nodes_with_integer_fields(tmp_path):
    structure = refined_beam()
    writer = ElementWriter(tmp_path, structure)
    writer(0.0)
    writer(1.0)
    collection = ET.parse(tmp_path / "elements.pvd").getroot()
    files = [d.get("file") for d in collection.iter("DataSet")]
    assert files == ["elements/elements_000000.vtu", "elements/elements_000001.vtu"]
    assert b"vtkZLibDataCompressor" in (tmp_path / files[1]).read_bytes()[:600]
    grid = read_vtu(tmp_path / files[1])
    # 20 cells x 4 subelements (interfaces 2, 4, 6 refined); no cohesive quads in this file
    assert grid["types"].tolist() == [12] * 80
    X = np.vstack([structure.X_base, structure.extra.vectors["X"].array.reshape(-1, 3)])
    u = np.vstack([structure.base.u.x.array.reshape(-1, 3),
                   structure.extra.vectors["u"].array.reshape(-1, 3)])  # fmt: skip
    nodes, _, spans = structure.elements()
    # the file's points are the elements' nodes, VTK-ordered, with their displacement
    vtk_order = [0, 1, 3, 2, 4, 5, 7, 6]
    np.testing.assert_array_equal(grid["points"][grid["cells"]], X[nodes[:, vtk_order]])
    displacement, kind = grid["point"]["displacement"]
    assert kind == "double"
    np.testing.assert_array_equal(displacement[grid["cells"]], u[nodes[:, vtk_order]])
    extra, kind = grid["point"]["extra_node"]
    assert kind == "unsigned char" and extra.sum() == structure.extra.n_local
    first, kind = grid["cell"]["first_ply"]
    assert kind == "int" and grid["cell"]["last_ply"][1] == "int"
    np.testing.assert_array_equal(first, spans[:, 0] + 1)
    assert sorted(set(zip(first, grid["cell"]["last_ply"][0], strict=True))) == [
        (1, 2), (3, 4), (5, 6), (7, 8)]  # fmt: skip
    assert grid["cell"]["rank"][1] == "int"
    assert "cohesive_damage" not in grid["cell"]


def test_cohesive_file_holds_the_interfaces_with_damage_and_opening(tmp_path):
    structure = refined_beam()
    cohesive = structure.cohesive
    cohesive.damage[:] = np.random.default_rng(1).uniform(size=cohesive.damage.shape)
    cohesive.delaminate(np.arange(5))  # an insert film's elements
    CohesiveWriter(tmp_path, structure)(0.0)
    grid = read_vtu(tmp_path / "cohesive/cohesive_000000.vtu")
    assert grid["types"].tolist() == [9] * 40  # 20 cells x 2 delaminating interfaces
    interface, kind = grid["cell"]["interface"]
    assert kind == "int"
    np.testing.assert_array_equal(interface, cohesive.interface)
    damage, kind = grid["cell"]["cohesive_damage"]
    assert kind == "double" and damage.min() >= 0.0
    np.testing.assert_allclose(damage, cohesive.damage[cohesive.damage_row].mean(axis=1))
    insert, kind = grid["cell"]["insert"]
    assert kind == "unsigned char" and insert.tolist() == [1] * 5 + [0] * 35
    X = np.vstack([structure.X_base, structure.extra.vectors["X"].array.reshape(-1, 3)])
    u = np.vstack([structure.base.u.x.array.reshape(-1, 3),
                   structure.extra.vectors["u"].array.reshape(-1, 3)])  # fmt: skip
    lower, upper = cohesive.nodes[:, [0, 1, 3, 2]], cohesive.nodes[:, [4, 5, 7, 6]]
    np.testing.assert_array_equal(grid["points"][grid["cells"]], X[lower])
    opening = grid["point"]["opening"][0][grid["cells"]]
    np.testing.assert_allclose(opening, u[upper] - u[lower], rtol=0, atol=1e-14)
    mid = grid["point"]["displacement"][0][grid["cells"]]
    np.testing.assert_allclose(mid, 0.5 * (u[upper] + u[lower]), rtol=0, atol=1e-14)


def test_field_selection_keeps_the_box_and_the_plies_and_thins_the_ply_frames(tmp_path):
    structure = refined_beam()
    box = (2.0, 4.0, -1.0, 2.0, -1.0, 5.0)  # x from 2 to 4 mm of the 10 mm beam
    selection = FieldSelection(plies=(1, 8), box=box, ply_every=3)
    ElementWriter(tmp_path, structure, selection=selection)(0.0)
    grid = read_vtu(tmp_path / "elements/elements_000000.vtu")
    centroids = grid["points"][grid["cells"]].mean(axis=1)
    assert len(centroids) == 4 * 4  # the 0.5 mm cells centred in [2, 4] mm, 4 subelements each
    assert np.all((centroids[:, 0] >= 2.0) & (centroids[:, 0] <= 4.0))
    plies = PlyWriter(tmp_path, structure, selection=selection)
    for t in range(7):
        plies(float(t))
    frames = [d.get("timestep") for d in ET.parse(tmp_path / "plies.pvd").getroot().iter("DataSet")]
    assert frames == ["0.0", "3.0", "6.0"]
    grid = read_vtu(tmp_path / "plies/plies_000000.vtu")
    assert sorted(set(grid["cell"]["ply"][0])) == [1, 8] and len(grid["types"]) == 4 * 2
    # a box that holds no element writes an empty, valid file
    empty = FieldSelection(box=(100.0, 101.0, 0.0, 1.0, 0.0, 1.0))
    CohesiveWriter(tmp_path, structure, selection=empty)(0.0)
    assert len(read_vtu(tmp_path / "cohesive/cohesive_000000.vtu")["types"]) == 0


# h5py in a process of its own: its HDF5 library and DOLFINx's cannot share one process
_READ_HDF5 = """
import sys
import h5py
import numpy as np
with h5py.File(sys.argv[1], "r") as f:
    np.savez(sys.argv[2], **{str(i): f[path][()] for i, path in enumerate(sys.argv[3:])})
"""


def test_displacement_xdmf_holds_the_mesh_once_and_every_time(tmp_path):
    """The XDMF names the mesh once and one displacement per time; the HDF5 data it points at
    (read by h5py, not DOLFINx) are the nodes and the displacement of each time."""
    import subprocess
    import sys

    structure = refined_beam()
    u = structure.base.u
    first = u.x.array.copy()
    writer = FieldWriter(tmp_path, [u])
    writer(0.0)
    u.x.array[:] *= 2.0
    writer(1.5e-4)
    writer.close()
    root = ET.parse(tmp_path / "displacement.xdmf").getroot()
    assert len(root.findall(".//Topology")) == 1
    assert root.find(".//Topology").get("TopologyType") == "Hexahedron"
    steps = [g for g in root.iter("Grid") if g.find("Time") is not None]
    assert [float(g.find("Time").get("Value")) for g in steps] == [0.0, 1.5e-4]
    items = [root.find(".//Geometry/DataItem").text.strip()]
    items += [g.find("Attribute[@Name='displacement']/DataItem").text.strip() for g in steps]
    files, paths = zip(*(item.split(":") for item in items), strict=True)
    assert set(files) == {"displacement.h5"}
    read = tmp_path / "read.npz"
    subprocess.run(
        [sys.executable, "-c", _READ_HDF5, tmp_path / "displacement.h5", read, *paths],
        check=True,
    )
    with np.load(read) as back:
        points, values = back["0"], [back["1"], back["2"]]
    assert points.shape == (structure.n_base, 3)
    # the file's node order is the geometry's, not the function's dofs: match by position
    file_order = np.lexsort(np.round(points, 9).T)
    dof_order = np.lexsort(np.round(structure.X_base, 9).T)
    np.testing.assert_allclose(points[file_order], structure.X_base[dof_order], atol=1e-12)
    for value, expected in zip(values, (first, 2.0 * first), strict=True):
        np.testing.assert_array_equal(value[file_order], expected.reshape(-1, 3)[dof_order])


@pytest.mark.slow
@pytest.mark.parametrize("shear_correction", [False, True])
def test_ply_file_holds_every_ply_as_a_slab_with_its_stress(tmp_path, shear_correction):
    """A uniform strain on the refined TCB beam: 8 slabs per cell at the plies' heights, and
    each slab's material-frame stress is T (C D eps) of its ply, from whichever subelement
    holds the ply: C its shell-frame stiffness, D = 1 but for the transverse shears, sqrt of
    the ply's shear factors in the holding subelement (m_yz, m_xz, its share of the
    laminate's shear flow; 1 without the correction, and the stress is C0 T eps)."""
    data = tomllib.loads((DATA / "tcb_adaptive.toml").read_text())
    data["laminate"]["angles"] = [0, 45, 90, -45, -45, 90, 45, 0]
    data["interfaces"]["symmetry"] = []
    data["model"]["shear_correction"] = shear_correction
    # the element's strain is then the imposed one exactly: a uniform strain of plies at
    # different angles is not a constant stress, and the enhanced thickness strain would add
    # its condensed part (what the file must show then; indicators' ply strains carry it)
    data["model"]["enhanced_strain"] = False
    structure = build_structure(parse_config(data))
    strain = np.array([[1e-4, 2e-5, 0.0], [2e-5, -3e-5, 1e-5], [0.0, 1e-5, 5e-5]])
    for X, u in (
        (structure.X_base, structure.base.u.x.array),
        (structure.extra.vectors["X"].array.reshape(-1, 3), structure.extra.vectors["u"].array),
    ):
        u[:] = (X @ strain.T).ravel()
    PlyWriter(tmp_path, structure)(0.0)
    grid = read_vtu(tmp_path / "plies/plies_000000.vtu")
    assert len(grid["types"]) == 20 * 8
    ply, kind = grid["cell"]["ply"]
    assert kind == "int" and np.all(np.bincount(ply)[1:] == 20)
    points = grid["points"][grid["cells"]]
    z = structure.laminate.ply_fractions * structure.laminate.thickness  # bottom face z = 0
    np.testing.assert_allclose(points[:, 0, 2], z[ply - 1], atol=1e-12)
    np.testing.assert_allclose(points[:, 4, 2], z[ply], atol=1e-12)
    voigt = np.array([strain[0, 0], strain[1, 1], strain[2, 2], 2 * strain[1, 2],
                      2 * strain[0, 2], 2 * strain[0, 1]])  # fmt: skip
    _, _, spans = structure.elements()
    shell_stiffness = structure.laminate.ply_stiffnesses()
    for k, p in enumerate(structure.laminate.plies):
        expected = p.material.stiffness() @ strain_rotation(p.angle) @ voigt
        first, stop = spans[(spans[:, 0] <= k) & (k < spans[:, 1])][0]
        m = ply_shear_factors(structure.laminate, first, stop, shear_correction)[k - first]
        m_xz, m_yz = m
        if shear_correction:
            assert stop - first > 1 and m_xz != 1.0  # the case tests something
        D = np.diag([1.0, 1.0, 1.0, np.sqrt(m_yz), np.sqrt(m_xz), 1.0])
        shell = shell_stiffness[k] @ D @ voigt
        rotated = to_material_frame(shell[None, None, :], np.array([p.angle]))[0, 0]
        if not shear_correction:
            np.testing.assert_allclose(rotated, expected, rtol=1e-9, atol=1e-9)
        expected = rotated
        for i, name in enumerate(STRESS_NAMES):
            values = grid["cell"][name][0][ply == k + 1]
            np.testing.assert_allclose(values, expected[i], rtol=1e-9, atol=1e-9)


def test_summary_is_valid_json_whatever_the_values(tmp_path):
    """Infinite and NaN values become the strings "inf", "-inf", "nan" (read back by float());
    NumPy scalars and arrays become numbers and lists; the file parses under strict JSON."""
    from mpi4py import MPI

    summary = {
        "peak_reaction_force_N": float("inf"),
        "final": {"kinetic_energy_mJ": np.float64("nan"), "external_work_mJ": -np.inf},
        "steps": np.int64(12),
        "list": [1.0, float("-inf"), np.array([np.nan, 2.0])],
        "fine": 1.5,
    }
    write_summary(tmp_path, summary, MPI.COMM_WORLD)
    text = (tmp_path / "summary.json").read_text()

    def refuse(constant):
        raise AssertionError(f"bare {constant} in summary.json")

    back = json.loads(text, parse_constant=refuse)
    assert back["peak_reaction_force_N"] == "inf" and float(back["peak_reaction_force_N"]) > 0
    assert back["final"] == {"kinetic_energy_mJ": "nan", "external_work_mJ": "-inf"}
    assert back["steps"] == 12 and back["list"] == [1.0, "-inf", ["nan", 2.0]]
    assert back["fine"] == 1.5
    assert not (tmp_path / "summary.json.partial").exists()
    # a regression that lets a bare non-finite number through fails loudly, not silently
    with pytest.raises(ValueError):
        json.dumps({"x": float("nan")}, allow_nan=False)
    assert json_safe({"x": (float("nan"),)}) == {"x": ["nan"]}


@pytest.mark.slow
def test_a_run_with_an_infinite_value_writes_valid_json(tmp_path, monkeypatch):
    """End to end: a run whose summary holds an infinite number (the structure's mass, made
    infinite here) still writes a summary.json that strict JSON reads."""
    from fenics_adaptive.model import structure
    from fenics_adaptive.runner import run_config

    monkeypatch.setattr(structure.Structure, "total_mass", lambda self: float("inf"))
    data = tomllib.loads((DATA / "small_beam.toml").read_text())
    data["solver"]["end_time"] = 2.0e-5
    del data["output"]["fields_interval"]
    run_config(parse_config(data), tmp_path / "out", show_progress=False, log=None)
    text = (tmp_path / "out" / "summary.json").read_text()
    summary = json.loads(text, parse_constant=lambda c: pytest.fail(f"bare {c}"))
    assert summary["model"]["total_mass_tonne"] == "inf"
    assert summary["status"] == "completed"
