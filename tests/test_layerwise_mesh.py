"""LW reference mesh: per-layer top/bottom face groups, columnar partition, cohesive node pairs.

Units: N, mm, s, tonne (lengths in mm).
"""

import dataclasses
import json
import subprocess
import sys
from pathlib import Path

import basix.ufl
import numpy as np
import pytest
import ufl
from dolfinx import fem, mesh
from fenics_adaptive.meshes import BeamMesh, layered_mesh
from mpi4py import MPI

from fenics_adaptive.model.layerwise import cohesive_pairs

MPIEXEC = Path(sys.executable).parent / "mpiexec"
LENGTH, WIDTH, NX, NY = 10.0, 1.0, 5, 2
THICKNESSES = [0.5, 0.4, 0.3, 0.6]
SPLIT = [True, False, True]


def split_beam() -> BeamMesh:
    return layered_mesh(MPI.COMM_WORLD, LENGTH, WIDTH, NX, NY, THICKNESSES, SPLIT)


def space(beam: BeamMesh) -> fem.FunctionSpace:
    return fem.functionspace(beam.mesh, ("Lagrange", 1, (3,)))


def area(beam: BeamMesh, name: str) -> float:
    """Area of a face group, exterior (ds) and interior (dS) facets together."""
    tags = beam.face_tags[name]
    ds = ufl.Measure("ds", domain=beam.mesh, subdomain_data=beam.facet_tags)
    dS = ufl.Measure("dS", domain=beam.mesh, subdomain_data=beam.facet_tags)
    value = fem.assemble_scalar(fem.form(1.0 * ds(tags) + 1.0 * dS(tags)))
    return beam.mesh.comm.allreduce(value, op=MPI.SUM)


@pytest.mark.slow
def test_every_layer_has_top_and_bottom_face_groups_of_the_full_area():
    beam = split_beam()
    x = beam.mesh.geometry.x
    fdim = beam.mesh.topology.dim - 1
    for k in range(beam.n_layers):
        for side, z in (("bottom", beam.layer_z[k]), ("top", beam.layer_z[k + 1])):
            name = f"{side}_layer{k}"
            assert area(beam, name) == pytest.approx(LENGTH * WIDTH, rel=1e-12), name
            facets = beam.facets(name)
            assert beam.mesh.comm.allreduce(len(facets), op=MPI.SUM) == NX * NY, name
            vertices = mesh.entities_to_geometry(beam.mesh, fdim, facets)
            assert np.allclose(x[vertices, 2], z, rtol=0.0, atol=1e-12), name
    tags = beam.face_tags
    assert tags["bottom_layer0"] == tags["bottom"]
    assert tags["top_layer3"] == tags["top"]
    assert tags["top_layer1"] == tags["bottom_layer2"]  # non-split: one surface, one tag
    assert tags["top_layer0"] != tags["bottom_layer1"]  # split: two coincident surfaces
    assert tags["top_layer2"] != tags["bottom_layer3"]
    # no facet carries two tags, and every tag of a face group is present
    values = beam.facet_tags.values
    assert len(np.unique(beam.facet_tags.indices)) == len(values)
    for name in beam.face_names:
        for tag in tags[name]:
            assert beam.mesh.comm.allreduce(int(np.sum(values == tag)), op=MPI.SUM) > 0, name


def test_cohesive_pairs_join_coincident_faces_of_a_split_beam():
    beam = split_beam()
    V = space(beam)
    pairs = cohesive_pairs(beam, V)
    assert beam.mesh.comm.allreduce(len(pairs), op=MPI.SUM) == 2 * NX * NY
    assert pairs.nodes.dtype == np.int32 and pairs.nodes.shape == (len(pairs), 8)
    assert sorted(set(pairs.boundary.tolist())) == [0, 2]
    x = V.tabulate_dof_coordinates()
    lower, upper = x[pairs.nodes[:, :4]], x[pairs.nodes[:, 4:]]
    assert np.abs(upper - lower).max() < 1e-12
    assert len(np.intersect1d(pairs.nodes[:, :4], pairs.nodes[:, 4:])) == 0  # two node sets
    z_boundary = beam.layer_z[pairs.boundary + 1]
    assert np.allclose(lower[:, :, 2], z_boundary[:, None], rtol=0.0, atol=1e-12)
    cell_nodes = V.dofmap.list
    layer = np.zeros(len(cell_nodes), dtype=int)
    layer[beam.cell_tags.indices] = beam.cell_tags.values - 1
    n_owned = beam.mesh.topology.index_map(3).size_local
    assert np.all(pairs.cell < n_owned)
    assert np.array_equal(layer[pairs.cell], pairs.boundary)
    assert np.array_equal(layer[pairs.upper_cell], pairs.boundary + 1)
    # lower nodes: the lower cell's top face (vertices 4-7) in its tensor order
    assert np.array_equal(pairs.nodes[:, :4], cell_nodes[pairs.cell][:, 4:])
    # upper nodes: the bottom face of the cell above, in any order
    upper_bottom = np.sort(cell_nodes[pairs.upper_cell][:, :4], axis=1)
    assert np.array_equal(np.sort(pairs.nodes[:, 4:], axis=1), upper_bottom)
    # tensor order on the face: node 1 - node 0 along the cell's xi, node 2 - node 0 along eta
    d_xi, d_eta = lower[:, 1] - lower[:, 0], lower[:, 2] - lower[:, 0]
    assert np.all(np.cross(d_xi, d_eta)[:, 2] > 0)
    assert np.allclose(lower[:, 3] - lower[:, 0], d_xi + d_eta)


def two_cell_beam(rotate_upper: bool, split: bool = True) -> BeamMesh:
    """One column of two unit cubes, split between them; the upper cell's vertices optionally
    numbered a quarter turn round the z axis from the lower one's."""
    corners = np.array([[i & 1, (i >> 1) & 1] for i in range(4)], dtype=float)
    x = np.vstack([np.column_stack([corners, np.full(4, z)]) for z in (0.0, 1.0, 1.0, 2.0)])
    lower = np.arange(8)
    upper = np.arange(8, 16) if split else np.arange(4, 12)
    if rotate_upper:  # new vertex a at old position (1, 0), (1, 1), (0, 0), (0, 1)
        upper = upper[[1, 3, 0, 2, 5, 7, 4, 6]]
    if not split:
        x = np.delete(x, np.s_[8:12], axis=0)
    element = basix.ufl.element("Lagrange", "hexahedron", 1, shape=(3,))
    msh = mesh.create_mesh(MPI.COMM_SELF, np.array([lower, upper]), element, x)
    centre_z = msh.geometry.x[msh.geometry.dofmaps[0]].mean(axis=1)[:, 2]
    cells = np.arange(2, dtype=np.int32)
    tags = mesh.meshtags(msh, 3, cells, (centre_z > 1.0).astype(np.int32) + 1)
    facet_tags = mesh.meshtags(msh, 2, np.zeros(0, np.int32), np.zeros(0, np.int32))
    return BeamMesh(msh, tags, facet_tags, {}, 1.0, 1.0, np.array([0.0, 1.0, 2.0]), (True,))


@pytest.mark.parametrize("rotate_upper", [False, True])
def test_upper_nodes_are_matched_by_position_not_by_local_index(rotate_upper):
    beam = two_cell_beam(rotate_upper)
    V = space(beam)
    pairs = cohesive_pairs(beam, V)
    assert len(pairs) == 1
    x = V.tabulate_dof_coordinates()
    upper_bottom = V.dofmap.list[pairs.upper_cell[0], :4]
    if rotate_upper:  # the test means something: local order alone would be wrong
        assert np.abs(x[upper_bottom] - x[pairs.nodes[0, :4]]).max() > 0.5
    assert np.abs(x[pairs.nodes[0, 4:]] - x[pairs.nodes[0, :4]]).max() < 1e-12
    face = x[pairs.nodes[0, :4], :2]
    assert np.allclose(face, [[0, 0], [1, 0], [0, 1], [1, 1]], rtol=0.0, atol=1e-12)


def test_missing_partner_cell_or_unsplit_boundary_is_an_error():
    beam = split_beam()
    V = space(beam)
    # the cells of layer 1 forgotten: nothing above layer 0 any more
    keep = beam.cell_tags.values != 2
    tags = mesh.meshtags(beam.mesh, 3, beam.cell_tags.indices[keep], beam.cell_tags.values[keep])
    with pytest.raises(RuntimeError, match="no cell of layer 1 on this rank above"):
        cohesive_pairs(dataclasses.replace(beam, cell_tags=tags), V)
    # boundary 1 claimed split although the mesh shares its nodes
    with pytest.raises(RuntimeError, match="boundary 1 is marked split"):
        cohesive_pairs(dataclasses.replace(beam, split=(True, True, True)), V)
    unsplit = two_cell_beam(rotate_upper=True, split=False)
    with pytest.raises(RuntimeError, match="marked split"):
        cohesive_pairs(unsplit, space(unsplit))
    # a layer above the split lifted off it: its nodes no longer coincide
    lifted = two_cell_beam(rotate_upper=False)
    upper_cell = np.flatnonzero(lifted.cell_tags.values == 2)
    lifted.mesh.geometry.x[lifted.mesh.geometry.dofmaps[0][upper_cell], 2] += 1e-3
    with pytest.raises(RuntimeError, match="no cell of layer 1 on this rank above"):
        cohesive_pairs(lifted, space(lifted))


def test_unsplit_and_single_layer_meshes_have_no_cohesive_elements():
    for thicknesses, split in (([1.0], None), ([0.5, 0.5], [False])):
        beam = layered_mesh(MPI.COMM_WORLD, LENGTH, WIDTH, NX, NY, thicknesses, split)
        pairs = cohesive_pairs(beam, space(beam))
        assert len(pairs) == 0 and pairs.nodes.shape == (0, 8)


MPI_SCRIPT = """
import json
import sys

import numpy as np
from mpi4py import MPI
from dolfinx import fem

from fenics_adaptive.model.layerwise import cohesive_pairs
from fenics_adaptive.meshes import layered_mesh

length, width, nx, ny = {length}, {width}, {nx}, {ny}
comm = MPI.COMM_WORLD
beam = layered_mesh(comm, length, width, nx, ny, {thicknesses}, {split})
V = fem.functionspace(beam.mesh, ("Lagrange", 1, (3,)))
pairs = cohesive_pairs(beam, V)
x = V.tabulate_dof_coordinates()
gap = float(np.abs(x[pairs.nodes[:, 4:]] - x[pairs.nodes[:, :4]]).max(initial=0.0))
n_owned = beam.mesh.topology.index_map(3).size_local
centres = beam.mesh.geometry.x[beam.mesh.geometry.dofmaps[0][:n_owned]].mean(axis=1)
columns = np.round(centres[:, :2] / [length / nx, width / ny] - 0.5).astype(int)
gathered = comm.gather((columns.tolist(), len(pairs), gap), root=0)
if comm.rank == 0:
    owner = {{}}
    for rank, (cols, _, _) in enumerate(gathered):
        for column in map(tuple, cols):
            owner.setdefault(column, set()).add(rank)
    order = sorted(owner)
    json.dump(
        {{
            "columns": len(owner),
            "split_columns": sum(len(ranks) > 1 for ranks in owner.values()),
            "ranks_in_column_order": [min(owner[c]) for c in order],
            "cells": [len(cols) for cols, _, _ in gathered],
            "pairs": [n for _, n, _ in gathered],
            "gap": max(g for _, _, g in gathered),
        }},
        sys.stdout,
    )
"""


@pytest.mark.mpi
def test_two_ranks_keep_columns_together_and_find_every_cohesive_pair(tmp_path):
    nx, ny = 7, 3
    script = tmp_path / "columns.py"
    script.write_text(
        MPI_SCRIPT.format(
            length=LENGTH, width=WIDTH, nx=nx, ny=ny, thicknesses=THICKNESSES, split=SPLIT
        )
    )
    result = subprocess.run(
        [str(MPIEXEC), "-n", "2", sys.executable, str(script)],
        capture_output=True,
        text=True,
        timeout=120,
        cwd=Path(__file__).parents[1],
    )
    assert result.returncode == 0, result.stderr
    report = json.loads(result.stdout)
    serial = layered_mesh(MPI.COMM_SELF, LENGTH, WIDTH, nx, ny, THICKNESSES, SPLIT)
    assert report["columns"] == nx * ny
    assert report["split_columns"] == 0
    ranks = report["ranks_in_column_order"]
    assert ranks == sorted(ranks) and set(ranks) == {0, 1}  # contiguous blocks by (x, y)
    assert sorted(report["cells"]) == [40, 44]  # 21 columns: 11 and 10, 4 cells each
    assert all(n > 0 for n in report["pairs"])
    assert sum(report["pairs"]) == len(cohesive_pairs(serial, space(serial))) == 2 * nx * ny
    assert report["gap"] < 1e-12
