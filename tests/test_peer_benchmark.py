"""The peer benchmark (``benchmarks/peer.py`` against Akantu) compares like with like: the
Akantu side's mesh has fenics-adaptive's nodes, cuts the film and nothing else, and opens the
arms with the same history. Akantu itself is not needed here (its worker's mesh and loading are
plain numpy)."""

from pathlib import Path

import numpy as np
import pytest
from helpers import load_benchmark
from mpi4py import MPI

from fenics_adaptive.settings.config import parse_config
from fenics_adaptive.settings.loads import Amplitude
from fenics_adaptive.simulation import build_structure

pytestmark = pytest.mark.skipif(MPI.COMM_WORLD.size > 1, reason="serial benchmark helpers")


def read_msh(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """Nodes (n, 3) and hexahedra (m, 8, zero-based) of a Gmsh 2.2 ASCII file."""
    lines = path.read_text().splitlines()
    start = lines.index("$Nodes") + 2
    nodes = np.array([[float(v) for v in line.split()[1:]] for line in
                      lines[start : lines.index("$EndNodes")]])  # fmt: skip
    start = lines.index("$Elements") + 2
    hexahedra = np.array([[int(v) - 1 for v in line.split()[5:]] for line in
                          lines[start : lines.index("$EndElements")]])  # fmt: skip
    return nodes, hexahedra


def test_the_akantu_arms_open_as_the_prescribed_motion_of_fenics_adaptive():
    akantu = load_benchmark("akantu_dcb")
    velocity, rise = 857.0, 3.5e-4
    ramp = Amplitude.ramp(rise, smooth=True)
    for t in np.linspace(0.0, 3 * rise, 13):
        expected = velocity * ramp.integral(t)
        assert akantu.opening_of_one_arm(t, velocity, rise) == pytest.approx(expected, rel=1e-12)


def test_the_akantu_mesh_has_the_same_nodes_and_cuts_only_the_film(tmp_path):
    peer, akantu = load_benchmark("peer"), load_benchmark("akantu_dcb")
    nx, ny = 20, 2
    config = parse_config(peer.base_config(nx, ny))
    structure = build_structure(config)
    grid = {"L": peer.LENGTH, "W": config.mesh.width, "H": config.laminate.thickness,
            "film": peer.FILM, "nx": nx, "ny": ny, "nz": 4}  # fmt: skip
    akantu.write_mesh(tmp_path / "dcb.msh", grid)
    nodes, hexahedra = read_msh(tmp_path / "dcb.msh")
    # the same points: fenics-adaptive's base nodes (its layerwise cut doubles them as well)
    ours = {tuple(np.round(x, 9)) for x in structure.X_base}
    theirs = {tuple(np.round(x, 9)) for x in nodes}
    assert ours == theirs
    # every hexahedron positive and the beam's volume whole
    corner = nodes[hexahedra]
    edges = corner[:, [1, 3, 4]] - corner[:, [0]]
    volumes = np.einsum("ei,ei->e", edges[:, 0], np.cross(edges[:, 1], edges[:, 2]))
    assert np.all(volumes > 0)
    width, height = config.mesh.width, config.laminate.thickness
    assert volumes.sum() == pytest.approx(peer.LENGTH * width * height, rel=1e-12)
    # doubled: the mid-plane nodes over the film only (the crack tip's line shared)
    points, counts = np.unique(np.round(nodes, 9), axis=0, return_counts=True)
    doubled = points[counts == 2]
    assert len(doubled) == round(peer.FILM / (peer.LENGTH / nx)) * (ny + 1)
    assert np.allclose(doubled[:, 2], 0.5 * height)
    assert doubled[:, 0].min() > peer.LENGTH - peer.FILM
    # the two arms share no node over the film and every node over the bond
    lower, upper = hexahedra[: len(hexahedra) // 2], hexahedra[len(hexahedra) // 2 :]
    shared = np.intersect1d(lower, upper)
    assert np.all(nodes[shared, 0] <= peer.LENGTH - peer.FILM + 1e-9)
    assert len(shared) == (round((peer.LENGTH - peer.FILM) / (peer.LENGTH / nx)) + 1) * (ny + 1)
