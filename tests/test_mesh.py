"""Gmsh beam/plate meshes: geometry, face groups, layers, split interfaces."""

import numpy as np
import pytest
import ufl
from dolfinx import fem
from fenics_adaptive.meshes import esl_mesh, layered_mesh
from mpi4py import MPI


def area(beam, name):
    ds = ufl.Measure("ds", domain=beam.mesh, subdomain_data=beam.facet_tags)
    value = fem.assemble_scalar(fem.form(1.0 * ds(beam.face_tags[name])))
    return beam.mesh.comm.allreduce(value, op=MPI.SUM)


@pytest.mark.slow
def test_esl_mesh_is_one_cell_through_the_thickness():
    beam = esl_mesh(MPI.COMM_WORLD, 50.0, 2.0, 10, 4, 2.048)
    x = beam.mesh.geometry.x
    assert sorted(set(np.round(x[:, 2], 12))) == [0.0, 2.048]
    cells = beam.mesh.comm.allreduce(beam.mesh.topology.index_map(3).size_local, op=MPI.SUM)
    assert cells == 40
    assert area(beam, "x0") == pytest.approx(2.0 * 2.048)
    assert area(beam, "top") == pytest.approx(100.0)
    assert area(beam, "y1") == pytest.approx(50.0 * 2.048)


@pytest.mark.slow
def test_layered_mesh_faces_per_layer_and_split_interfaces():
    thicknesses = [0.5, 0.5, 0.5, 0.5]
    beam = layered_mesh(MPI.COMM_WORLD, 10.0, 1.0, 5, 1, thicknesses, [True, False, True])
    assert beam.n_layers == 4
    for k in range(4):
        assert area(beam, f"x1_layer{k}") == pytest.approx(0.5)
    assert area(beam, "x1") == pytest.approx(2.0)
    # node planes: 5 distinct z levels, the split ones (z = 0.5, 1.5) carry two node sets
    x = beam.mesh.geometry.x
    n_local = beam.mesh.geometry.index_map().size_local
    z = np.round(x[:n_local, 2], 12)
    counts = {
        level: beam.mesh.comm.allreduce(int(np.sum(z == level)), op=MPI.SUM)
        for level in (0.0, 0.5, 1.0, 1.5, 2.0)
    }
    per_plane = 6 * 2
    assert counts == {
        0.0: per_plane,
        0.5: 2 * per_plane,
        1.0: per_plane,
        1.5: 2 * per_plane,
        2.0: per_plane,
    }


def test_bad_mesh_parameters_are_refused():
    with pytest.raises(ValueError, match="nx"):
        esl_mesh(MPI.COMM_WORLD, 10.0, 1.0, 0, 1, 1.0)
    with pytest.raises(ValueError, match="length"):
        esl_mesh(MPI.COMM_WORLD, -1.0, 1.0, 2, 1, 1.0)
