"""Output files: the enriched-mesh VTU (extra nodes and subelements visible), the history
columns' documentation, and summary.json as valid JSON whatever its values."""

import base64
import json
import tomllib
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pytest

from fenics_adaptive.io.output import (
    COLUMN_UNITS,
    HEADER,
    STRESS_NAMES,
    ElementWriter,
    HistoryWriter,
    PlyWriter,
    json_safe,
    parse_history,
    read_history,
    write_summary,
)
from fenics_adaptive.materials.ply_damage import strain_rotation
from fenics_adaptive.settings.config import parse_config
from fenics_adaptive.simulation import build_structure
from fenics_adaptive.solver.explicit import COLUMNS
from fenics_adaptive.solver.history import HistoryRow

DATA = Path(__file__).parent / "data"


def decode(array: ET.Element, dtype: str) -> np.ndarray:
    raw = base64.b64decode(array.text)
    n = np.frombuffer(raw[:4], dtype="<u4")[0]
    return np.frombuffer(raw[4 : 4 + n], dtype=dtype)


def test_every_history_column_has_a_unit():
    assert set(COLUMN_UNITS) == set(COLUMNS)


def test_the_history_header_carries_the_units_and_reads_back_exactly(tmp_path):
    """history.csv's header is ``<column>_<unit>``; numpy reads the units with the names,
    ``read_history`` and the restart's parser give the plain names and the exact values, also
    from a file of the earlier header without units."""
    from mpi4py import MPI

    rng = np.random.default_rng(3)
    fields = list(HistoryRow.__dataclass_fields__)
    rows = [
        HistoryRow(**dict(zip(fields, rng.normal(size=len(fields)), strict=True))) for _ in range(3)
    ]
    writer = HistoryWriter(tmp_path, MPI.COMM_SELF)
    for row in rows:
        writer.on_history(row)
    writer.close(completed=True)
    path = tmp_path / "history.csv"
    header = path.read_text().splitlines()[0].split(",")
    assert header == HEADER
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
    assert list(columns) == COLUMNS
    np.testing.assert_array_equal(columns["energy_balance"], [r.energy_balance for r in rows])
    assert parse_history(path.read_text(), str(path)) == rows
    # the earlier header (names only) reads the same
    old = path.read_text().replace(",".join(HEADER), ",".join(COLUMNS), 1)
    assert old.splitlines()[0] == ",".join(COLUMNS)
    assert parse_history(old, "old") == rows


def test_element_file_holds_subelements_extra_nodes_and_cohesive_elements(tmp_path):
    data = tomllib.loads((DATA / "tcb_adaptive.toml").read_text())  # refined from the start
    structure = build_structure(parse_config(data))
    rng = np.random.default_rng(0)
    structure.base.u.x.array[:] = rng.normal(size=structure.base.u.x.array.shape)
    writer = ElementWriter(tmp_path, structure)
    writer(0.0)
    writer(1.0)
    collection = ET.parse(tmp_path / "elements.pvd").getroot()
    files = [d.get("file") for d in collection.iter("DataSet")]
    assert files == ["elements/elements_000000.vtu", "elements/elements_000001.vtu"]
    piece = ET.parse(tmp_path / files[1]).getroot().find("UnstructuredGrid/Piece")
    n_points, n_cells = int(piece.get("NumberOfPoints")), int(piece.get("NumberOfCells"))
    # 20 cells x 4 subelements (interfaces 2, 4, 6 refined) + 20 x 2 cohesive elements
    assert n_cells == 80 + 40
    assert n_points == structure.n_base + structure.extra.n_local
    arrays = {a.get("Name"): a for a in piece.iter("DataArray")}
    types = decode(arrays["types"], "u1")
    assert (types == 12).sum() == 80 and (types == 9).sum() == 40
    points = decode(piece.find("Points/DataArray"), "<f8").reshape(-1, 3)
    X = np.vstack([structure.X_base, structure.extra.vectors["X"].array.reshape(-1, 3)])
    np.testing.assert_array_equal(points, X)
    u = decode(arrays["displacement"], "<f8").reshape(-1, 3)
    np.testing.assert_array_equal(u[: structure.n_base], structure.base.u.x.array.reshape(-1, 3))
    extra = decode(arrays["extra_node"], "<f8")
    assert extra.sum() == structure.extra.n_local
    plies = decode(arrays["first_ply"], "<f8")[:80], decode(arrays["last_ply"], "<f8")[:80]
    assert sorted(set(zip(*plies, strict=True))) == [(1, 2), (3, 4), (5, 6), (7, 8)]


@pytest.mark.slow
def test_ply_file_holds_every_ply_as_a_slab_with_its_stress(tmp_path):
    """A uniform strain on the refined TCB beam: 8 slabs per cell at the plies' heights, and
    each slab's material-frame stress is C0 T eps of its ply, from whichever subelement holds
    the ply."""
    data = tomllib.loads((DATA / "tcb_adaptive.toml").read_text())
    data["laminate"]["angles"] = [0, 45, 90, -45, -45, 90, 45, 0]
    data["interfaces"]["symmetry"] = []
    structure = build_structure(parse_config(data))
    strain = np.array([[1e-4, 2e-5, 0.0], [2e-5, -3e-5, 1e-5], [0.0, 1e-5, 5e-5]])
    for X, u in (
        (structure.X_base, structure.base.u.x.array),
        (structure.extra.vectors["X"].array.reshape(-1, 3), structure.extra.vectors["u"].array),
    ):
        u[:] = (X @ strain.T).ravel()
    PlyWriter(tmp_path, structure)(0.0)
    piece = ET.parse(tmp_path / "plies/plies_000000.vtu").getroot().find("UnstructuredGrid/Piece")
    assert int(piece.get("NumberOfCells")) == 20 * 8
    arrays = {a.get("Name"): a for a in piece.iter("DataArray")}
    ply = decode(arrays["ply"], "<f8").astype(int)
    assert np.all(np.bincount(ply)[1:] == 20)
    points = decode(piece.find("Points/DataArray"), "<f8").reshape(-1, 8, 3)
    z = structure.laminate.ply_fractions * structure.laminate.thickness  # bottom face z = 0
    np.testing.assert_allclose(points[:, 0, 2], z[ply - 1], atol=1e-12)
    np.testing.assert_allclose(points[:, 4, 2], z[ply], atol=1e-12)
    voigt = np.array([strain[0, 0], strain[1, 1], strain[2, 2], 2 * strain[1, 2],
                      2 * strain[0, 2], 2 * strain[0, 1]])  # fmt: skip
    for k, p in enumerate(structure.laminate.plies):
        expected = p.material.stiffness() @ strain_rotation(p.angle) @ voigt
        for i, name in enumerate(STRESS_NAMES):
            values = decode(arrays[name], "<f8")[ply == k + 1]
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
