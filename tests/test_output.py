"""Output files: the enriched-mesh VTU (extra nodes and subelements visible) and the history
columns' documentation."""

import base64
import tomllib
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np

from fenics_adaptive.config import parse_config
from fenics_adaptive.explicit import COLUMNS
from fenics_adaptive.output import COLUMN_UNITS, ElementWriter
from fenics_adaptive.runner import build_structure

DATA = Path(__file__).parent / "data"


def decode(array: ET.Element, dtype: str) -> np.ndarray:
    raw = base64.b64decode(array.text)
    n = np.frombuffer(raw[:4], dtype="<u4")[0]
    return np.frombuffer(raw[4 : 4 + n], dtype=dtype)


def test_every_history_column_has_a_unit():
    assert set(COLUMN_UNITS) == set(COLUMNS)


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
